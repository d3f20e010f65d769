"""VIO parts on their own (issue 8): virtual stereo L(2), and the system fed by hand: initialization
from rest, a frame without features, a rendered frame with no texture."""
import dataclasses as dc

import numpy as np
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.systems.analysis import Simulator

from alight.systems.boundary import STATE_ESTIMATE, CameraFrame, ImuSamples
from alight.systems.sensors.rgbd_camera import (GeometricRgbdCamera, RgbdCameraParams,
                                                depth_noise_std, occluded, ray_depth)
from alight.systems.sensors.rgbd_camera_map import LandmarkMap, LandmarkMapParams
from alight.systems.vio.estimator import VioParams, VioStatus
from alight.systems.vio.frontend import FrontendParams, Keypoints, KltTracker, virtual_stereo
from alight.systems.vio.odometry import VIO_ODOMETRY, VisualInertialOdometry


def test_virtual_stereo_is_the_rgb_camera_shifted_by_the_baseline():
    K = np.array([[460.0, 0, 319.5], [0, 460.0, 239.5], [0, 0, 1]])
    p_C = np.array([[0.4, -0.2, 2.0], [-1.0, 0.5, 5.0]])
    uv = p_C[:, :2] / p_C[:, 2:] * 460.0 + [319.5, 239.5]
    u_virtual, back = virtual_stereo(uv, p_C[:, 2], K, 0.1)
    np.testing.assert_allclose(back, p_C, atol=1e-12)
    np.testing.assert_allclose(u_virtual, uv[:, 0] - 460.0 * 0.1 / p_C[:, 2])  # disparity f b / z
    u_missing, _ = virtual_stereo(uv, np.array([np.nan, 5.0]), K, 0.1)
    assert np.isnan(u_missing[0]) and np.isfinite(u_missing[1])


def test_depth_noise_grows_with_the_square_of_range():
    sigma = depth_noise_std(np.array([1.0, 2.0, 4.0]), 460.0, 0.1, 0.15)
    np.testing.assert_allclose(sigma / sigma[0], [1, 4, 16])
    assert 0.01 < sigma[1] < 0.02  # 1.3 cm at 2 m


class RestRig:
    """The VIO alone at rest: level IMU samples (with the configured biases) and frames of
    fixed landmarks 2-6 m in front of the camera."""

    def __init__(self):
        self.camera = RgbdCameraParams()
        self.dut = VisualInertialOdometry(VioParams())
        self.context = self.dut.CreateDefaultContext()
        self.simulator = Simulator(self.dut, self.context)
        self.samples = ImuSamples.empty()
        self.seq = 0
        rng = np.random.default_rng(0)
        self.p_C = np.column_stack([rng.uniform(-1.5, 1.5, (60, 2)), rng.uniform(2, 6, 60)])
        self.K = self.camera.lens().K

    def frame(self, t, keypoints=True) -> CameraFrame:
        n = len(self.p_C) if keypoints else 0
        uv = self.p_C[:n, :2] / self.p_C[:n, 2:] @ self.K[:2, :2].T + self.K[:2, 2]
        return CameraFrame(stamp=t, calibration=self.camera.calibration(), keypoints=uv,
                           keypoint_ids=np.arange(n), depth=self.p_C[:n, 2].copy())

    def advance(self, t_end, frame_fn):
        t = self.context.get_time()
        while t < t_end - 1e-9:
            self.samples = self.samples.appended(self.seq, t, [0.05, -0.04, 9.81 + 0.03],
                                                 [0.004, -0.003, 0.002], 100)
            self.seq += 1
            self.dut.GetInputPort("imu").FixValue(self.context, self.samples)
            self.dut.GetInputPort("rgbd").FixValue(self.context, frame_fn(t))
            t = round(t + 0.005, 9)
            self.simulator.AdvanceTo(t)

    def outputs(self):
        return (self.dut.GetOutputPort("state_estimate").Eval(self.context),
                self.dut.GetOutputPort("odometry").Eval(self.context))


def test_initializes_at_rest_then_survives_frames_without_features():
    rig = RestRig()
    rig.advance(1.0, lambda t: rig.frame(np.floor(t * 30) / 30))
    estimate, odometry = rig.outputs()
    assert STATE_ESTIMATE.get(estimate, "valid") == 1.0
    assert VIO_ODOMETRY.get(odometry, "status") == VioStatus.TRACKING
    np.testing.assert_allclose(STATE_ESTIMATE.get(estimate, "p_EB"), [0, 0, 0.22], atol=0.01)
    np.testing.assert_allclose(VIO_ODOMETRY.get(odometry, "b_g"), [0.004, -0.003, 0.002],
                               atol=1e-4)
    # frames with no keypoints at all (an empty scene): no crash, no NaN, IMU-only, then lost
    rig.advance(1.5, lambda t: rig.frame(np.floor(t * 30) / 30, keypoints=False))
    estimate, odometry = rig.outputs()
    assert np.all(np.isfinite(estimate)) and np.all(np.isfinite(VIO_ODOMETRY.get(odometry,
                                                                                  "p_WS")))
    assert VIO_ODOMETRY.get(odometry, "status") == VioStatus.IMU_ONLY
    assert STATE_ESTIMATE.get(estimate, "valid") == 1.0
    assert np.linalg.norm(STATE_ESTIMATE.get(estimate, "p_EB") - [0, 0, 0.22]) < 0.05
    rig.advance(3.7, lambda t: rig.frame(np.floor(t * 30) / 30, keypoints=False))
    estimate, odometry = rig.outputs()
    assert VIO_ODOMETRY.get(odometry, "status") == VioStatus.LOST
    assert STATE_ESTIMATE.get(estimate, "valid") == 0.0 and np.all(np.isfinite(estimate))
    # features again: the window restarts from the propagated state
    rig.advance(4.5, lambda t: rig.frame(np.floor(t * 30) / 30))
    estimate, odometry = rig.outputs()
    assert VIO_ODOMETRY.get(odometry, "status") == VioStatus.TRACKING
    assert VIO_ODOMETRY.get(odometry, "restarts") == 1
    assert STATE_ESTIMATE.get(estimate, "valid") == 1.0


def test_a_rendered_frame_without_texture_gives_no_keypoints_and_no_nan():
    rig = RestRig()
    rig.advance(1.0, lambda t: rig.frame(np.floor(t * 30) / 30))
    blank = CameraFrame(stamp=1.0, image=np.zeros((480, 640, 3), np.uint8),
                        depth=np.full((480, 640), np.nan, np.float32),
                        calibration=rig.camera.calibration())
    rig.advance(1.3, lambda t: blank if t < 1.1 else CameraFrame(
        stamp=np.floor(t * 30) / 30, image=blank.image, depth=blank.depth,
        calibration=blank.calibration))
    estimate, odometry = rig.outputs()
    assert VIO_ODOMETRY.get(odometry, "tracked") == 0
    assert np.all(np.isfinite(estimate)) and STATE_ESTIMATE.get(estimate, "valid") == 1.0


def test_a_restart_whose_smoother_update_fails_is_bridged_then_retried(monkeypatch):
    """A keyframe that diverges, then a restart that diverges too (an indeterminate system, as
    the rendered source once gave, which crashed the flight): the VIO keeps its IMU-propagated
    estimate, never NaN, and restarts at a later keyframe."""
    from alight.systems.vio import backend
    rig = RestRig()
    rig.advance(1.0, lambda t: rig.frame(np.floor(t * 30) / 30))
    failures = {"left": 3}
    real_update = backend.SlidingWindow._update

    def failing_update(self, *args, **kwargs):
        if failures["left"] > 0:
            failures["left"] -= 1
            raise backend.DivergedError("smoother update failed: indeterminate linear system")
        return real_update(self, *args, **kwargs)
    monkeypatch.setattr(backend.SlidingWindow, "_update", failing_update)
    rig.advance(1.2, lambda t: rig.frame(np.floor(t * 30) / 30))
    estimate, odometry = rig.outputs()
    assert failures["left"] == 0                       # the keyframe and two restarts failed
    assert np.all(np.isfinite(estimate)) and STATE_ESTIMATE.get(estimate, "valid") == 1.0
    assert np.linalg.norm(STATE_ESTIMATE.get(estimate, "p_EB") - [0, 0, 0.22]) < 0.05
    rig.advance(1.6, lambda t: rig.frame(np.floor(t * 30) / 30))
    estimate, odometry = rig.outputs()
    assert VIO_ODOMETRY.get(odometry, "status") == VioStatus.TRACKING
    assert VIO_ODOMETRY.get(odometry, "restarts") >= 3
    np.testing.assert_allclose(STATE_ESTIMATE.get(estimate, "p_EB"), [0, 0, 0.22], atol=0.02)


def test_keyframes_add_at_most_max_landmarks_known_first_and_the_window_forgets_as_gtsam():
    """The back end's bound (issue 19): a keyframe adds at most `max_landmarks` observations, of
    landmarks in the window first; the window's landmark bookkeeping (what `knows` answers) is
    exactly the smoother's variables after it marginalized what fell out of the lag."""
    import dataclasses as dc

    import gtsam
    from gtsam.symbol_shorthand import L

    from alight.systems.vio.backend import BackendParams, Observation, SlidingWindow
    camera = RgbdCameraParams()
    K = camera.lens().K
    params = dc.replace(BackendParams(), lag=0.5, max_landmarks=30)
    window = SlidingWindow(params, camera.calibration())
    rng = np.random.default_rng(1)
    p_C = np.column_stack([rng.uniform(-1.5, 1.5, (400, 2)), rng.uniform(2, 6, 400)])

    def observations(k):   # tracks 8k .. 8k+49 in view: 8 leave and 8 arrive per keyframe
        ids = np.arange(8 * k, 8 * k + 50)
        uv = p_C[ids, :2] / p_C[ids, 2:] @ K[:2, :2].T + K[:2, 2]
        u_virtual, back = virtual_stereo(uv, p_C[ids, 2], K, camera.baseline)
        return [Observation(int(i), uv_i, float(u), b)
                for i, uv_i, u, b in zip(ids, uv, u_virtual, back)]

    nav = gtsam.NavState(gtsam.Rot3(), np.zeros(3), np.zeros(3))
    bias = gtsam.imuBias.ConstantBias()
    window.start(0.0, nav, bias, observations(0))
    for k in range(1, 30):
        obs = observations(k)
        known_before = [o.track for o in obs if window.knows(o.track)]
        added = window.selected(obs)
        assert len(added) == params.max_landmarks
        assert [o.track for o in added[:len(known_before)]] == known_before[:30]
        pim = gtsam.PreintegratedCombinedMeasurements(window.imu_params, bias)
        for _ in range(20):
            pim.integrateMeasurement(np.array([0.0, 0.0, params.gravity]), np.zeros(3), 0.005)
        window.add_keyframe(0.1 * k, pim, obs)
        in_smoother = {gtsam.Symbol(key).index()
                       for key in window._smoother.isam.calculateEstimate().keys()
                       if gtsam.Symbol(key).chr() == ord("l")}
        assert {o.track for o in obs if window.knows(o.track)} <= in_smoother
        assert window.landmark_count() == len(in_smoother)
        assert all(window.knows(track) for track in in_smoother)
    assert 0 < window.landmark_count() < 8 * 30  # old landmarks were marginalized
    np.testing.assert_allclose(window.state.nav.position(), 0.0, atol=0.05)


# --- the geometric camera as a model of the front end's output (issue 20) ---------------------

def _camera_pose(p, yaw=0.0):
    return RigidTransform(RollPitchYaw(0, 0, yaw), p) @ RgbdCameraParams().X_BC()


def test_a_long_map_is_seen_as_projecting_all_of_it_would_see_it():
    """The camera projects only the map cells that reach into its view: on a map 640 m long it
    observes the same landmarks at the same pixels as the whole map projected (the brute force,
    written out here), from poses all along it, in every direction and height."""
    params = RgbdCameraParams(landmarks=LandmarkMapParams(extent=[-40.0, -40.0, 40.0, 600.0],
                                                          boxes=280))
    camera = GeometricRgbdCamera(params, 0)
    m, lens = camera.landmarks, params.lens()
    rng = np.random.default_rng(3)
    seen = 0
    for _ in range(40):
        X_WC = RigidTransform(RollPitchYaw(*rng.uniform(-0.4, 0.4, 2), rng.uniform(-3.2, 3.2)),
                              [rng.uniform(-45, 45), rng.uniform(-50, 610),
                               rng.uniform(0.5, 12)]) @ params.X_BC()
        p_CL = X_WC.inverse().multiply(m.p_WL.T).T
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = lens.project(p_CL)
        c = X_WC.translation()
        candidates = np.flatnonzero((p_CL[:, 2] > 0.1) & (p_CL[:, 2] < params.max_range)
                                    & lens.in_image(uv, params.border_margin)
                                    & (np.einsum("ij,ij->i", m.n_WL, c - m.p_WL) > 0))
        hidden = occluded(c, m.p_WL[candidates], m.boxes[:, :5], m.box[candidates])
        expected = candidates[~hidden].tolist()
        visible, uv_seen, z_seen = camera.visible(X_WC)
        assert visible == expected
        np.testing.assert_allclose(uv_seen, uv[visible].reshape(-1, 2), atol=1e-9)
        np.testing.assert_allclose(z_seen, p_CL[visible, 2], atol=1e-9)
        seen += len(visible)
    assert seen > 40 * 100  # the poses do see the map


def test_the_keypoint_pixels_are_the_lens_projection_bit_for_bit():
    """The geometric camera projects its keypoints without OpenCV's call; the same pixels."""
    params = RgbdCameraParams(landmarks=LandmarkMapParams(extent=[-5.0, -5.0, 5.0, 5.0], boxes=2))
    rng = np.random.default_rng(5)
    p_C = np.column_stack([rng.uniform(-40, 40, (100000, 2)), rng.uniform(0.1, 40, 100000)])
    assert np.array_equal(GeometricRgbdCamera(params, 0).pixels(p_C), params.lens().project(p_C))


def test_a_landmark_behind_a_box_or_on_a_back_face_is_not_observed():
    box = [4.0, -0.5, 5.0, 0.5, 2.0, 0.0]  # x0, y0, x1, y1, height
    # behind the box (ground), on its front face (-x), on its back face (+x)
    p_WL = np.array([[8.0, 0.0, 0.0], [4.0, 0.0, 1.0], [5.0, 0.2, 1.0]])
    n_WL = np.array([[0, 0, 1.0], [-1.0, 0, 0], [1.0, 0, 0]])
    own = np.array([-1, 0, 0])
    camera = GeometricRgbdCamera(RgbdCameraParams(), 0, LandmarkMap(p_WL, np.array([box]),
                                                                     n_WL, own))
    behind = camera.visible(_camera_pose([0.0, 0.0, 1.5]))[0]
    assert behind == [1]  # the front face only: its own box does not hide it
    assert 0 in camera.visible(_camera_pose([0.0, 3.0, 1.5]))[0]  # seen from around the box
    # the back-face point is hidden by the back-face rule alone: turned toward the camera, seen
    flipped = GeometricRgbdCamera(RgbdCameraParams(), 0, LandmarkMap(
        p_WL, np.array([box]), n_WL * [[1], [1], [-1]], own))
    assert flipped.visible(_camera_pose([0.0, 0.0, 1.5]))[0] == [1, 2]
    # a ray through a pixel: the depth of the first surface (the box's front face at x = 4)
    assert occluded(np.array([0.0, 0, 1.5]), p_WL[:1], np.array([box])[:, :5], np.array([-1]))[0]
    t = ray_depth(np.array([0.0, 0, 1.0]), np.array([[1.0, 0, 0], [1.0, 0, -0.1]]),
                  np.array([box])[:, :5])
    np.testing.assert_allclose(t, [4.0, 4.0])


def test_outlier_matches_occur_at_the_configured_rate_and_the_front_end_rejects_them():
    params = dc.replace(RgbdCameraParams(), outlier_probability=0.05)
    camera = GeometricRgbdCamera(params, 0)
    tracker = KltTracker(FrontendParams())
    K = params.lens().K
    tracks, next_id, jumps, tracked, caught, false_alarms = {}, 0, 0, 0, 0, 0
    for k in range(60):
        X_WC = _camera_pose([0.05 * k, 0.01 * k, 1.5], yaw=0.004 * k)
        rng = np.random.default_rng(k)
        previous = dict(tracks)
        frame, tracks, next_id, jump = camera.observe(X_WC, k / 30, rng, tracks, next_id)
        if k == 5:  # reproducible: the same pose, tracks and seed give the same frame
            again = camera.observe(X_WC, k / 30, np.random.default_rng(k), previous, next_id)[0]
            np.testing.assert_array_equal(again.keypoints, frame.keypoints)
        is_tracked = np.isin(frame.keypoint_ids, list(previous.values()))
        jumps, tracked = jumps + jump.sum(), tracked + is_tracked.sum()
        assert not (jump & ~is_tracked).any()  # only a tracked keypoint slides away
        kept = tracker.check(Keypoints(frame.keypoint_ids, frame.keypoints, frame.depth), K).ids
        dropped = ~np.isin(frame.keypoint_ids, kept)
        caught += (dropped & jump).sum()
        false_alarms += (dropped & ~jump).sum()
    assert 0.035 < jumps / tracked < 0.065
    assert caught >= 0.85 * jumps and false_alarms < 0.01 * tracked
    assert tracker.rejected == caught + false_alarms


def test_the_vio_at_rest_stays_put_with_outlier_matches():
    rig = RestRig()
    params = dc.replace(rig.camera, outlier_probability=0.05)
    camera = GeometricRgbdCamera(params, 0)
    X_WC = _camera_pose([0.0, 0.0, 0.22])
    frames, state = {}, [{}, 0]

    def frame(t):
        stamp = np.floor(t * 30) / 30
        if stamp not in frames:
            frames[stamp], state[0], state[1], _ = camera.observe(
                X_WC, stamp, np.random.default_rng(len(frames)), state[0], state[1])
        return frames[stamp]
    rig.advance(3.0, frame)
    estimate, odometry = rig.outputs()
    assert VIO_ODOMETRY.get(odometry, "status") == VioStatus.TRACKING
    np.testing.assert_allclose(STATE_ESTIMATE.get(estimate, "p_EB"), [0, 0, 0.22], atol=0.01)
    assert rig.dut.estimator._tracker.rejected > 50  # ~0.05 x 150 x 90 frames injected


def test_the_fixed_lag_smoother_gives_gtsams_estimate_and_marginals_with_the_newest_at_the_root():
    """backend.FixedLagSmoother (the newest keyframe eliminated last) against GTSAM's
    IncrementalFixedLagSmoother on the same factors: a camera moving past landmarks, stereo
    measurements with noise, odometry between poses, 3 s at 10 Hz with a 1 s lag. The same
    estimate and the same marginal covariance of the newest pose at every step; the variables
    older than the lag are gone from ours as from GTSAM's."""
    import gtsam
    from gtsam.symbol_shorthand import L, X

    from alight.systems.vio.backend import FixedLagSmoother
    rng = np.random.default_rng(3)
    K = gtsam.Cal3_S2Stereo(460.0, 460.0, 0.0, 319.5, 239.5, 0.1)
    stereo_noise = gtsam.noiseModel.Isotropic.Sigma(3, 0.5)
    odometry_noise = gtsam.noiseModel.Isotropic.Sigma(6, 0.05)
    landmarks = np.column_stack([rng.uniform(-2, 8, 60), rng.uniform(-2, 2, 60),
                                 rng.uniform(3, 8, 60)])
    ours = FixedLagSmoother(1.0, gtsam.ISAM2Params())
    theirs = gtsam.IncrementalFixedLagSmoother(1.0, gtsam.ISAM2Params())
    for k in range(30):
        t = 0.1 * k
        pose = gtsam.Pose3(gtsam.Rot3.Yaw(0.02 * k), np.array([0.2 * k, 0.0, 0.0]))
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {X(k): t}
        values.insert(X(k), pose.compose(gtsam.Pose3(gtsam.Rot3.Yaw(0.01), [0.02, -0.01, 0.0])))
        if k == 0:
            graph.add(gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Isotropic.Sigma(6, 1e-3)))
        else:
            previous = gtsam.Pose3(gtsam.Rot3.Yaw(0.02 * (k - 1)), np.array([0.2 * (k - 1), 0, 0]))
            graph.add(gtsam.BetweenFactorPose3(X(k - 1), X(k), previous.between(pose),
                                               odometry_noise))
        camera = gtsam.StereoCamera(pose, K)
        for j, p_W in enumerate(landmarks):
            p_C = pose.transformTo(p_W)
            if not 1.0 < p_C[2] < 10.0 or abs(p_C[0] / p_C[2]) > 0.6 or abs(p_C[1] / p_C[2]) > 0.5:
                continue
            z = camera.project(p_W)
            measured = gtsam.StereoPoint2(z.uL() + rng.normal(0, 0.5),
                                          z.uR() + rng.normal(0, 0.5), z.v() + rng.normal(0, 0.5))
            graph.add(gtsam.GenericStereoFactor3D(measured, stereo_noise, X(k), L(j), K))
            if not ours.isam.valueExists(L(j)):   # new, or marginalized and seen again
                values.insert(L(j), p_W + rng.normal(0, 0.05, 3))
            stamps[L(j)] = t
        gtsam_stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        for key, stamp in stamps.items():
            gtsam_stamps.insert((key, stamp))
        theirs.update(graph, values, gtsam_stamps)
        ours.update(graph, values, stamps)
        np.testing.assert_allclose(ours.isam.calculateEstimatePose3(X(k)).matrix(),
                                   theirs.calculateEstimatePose3(X(k)).matrix(), atol=1e-6)
        np.testing.assert_allclose(ours.isam.marginalCovariance(X(k)),
                                   theirs.marginalCovariance(X(k)), rtol=1e-5, atol=1e-12)
        assert ours.isam.calculateEstimate().keys() == theirs.calculateEstimate().keys()
    assert not ours.isam.valueExists(X(15)) and ours.isam.valueExists(X(20))
