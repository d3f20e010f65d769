"""The MAVLink vehicle against a scripted PX4 stand-in over UDP loopback: its ports, IMU delivery,
the setpoint stream, the arming/offboard/ack sequences, link loss, the real-time runner and its
final safe command. Real-time runs here last 1-2 s each."""
import logging
import math
import os
import signal
import threading
import time

import numpy as np
import pytest
from pydrake.systems.framework import DiagramBuilder, LeafSystem, PortDataType
from pydrake.systems.primitives import VectorLogSink
from pymavlink.dialects.v20 import common as mavlink

from alight.diagrams.running.run_log import ImuLogSink
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.hw import px4
from alight.hw.frames import b_to_frd, q_wb_to_nf
from alight.hw.link import CommandDenied, LinkParams, LinkTimeout, MavlinkLink
from alight.hw.mavlink_vehicle import (HW_ONLY_OUTPUTS, LINK_STATUS, MavlinkVehicleParams,
                                       command_sender, make_mavlink_vehicle)
from alight.hw.realtime import LagReporter, WallClock, run_realtime
from alight.systems import boundary
from alight.systems.boundary import FC_COMMAND, FC_STATUS, ActiveMode, Refusal
from mavlink_fake import FakeAutopilot


@pytest.fixture
def fake():
    autopilot = FakeAutopilot()
    yield autopilot
    autopilot.close()


@pytest.fixture
def link(fake):
    link = MavlinkLink.open(fake.url, LinkParams(command_timeout=0.1), WallClock())
    link.wait_for_autopilot(5.0)
    yield link
    link.close()


def command(t, arm=0.0, thrust=0.0, mode=1, q_WD=(1, 0, 0, 0), w_D=(0, 0, 0)):
    return FC_COMMAND.pack(stamp=t, mode=mode, q_WD=q_WD, w_D=w_D, thrust=thrust, arm=arm)


class CommandScript(LeafSystem):
    """Output `fc_command` = script(t), sampled every 10 ms (a stand-in onboard controller)."""

    def __init__(self, script):
        super().__init__()
        self._script = script
        state = self.DeclareDiscreteState(FC_COMMAND.size)
        self.DeclarePeriodicDiscreteUpdateEvent(0.01, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self.DeclareStateOutputPort("fc_command", state)

    def _update(self, context, discrete_state):
        discrete_state.set_value(self._script(context.get_time()))


def fly(link, script, duration, params=None, safe_stop=None):
    """Runs the MAVLink vehicle in real time driven by `script`; returns its logs."""
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(
        link, params or MavlinkVehicleParams()))
    source = builder.AddSystem(CommandScript(script))
    builder.Connect(source.get_output_port(), vehicle.GetInputPort("fc_command"))
    logs = {}
    for name, size in (("fc_status", FC_STATUS.size), ("link_status", LINK_STATUS.size),
                       ("fc_attitude", boundary.FC_ATTITUDE.size), ("range", boundary.RANGE.size)):
        logs[name] = builder.AddSystem(VectorLogSink(size, 0.004))
        builder.Connect(vehicle.GetOutputPort(name), logs[name].get_input_port())
    imu = builder.AddSystem(ImuLogSink(0.01))
    builder.Connect(vehicle.GetOutputPort("imu"), imu.get_input_port())
    diagram = builder.Build()
    simulator, report = run_realtime(diagram, duration, link.clock, safe_stop=safe_stop)
    command_sender(vehicle).wait_idle()
    context = simulator.get_context()
    out = {name: sink.FindLog(context) for name, sink in logs.items()}
    imu.ForcedPublish(imu.GetMyContextFromRoot(context))
    out["imu"] = imu.frame()
    out["report"] = report
    out["sender"] = command_sender(vehicle)
    return out


def fly_while_sending(link, stream, duration: float = 1.6):
    """`fly` idle commands while `stream()` sends from the scripted autopilot on a thread."""
    sender = threading.Thread(target=stream)
    sender.start()
    out = fly(link, lambda t: command(t), duration)
    sender.join()
    return out


def status_field(log, field):
    return log.data()[FC_STATUS.slice(field)].ravel()


def test_mavlink_vehicle_ports_match_the_simulated_vehicle(vehicle_config, link):
    sim = make_sim_vehicle(vehicle_config)
    hw = make_mavlink_vehicle(link, MavlinkVehicleParams())

    def ports(diagram, kind):
        count = diagram.num_input_ports() if kind == "in" else diagram.num_output_ports()
        get = diagram.get_input_port if kind == "in" else diagram.get_output_port
        return {get(i).get_name(): get(i) for i in range(count)}
    for kind in ("in", "out"):
        sim_ports, hw_ports = ports(sim, kind), ports(hw, kind)
        boundary_names = set(sim_ports) - set(boundary.SIM_ONLY_OUTPUTS)
        assert boundary_names == set(hw_ports) - set(HW_ONLY_OUTPUTS)
        for name in boundary_names:
            assert sim_ports[name].get_data_type() == hw_ports[name].get_data_type()
            assert sim_ports[name].size() == hw_ports[name].size()
    assert set(ports(hw, "out")) - set(ports(sim, "out")) == {"link_status"}
    sim_context, hw_context = sim.CreateDefaultContext(), hw.CreateDefaultContext()
    for diagram, context in ((sim, sim_context), (hw, hw_context)):
        diagram.GetInputPort("fc_command").FixValue(context, command(0.0))
    for name, value_type in boundary.ABSTRACT_OUTPUTS.items():
        assert hw.GetOutputPort(name).get_data_type() == PortDataType.kAbstractValued
        assert type(hw.GetOutputPort(name).Eval(hw_context)) is \
            type(sim.GetOutputPort(name).Eval(sim_context)) is value_type


def test_every_imu_sample_crosses_once_with_its_mapped_time(fake, link):
    sent = {}  # k -> (t_fc, monotonic send time)

    def stream():
        for k in range(200):
            t_fc = fake.fc_time()
            message = fake.mav.highres_imu_encode(int(t_fc * 1e6), k, 0.1, -9.81, 0.01 * k,
                                                  0.02, 0.03, 0, 0, 0, 0, 0, 0, 20.0, 0b111111)
            sent[k] = (t_fc, time.monotonic())
            if k == 120:
                late = message      # held back, sent after the next one: out of order
            else:
                fake.send(message)
            if k == 50:
                fake.send(message)  # a duplicate
            if k == 121:
                fake.send(late)
            time.sleep(0.005)
    out = fly_while_sending(link, stream)
    imu = out["imu"]
    k = np.round(imu["accel_x"].to_numpy()).astype(int)
    # Every sample once, in order; the duplicate and the late one are dropped and counted.
    assert list(k) == [i for i in range(200) if i != 120]
    assert list(imu["seq"]) == list(range(len(imu)))
    assert link.imu_out_of_order == 2
    np.testing.assert_allclose(imu[["accel_y", "accel_z"]], [[-0.1, 9.81]] * len(imu), rtol=1e-6)
    np.testing.assert_allclose(imu["gyro_x"], 0.01 * k, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(imu[["gyro_y", "gyro_z"]], [[-0.02, -0.03]] * len(imu),
                               rtol=1e-6)
    # Stamps: the autopilot's time mapped onto the onboard clock agrees with when the sample
    # left the autopilot (loopback), within 5 ms.
    t_sent = np.array([link.clock.from_monotonic(sent[i][1]) for i in k])
    assert np.max(np.abs(imu["time"].to_numpy() - t_sent)) < 5e-3
    assert np.all(np.diff(imu["time"]) > 0)


def test_the_downward_distance_sensor_is_the_range_port_stamped_on_our_clock(fake, link):
    """DISTANCE_SENSOR (cm) facing down is `range` in m with its variance; a forward one is not
    ours; a reading beyond the sensor's own maximum or of signal quality 1 is not valid."""
    R = boundary.RANGE
    sent = []

    def stream():
        for k in range(120):
            wall = time.monotonic()          # the sensor's time, on both clocks at once
            t_fc = wall - fake.start
            down = 150 + k if k < 80 else 4100          # beyond max_distance 4000 from k = 80
            fake.send(fake.mav.distance_sensor_encode(
                int(t_fc * 1e3), 5, 4000, down, mavlink.MAV_DISTANCE_SENSOR_LASER, 0,
                mavlink.MAV_SENSOR_ROTATION_PITCH_270, 4, signal_quality=100))
            fake.send(fake.mav.distance_sensor_encode(   # forward-looking: another sensor
                int(t_fc * 1e3), 5, 4000, 20, mavlink.MAV_DISTANCE_SENSOR_LASER, 1,
                mavlink.MAV_SENSOR_ROTATION_NONE, 4, signal_quality=100))
            sent.append((t_fc, wall, down))
            time.sleep(0.01)
    out = fly_while_sending(link, stream)
    log = out["range"]
    data, t = log.data().T, log.sample_times()
    valid = data[:, R.slice("valid")].ravel() > 0.5
    distance = data[:, R.slice("range")].ravel()
    seen = valid & (t > 0.2)
    assert seen.sum() > 50
    # every valid reading is one the downward sensor sent (the forward one never shows)
    downward = {round(d * 1e-2, 6) for _, _, d in sent if d <= 4000}
    assert {round(d, 6) for d in distance[seen]} <= downward
    np.testing.assert_allclose(data[seen, R.slice("var")].ravel(), 4e-4)
    # out of range at the end: the port says not valid
    assert not valid[-1] and distance[-1] == pytest.approx(41.0)
    # stamps: the sensor's time on the onboard clock, within 5 ms (its millisecond field and the
    # TIMESYNC mapping over loopback)
    stamp = data[seen, R.slice("stamp")].ravel()
    by_distance = {round(d * 1e-2, 6): link.clock.from_monotonic(wall) for _, wall, d in sent}
    expected = np.array([by_distance[round(d, 6)] for d in distance[seen]])
    assert np.max(np.abs(stamp - expected)) < 5e-3


def test_commands_stream_as_set_attitude_target_in_both_modes(fake, link):
    q_WD = np.array([np.cos(0.1), np.sin(0.1), 0, 0])  # 11.5 deg roll, y_B (left) up

    def script(t):
        if t < 0.5:
            return command(t, thrust=0.3, q_WD=q_WD)
        if t < 0.6:
            return command(np.nan, thrust=0.3)        # refused: never sent
        if t < 1.0:
            return command(t, mode=2, thrust=0.4, w_D=(0.1, 0.2, 0.3))
        return command(1.0, mode=2, thrust=0.4, w_D=(0.1, 0.2, 0.3))  # stale after 1.5 s
    start = time.monotonic()
    out = fly(link, script, 2.0)
    times = np.array([t for t, _ in fake.setpoints]) - start
    messages = [m for _, m in fake.setpoints]
    attitude = [m for m in messages if m.type_mask == 7]
    rates = [m for m in messages if m.type_mask == 128]
    assert len(attitude) + len(rates) == len(messages)
    # Streamed at the command rate (100 Hz) while fresh: 0.5 s of attitude, then the previous
    # command through the refused ones, rates from 0.6 s to the stale limit (1.0 + 0.5 s).
    assert 50 <= len(attitude) <= 65
    assert 80 <= len(rates) <= 95
    np.testing.assert_allclose(attitude[0].q, q_wb_to_nf(q_WD), atol=1e-7)
    assert attitude[0].thrust == pytest.approx(0.3)
    np.testing.assert_allclose([rates[0].body_roll_rate, rates[0].body_pitch_rate,
                                rates[0].body_yaw_rate], b_to_frd([0.1, 0.2, 0.3]), atol=1e-7)
    assert all(np.all(np.isfinite(m.q)) and math.isfinite(m.thrust) for m in messages)
    assert times[-1] - start < 1.6 + 0.15 and times[-1] > 1.35  # nothing after the stale limit
    refused = status_field(out["fc_status"], "refused")
    assert refused[-1] == 1  # one distinct refused input (held for 0.1 s)
    assert status_field(out["fc_status"], "last_refusal")[-1] == Refusal.NOT_FINITE


def test_arming_sequence_streams_then_offboard_then_arm_with_a_resend(fake, link):
    fake.answers[mavlink.MAV_CMD_COMPONENT_ARM_DISARM] = [None]  # the first ARM is lost
    start = time.monotonic()
    out = fly(link, lambda t: command(t, arm=float(0.5 <= t < 1.4)), 2.0)
    set_mode = fake.commands_named(mavlink.MAV_CMD_DO_SET_MODE)
    arms = fake.commands_named(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    assert len(set_mode) == 1 and int(set_mode[0].param2) == px4.MainMode.OFFBOARD
    assert [(m.param1, m.confirmation) for m in arms] == [(1.0, 0), (1.0, 1), (0.0, 0)]
    t_mode = next(t for t, m in fake.commands if m.command == mavlink.MAV_CMD_DO_SET_MODE)
    t_arm = [t for t, m in fake.commands if m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM]
    first_setpoint = fake.setpoints[0][0]
    assert t_mode - first_setpoint >= 0.3          # a running stream before OFFBOARD
    assert t_mode < t_arm[0] < t_arm[1] < t_mode + 0.5  # resent after the ack timeout
    armed = status_field(out["fc_status"], "armed")
    t = out["fc_status"].sample_times()
    assert armed[(t > 0.9) & (t < 1.4)].min() == 1.0 and armed[t > 1.7].max() == 0.0
    mode = status_field(out["fc_status"], "mode")
    assert set(mode[(t > 0.9) & (t < 1.4)]) == {ActiveMode.ATTITUDE_THRUST}
    assert out["sender"].denied == 0
    assert t_arm[-1] - start < 1.4 + 0.2  # the disarm followed the arm flag's fall


def test_a_denied_arm_is_a_clear_error_counted_on_link_status(fake, link):
    fake.answers[mavlink.MAV_CMD_COMPONENT_ARM_DISARM] = [
        mavlink.MAV_RESULT_TEMPORARILY_REJECTED] * 2
    fake.texts[mavlink.MAV_CMD_COMPONENT_ARM_DISARM] = "Arming denied: thrust setpoint above 0.15"
    with pytest.raises(CommandDenied, match="TEMPORARILY_REJECTED.*thrust setpoint above"):
        link.arm()
    out = fly(link, lambda t: command(t, arm=float(t >= 0.5)), 1.2)
    assert out["sender"].denied == 1 and "Arming denied" in out["sender"].last_error
    denied = out["link_status"].data()[LINK_STATUS.slice("commands_denied")].ravel()
    assert denied[-1] == 1
    assert status_field(out["fc_status"], "armed").max() == 0.0
    assert not fake.armed


def test_unanswered_commands_time_out_after_the_configured_attempts(fake, link):
    fake.answers[mavlink.MAV_CMD_NAV_LAND] = [None] * 10
    start = time.monotonic()
    with pytest.raises(LinkTimeout, match="NAV_LAND.*5 attempts"):
        link.land()
    assert len(fake.commands_named(mavlink.MAV_CMD_NAV_LAND)) == 5
    assert 0.5 <= time.monotonic() - start < 1.0  # 5 x 0.1 s


def test_link_loss_shows_on_fc_status_within_the_timeout(fake, link):
    silenced = {}

    def script(t):
        if t >= 0.6 and not silenced:
            fake.silence()
            silenced["at"] = link.clock.from_monotonic(fake.last_sent)
        return command(t)
    out = fly(link, script, 1.5)
    t = out["fc_status"].sample_times()
    alive = status_field(out["fc_status"], "link_alive")
    assert alive[(t > 0.2) & (t < 0.6)].min() == 1.0
    lost_at = t[np.argmax((t > 0.6) & (alive == 0.0))]
    delay = lost_at - silenced["at"]
    # link_timeout 0.5 s, sampled every 4 ms; 30 ms allowed for scheduling on a loaded machine.
    assert 0.45 < delay <= 0.5 + 0.004 + 0.03
    assert alive[t > lost_at].max() == 0.0


def test_final_safe_command_disarms_on_the_ground_and_lands_in_the_air(fake, link):
    assert link.safe_stop() == "disarmed: nothing to do"
    fake.armed = True
    time.sleep(0.3)
    assert link.safe_stop() == "on the ground: disarmed" and not fake.armed
    fake.armed, fake.landed_state = True, mavlink.MAV_LANDED_STATE_IN_AIR
    time.sleep(0.3)
    assert "AUTO.LAND" in link.safe_stop() and fake.custom_mode == px4.LAND


class Stall(LeafSystem):
    """Sleeps `stall` of wall time every 10 ms between t0 and t1; raises KeyboardInterrupt (a
    Ctrl-C) at `interrupt_at`."""

    def __init__(self, t0, t1, stall, interrupt_at):
        super().__init__()
        self._t0, self._t1, self._stall, self._interrupt = t0, t1, stall, interrupt_at
        self.DeclarePeriodicPublishEvent(0.01, 0.0, self._publish)

    def _publish(self, context):
        t = context.get_time()
        if self._t0 <= t < self._t1:
            time.sleep(self._stall)
        if t >= self._interrupt:
            raise KeyboardInterrupt


def test_realtime_runner_reports_overruns_and_stops_on_ctrl_c_with_the_safe_command():
    builder = DiagramBuilder()
    builder.AddSystem(Stall(0.2, 0.3, 0.03, interrupt_at=0.6))
    diagram = builder.Build()
    stops = []
    start = time.monotonic()
    simulator, report = run_realtime(diagram, 5.0, WallClock(),
                                     safe_stop=lambda: stops.append(1) or "disarmed")
    assert report.interrupted and stops == [1] and report.safe_stop == "disarmed"
    assert report.sim_time == pytest.approx(0.6, abs=0.011)
    # 10 ticks of 10 ms took 30 ms each: the run fell up to ~0.2 s behind and caught up.
    assert report.overruns >= 5 and 0.15 < report.max_lag < 0.4
    assert time.monotonic() - start < 1.5


class SendSignal(LeafSystem):
    """Sends this process `signum` once, at `at` [s] of diagram time (a real Ctrl-C / kill)."""

    def __init__(self, signum, at):
        super().__init__()
        self._signum, self._at, self.sent = signum, at, False
        self.DeclarePeriodicPublishEvent(0.01, 0.0, self._publish)

    def _publish(self, context):
        if context.get_time() >= self._at and not self.sent:
            self.sent = True
            os.kill(os.getpid(), self._signum)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_realtime_runner_stops_on_a_real_signal_within_a_tick(signum):
    """The signal arrives while Drake runs the diagram's Python systems: the runner stops at the
    next tick and sends the safe command (an exception raised by the handler inside Drake's
    AdvanceTo could be lost: a sim-autopilot once ran on for over 60 s after Ctrl-C)."""
    builder = DiagramBuilder()
    builder.AddSystem(SendSignal(signum, at=0.3))
    diagram = builder.Build()
    previous = signal.getsignal(signum)
    simulator, report = run_realtime(diagram, 5.0, WallClock(), safe_stop=lambda: "disarmed")
    assert report.interrupted and report.safe_stop == "disarmed"
    assert report.sim_time == pytest.approx(0.31, abs=0.011)
    assert signal.getsignal(signum) == previous      # the handlers are put back


def test_lateness_is_one_warning_per_period_with_the_achieved_rate(caplog):
    reporter = LagReporter(rate=1.0, period=5.0, tolerance=0.02)
    with caplog.at_level(logging.WARNING, logger="alight.hw"):
        for k in range(1, 1001):  # 10 s of ticks on time: nothing said
            assert not reporter.tick(0.01 * k, 0.0, 0.01 * k)
        late = [reporter.tick(10.0 + 0.01 * k, 0.01 * k, 10.0 + 0.02 * k)
                for k in range(1, 1001)]  # 10 s simulated in 20 s of wall time
    assert sum(late) == 998  # lag above 20 ms from the third tick on
    warnings = [r.getMessage() for r in caplog.records]
    assert reporter.warnings == len(warnings) == 3  # windows closed at 15, 20, 25 s of wall
    assert all(w.startswith("not keeping real time: 0.50 x real time over the last 5.0 s")
               for w in warnings), warnings


def test_realtime_runner_starts_when_told_and_can_be_stopped_while_waiting():
    builder = DiagramBuilder()
    builder.AddSystem(Stall(1.0, 1.0, 0.0, interrupt_at=math.inf))  # on time
    diagram = builder.Build()
    start = time.monotonic()
    go = start + 0.3
    simulator, report = run_realtime(diagram, 0.2, WallClock(),
                                     start_when=lambda: time.monotonic() >= go)
    # time 0 is the start: the 0.3 s of waiting are neither simulated nor late
    assert report.sim_time == pytest.approx(0.2) and report.overruns == 0
    assert report.wall_time == pytest.approx(0.2, abs=0.05)
    assert time.monotonic() - start > 0.45  # the 0.3 s wait, then the 0.2 s run
    previous = signal.getsignal(signal.SIGINT)
    threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
    simulator, report = run_realtime(diagram, 5.0, WallClock(), start_when=lambda: False,
                                     safe_stop=lambda: "nothing to stop")
    assert report.interrupted and report.ticks == 0 and report.safe_stop == "nothing to stop"
    assert signal.getsignal(signal.SIGINT) == previous
