"""The simulated autopilot: its PX4 rules on their own (offboard needs a setpoint stream, arming and
disarming conditions, offboard loss reported as AUTO.LAND), then `alight sim-autopilot` as a
process flown over MAVLink by the companion link: a refused OFFBOARD, a denied arm, a climb, and
the offboard-loss failsafe descent landing and disarming the vehicle on its own."""
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from alight.diagrams.running.run_log import read_run
from alight.hw import px4
from alight.hw.autopilot_rules import (ACCEPTED, TEMPORARILY_REJECTED, AutopilotRules,
                                       FlightMode, decode_attitude_target)
from alight.hw.frames import b_to_frd, q_wb_to_nf
from alight.hw.link import CommandDenied, LinkParams, MavlinkLink
from alight.hw.realtime import WallClock
from alight.systems.boundary import FC_COMMAND, FC_STATUS, ActiveMode, CommandMode
from mavlink_fake import SimAutopilotProcess, wait_for, realtime

ENCODER = mavlink.MAVLink(None, 1, 191)
STALE = 0.5        # models/sim_vehicle.yaml commander.stale_timeout
MAX_ARM = 0.15     # commander.max_arm_thrust
ATTITUDE_ONLY = 7  # type mask: body rates ignored
RATES_ONLY = 128   # type mask: attitude ignored


def setpoint(thrust, mask=ATTITUDE_ONLY, q_NF=(1, 0, 0, 0), rates_F=(0, 0, 0)):
    return ENCODER.set_attitude_target_encode(0, 1, 1, mask, list(q_NF), *rates_F, thrust)


def status(armed, landed, mode=None):
    mode = (ActiveMode.ATTITUDE_THRUST if armed else ActiveMode.DISARMED) if mode is None else mode
    return FC_STATUS.pack(stamp=0.0, armed=float(armed), mode=mode, link_alive=1.0,
                          last_command_stamp=0.0, refused=0, last_refusal=0, landed=float(landed))


def set_mode(rules, mode, now, fc_status):
    main, sub = px4.split_custom_mode(mode)
    return rules.command(mavlink.MAV_CMD_DO_SET_MODE,
                         [mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub, 0, 0, 0, 0], now,
                         fc_status)


def arm(rules, value, now, fc_status, force=False):
    return rules.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                         [value, px4.FORCE_DISARM if force else 0, 0, 0, 0, 0, 0], now, fc_status)


def test_setpoints_decode_into_design_frames_and_bad_ones_are_refused():
    q_WD = np.array([np.cos(0.2), 0, np.sin(0.2), 0])
    decoded = decode_attitude_target(setpoint(0.4, q_NF=q_wb_to_nf(q_WD)), None)
    assert decoded.mode == CommandMode.ATTITUDE_THRUST and decoded.thrust == pytest.approx(0.4)
    np.testing.assert_allclose(decoded.q_WD, q_WD, atol=1e-7)
    rates = decode_attitude_target(setpoint(0.5, RATES_ONLY, rates_F=b_to_frd([0.1, -0.2, 0.3])),
                                   None)
    assert rates.mode == CommandMode.RATES_THRUST
    np.testing.assert_allclose(rates.w_D, [0.1, -0.2, 0.3], atol=1e-7)
    assert decode_attitude_target(setpoint(np.nan), None) is None
    assert decode_attitude_target(setpoint(0.5, q_NF=(np.nan, 0, 0, 0)), None) is None
    assert decode_attitude_target(setpoint(0.5, RATES_ONLY | 1), None) is None  # no roll rate
    thrust_ignored = ATTITUDE_ONLY | mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
    assert decode_attitude_target(setpoint(0.9, thrust_ignored), None) is None
    assert decode_attitude_target(setpoint(0.9, thrust_ignored), decoded).thrust == \
        pytest.approx(0.4)


def test_offboard_is_refused_without_a_recent_setpoint_stream():
    rules = AutopilotRules(STALE, MAX_ARM)
    ground = status(armed=False, landed=True)
    answer = set_mode(rules, px4.OFFBOARD, 1.0, ground)
    assert answer.result == TEMPORARILY_REJECTED and "no setpoints" in answer.text
    assert rules.setpoint_received(setpoint(0.1), 1.0)
    assert set_mode(rules, px4.OFFBOARD, 1.0 + STALE - 0.01, ground).result == ACCEPTED
    late = AutopilotRules(STALE, MAX_ARM)
    late.setpoint_received(setpoint(0.1), 1.0)
    assert set_mode(late, px4.OFFBOARD, 1.0 + STALE + 0.01, ground).result == \
        TEMPORARILY_REJECTED  # the last setpoint is too old
    assert rules.command(mavlink.MAV_CMD_DO_SET_MODE, [0, 0, 0, 0, 0, 0, 0], 2.0,
                         ground).result == mavlink.MAV_RESULT_DENIED  # not a PX4 custom mode


def test_arming_and_disarming_conditions():
    rules = AutopilotRules(STALE, MAX_ARM)
    ground = status(armed=False, landed=True)
    rules.setpoint_received(setpoint(0.5), 1.0)
    assert set_mode(rules, px4.OFFBOARD, 1.0, ground).result == ACCEPTED
    denied = arm(rules, 1.0, 1.1, ground)
    assert denied.result == TEMPORARILY_REJECTED and "thrust setpoint above 0.15" in denied.text
    assert not rules.arm_request
    assert arm(rules, 1.0, 1.1 + STALE, ground).result == TEMPORARILY_REJECTED  # stream stale
    rules.setpoint_received(setpoint(0.1), 2.0)
    assert arm(rules, 1.0, 2.0, ground).result == ACCEPTED and rules.arm_request
    assert rules.fc_command(2.0, ground, np.zeros(8))[FC_COMMAND.slice("arm")] == 1.0
    flying = status(armed=True, landed=False)
    assert arm(rules, 0.0, 2.5, flying).result == TEMPORARILY_REJECTED  # not in the air
    assert rules.arm_request
    assert set_mode(rules, px4.HOLD, 2.5, flying).result == TEMPORARILY_REJECTED
    assert arm(rules, 0.0, 2.5, flying, force=True).result == ACCEPTED
    assert not rules.arm_request


def test_stream_loss_stops_forwarding_and_the_failsafe_shows_as_auto_land():
    rules = AutopilotRules(STALE, MAX_ARM)
    attitude = np.array([0.0, 1, 0, 0, 0, 0, 0, 0])
    ground = status(armed=False, landed=True)
    rules.setpoint_received(setpoint(0.1), 0.0)
    set_mode(rules, px4.OFFBOARD, 0.0, ground)
    arm(rules, 1.0, 0.0, ground)
    flying = status(armed=True, landed=False)
    for k in range(1, 50):  # a 100 Hz stream: each one forwarded, stamped on reception
        rules.setpoint_received(setpoint(0.7), 0.01 * k)
        command = rules.fc_command(0.01 * k, flying, attitude)
        assert FC_COMMAND.get(command, "stamp") == pytest.approx(0.01 * k)
        assert FC_COMMAND.get(command, "thrust") == pytest.approx(0.7)
    # The stream stops: the last setpoint keeps its reception stamp (the flight controller's own
    # stale timeout then starts its failsafe descent).
    command = rules.fc_command(1.2, flying, attitude)
    assert FC_COMMAND.get(command, "stamp") == pytest.approx(0.49)
    failsafe = status(armed=True, landed=False, mode=ActiveMode.FAILSAFE_DESCENT)
    rules.fc_command(1.3, failsafe, attitude)
    assert rules.mode == FlightMode.LAND
    base_mode, custom_mode, system_status = rules.heartbeat(failsafe)
    assert custom_mode == px4.LAND and system_status == mavlink.MAV_STATE_CRITICAL
    assert base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    rules.setpoint_received(setpoint(0.7), 1.4)
    answer = set_mode(rules, px4.OFFBOARD, 1.4, failsafe)
    assert answer.result == TEMPORARILY_REJECTED and "Landing" in answer.text
    # Landed and disarmed by the flight controller's land detector: back to Hold.
    rules.fc_command(5.0, ground, attitude)
    assert rules.mode == FlightMode.HOLD and not rules.arm_request


class Streamer:
    """Sends SET_ATTITUDE_TARGET (level attitude, `thrust`) at 50 Hz until `stop()`."""

    def __init__(self, link: MavlinkLink, thrust: float):
        self.link, self.thrust = link, thrust
        self._running = True
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self):
        while self._running:
            self.link.send_attitude_target(FC_COMMAND.pack(
                stamp=self.link.clock.now(), mode=CommandMode.ATTITUDE_THRUST, q_WD=[1, 0, 0, 0],
                w_D=np.zeros(3), thrust=self.thrust, arm=1.0))
            time.sleep(0.02)

    def stop(self):
        self._running = False
        self._thread.join()



def sleep_sim(link, duration):
    """Waits `duration` of the autopilot's clock (the simulation may run behind the wall clock)."""
    start = link.state().attitude_t_fc
    wait_for(lambda: link.state().attitude_t_fc >= start + duration, 30.0,
             f"{duration} s simulated")


@pytest.mark.mission
@realtime
def test_sim_autopilot_refuses_offboard_and_arm_then_fails_safe_when_offboard_is_lost(tmp_path):
    server = SimAutopilotProcess(tmp_path / "sim-autopilot")
    link = None
    try:
        link = MavlinkLink.open(server.url, LinkParams(), WallClock())
        link.wait_for_autopilot(20.0)
        assert set(link.request_message_rates().values()) == {"ok"}
        with pytest.raises(CommandDenied, match="TEMPORARILY_REJECTED.*no setpoints"):
            link.set_mode(px4.OFFBOARD)
        streamer = Streamer(link, thrust=0.5)
        sleep_sim(link, 0.3)
        link.set_mode(px4.OFFBOARD)
        with pytest.raises(CommandDenied, match="thrust setpoint above 0.15"):
            link.arm()
        streamer.thrust = 0.1
        sleep_sim(link, 0.1)
        link.arm()
        wait_for(lambda: link.state().armed and link.state().offboard, 10.0, "armed in OFFBOARD")
        streamer.thrust = 0.8    # climb ...
        sleep_sim(link, 1.5)
        streamer.thrust = 0.637  # ... and hover thrust
        sleep_sim(link, 0.3)
        streamer.stop()
        wait_for(lambda: link.state().custom_mode == px4.LAND, 10.0, "AUTO.LAND reported")
        wait_for(lambda: not link.state().armed, 60.0, "landed and disarmed on its own")
        assert link.counters_snapshot().malformed == 0
    finally:
        if link is not None:
            link.close()
        assert server.stop() == 0, "".join(server.output)
    run = read_run(server.run_dir)
    gt, fc_status, fc_command = run["ground_truth"], run["fc_status"], run["fc_command"]
    # The failsafe began one stale timeout after the last setpoint was received (the flight
    # controller runs at 250 Hz, the bridge every 2 ms, the logs every 10 ms).
    failsafe = fc_status["mode"].to_numpy() == ActiveMode.FAILSAFE_DESCENT
    t_failsafe = fc_status["time"].to_numpy()[np.argmax(failsafe)]
    last_setpoint = fc_command["stamp"].to_numpy()[np.searchsorted(fc_command["time"],
                                                                   t_failsafe)]
    assert failsafe.any() and STALE <= t_failsafe - last_setpoint <= STALE + 0.02
    # It flew, then came down at about the failsafe's 1 m/s and stayed down, disarmed.
    z = gt["p_WB_2"].to_numpy()
    rest = z[0]
    assert z.max() - rest > 0.5
    descent = gt[(gt["time"] > t_failsafe + 1.0) & (z > rest + 0.1)]["v_WB_2"].to_numpy()
    assert len(descent) and np.all(np.abs(descent) < 1.6)
    assert abs(z[-1] - rest) < 0.03 and fc_status["armed"].iloc[-1] == 0.0
