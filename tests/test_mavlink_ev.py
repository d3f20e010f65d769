"""External vision and landing target (issue 22): ODOMETRY and LANDING_TARGET as PX4 reads them,
the simulated PX4's EKF2 emulation fusing external vision, its Hold / offboard-loss rules, and
the MAVLink vehicle sending the onboard estimate."""
import math
import os
import threading
import time

import numpy as np
import pytest
from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.action import Action
from mavsdk.plugins.mission_raw import MissionRaw
from mavsdk.plugins.offboard import Attitude, Offboard
from mavsdk.plugins.param import Param
from mavsdk.plugins.telemetry import FlightMode as MavsdkMode, Telemetry
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import VectorLogSink
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

from alight.diagrams.running.run_log import read_run
from alight.hw import px4
from alight.hw.autopilot_rules import (ACCEPTED, TEMPORARILY_REJECTED, AutopilotRules,
                                       FlightMode, Px4RulesParams)
from alight.hw.external_vision import (decode_landing_target, decode_odometry,
                                       landing_target_message, odometry_message, quality)
from alight.hw.frame_channel import EstimateSample, FrameSubscriber, default_frame_address
from alight.hw.frames import ned_yaw_to_heading
from alight.hw.link import LinkParams, MavlinkLink
from alight.hw.mavlink_vehicle import MavlinkVehicleParams, make_mavlink_vehicle
from alight.hw.realtime import WallClock, run_realtime
from alight.systems.autopilot.ev_fusion import (LOCAL_POSITION, ExternalVisionFusion,
                                                ExternalVisionParams)
from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, STATE_ESTIMATE,
                                     TARGET_ESTIMATE, ActiveMode, ImuSamples)
from alight.systems.rotations import heading_quaternion
from alight.systems.thrust_curve import GRAVITY
from mavlink_fake import FakeAutopilot, HilProcess, SimAutopilotProcess, free_udp_port, realtime
from test_mavlink_hil import fly_hil
from test_mavlink_mavsdk import wait_for

MAV = mavlink.MAVLink(None)


def over_the_wire(message):
    [parsed] = mavlink.MAVLink(None).parse_buffer(message.pack(MAV))
    return parsed


def estimate(**fields):
    values = dict(stamp=2.5, p_EB=[1.0, 2.0, 3.0], v_EB=[0.5, -0.2, 0.1],
                  q_EB=heading_quaternion(0.7), var_pv=[1e-4] * 3 + [4e-4] * 3,
                  var_heading=1e-3, frame_counter=2)
    values.update(fields)
    return STATE_ESTIMATE.vector(**values)

def position_errors(positions, truth):
    """MAVSDK `position_velocity_ned` samples [(autopilot time s, PositionVelocityNed)] against
    the ground-truth stream: their stamps, the true NED positions there and the errors [m]."""
    t, p = truth["time"].to_numpy(), truth[["p_WB_0", "p_WB_1", "p_WB_2"]].to_numpy()
    ned = np.array([[pv.position.north_m, pv.position.east_m, pv.position.down_m]
                    for _, pv in positions])
    stamps = np.array([s for s, _ in positions])
    true_ned = np.column_stack([np.interp(stamps, t, p[:, 0]), -np.interp(stamps, t, p[:, 1]),
                                -np.interp(stamps, t, p[:, 2])])
    return stamps, true_ned, np.linalg.norm(ned - true_ned, axis=1)



def test_odometry_is_external_vision_in_frd_and_round_trips():
    sent = estimate()
    message = over_the_wire(odometry_message(MAV, sent, 2_500_000, 7,
                                             mavlink.MAV_ESTIMATOR_TYPE_VIO, quality(sent, 1.0)))
    assert (message.frame_id, message.child_frame_id) == (mavlink.MAV_FRAME_LOCAL_FRD,
                                                          mavlink.MAV_FRAME_BODY_FRD)
    assert (message.reset_counter, message.estimator_type) == (7, mavlink.MAV_ESTIMATOR_TYPE_VIO)
    assert message.quality == 99  # 1 cm std of a worst 1 m
    # z up 3 m is z down -3 m; heading 0.7 rad counter-clockwise is a NED yaw of -0.7 rad
    assert [message.x, message.y, message.z] == pytest.approx([1.0, -2.0, -3.0])
    yaw = 2 * math.atan2(message.q[3], message.q[0])
    assert ned_yaw_to_heading(yaw) == pytest.approx(0.7, abs=1e-6)
    # The body-frame velocity: forward speed of the world velocity seen at heading 0.7
    forward = 0.5 * math.cos(0.7) - 0.2 * math.sin(0.7)
    assert message.vx == pytest.approx(forward, abs=1e-6)
    assert [message.pose_covariance[i] for i in (0, 6, 11, 20)] == pytest.approx(
        [1e-4, 1e-4, 1e-4, 1e-3])
    received = decode_odometry(message)
    for field in ("p_EB", "v_EB", "q_EB", "var_pv"):
        np.testing.assert_allclose(STATE_ESTIMATE.get(received, field),
                                   STATE_ESTIMATE.get(sent, field), rtol=1e-6, atol=1e-6)
    assert STATE_ESTIMATE.get(received, "stamp") == 2.5
    assert STATE_ESTIMATE.get(received, "frame_counter") == 7
    assert STATE_ESTIMATE.get(received, "valid") == 1.0


def test_what_px4_would_not_fuse_is_refused_and_a_failed_estimate_is_invalid():
    good = odometry_message(MAV, estimate(), 1, 0, mavlink.MAV_ESTIMATOR_TYPE_VISION, 50)
    mocap = odometry_message(MAV, estimate(), 1, 0, mavlink.MAV_ESTIMATOR_TYPE_MOCAP, 50)
    body = odometry_message(MAV, estimate(), 1, 0, mavlink.MAV_ESTIMATOR_TYPE_VISION, 50,
                            frame=mavlink.MAV_FRAME_BODY_FRD)
    assert decode_odometry(over_the_wire(good)) is not None
    assert decode_odometry(over_the_wire(mocap)) is None  # PX4: the mocap topic, not EKF2's
    assert decode_odometry(over_the_wire(body)) is None   # PX4: frame not supported
    failed = estimate(valid=0.0)
    assert quality(failed, 1.0) == -1
    message = odometry_message(MAV, failed, 1, 0, mavlink.MAV_ESTIMATOR_TYPE_VISION, -1)
    assert STATE_ESTIMATE.get(decode_odometry(over_the_wire(message)), "valid") == 0.0
    assert quality(estimate(var_pv=[0.25] * 6), 1.0) == 50


def test_landing_target_is_local_ned_with_a_valid_position():
    target = TARGET_ESTIMATE.vector(p_WT=[4.0, 1.0, 0.5], q_WT=heading_quaternion(0.3), valid=1)
    vehicle = estimate(p_EB=[4.0, 1.0, 2.5], q_EB=[1.0, 0.0, 0.0, 0.0])
    message = over_the_wire(landing_target_message(MAV, target, vehicle, 123))
    assert (message.frame, message.position_valid) == (mavlink.MAV_FRAME_LOCAL_NED, 1)
    assert [message.x, message.y, message.z] == pytest.approx([4.0, -1.0, -0.5])
    assert message.distance == pytest.approx(2.0)  # straight below
    assert (message.angle_x, message.angle_y) == pytest.approx((0.0, 0.0), abs=1e-9)
    np.testing.assert_allclose(decode_landing_target(message), [4.0, 1.0, 0.5], atol=1e-6)


# --- EKF2 emulation ---------------------------------------------------------------------------

def truth(t):
    """A climbing, swaying path [m] with its velocity and acceleration."""
    p = np.array([0.5 * t, math.sin(t), 1.0 + 0.2 * t])
    v = np.array([0.5, math.cos(t), 0.2])
    a = np.array([0.0, -math.sin(t), 0.0])
    return p, v, a


class Source(LeafSystem):
    """Level IMU samples at 200 Hz measuring `truth`, and odometry at 30 Hz: truth plus noise
    (std `noise`), 20 ms old, with `events(t)` -> dict of overrides (a frame jump, a stop)."""

    def __init__(self, noise, events):
        super().__init__()
        self._noise, self._events = noise, events
        self._rng = np.random.default_rng(4)
        self._imu = self.DeclareAbstractState(AbstractValue.Make(ImuSamples.empty()))
        self._odometry = self.DeclareDiscreteState(STATE_ESTIMATE.vector(valid=0.0))
        self.DeclarePeriodicUnrestrictedUpdateEvent(0.005, 0.0, self._sample)
        self.DeclarePeriodicDiscreteUpdateEvent(1 / 30, 0.0, self._measure)
        self.DeclareStateOutputPort("imu", self._imu)
        self.DeclareStateOutputPort("odometry", self._odometry)
        self.count = 0

    def _sample(self, context, state):
        t = context.get_time()
        samples = context.get_abstract_state(self._imu).get_value()
        f_B = truth(t)[2] + [0.0, 0.0, GRAVITY]
        state.get_mutable_abstract_state(self._imu).set_value(
            samples.appended(self.count, t, f_B, np.zeros(3), 50))
        self.count += 1

    def _measure(self, context, discrete_state):
        t = context.get_time()
        events = self._events(t)
        if events.get("stopped"):
            return
        p, v, _ = truth(t - 0.02)
        p = p + events.get("offset", 0.0) + self._rng.normal(0, self._noise, 3)
        discrete_state.set_value(STATE_ESTIMATE.vector(
            stamp=t - 0.02, p_EB=p, v_EB=v, var_pv=[self._noise ** 2] * 3 + [0.01] * 3,
            frame_counter=events.get("frame", 0)))


def fuse(duration, events=lambda t: {}, params=None, noise=0.05):
    builder = DiagramBuilder()
    source = builder.AddSystem(Source(noise, events))
    fusion = builder.AddSystem(ExternalVisionFusion(params or ExternalVisionParams(
        ev_delay=0.02, noaid_tout=1.0)))
    level = builder.AddSystem(_Constant(FC_ATTITUDE.pack(stamp=0, q_WB=[1, 0, 0, 0],
                                                         w_B=np.zeros(3))))
    builder.Connect(source.GetOutputPort("imu"), fusion.GetInputPort("imu"))
    builder.Connect(source.GetOutputPort("odometry"), fusion.GetInputPort("odometry"))
    builder.Connect(level.get_output_port(), fusion.GetInputPort("fc_attitude"))
    log = builder.AddSystem(VectorLogSink(LOCAL_POSITION.size, 0.01))
    builder.Connect(fusion.GetOutputPort("local_position"), log.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration)
    data = log.FindLog(simulator.get_context()).data()
    return {name: data[LOCAL_POSITION.slice(name)].T.squeeze()
            for name, _ in LOCAL_POSITION.fields}


class _Constant(LeafSystem):
    def __init__(self, value):
        super().__init__()
        self.DeclareVectorOutputPort("y", len(value), lambda c, o: o.SetFromVector(value))


def test_fusion_follows_the_vision_within_its_noise_and_below_it():
    out = fuse(8.0)
    t = out["stamp"]
    steady = t > 1.0
    error = out["p_WB"][steady] - np.array([truth(s)[0] for s in t[steady]])
    rms = np.sqrt(np.mean(error ** 2, axis=0))
    assert np.all(rms < 0.05)  # filtered: below the 5 cm noise of each sample
    v_error = out["v_WB"][steady] - np.array([truth(s)[1] for s in t[steady]])
    assert np.all(np.sqrt(np.mean(v_error ** 2, axis=0)) < 0.05)
    assert np.all(out["valid"][steady] == 1.0)
    assert np.all(np.sqrt(out["var_p"][steady]) < 0.06)
    assert out["reset_counter"][-1] == 0 and out["rejected"][-1] == 0


def test_fusion_resets_on_a_frame_switch_gates_a_jump_and_times_out_without_vision():
    def events(t):
        if 2.0 <= t < 3.0:
            return {"offset": np.array([3.0, 0.0, 0.0])}  # a jump, same frame: gated
        if 3.0 <= t < 5.0:
            return {"offset": np.array([10.0, 0.0, 0.0]), "frame": 1}  # a new frame
        return {"stopped": True} if t >= 5.0 else {}
    out = fuse(7.0, events)
    t, x = out["stamp"], out["p_WB"][:, 0]
    jump = (t > 2.1) & (t < 2.9)
    assert np.all(np.abs(x[jump] - 0.5 * t[jump]) < 0.15)  # not pulled by the jump
    assert 24 <= out["rejected"][np.searchsorted(t, 2.9)] <= 27  # x only: 30 Hz for 0.9 s
    switched = (t > 3.1) & (t < 4.9)
    assert np.all(np.abs(x[switched] - (0.5 * t[switched] + 10.0)) < 0.15)
    assert out["reset_counter"][-1] == 1
    # Vision stops at 5 s: dead reckoning stays valid EKF2_NOAID_TOUT (1 s here), then not
    assert np.all(out["valid"][(t > 3.1) & (t < 5.9)] == 1.0)
    assert np.all(out["valid"][t > 6.1] == 0.0)


def test_no_vision_source_no_local_position():
    out = fuse(1.0, params=ExternalVisionParams(ev_ctrl=0))
    assert not np.any(out["valid"])


# --- PX4 rules --------------------------------------------------------------------------------

HOVER = 0.637


def status(armed=True, landed=False, mode=ActiveMode.ATTITUDE_THRUST):
    return FC_STATUS.vector(armed=float(armed), landed=float(landed), mode=mode)


LEVEL = FC_ATTITUDE.pack(stamp=0.0, q_WB=heading_quaternion(0.4), w_B=np.zeros(3))


def position(p=(1.0, 2.0, 3.0), v=(0.0, 0.0, 0.0), valid=True):
    return LOCAL_POSITION.vector(p_WB=p, v_WB=v, valid=float(valid))


def offboard(rules, now=0.0):
    target = MAV.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.1)
    assert rules.setpoint_received(target, now)
    assert rules.command(mavlink.MAV_CMD_DO_SET_MODE,
                         [1, px4.MainMode.OFFBOARD, 0, 0], now, status()).result == ACCEPTED


def test_hold_in_the_air_needs_a_position_and_holds_it():
    rules = AutopilotRules(0.5, 0.15, HOVER, 0.004)
    rules.fc_command(0.0, status(), LEVEL, position(valid=False))
    hold = [1, px4.MainMode.AUTO, px4.AutoSubMode.LOITER, 0]
    answer = rules.command(mavlink.MAV_CMD_DO_SET_MODE, hold, 0.0, status())
    assert answer.result == TEMPORARILY_REJECTED and "no position estimate" in answer.text
    rules.fc_command(0.01, status(), LEVEL, position())
    assert rules.command(mavlink.MAV_CMD_DO_SET_MODE, hold, 0.01, status()).result == ACCEPTED
    # At the held point, at rest: level at the held heading, hover thrust, stamped now
    command = rules.fc_command(0.02, status(), LEVEL, position())
    assert FC_COMMAND.get(command, "stamp") == 0.02
    assert FC_COMMAND.get(command, "thrust") == pytest.approx(HOVER, abs=1e-3)
    np.testing.assert_allclose(FC_COMMAND.get(command, "q_WD"), heading_quaternion(0.4),
                               atol=1e-6)
    # Below the held point: more thrust; east of it (+y in W): leaning back to -y (roll right)
    below = rules.fc_command(0.03, status(), LEVEL, position(p=(1.0, 2.0, 2.5)))
    assert FC_COMMAND.get(below, "thrust") > HOVER + 0.05
    east = rules.fc_command(0.04, status(), LEVEL, position(p=(1.0, 2.5, 3.0)))
    q = FC_COMMAND.get(east, "q_WD")
    z_D_y = 2 * (q[2] * q[3] - q[0] * q[1])  # y component of the desired body z axis
    assert z_D_y < -0.05
    # The position lost while holding: AUTO.LAND, said so
    rules.fc_command(0.05, status(), LEVEL, position(valid=False))
    assert rules.mode == FlightMode.LAND and "landing" in rules.notices[-1]


@pytest.mark.parametrize("valid, action, expected", [
    (True, 0, FlightMode.POSITION), (True, 5, FlightMode.HOLD), (True, 4, FlightMode.LAND),
    (False, 0, FlightMode.LAND), (False, 5, FlightMode.LAND)])
def test_offboard_loss_holds_with_a_position_and_lands_without(valid, action, expected):
    rules = AutopilotRules(0.5, 0.15, HOVER, 0.004, Px4RulesParams(com_obl_rc_act=action))
    offboard(rules)
    stamp = FC_COMMAND.get(rules.fc_command(0.48, status(), LEVEL, position(valid=valid)),
                           "stamp")
    assert rules.mode == FlightMode.OFFBOARD and stamp == 0.0  # the setpoint, forwarded
    command = rules.fc_command(0.495, status(), LEVEL, position(valid=valid))
    assert rules.mode == expected  # before the flight controller's own 0.5 s timeout
    if expected != FlightMode.LAND:  # held: fresh commands, the FC's link stays alive
        assert FC_COMMAND.get(command, "stamp") == 0.495
    else:
        assert FC_COMMAND.get(command, "stamp") == 0.0  # nothing new: the FC descends


def test_offboard_loss_on_the_ground_falls_back_to_hold():
    rules = AutopilotRules(0.5, 0.15, HOVER, 0.004)
    offboard(rules)
    rules.fc_command(1.0, status(armed=False, landed=True), LEVEL, position(valid=False))
    assert rules.mode == FlightMode.HOLD


def test_an_unemulated_offboard_loss_action_is_a_clear_error():
    with pytest.raises(ValueError, match="COM_OBL_RC_ACT 3"):
        Px4RulesParams(com_obl_rc_act=3)


# --- alight hil against alight sim-autopilot --------------------------------------------------

def true_at(truth, times, field, size=3):
    columns = [f"{field}_{i}" for i in range(size)]
    return np.column_stack([np.interp(times, truth["time"], truth[c]) for c in columns])


@pytest.mark.mission
@realtime
def test_hil_fly_forwards_its_estimate_and_the_autopilot_position_follows_the_truth(tmp_path):
    """`alight hil --mission fly` sends its mocap estimate as ODOMETRY; the simulated PX4's
    fused local position (what LOCAL_POSITION_NED carries) follows the true position within
    the odometry's noise (mocap: 1 mm) plus the filter's lag."""
    status, text, sim, onboard = fly_hil(tmp_path, (
        "--mission", "fly", "--waypoints", "0,0,1.5; 1,0,1.5"), duration=40.0)
    assert status == 0, text
    local = sim["local_position"]
    local = local[local["valid"] > 0.5]
    assert len(local) > 100 * 8  # valid from the first odometry on
    # While the odometry flows (after the mission ends, EKF2 dead-reckons on the IMU)
    local = local[local["time"] - local["last_fusion"] < 0.05]
    assert len(local) > 100 * 8
    realtime = sim.metadata["realtime"]
    if realtime["max_lag"] > 0.05:  # quiet: 0 overruns, max lag 7 ms; CI beside other tests:
        # 602 of 1191 ticks over, 264 ms, and its filter's errors grow
        pytest.skip(f"the simulated autopilot did not keep real time ({realtime['overruns']} "
                    f"overruns of {realtime['ticks']} ticks, max lag "
                    f"{1e3 * realtime['max_lag']:.0f} ms): its filter's accuracy is not judged")
    flying = sim["ground_truth"]
    error = local[["p_WB_0", "p_WB_1", "p_WB_2"]].to_numpy() \
        - true_at(flying, local["time"].to_numpy(), "p_WB")
    std = np.sqrt(local[["var_p_0", "var_p_1", "var_p_2"]].to_numpy())
    print("local position error p50/p99/max [m]:", np.percentile(np.abs(error), [50, 99]),
          np.abs(error).max(), "within 3 std:", np.mean(np.abs(error) < 3 * std))
    # Within the odometry noise EKF2 assumes (EKF2_EVP_NOISE 0.1 m: the reported 1 mm is
    # floored there). The filter's own covariance is optimistic (92 % of samples within 3 std
    # on every axis): it has no accelerometer-bias or attitude states, EKF2 has.
    assert np.percentile(np.linalg.norm(error, axis=1), 99) < 0.1
    times = local["time"].to_numpy()
    v_error = np.linalg.norm(local[["v_WB_0", "v_WB_1", "v_WB_2"]].to_numpy()
                             - true_at(flying, times, "v_WB"), axis=1)
    # Lift-off and touchdown change the velocity within a few ms; the filter follows them
    # with its fusion lag (0.13-0.15 m/s at lift-off, 0.4 m/s at the touchdown's impact for a
    # sample or two). Judged apart: the calm flight (true acceleration under 1 m/s^2, about
    # 3/4 of the samples) by its p99, everything by its p90.
    truth_times = flying["time"].to_numpy()
    acceleration = np.linalg.norm(np.gradient(
        flying[["v_WB_0", "v_WB_1", "v_WB_2"]].to_numpy(), truth_times, axis=0), axis=1)
    calm = np.interp(times, truth_times, acceleration) < 1.0
    print("velocity error p99 calm / p90 all [m/s]:", np.percentile(v_error[calm], 99),
          np.percentile(v_error, 90), "calm fraction", calm.mean())
    assert calm.mean() > 0.5
    # EKF2_EVV_NOISE is 0.1 m/s per axis; the emulated filter has no accelerometer-bias state,
    # so a bias of 2-3 cm/s per axis stays (seen at rest on the ground).
    assert np.percentile(v_error[calm], 99) < 0.15
    assert np.percentile(v_error, 90) < 0.12
    # One frame, no reset; few samples gated (the mocap's velocity, a filtered difference, is
    # noisier than the 0.1 m/s EKF2_EVV_NOISE it is fused with)
    seconds = local["time"].iloc[-1] - local["time"].iloc[0]
    print("resets", local["reset_counter"].max(), "rejected", local["rejected"].max(),
          "in", seconds, "s")
    assert local["reset_counter"].max() == 0
    assert local["rejected"].max() < 0.01 * 30 * 6 * seconds  # 30 Hz, 3 positions + 3 velocities



@pytest.mark.mission
@realtime
def test_mavsdk_on_the_ground_station_link_follows_a_hil_flight(tmp_path):
    """`alight hil --mission fly` flies over the companion link and forwards its estimate as
    ODOMETRY; a MAVSDK client (a ground station) on the autopilot's second link (`--gcs`) reads
    a parameter and the (empty) mission during the flight, and `position_velocity_ned`, which
    follows the ground truth within the odometry noise EKF2 assumes (0.1 m), plus the pairing of
    each position with the latest attitude time."""
    port, gcs_port = free_udp_port(), free_udp_port()
    hil = HilProcess(port, ("--mission", "fly", "--waypoints", "0,0,1.5; 1,0,1.5",
                            "--run-dir", str(tmp_path / "hil")))
    server = SimAutopilotProcess(tmp_path / "sim-autopilot", duration=40.0, port=port,
                                 frames=True, args=("--gcs", f"udp:127.0.0.1:{gcs_port}"))
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    seen = {"attitude": [], "position": []}
    try:
        assert mavsdk.add_any_connection(f"udpout://127.0.0.1:{gcs_port}") == \
            ConnectionResult.SUCCESS
        system = mavsdk.first_autopilot(15.0)
        assert system is not None
        telemetry = Telemetry(system)
        telemetry.subscribe_attitude_quaternion(lambda q, _: seen["attitude"].append(q))
        telemetry.subscribe_position_velocity_ned(lambda pv, _: seen["position"].append(
            (seen["attitude"][-1].timestamp_us * 1e-6 if seen["attitude"] else math.nan, pv)))
        # The ground station's parameter and mission requests answered during the flight
        wait_for(lambda: len(seen["position"]) > 30, 30.0, "positions")
        assert Param(system).get_param_float("MPC_THR_HOVER") == pytest.approx(0.637)
        assert MissionRaw(system).download_mission() == []
        status = hil.wait(150.0)
    finally:
        mavsdk.destroy()
        assert server.stop() == 0, "".join(server.output)
    assert status == 0, hil.text
    sim = read_run(server.run_dir)
    truth = sim["ground_truth"]
    p = truth[["p_WB_0", "p_WB_1", "p_WB_2"]].to_numpy()
    # While the odometry flows (when `alight hil` has ended, EKF2 dead-reckons on the IMU)
    last_vision = sim["local_position"]["last_fusion"].max()
    stamps, true_ned, error = position_errors(
        [(s, pv) for s, pv in seen["position"]
         if s <= last_vision and math.isfinite(pv.position.north_m)], truth)
    print(f"MAVSDK (ground-station link) position error p50 {np.median(error):.3f} p99 "
          f"{np.percentile(error, 99):.3f} m over {len(error)} samples, "
          f"{np.ptp(stamps):.1f} s; the vehicle flew {np.ptp(p[:, 0]):.2f} m x, "
          f"{np.ptp(p[:, 2]):.2f} m z")
    assert len(error) > 100 and np.ptp(stamps) > 8.0
    assert np.ptp(true_ned[:, 0]) > 0.8 and np.ptp(true_ned[:, 2]) > 1.2  # it saw the flight
    assert np.percentile(error, 99) < 0.1 + 0.04


class VisionCompanion:
    """A second companion process stand-in on its own UDP port: forwards the simulated world's
    mocap (frame channel) to the autopilot as ODOMETRY at 30 Hz while `odometry` is set, and
    streams a level hover SET_ATTITUDE_TARGET at 20 Hz while `setpoints` is set (the autopilot
    handles every client's messages; it answers its one peer, MAVSDK here)."""

    def __init__(self, port: int, frames):
        self._connection = mavutil.mavlink_connection(
            f"udpout:127.0.0.1:{port}", source_system=1, source_component=197, dialect="common")
        self._connection.mav = mavlink.MAVLink(self._connection, 1, 197)
        self._frames = frames
        self.odometry, self.setpoints, self.sent = True, False, 0
        self._running = True
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def command(self, command, *params):
        self._connection.mav.send(self._connection.mav.command_long_encode(
            1, 1, command, 0, *params, *[0.0] * (7 - len(params))))

    def _loop(self):
        mav, last, next_setpoint = self._connection.mav, -1.0, 0.0
        while self._running:
            sample = self._frames.latest("mocap")
            if self.odometry and isinstance(sample, EstimateSample) and sample.stamp > last:
                last = sample.stamp
                mav.send(odometry_message(mav, np.array(sample.value), int(sample.stamp * 1e6),
                                          0, mavlink.MAV_ESTIMATOR_TYPE_VISION,
                                          quality(np.array(sample.value), 1.0)))
                self.sent += 1
            if self.setpoints and time.monotonic() >= next_setpoint:
                mav.send(mav.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, 0.64))
                next_setpoint = time.monotonic() + 0.05
            time.sleep(1 / 30)

    def close(self):
        self._running = False
        self._thread.join(2.0)
        self._connection.close()


@pytest.mark.mission
@realtime
def test_mavsdk_sees_the_vision_position_and_px4_holds_on_offboard_stop_and_loss(tmp_path):
    """MAVSDK (the peer) flies OFFBOARD attitude setpoints while a vision companion sends the
    world's mocap as ODOMETRY: `position_velocity_ned` follows the truth; offboard.stop() (Hold)
    holds the position; an offboard loss with a valid estimate holds (COM_OBL_RC_ACT 0:
    Position), without one (vision stopped, EKF2_NOAID_TOUT 1 s here) lands."""
    server = SimAutopilotProcess(tmp_path / "sim-autopilot", frames=True, duration=90.0, args=(
        "--set", "vehicle.flight_controller.external_vision.noaid_tout: 1.0"))
    frames = FrameSubscriber(default_frame_address(str(server.port)))
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
    seen = {"attitude": [], "position": [], "mode": []}
    companion = None
    try:
        assert mavsdk.add_any_connection(f"udpout://127.0.0.1:{server.port}") == \
            ConnectionResult.SUCCESS
        system = mavsdk.first_autopilot(15.0)
        telemetry, action, offboard = Telemetry(system), Action(system), Offboard(system)

        def sim_time():
            return seen["attitude"][-1].timestamp_us * 1e-6 if seen["attitude"] else 0.0
        telemetry.subscribe_attitude_quaternion(lambda q, _: seen["attitude"].append(q))
        telemetry.subscribe_position_velocity_ned(
            lambda pv, _: seen["position"].append((sim_time(), pv)))
        telemetry.subscribe_flight_mode(lambda m, _: seen["mode"].append((sim_time(), m)))

        def sleep_sim(duration):
            start = sim_time()
            wait_for(lambda: sim_time() >= start + duration, 30.0, f"{duration} s simulated")

        def mode_is(mode):
            return bool(seen["mode"]) and seen["mode"][-1][1] == mode

        def companion_offboard():  # its ack goes to the peer: resent until the mode shows
            for _ in range(10):
                companion.command(mavlink.MAV_CMD_DO_SET_MODE, 1, px4.MainMode.OFFBOARD)
                try:
                    return wait_for(lambda: mode_is(MavsdkMode.OFFBOARD), 0.5, "OFFBOARD")
                except AssertionError:
                    pass
            raise AssertionError("OFFBOARD refused: " + "".join(server.output[-5:]))
        wait_for(lambda: seen["attitude"], 15.0, "attitude telemetry")
        companion = VisionCompanion(server.port, frames)  # after MAVSDK is the peer
        wait_for(lambda: seen["position"] and math.isfinite(seen["position"][-1][1].position
                                                            .north_m), 15.0, "a position")
        # Take off in OFFBOARD on attitude setpoints, climbing
        offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.1))
        offboard.start()
        sleep_sim(0.3)
        action.arm()
        wait_for(lambda: telemetry.armed() and mode_is(MavsdkMode.OFFBOARD), 10.0,
                 "armed in OFFBOARD")
        offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.8))
        wait_for(telemetry.in_air, 10.0, "in the air")
        sleep_sim(0.4)
        offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.64))
        sleep_sim(0.3)
        offboard.stop()  # MAVSDK asks for Hold
        wait_for(lambda: mode_is(MavsdkMode.HOLD), 5.0, "Hold")
        t_hold = sim_time()
        sleep_sim(4.0)
        # Offboard again from the companion, whose setpoints then stop: offboard loss
        companion.setpoints = True
        sleep_sim(0.5)
        companion_offboard()
        sleep_sim(0.5)
        companion.setpoints = False
        wait_for(lambda: mode_is(MavsdkMode.POSCTL), 5.0, "Position after the loss")
        t_loss = sim_time()
        sleep_sim(4.0)
        # Once more without a position: the vision stops first, then the setpoints
        companion.setpoints = True
        sleep_sim(0.5)
        companion_offboard()
        companion.odometry = False
        sleep_sim(1.5)
        t_blind = sim_time()
        companion.setpoints = False
        wait_for(lambda: mode_is(MavsdkMode.LAND), 5.0, "Land after the loss without position")
        wait_for(lambda: not telemetry.armed(), 30.0, "landed and disarmed")
    finally:
        print("modes", [(round(s, 2), m) for s, m in seen["mode"]])
        if companion is not None:
            companion.close()
        mavsdk.destroy()
        frames.close()
        assert server.stop() == 0, "".join(server.output)
    truth = read_run(server.run_dir)["ground_truth"]
    t = truth["time"].to_numpy()
    p = truth[["p_WB_0", "p_WB_1", "p_WB_2"]].to_numpy()
    # MAVSDK's position (NED) is the truth to the odometry noise EKF2 assumes (0.1 m), with
    # the telemetry's pairing to the latest attitude time (<= 20 ms at < 2 m/s)
    _, _, error = position_errors([(s, pv) for s, pv in seen["position"] if s < t_blind], truth)
    print(f"MAVSDK position error p50 {np.median(error):.3f} p99 "
          f"{np.percentile(error, 99):.3f} m over {len(error)} samples; climb "
          f"{p[:, 2].max() - p[0, 2]:.2f} m")
    assert len(error) > 100 and np.percentile(error, 99) < 0.1 + 0.04
    assert p[:, 2].max() - p[0, 2] > 1.0

    def still(start, end):  # position spread and speed over [start, end]
        window = (t >= start) & (t <= end)
        spread = np.ptp(p[window], axis=0)
        return np.linalg.norm(spread), window
    spread, _ = still(t_hold + 2.0, t_hold + 4.0)
    print(f"Hold: spread {spread:.3f} m")
    assert spread < 0.2
    spread, _ = still(t_loss + 2.0, t_loss + 4.0)
    print(f"offboard loss with a position: spread {spread:.3f} m")
    assert spread < 0.2
    # Without a position: the flight controller's descent (1 m/s), down to the ground
    v_z = truth["v_WB_2"].to_numpy()
    descending = (t > t_blind + 1.5) & (t < t_blind + 3.0)
    print(f"descent without a position: {np.median(v_z[descending]):.2f} m/s")
    assert np.median(v_z[descending]) == pytest.approx(-1.0, abs=0.15)
    assert abs(p[-1, 2] - p[0, 2]) < 0.05  # back on the ground, disarmed (above)


@pytest.mark.mission
@realtime
def test_hil_landing_sends_the_target_estimate_as_landing_target(tmp_path):
    """`alight hil --mission land` sends its target EKF's estimate as LANDING_TARGET; the
    simulated autopilot (a pymavlink receiver) logs each one PX4 would use (LOCAL_NED,
    position_valid): at 20 Hz while the EKF tracks, each the EKF's estimate at its stamp,
    within the EKF's covariance of the true target relative to the vehicle (skipped, with the
    figures, when the onboard side lagged the autopilot: the messages' age tells)."""
    scenario = ("--scenario", "scenario_field_hil.yaml", "--target-speed", "2")
    status, text, sim, onboard = fly_hil(tmp_path, ("--mission", "land", *scenario),
                                         (*scenario, "--seed", "0"), duration=60.0)
    assert status == 0, text
    received = sim["landing_target"]
    received = received[received["count"] > 0].drop_duplicates("count")
    t = received["sent"].to_numpy()  # the message's time (the estimate's, autopilot clock)
    p_WT = received[["p_WT_0", "p_WT_1", "p_WT_2"]].to_numpy()
    # The EKF's estimate at that stamp (onboard clock: autopilot time - offset): the messages
    # whose stamp the log (the mission's 20 Hz, in phase with the sender) holds carry it
    offset = onboard.metadata["autopilot_clock_offset"]
    target = onboard["target_estimate"]
    target = target[target["valid"] > 0.5]
    stamps = target["stamp"].to_numpy() + offset
    rows = np.clip(np.searchsorted(stamps, t), 1, len(target) - 1)
    rows = np.where(np.abs(stamps[rows - 1] - t) < np.abs(stamps[rows] - t), rows - 1, rows)
    logged = np.abs(stamps[rows] - t) < 1e-4
    gap = np.linalg.norm(p_WT[logged] - target[["p_WT_0", "p_WT_1", "p_WT_2"]].to_numpy()
                         [rows[logged]], axis=1)
    print(f"LANDING_TARGET: {len(t)} received over {np.ptp(t):.1f} s, {logged.sum()} at a "
          f"logged stamp: max difference {gap.max():.2e} m")
    assert logged.sum() > 0.5 * len(t) > 20 * 3 * 0.5  # seconds of tracking at 20 Hz
    assert gap.max() < 1e-4  # float32 on the wire
    assert len(t) / np.ptp(t) > 15.0
    # Against the truth: the target relative to the vehicle (the EKF's minus the vehicle's
    # estimate, 1 mm mocap) within 3 std of the EKF's own covariance, + 1 cm for the clock
    # offset's and the stamp pairing's error
    truth = sim["ground_truth"]
    std = np.sqrt(np.column_stack([np.interp(t, stamps, target[f"var_p_{i}"])
                                   for i in range(3)]))
    estimate = onboard["state_estimate"]
    p_EB = np.column_stack([np.interp(t - offset, estimate["stamp"], estimate[f"p_EB_{i}"])
                            for i in range(3)])
    error = (p_WT - p_EB) - (true_at(truth, t, "p_WT") - true_at(truth, t, "p_WB"))
    median = np.median(np.linalg.norm(error, axis=1))
    within = np.mean(np.all(np.abs(error) < 3 * std + 0.01, axis=1))
    # How late each message was used: the autopilot's time at reception minus the estimate's.
    # An onboard side that keeps up sends within a tick (measured p90 25 ms, max 37 ms);
    # one that lags the autopilot (a loaded machine) tracks frames late and its errors grow.
    age = np.percentile(received["stamp"].to_numpy() - t, 90)
    realtime = onboard.metadata["realtime"]
    print(f"onboard real time: {realtime['overruns']} overruns, max lag "
          f"{1e3 * realtime['max_lag']:.0f} ms")
    print(f"relative to the vehicle vs truth: p50 {median:.3f} m, {100 * within:.0f} % within "
          f"3 std; message age p90 {1e3 * age:.0f} ms")
    outside = ~np.all(np.abs(error) < 3 * std + 0.01, axis=1)
    if outside.any():   # where the misses are: when, how far, against which std
        worst = np.argsort(-np.max(np.abs(error) / (3 * std + 0.01), axis=1))[:5]
        print(f"outside 3 std at t = {np.round(t[outside][:10] - t[0], 2)} s after the first "
              f"message; worst error {np.round(error[worst], 3)} m, std {np.round(std[worst], 3)} m")
    if age > 0.05:  # measured: 3.5 s of age gave 0.39 m p50, 43 % within 3 std
        pytest.skip(f"the onboard side lagged the autopilot (LANDING_TARGET age p90 "
                    f"{1e3 * age:.0f} ms > 50 ms, load {os.getloadavg()[0]:.0f}): accuracy "
                    f"against the truth not judged (p50 {median:.3f} m, {100 * within:.0f} % "
                    f"within 3 std)")
    assert median < 0.06 and within > 0.85


# --- the MAVLink vehicle's ODOMETRY ---------------------------------------------------------

class EstimateScript(LeafSystem):
    """Output `state_estimate`: stamped now, at 1 m height, every 10 ms; frame 1 from 0.5 s."""

    def __init__(self):
        super().__init__()
        state = self.DeclareDiscreteState(STATE_ESTIMATE.vector(valid=0.0))
        self.DeclarePeriodicDiscreteUpdateEvent(0.01, 0.0, self._update)
        self.DeclareStateOutputPort("state_estimate", state)

    def _update(self, context, discrete_state):
        t = context.get_time()
        discrete_state.set_value(estimate(stamp=t, p_EB=[t, 0.0, 1.0],
                                          frame_counter=float(t >= 0.5)))


def test_the_mavlink_vehicle_sends_its_odometry_input_as_external_vision():
    fake = FakeAutopilot()
    link = MavlinkLink.open(fake.url, LinkParams(command_timeout=0.1), WallClock())
    try:
        link.wait_for_autopilot(5.0)
        builder = DiagramBuilder()
        vehicle = builder.AddSystem(make_mavlink_vehicle(link, MavlinkVehicleParams()))
        source = builder.AddSystem(EstimateScript())
        builder.Connect(source.get_output_port(), vehicle.GetInputPort("odometry"))
        idle = builder.AddSystem(_Constant(FC_COMMAND.pack(
            stamp=0.0, mode=1, q_WD=[1, 0, 0, 0], w_D=np.zeros(3), thrust=0.0, arm=0.0)))
        builder.Connect(idle.get_output_port(), vehicle.GetInputPort("fc_command"))
        run_realtime(builder.Build(), 1.0, link.clock)
        time_sent = [(t, m) for t, m in fake.positions if m.get_type() == "ODOMETRY"]
    finally:
        link.close()
        fake.close()
    assert 27 <= len(time_sent) <= 32  # 30 Hz for 1 s
    resets = [m.reset_counter for _, m in time_sent]
    assert resets == sorted(resets) and resets[0] == 0 and resets[-1] == 1  # the frame switch
    # On the autopilot's clock: an estimate stamped when sent arrives after its stamp, mostly
    # within milliseconds (a loaded machine delays some)
    latency = np.array([received - fake.start - m.time_usec * 1e-6 for received, m in time_sent])
    assert np.all(latency > -0.005) and np.median(latency) < 0.02 and np.all(latency < 0.5)
    for _, message in time_sent:
        assert message.z == pytest.approx(-1.0) and message.estimator_type == \
            mavlink.MAV_ESTIMATOR_TYPE_VISION
