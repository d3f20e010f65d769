"""The target EKF, L(5)-(10) and (28)-(35): its measurement model and gating on its own, and a
simulated pass (the geometric down camera, the camera pose from the mocap odometry source): the
hexacopter climbs to about 9 m and hovers while the target drives underneath at 5 m/s."""
import dataclasses as dc

import numpy as np
import pytest
from pydrake.common import RandomGenerator
from pydrake.math import RigidTransform, RollPitchYaw, RotationMatrix
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import VectorLogSink
from scipy.stats import chi2

from alight.diagrams.onboard.pilot import pilot_model
from alight.diagrams.onboard.mocap import add_mocap
from alight.diagrams.onboard.perception import add_target_perception, load_target_estimator_params
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.systems.boundary import GROUND_TRUTH, STATE_ESTIMATE, TARGET_ESTIMATE, CameraFrame
from alight.systems.control.scripted_pilot import ScriptedPilot
from alight.systems.perception.pattern import Pattern, load_pattern_params
from alight.systems.perception.target_estimator import (PERCEPTION_STATUS, EstimatorState,
                                                        PoseHistory, TargetEstimator)
from alight.systems.perception.target_ekf import TargetEkf
from alight.systems.rotations import quaternion_from_rotation_vector, quaternion_product
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.sensors.mocap import MocapParams
from alight.systems.target.vehicle import load_target_params
from conftest import profile

# Climb to about 9.3 m (8.3 m above the platform) and hover.
CLIMB = """
{duration: 0.5, arm: true, vertical_acceleration: -9.81}
{duration: 2.5, arm: true, vertical_acceleration: 1.5}
{duration: 2.5, arm: true, vertical_acceleration: -1.5}
{duration: 7.0, arm: true, vertical_acceleration: 0.0}
"""
SPEED = 5.0       # m/s, the target (issue 5: velocity convergence at 5 m/s)
DURATION = 12.5   # s: the target is in view from about 7 s to 11.5 s


@pytest.fixture(scope="module")
def target_pass(vehicle_config):
    return fly_pass(vehicle_config, 7)


# Climb to the landing mission's Follow height (5.2 m, 4.2 m above the platform) and hover.
CLIMB_FOLLOW = """
{duration: 0.5, arm: true, vertical_acceleration: -9.81}
{duration: 1.86, arm: true, vertical_acceleration: 1.5}
{duration: 1.86, arm: true, vertical_acceleration: -1.5}
{duration: 9.0, arm: true, vertical_acceleration: 0.0}
"""


def fly_pass(vehicle_config, seed: int, speed: float = SPEED, climb: str = CLIMB,
             duration: float = DURATION) -> dict:
    """The car passing under the hovering vehicle, its target estimate and the truth, `seed`."""
    target = load_target_params()
    target = dc.replace(target, profile="straight", initial_position=[0.0, -40.0],
                        initial_heading=90.0, straight=dc.replace(target.straight, speed=speed))
    config = dc.replace(vehicle_config, target=target,
                        down_camera=DownCameraParams(source="geometric"))
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config))
    pilot = builder.AddNamedSystem("pilot", ScriptedPilot(profile(climb),
                                                          pilot_model(config.airframe)))
    builder.Connect(pilot.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    state_estimate = add_mocap(builder, vehicle.GetOutputPort("ground_truth"), MocapParams())
    perception = add_target_perception(builder, vehicle.GetOutputPort("down_image"),
                                       state_estimate, load_target_estimator_params())
    logs = {}
    for name, port, size in (("truth", vehicle.GetOutputPort("ground_truth"), GROUND_TRUTH.size),
                             ("estimate", perception.target_estimate, TARGET_ESTIMATE.size),
                             ("status", perception.perception_status, PERCEPTION_STATUS.size)):
        logs[name] = builder.AddNamedSystem(f"log_{name}", VectorLogSink(size, 0.05))
        builder.Connect(port, logs[name].get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(seed))
    simulator.AdvanceTo(duration)
    found = {name: log.FindLog(context) for name, log in logs.items()}
    t = found["truth"].sample_times()
    truth, estimate = found["truth"].data().T, found["estimate"].data().T
    status = found["status"].data().T
    valid = TARGET_ESTIMATE.get(estimate.T, "valid") > 0.5
    t_first = t[np.argmax(valid)]
    return dict(t=t, truth=truth, estimate=estimate, status=status, t_first=t_first,
                t_last=np.nanmax(estimate[:, TARGET_ESTIMATE.slice("last_measurement")]))


def _errors(run, field):
    return run["estimate"][:, TARGET_ESTIMATE.slice(field)] - run["truth"][:, GROUND_TRUTH.slice(field)]


@pytest.mark.mission
def test_estimator_initializes_from_a_detection_and_tracks_keypoints(target_pass):
    run = target_pass
    status = run["status"][-1]
    print(f"\nfirst detection {run['t_first']:.2f} s, last measurement {run['t_last']:.2f} s, "
          f"status {dict(zip(PERCEPTION_STATUS.names(), status.round(3)))}")
    assert 6.0 < run["t_first"] < 8.0
    assert run["t_last"] > run["t_first"] + 3.0  # about 4.5 s in view at 5 m/s from 8.3 m
    assert PERCEPTION_STATUS.get(status, "initializations") == 1  # tracked throughout
    assert PERCEPTION_STATUS.get(status, "skipped") == 0


@pytest.mark.mission
def test_position_and_velocity_errors_after_convergence(target_pass):
    run = target_pass
    t = run["t"]
    converged = (t > run["t_first"] + 1.0) & (t < run["t_last"])
    dp, dv = _errors(run, "p_WT")[converged], _errors(run, "v_WT")[converged]
    rms_p, rms_v = np.sqrt(np.mean(dp ** 2, axis=0)), np.sqrt(np.mean(dv ** 2, axis=0))
    print(f"\nRMS position error {100 * rms_p.round(4)} cm, max horizontal "
          f"{100 * np.linalg.norm(dp[:, :2], axis=1).max():.1f} cm; RMS velocity error "
          f"{rms_v.round(3)} m/s, max {np.linalg.norm(dv, axis=1).max():.2f} m/s")
    # 5 px keypoint noise at about 500 px focal length from 8.3 m is 8 cm per keypoint; nine
    # keypoints per frame at 20 Hz average it down. The camera's 5 ms clock offset alone is
    # 2.5 cm along the track at 5 m/s; mocap adds 1 cm. Landing needs the platform to
    # well within its 0.75 m half side: 15 cm horizontal, 0.3 m/s.
    assert np.linalg.norm(dp[:, :2], axis=1).max() < 0.15
    assert np.abs(dp[:, 2]).max() < 0.25
    assert np.linalg.norm(dv, axis=1).max() < 0.3


@pytest.mark.mission
def test_velocity_converges_within_a_second_of_the_first_detection(target_pass):
    run = target_pass
    t = run["t"]
    speed_error = np.linalg.norm(_errors(run, "v_WT"), axis=1)
    in_view = (t >= run["t_first"]) & (t < run["t_last"])
    above = t[in_view & (speed_error > 0.5)]
    converged_after = (above.max() if len(above) else run["t_first"]) - run["t_first"]
    print(f"\nvelocity error below 0.5 m/s from {converged_after:.2f} s after the first detection")
    # The filter starts at zero velocity (5 m/s off, 5 m/s sigma) and learns it from the
    # keypoints' motion: the mission must not chase a wrong velocity for long.
    assert converged_after < 1.0


@pytest.mark.mission
def test_a_fast_car_under_the_follow_height_is_tracked_from_its_first_detection(vehicle_config):
    """A car at 6 m/s (issue 23's speeds) under the vehicle hovering at Follow's height: between
    two frames the pattern moves 37 px, more than the tracker's 30 px reach, while the filter
    just initialized does not know the car's velocity. Tracking from that prediction picked
    other keypoints, the detection's were then rejected and the filter re-initialized at zero
    velocity frame after frame (the mission braked, the car left the view); the detector finds
    the pattern until the prediction fits the tracker's window (`track_sigmas`)."""
    run = fly_pass(vehicle_config, 3, speed=6.0, climb=CLIMB_FOLLOW, duration=8.5)
    t, status = run["t"], run["status"][-1]
    speed_error = np.linalg.norm(_errors(run, "v_WT")[:, :2], axis=1)
    in_view = (t >= run["t_first"]) & (t < run["t_last"])
    above = t[in_view & (speed_error > 0.5)]
    converged_after = (above.max() if len(above) else run["t_first"]) - run["t_first"]
    print(f"\nin view {run['t_first']:.2f}-{run['t_last']:.2f} s, horizontal velocity error "
          f"under 0.5 m/s {converged_after:.2f} s after the first detection, status "
          f"{dict(zip(PERCEPTION_STATUS.names(), status.round(3)))}")
    assert run["t_last"] > run["t_first"] + 1.0      # about 1.7 s in view at 6 m/s
    assert PERCEPTION_STATUS.get(status, "initializations") == 1
    assert converged_after < 0.3


@pytest.mark.mission
def test_nees_is_not_overconfident(vehicle_config):
    """Normalized estimation error squared of position and velocity (6 dof; the output carries
    the covariance's diagonal), pooled over six seeded passes, samples 0.5 s apart (about the
    filter's correlation time) in each converged window: the mean must not exceed the 99 %
    chi-square bound (an overconfident filter would reject good keypoints and trust its
    prediction through a loss). Measured: mean NEES 2.62 (expected 6 for a consistent
    filter): the EKF, at L Sec. 5.2.2's keypoint noise of 5 px, is conservative; one pass reads
    1.5-6.0 over its 6 samples, so a one-pass two-sided test passed or failed by seed. The 5 px
    stands for more than the front end's pixel scatter (0.3 px): the camera pose the EKF is
    given (the state estimate, interpolated to the frame's stamp) has errors it does not model.
    The same six passes with `ekf.keypoint_noise_std` set (at d9c4ae3): 8 px NEES 1.78,
    position / velocity RMS 8.8 cm / 0.13 m/s; 5 px 2.62, 6.1 cm / 0.10; 4 px 3.45, 5.7 cm /
    0.10; 3 px 6.41, 7.4 cm / 0.14; 2 px 15.4, 21 cm / 1.3 m/s: consistency near 3 px costs
    accuracy, so L's 5 px stays."""
    nees = []
    for seed in (1, 2, 3, 4, 5, 7):
        run = fly_pass(vehicle_config, seed)
        t, estimate = run["t"], run["estimate"]
        samples = (t > run["t_first"] + 1.0) & (t < run["t_last"])
        samples &= np.isclose(np.mod(t, 0.5), 0.0, atol=1e-6) | np.isclose(np.mod(t, 0.5), 0.5)
        e = np.hstack([_errors(run, "p_WT"), _errors(run, "v_WT")])[samples]
        variance = np.hstack([estimate[:, TARGET_ESTIMATE.slice("var_p")],
                              estimate[:, TARGET_ESTIMATE.slice("var_v")]])[samples]
        assert samples.sum() >= 6, seed
        nees += list(np.sum(e ** 2 / variance, axis=1))
    n = len(nees)
    high = chi2.ppf(0.995, 6 * n) / n
    print(f"\nmean NEES {np.mean(nees):.2f} over {n} samples (6 dof), 99 % upper bound "
          f"{high:.2f}")
    assert np.mean(nees) <= high


@pytest.mark.mission
def test_estimate_keeps_predicting_and_covariance_grows_without_measurements(target_pass):
    run = target_pass
    t, estimate = run["t"], run["estimate"]
    after = t > run["t_last"] + 0.1
    var_p = estimate[after][:, TARGET_ESTIMATE.slice("var_p")].sum(axis=1)
    assert after.sum() >= 10 and np.all(np.diff(var_p) > 0)
    # Still predicting along the track at the estimated velocity: the position error stays
    # within the growth of its own uncertainty (3 sigma).
    dp = _errors(run, "p_WT")[after]
    assert np.all(np.linalg.norm(dp, axis=1) < 3 * np.sqrt(var_p) + 0.1)
    stamps = estimate[after][:, TARGET_ESTIMATE.slice("stamp")].ravel()
    np.testing.assert_allclose(stamps, t[after], atol=1e-9)
    # The estimator reports the time of the last accepted measurement, not the present.
    np.testing.assert_allclose(
        estimate[after][:, TARGET_ESTIMATE.slice("last_measurement")].ravel(), run["t_last"])


# --- the filter on its own ---------------------------------------------------------------------
@pytest.fixture
def ekf():
    dut = TargetEkf(load_target_estimator_params().ekf)
    dut.initialize(0.0, [1.0, 2.0, 1.0], quaternion_from_rotation_vector(np.array([0.1, -0.05, 0.7])), 8.0)
    dut.v = np.array([0.0, 5.0, 0.0])
    return dut


def _camera():
    R_WC = np.diag([1.0, -1.0, -1.0])  # looking down
    return R_WC, np.array([0.5, 1.5, 9.0]), np.array([[500.0, 0, 320], [0, 500.0, 256], [0, 0, 1]])


def test_keypoint_jacobian_matches_finite_differences(ekf):
    """H of L(33)-(35) against central differences of h (L(9), (32)) under the error state's
    own perturbation (global, multiplicative for the orientation)."""
    R_WC, p_WC, K = _camera()
    pattern = Pattern(load_pattern_params())
    for p_TK in pattern.p_TK[[0, 5, 8]]:
        H = ekf.keypoint(p_TK, R_WC, p_WC, K).H
        numeric = np.zeros((2, 9))
        for i in range(9):
            columns = []
            for sign in (1.0, -1.0):
                perturbed = TargetEkf(ekf.params)
                perturbed.t, perturbed.p, perturbed.q, perturbed.v = ekf.t, ekf.p.copy(), \
                    ekf.q.copy(), ekf.v.copy()
                delta = np.zeros(9)
                delta[i] = sign * 1e-6
                perturbed.p += delta[0:3]
                perturbed.q = quaternion_product(quaternion_from_rotation_vector(delta[3:6]),
                                                 perturbed.q)
                perturbed.v += delta[6:9]
                columns.append(perturbed.keypoint(p_TK, R_WC, p_WC, K).uv)
            numeric[:, i] = (columns[0] - columns[1]) / 2e-6
        np.testing.assert_allclose(H, numeric, atol=1e-3 * np.abs(numeric).max())


def test_a_re_initialization_keeps_a_known_velocity_and_not_an_unknown_one(ekf):
    """The car does not stop when its track is lost to wrong associations: a valid filter's
    velocity known within `reinit_keep_velocity_std` survives a re-initialization from a
    detection, with `reinit_velocity_std` (or its own std, if larger), and survives the next
    one too; the first initialization, an invalid filter and an unknown velocity start at zero
    (L Sec. 5.2.2)."""
    params = load_target_estimator_params()
    estimator = TargetEstimator(Pattern(params.pattern), params)
    state = EstimatorState(ekf, PoseHistory(1.0), valid=True)
    ekf.P[6:9, 6:9] = np.diag([0.2, 0.2, 0.2]) ** 2
    v, a, std = estimator._kept_motion(state)
    np.testing.assert_allclose(v, [0.0, 5.0, 0.0])
    assert std == params.reinit_velocity_std
    ekf.initialize(1.0, [3.0, 4.0, 1.0], [1.0, 0.0, 0.0, 0.0], 4.2, (v, a, std))
    np.testing.assert_allclose(ekf.v, [0.0, 5.0, 0.0])
    np.testing.assert_allclose(np.sqrt(np.diag(ekf.P)[6:9]), std)
    # kept once, kept again (with 0.3 m/s the second re-initialization of an 8 m/s car zeroed it)
    ekf.predict(1.1)
    v, a, std = estimator._kept_motion(state)
    np.testing.assert_allclose(v, [0.0, 5.0, 0.0])
    assert std == pytest.approx(ekf.horizontal_velocity_std) and std > params.reinit_velocity_std
    # not known well enough: zero
    ekf.P[6:9, 6:9] = np.diag([1.5 * params.reinit_keep_velocity_std] * 3) ** 2
    assert estimator._kept_motion(state) is None
    ekf.P[6:9, 6:9] = np.diag([0.2, 0.2, 0.2]) ** 2
    assert estimator._kept_motion(dc.replace(state, valid=False)) is None
    ekf.initialize(2.0, [3.0, 4.0, 1.0], [1.0, 0.0, 0.0, 0.0], 4.2)
    np.testing.assert_allclose(ekf.v, 0.0)


def test_an_odometry_correction_moves_the_target_and_the_camera_poses_with_the_vehicle(ekf):
    """The VIO's keyframe smoother moves the vehicle's current position (5-20 cm at 8 m/s) and
    says so in `p_EO`: the target, measured relative to the vehicle, moves with it, and so do the
    camera poses that frames still to come are placed with; its velocity and covariance do not
    change (before, each correction read as target motion and re-initialized the filter 2-8
    times per descent at 8 m/s). A frame switch takes the new frame's p_EO as it is."""
    params = load_target_estimator_params()
    estimator = TargetEstimator(Pattern(params.pattern), params)
    state = EstimatorState(ekf, PoseHistory(1.0), valid=True)

    def record(t, y, p_EO, frame_counter=0.0):
        estimator._record_pose(state, STATE_ESTIMATE.vector(
            stamp=t, p_EB=[0.0, y, 5.0], v_EB=[0.0, 8.0, 0.0], p_EO=p_EO,
            frame_counter=frame_counter))

    record(0.0, 0.0, [0.0, 0.0, 0.0])
    record(0.01, 0.08, [0.0, 0.0, 0.0])
    p, v, P = ekf.p.copy(), ekf.v.copy(), ekf.P.copy()
    camera_before = state.poses.at(0.005, 0.1).translation()
    correction = np.array([0.03, 0.1, -0.01])
    record(0.02, 0.16 + correction[1], correction)
    np.testing.assert_allclose(ekf.p, p + correction)
    np.testing.assert_array_equal(ekf.v, v)
    np.testing.assert_array_equal(ekf.P, P)
    np.testing.assert_allclose(state.poses.at(0.005, 0.1).translation(),
                               camera_before + correction)
    # the next estimate without a new correction moves nothing
    record(0.03, 0.24 + correction[1], correction)
    np.testing.assert_allclose(ekf.p, p + correction)
    # another source (a frame switch, M Sec. 3.5) reports its own p_EO: no shift
    record(0.04, 0.32, [0.0, 0.0, 0.0], frame_counter=1.0)
    np.testing.assert_allclose(ekf.p, p + correction)


def test_prediction_moves_at_constant_velocity_and_grows_the_covariance(ekf):
    P0 = ekf.P.copy()
    ekf.predict(0.5)
    np.testing.assert_allclose(ekf.p, [1.0, 4.5, 1.0])
    assert np.all(np.diag(ekf.P) > np.diag(P0))
    # The velocity's variance grows by sigma_vel^2 dt (the paper's 0.1 m/s/sqrt(Hz)).
    np.testing.assert_allclose(np.diag(ekf.P)[6:9] - np.diag(P0)[6:9], 0.1 ** 2 * 0.5)


def test_chi_square_gate_rejects_an_outlier_and_accepts_a_consistent_keypoint(ekf):
    R_WC, p_WC, K = _camera()
    p_TK = Pattern(load_pattern_params()).p_TK[2]
    ekf.P = np.diag([0.01] * 3 + [1e-4] * 3 + [0.01] * 3)
    prediction = ekf.keypoint(p_TK, R_WC, p_WC, K)
    p_before = ekf.p.copy()
    accepted, d2 = ekf.update(prediction, prediction.uv + [60.0, 0.0])
    assert not accepted and d2 > 9.0
    np.testing.assert_array_equal(ekf.p, p_before)  # a rejected keypoint changes nothing
    accepted, d2 = ekf.update(prediction, prediction.uv + [4.0, -3.0])
    assert accepted and d2 < 9.0
    assert not np.allclose(ekf.p, p_before)


# --- the estimator after touchdown: a lone keypoint under the camera ----------------------------
def _lone_keypoint_pass(min_keypoint_depth: float, seed: int = 0):
    """The estimator fed 3 s of 20 Hz frames from a vehicle landed on the moving target (2.4 m/s),
    the camera 14 cm above the pattern and 5 cm off its centre: only the centre keypoint (id 8)
    is in view, with 0.3 px noise, the camera pose from mocap (1 mm, 0.3 deg noise). The filter
    starts at the truth with a converged covariance. Returns (error, std) of the position per
    frame while the estimate is valid, and the frames' accepted keypoints."""
    params = dc.replace(load_target_estimator_params(), min_keypoint_depth=min_keypoint_depth)
    pattern = Pattern(load_pattern_params())
    estimator = TargetEstimator(pattern, params)
    lens = DownCameraParams(source="geometric").lens()
    rng = np.random.default_rng(seed)
    v = np.array([0.0, 2.4, 0.0])
    p_TB = np.array([-0.049, 0.012, 0.219])   # the vehicle on the platform (HIL run, 19 s)
    state = EstimatorState(TargetEkf(params.ekf), PoseHistory(params.pose_history), valid=True)
    ekf = state.ekf
    ekf.initialize(0.0, [0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0], 0.14)
    ekf.v = v.copy()
    ekf.P = np.diag([0.003 ** 2] * 2 + [0.007 ** 2] + [0.01 ** 2] * 3 + [0.05 ** 2] * 3)
    state.last_accepted = 0.0
    errors, stds, accepted = [], [], []
    for k in range(1, 61):
        t = 0.05 * k
        p_WT = np.array([0.0, 0.0, 1.0]) + v * t
        X_WB_true = RigidTransform(p_WT + p_TB)
        for dt in (-0.02, -0.01, 0.0):  # mocap samples up to the frame's stamp
            noise = RotationMatrix(RollPitchYaw(rng.normal(0.0, np.radians(0.3), 3)))
            state.poses.add(t + dt, X_WB_true.translation() + v * dt + rng.normal(0, 0.001, 3),
                            noise.ToQuaternion().wxyz(), v)
        p_CK = (X_WB_true @ RigidTransform(lens.X_BC)).inverse().multiply(p_WT)
        uv = lens.project(p_CK) + rng.normal(0.0, 0.3, 2)
        estimator.process(state, CameraFrame(stamp=t, calibration=lens.calibration(),
                                             keypoints=uv, keypoint_ids=np.array([8])))
        if state.valid:
            errors.append(ekf.p - p_WT)
            stds.append(np.sqrt(np.diag(ekf.P)[0:3]))
        accepted.append(PERCEPTION_STATUS.get(state.status, "accepted"))
    return np.array(errors), np.array(stds), np.array(accepted)


def test_a_keypoint_under_the_landed_camera_is_not_fused():
    """After touchdown (`alight hil --mission land`, the landing test of test_mavlink_ev) the
    camera 14 cm above the pattern sees its centre keypoint alone. Fused every frame, that bearing
    (1/depth: its linearization fails this close) dragged the estimate 0.8-1.1 m along the ray in
    3 s with a 3-sigma of 0.6 m; closer than `min_keypoint_depth` it is not fused, and the filter
    predicts at the target's velocity with a growing covariance until `lost_timeout` (2 s) ends
    its validity."""
    error, std, accepted = _lone_keypoint_pass(min_keypoint_depth=0.0)   # fused, as it was
    assert np.all(accepted == 1)
    assert np.mean(np.all(np.abs(error) < 3 * std, axis=1)) < 0.7
    assert np.abs(error[-1, 2]) > 0.3
    params = load_target_estimator_params()
    assert params.min_keypoint_depth > 0.14
    error, std, accepted = _lone_keypoint_pass(params.min_keypoint_depth)
    assert np.all(accepted == 0) and len(error) == 40   # valid for 2 s
    assert np.all(np.abs(error) < 3 * std) and np.abs(error).max() < 0.01


@pytest.mark.parametrize("enabled", [True, False])
def test_the_whole_frame_search_is_told_the_cameras_height_with_height_level_search(
        monkeypatch, enabled):
    """Without a target estimate, an image frame is searched whole; with `height_level_search`
    (the default) the detector gets the camera's height above the ground from the state
    estimate, so it can search at a coarser level (PatternDetector.whole_frame_level)."""
    from alight.systems.perception.detector import PatternDetector
    params = dc.replace(load_target_estimator_params(), height_level_search=enabled)
    estimator = TargetEstimator(Pattern(load_pattern_params()), params)
    heights = []
    monkeypatch.setattr(PatternDetector, "detect",
                        lambda self, frame, R_CT_reference=None, z_up_C=None, prediction=None,
                        height=None: heights.append(height) or [])
    lens = DownCameraParams(source="rendered").lens()
    state = EstimatorState(TargetEkf(params.ekf), PoseHistory(params.pose_history))
    X_WB = RigidTransform(RollPitchYaw(0.0, 0.1, 0.3), [2.0, -1.0, 4.5])
    state.poses.add(1.0, X_WB.translation(), X_WB.rotation().ToQuaternion().wxyz(), np.zeros(3))
    estimator.process(state, CameraFrame(stamp=1.0, calibration=lens.calibration(),
                                         image=np.zeros((lens.height, lens.width), np.uint8)))
    camera_height = (X_WB @ RigidTransform(lens.X_BC)).translation()[2]
    assert heights == ([pytest.approx(camera_height)] if enabled else [None])


def _turning_car_velocity_errors(ekf: TargetEkf, seconds: float = 4.0) -> np.ndarray:
    """The filter tracking the pattern of a car on the MBZIRC lobe's circle (10 m radius at
    15 km/h, heading along the track) from a camera 6 m above it at 20 Hz (1 px keypoint
    noise): its velocity error across the car's travel [m/s] at each frame after the first second
    (positive: toward the centre of the turn)."""
    rng = np.random.default_rng(0)
    radius, speed, period = 10.0, 15 / 3.6, 0.05
    rate = speed / radius
    R_WC, _, K = _camera()
    p_TK = Pattern(load_pattern_params()).p_TK
    state = lambda t: (radius * np.array([np.sin(rate * t), 1 - np.cos(rate * t), 0.0]),
                       speed * np.array([np.cos(rate * t), np.sin(rate * t), 0.0]),
                       np.array([-np.sin(rate * t), np.cos(rate * t), 0.0]))
    ekf.initialize(0.0, state(0.0)[0], quaternion_from_rotation_vector([0, 0, 0]), 6.0)
    ekf.v = state(0.0)[1].copy()
    errors = []
    for k in range(1, int(seconds / period) + 1):
        t = k * period
        p, v, inward = state(t)
        R_WT = RotationMatrix(RollPitchYaw(0.0, 0.0, rate * t)).matrix()
        ekf.predict(t)
        p_WC = p + [0.0, 0.0, 6.0]
        for point in p_TK:
            prediction = ekf.keypoint(point, R_WC, p_WC, K)
            p_CK = R_WC.T @ (p + R_WT @ point - p_WC)
            uv = K[:2, :2] @ (p_CK[:2] / p_CK[2]) + K[:2, 2] + rng.normal(0, 1.0, 2)
            ekf.update(prediction, uv)
        if t > 1.0:
            errors.append((ekf.v - v) @ inward)
    return np.array(errors)


def test_the_acceleration_state_removes_the_sideways_velocity_lag_on_a_turning_car():
    """Beyond L Sec. 5.2.2 (issue 23): the paper's constant-velocity filter lets its velocity lag
    a car turning at 1.7 m/s^2 (pointing outside the turn); with `sigma_acc` the acceleration
    state follows the turn (measured with 1 px keypoint noise: mean -0.48 m/s against -0.019)."""
    params = load_target_estimator_params().ekf
    constant_velocity = _turning_car_velocity_errors(TargetEkf(params))
    with_acceleration = _turning_car_velocity_errors(
        TargetEkf(dc.replace(params, sigma_acc=[0.3, 0.3, 0.1])))
    print(f"sideways velocity error: constant velocity {constant_velocity.mean():+.3f} m/s, "
          f"with acceleration {with_acceleration.mean():+.3f} m/s")
    assert constant_velocity.mean() < -0.3
    assert abs(with_acceleration.mean()) < 0.03
