"""A ground station connects to the simulated autopilot (hw/ground_station.py): PX4's parameter
protocol over the emulated parameters (list, read, set; read-only and out-of-range sets refused
with the unchanged value), the mission protocol with no mission; then MAVSDK (a third-party
client, as a ground station) against `alight sim-autopilot`: it finds a PX4, reads all parameters
with PX4's names and types, sets one, is refused a read-only one, downloads an empty mission and
reads telemetry; and the parameter it set changes the autopilot's behaviour (its OFFBOARD rule)."""
import json
import socket
import struct
import time

import pytest
from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.mission_raw import MissionRaw
from mavsdk.plugins.param import Param, ParamError
from mavsdk.plugins.telemetry import FlightMode, Telemetry
from pymavlink.dialects.v20 import common as mavlink

from alight.diagrams.cli import main
from alight.diagrams.cli.hil import local_autopilot
from alight.diagrams.scenario import load_scenario
from alight.hw import px4
from alight.hw.autopilot_rules import AutopilotRules
from alight.hw.ground_station import INT32, REAL32, GroundStationService, emulated_parameters
from alight.hw.link import CommandDenied, LinkParams, MavlinkLink
from alight.hw.realtime import WallClock
from alight.systems.autopilot.config import FlightControllerParams
from mavlink_fake import FrameEncoder, SimAutopilotProcess, free_udp_port, wait_for, realtime

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



def sleep_sim(link, duration):
    """Waits `duration` of the autopilot's clock (the simulation may run behind the wall clock)."""
    start = link.state().attitude_t_fc
    wait_for(lambda: link.state().attitude_t_fc >= start + duration, 30.0, f"{duration} s")


@pytest.mark.mission
@realtime
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


class UdpClient:
    """A MAVLink client on its own UDP socket (`mavlink1`: sends MAVLink 1 frames, as pymavlink
    by default); `receive(seconds)` -> [(version, message)] of what came in meanwhile."""

    def __init__(self, port: int, system: int, component: int, mavlink1: bool):
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.settimeout(0.05)
        self.address, self.mavlink1 = ("127.0.0.1", port), mavlink1
        self.encoder = FrameEncoder(system, component)
        self.mav = self.encoder.mav

    def send(self, message):
        self.encoder._data = bytearray()
        self.mav.send(message, force_mavlink1=self.mavlink1)
        self.socket.sendto(bytes(self.encoder._data), self.address)

    def receive(self, seconds: float) -> list:
        got, deadline = [], time.monotonic() + seconds
        while time.monotonic() < deadline:
            try:
                data = self.socket.recv(65535)
            except TimeoutError:
                continue
            parser = mavlink.MAVLink(None)
            parser.robust_parsing = True
            got += [(1 if m.get_msgbuf()[0] == mavlink.PROTOCOL_MARKER_V1 else 2, m)
                    for m in parser.parse_buffer(data) or [] if m.get_type() != "BAD_DATA"]
        return got

    def close(self):
        self.socket.close()


def kinds(received) -> set:
    return {m.get_type() for _, m in received}


@pytest.mark.mission
@realtime
def test_a_ground_station_link_beside_the_companion_link(tmp_path):
    """`alight sim-autopilot --gcs`: a second MAVLink instance, as PX4 SITL's 14550 beside 14540.
    Each link has its own peer (a valid frame names it; another address is not answered), its own
    MAVLink version (MAVLink 1 ground station, MAVLink 2 companion), its own stream rates (an
    ATTITUDE stream stopped on the companion link still flows to the ground station); parameter,
    mission and command requests are answered on the link they came on only."""
    gcs_port = free_udp_port()
    server = SimAutopilotProcess(tmp_path / "sim-autopilot", duration=60.0,
                                 args=("--gcs", f"udp:127.0.0.1:{gcs_port}"))
    companion = UdpClient(server.port, 1, mavlink.MAV_COMP_ID_ONBOARD_COMPUTER, mavlink1=False)
    gcs = UdpClient(gcs_port, 255, 190, mavlink1=True)
    stranger = UdpClient(gcs_port, 254, 190, mavlink1=False)
    heartbeat = (mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    try:
        companion.send(companion.mav.heartbeat_encode(*heartbeat))
        gcs.send(gcs.mav.heartbeat_encode(*heartbeat))
        time.sleep(0.3)
        stranger.send(stranger.mav.heartbeat_encode(*heartbeat))  # the gcs link has its peer
        on_companion, on_gcs = companion.receive(1.5), gcs.receive(0.1)
        assert {"HEARTBEAT", "ATTITUDE", "HIGHRES_IMU"} <= kinds(on_companion) & kinds(on_gcs)
        assert {v for v, _ in on_companion} == {2} and {v for v, _ in on_gcs} == {1}
        assert stranger.receive(0.2) == []
        # Stop ATTITUDE on the companion link only
        companion.send(companion.mav.command_long_encode(
            1, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mavlink.MAVLINK_MSG_ID_ATTITUDE, -1,
            0, 0, 0, 0, 0))
        # The ground station asks for a parameter, the mission and the autopilot's version
        gcs.send(gcs.mav.param_request_read_encode(1, 1, b"MPC_THR_HOVER", -1))
        gcs.send(gcs.mav.mission_request_list_encode(1, 1, 0))
        gcs.send(gcs.mav.command_long_encode(1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
                                             mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
                                             0, 0, 0, 0, 0, 0))
        time.sleep(0.5)  # the stop takes effect
        companion.receive(0.05)
        on_companion, on_gcs = companion.receive(1.0), gcs.receive(0.1)
        gcs_messages = {m.get_type(): m for _, m in on_gcs}
        assert gcs_messages["PARAM_VALUE"].param_value == pytest.approx(0.637)
        assert gcs_messages["MISSION_COUNT"].count == 0
        assert gcs_messages["COMMAND_ACK"].command == mavlink.MAV_CMD_REQUEST_MESSAGE
        assert gcs_messages["COMMAND_ACK"].result == mavlink.MAV_RESULT_ACCEPTED
        assert "AUTOPILOT_VERSION" in gcs_messages and "ATTITUDE" in gcs_messages
        assert {v for v, _ in on_gcs} == {1}
        assert not {"PARAM_VALUE", "MISSION_COUNT", "COMMAND_ACK", "AUTOPILOT_VERSION",
                    "ATTITUDE"} & kinds(on_companion)
        assert {"HEARTBEAT", "ATTITUDE_QUATERNION"} <= kinds(on_companion)
    finally:
        for client in (companion, gcs, stranger):
            client.close()
        assert server.stop() == 0, "".join(server.output)
    statistics = json.loads(server.stats.read_text())
    assert statistics["gcs_link"]["messages_v1"] >= 4 and statistics["link"]["messages_v1"] == 0


@pytest.mark.mission
def test_hil_local_passes_the_ground_station_link_on(tmp_path):
    """`alight hil --local --gcs URL` starts its simulated autopilot with that second link: a
    ground station there (MAVLink 1) starts the simulation and gets the PX4 HEARTBEAT."""
    gcs_port = free_udp_port()
    with local_autopilot(load_scenario("hover"), 1.0, str(tmp_path / "run"),
                         gcs=f"udp:127.0.0.1:{gcs_port}"):
        gcs = UdpClient(gcs_port, 255, 190, mavlink1=True)
        try:
            gcs.send(gcs.mav.heartbeat_encode(mavlink.MAV_TYPE_GCS,
                                              mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))
            heartbeats = [(v, m) for v, m in gcs.receive(3.0) if m.get_type() == "HEARTBEAT"]
        finally:
            gcs.close()
    assert heartbeats and {v for v, _ in heartbeats} == {1}
    assert {m.autopilot for _, m in heartbeats} == {mavlink.MAV_AUTOPILOT_PX4}
    assert json.loads((tmp_path / "run-sim-autopilot" / "metadata.json").read_text())["gcs"] \
        == f"udp:127.0.0.1:{gcs_port}"


def test_hil_gcs_needs_local(capsys):
    assert main(["hil", "--connect", "udp:127.0.0.1:9", "--gcs", "udp:127.0.0.1:14550"]) == 2
    assert "--gcs goes with --local" in capsys.readouterr().err
