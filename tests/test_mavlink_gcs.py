"""A ground station connects to the simulated autopilot (hw/ground_station.py): PX4's parameter
protocol over the emulated parameters (list, read, set; read-only and out-of-range sets refused
with the unchanged value), the mission protocol with no mission; then MAVSDK (a third-party
client, as a ground station) against `alight sim-autopilot`: it finds a PX4, reads all parameters
with PX4's names and types, sets one, is refused a read-only one, downloads an empty mission and
reads telemetry; and the parameter it set changes the autopilot's behaviour (its OFFBOARD rule)."""
import struct
import time

import pytest
from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.mission_raw import MissionRaw
from mavsdk.plugins.param import Param, ParamError
from mavsdk.plugins.telemetry import FlightMode, Telemetry
from pymavlink.dialects.v20 import common as mavlink

from alight.hw import px4
from alight.hw.autopilot_rules import AutopilotRules
from alight.hw.ground_station import INT32, REAL32, GroundStationService, emulated_parameters
from alight.hw.link import CommandDenied, LinkParams, MavlinkLink
from alight.hw.realtime import WallClock
from alight.systems.autopilot.config import FlightControllerParams
from mavlink_fake import FrameEncoder, SimAutopilotProcess

GCS = FrameEncoder(255, 190)


def service():
    flight_controller = FlightControllerParams()
    rules = AutopilotRules(flight_controller.commander.stale_timeout, 0.15)
    encoder = FrameEncoder(1, 1)
    return GroundStationService(emulated_parameters(flight_controller, rules, 1, 1),
                                encoder.mav), flight_controller, rules


def received(message):
    """`message` as the autopilot receives it from the ground station (sent, then parsed)."""
    [parsed] = mavlink.MAVLink(None).parse_buffer(GCS.frame(message))
    return parsed


def ask(gcs, kind, *fields):
    """The service's answer to a `kind` message with `fields` from the ground station."""
    return gcs.answer(received(getattr(GCS.mav, f"{kind}_encode")(*fields)))


def param_set(name, value, kind=REAL32):
    return received(GCS.mav.param_set_encode(1, 1, name.encode(), value, kind))


def test_parameters_list_read_and_set_change_the_emulation_they_name():
    gcs, flight_controller, rules = service()
    listed = ask(gcs, "param_request_list", 1, 1)
    names = [m.param_id for m in listed]
    assert names == sorted(names) and {"MPC_THR_HOVER", "COM_OF_LOSS_T", "MC_ROLL_P",
                                       "MC_YAWRATE_MAX", "MAV_SYS_ID"} <= set(names)
    assert [m.param_index for m in listed] == list(range(len(listed)))
    assert {m.param_count for m in listed} == {len(listed)}
    values = {m.param_id: m for m in listed}
    assert values["MPC_THR_HOVER"].param_value == pytest.approx(0.637)
    assert values["MC_ROLLRATE_MAX"].param_value == pytest.approx(3.8 * 180 / 3.141592653589793)
    assert values["MAV_SYS_ID"].param_type == INT32
    assert struct.pack("<f", values["MAV_SYS_ID"].param_value) == struct.pack("<i", 1)
    by_name = ask(gcs, "param_request_read", 1, 1, b"COM_OF_LOSS_T", -1)
    by_index = ask(gcs, "param_request_read", 1, 1, b"", names.index("COM_OF_LOSS_T"))
    assert [m.param_value for m in by_name + by_index] == pytest.approx([0.5, 0.5])
    assert ask(gcs, "param_request_read", 1, 1, b"NO_SUCH", -1) == []
    # A writable parameter changes the objects the running emulation reads
    [answer] = gcs.answer(param_set("COM_OF_LOSS_T", 1.5))
    assert answer.param_value == pytest.approx(1.5)
    assert flight_controller.commander.stale_timeout == pytest.approx(1.5)
    assert rules.stale_timeout == pytest.approx(1.5)
    gcs.answer(param_set("MC_PITCH_P", 4.0))
    assert flight_controller.attitude.gain == pytest.approx([6.0, 4.0, 2.8])
    gcs.answer(param_set("MPC_TILTMAX_AIR", 20.0))
    assert rules.params.hold.tiltmax_air == 20.0
    [answer] = gcs.answer(param_set("COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", 5))[0],
                                    INT32))
    assert rules.params.com_obl_rc_act == 5 and isinstance(rules.params.com_obl_rc_act, int)
    assert struct.pack("<f", answer.param_value) == struct.pack("<i", 5)
    # Refused: read-only, out of range, wrong type, not emulated; each with a STATUSTEXT and the
    # unchanged value
    five = struct.unpack("<f", struct.pack("<i", 5))[0]
    for name, value, kind, why, before in (
            ("MPC_THR_HOVER", 0.5, REAL32, "read-only", 0.637),
            ("COM_OF_LOSS_T", 99.0, REAL32, "outside [0.01, 10]", 1.5),
            ("COM_DISARM_LAND", 1.0, INT32, "type", 2.0),
            ("COM_OBL_RC_ACT", struct.unpack("<f", struct.pack("<i", 3))[0], INT32,
             "3 not in [0, 4, 5]", five)):
        text, unchanged = gcs.answer(param_set(name, value, kind))
        assert text.get_type() == "STATUSTEXT" and why in text.text and name in text.text
        assert unchanged.param_id == name
        assert struct.pack("<f", unchanged.param_value) == struct.pack("<f", before)
    assert flight_controller.commander.hover_thrust == 0.637
    assert flight_controller.commander.stale_timeout == pytest.approx(1.5)
    assert flight_controller.commander.land_time == 2.0 and rules.params.com_obl_rc_act == 5


def test_the_mission_protocol_answers_no_mission():
    gcs, _, _ = service()
    [count] = ask(gcs, "mission_request_list", 1, 1, 0)
    assert count.get_type() == "MISSION_COUNT" and count.count == 0
    assert (count.target_system, count.target_component) == (255, 190)
    [ack] = ask(gcs, "mission_count", 1, 1, 3, 0)
    assert ack.type == mavlink.MAV_MISSION_UNSUPPORTED
    [ack] = ask(gcs, "mission_clear_all", 1, 1, 0)
    assert ack.type == mavlink.MAV_MISSION_ACCEPTED


def wait_for(condition, timeout, what):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.02)
    raise AssertionError(f"not within {timeout} s: {what}")


def sleep_sim(link, duration):
    """Waits `duration` of the autopilot's clock (the simulation may run behind the wall clock)."""
    start = link.state().attitude_t_fc
    wait_for(lambda: link.state().attitude_t_fc >= start + duration, 30.0, f"{duration} s")


@pytest.mark.mission
def test_mavsdk_as_a_ground_station_reads_and_sets_parameters_and_finds_no_mission(tmp_path):
    server = SimAutopilotProcess(tmp_path / "sim-autopilot", duration=60.0)
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        assert mavsdk.add_any_connection(f"udpout://127.0.0.1:{server.port}") == \
            ConnectionResult.SUCCESS
        system = mavsdk.first_autopilot(15.0)
        assert system is not None
        param, mission, telemetry = Param(system), MissionRaw(system), Telemetry(system)
        everything = param.get_all_params()
        floats = {p.name: p.value for p in everything.float_params}
        ints = {p.name: p.value for p in everything.int_params}
        assert floats["MPC_THR_HOVER"] == pytest.approx(0.637)
        assert floats["COM_OF_LOSS_T"] == pytest.approx(0.5)
        assert ints["MAV_SYS_ID"] == 1 and ints["SYS_HITL"] == 1
        param.set_param_float("COM_OF_LOSS_T", 1.5)
        assert param.get_param_float("COM_OF_LOSS_T") == pytest.approx(1.5)
        with pytest.raises(ParamError):
            param.set_param_float("MPC_THR_HOVER", 0.5)
        assert param.get_param_float("MPC_THR_HOVER") == pytest.approx(0.637)
        assert mission.download_mission() == []
        wait_for(lambda: telemetry.flight_mode() == FlightMode.HOLD, 10.0, "Hold")
        assert not telemetry.armed()
    finally:
        mavsdk.destroy()
    # The set COM_OF_LOSS_T is the autopilot's: a setpoint 1 s old still counts as a stream for
    # OFFBOARD (with the default 0.5 s it is refused), one 1.7 s old does not. A new client after
    # the peer timeout.
    time.sleep(3.2)
    link = MavlinkLink.open(server.url, LinkParams(), WallClock())
    try:
        link.wait_for_autopilot(10.0)
        wait_for(lambda: link.state().attitude_valid, 5.0, "attitude telemetry")
        setpoint = link.mav.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.1)
        link.send(setpoint)
        sleep_sim(link, 1.0)
        link.set_mode(px4.OFFBOARD)  # raises CommandDenied with the default timeout
        wait_for(lambda: link.state().offboard, 5.0, "OFFBOARD")
        link.set_mode(px4.HOLD)
        link.send(setpoint)
        sleep_sim(link, 1.7)  # older than the set timeout: no stream
        with pytest.raises(CommandDenied, match="no setpoints"):
            link.set_mode(px4.OFFBOARD)
    finally:
        link.close()
        assert server.stop() == 0, "".join(server.output)
