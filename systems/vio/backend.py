"""The VIO back end, L(1)-(4): a sliding window of keyframe states x_R = [p_WS, q_WS, v_WS, b_g, b_a]
and landmarks, optimizing reprojection errors in the real camera (4), in the virtual stereo camera
of L(2) and IMU pre-integration errors between keyframes (the cost J of L(3)), with old states
marginalized so that the cost stays bounded.

Built on GTSAM: iSAM2 over a fixed lag (`FixedLagSmoother`: everything older than `lag` is
marginalized into a Gaussian prior), `CombinedImuFactor` (IMU pre-integration with bias random
walk, Forster et al.), `GenericStereoFactor3D` (the real + virtual camera pair: u_left,
u_virtual, v) for keypoints with depth and `GenericProjectionFactorCal3_S2` (4) for those
without, both with a Huber loss.
The IMU frame S is the body frame B (the vehicle's IMU sits at its origin); X_BC is the camera's
calibrated mount.
"""
import dataclasses as dc
import functools
import math

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, L, V, X

from alight.systems.params import bounded, choice


@dc.dataclass
class BackendParams:
    lag: float = bounded(1.5, 0.1, 30.0, "s")                     # window length
    keypoint_noise_std: float = bounded(1.0, 0.01, 100.0, "px")   # W_r of L(3)
    huber_threshold: float = bounded(1.345, 0.1, 100.0)           # in standard deviations
    gravity: float = bounded(9.81, 9.0, 10.0, "m/s^2")
    accel_noise_density: float = bounded(0.02, 1e-6, 10.0, "m/s^2/sqrt(Hz)")
    gyro_noise_density: float = bounded(1.7e-3, 1e-7, 1.0, "rad/s/sqrt(Hz)")
    accel_bias_random_walk: float = bounded(1e-3, 1e-7, 1.0, "m/s^3/sqrt(Hz)")
    gyro_bias_random_walk: float = bounded(2e-5, 1e-8, 1.0, "rad/s^2/sqrt(Hz)")
    initial_position_std: float = bounded(0.01, 1e-4, 100.0, "m")
    initial_attitude_std: list[float] = bounded([0.5, 0.5, 0.1], 1e-3, 180.0, "deg")  # r, p, yaw
    initial_velocity_std: float = bounded(0.01, 1e-4, 100.0, "m/s")
    initial_accel_bias_std: float = bounded(0.1, 1e-5, 10.0, "m/s^2")
    initial_gyro_bias_std: float = bounded(0.005, 1e-6, 1.0, "rad/s")
    max_speed: float = bounded(40.0, 1.0, 1000.0, "m/s")          # beyond: the solution diverged
    # landmarks one keyframe observes in the window, at most (the bound on the back end's work)
    max_landmarks: int = bounded(110, 4, 10000)
    # iSAM2's linear solver of a window. Cholesky (GTSAM's default) declared the window's system
    # indeterminate at 5-5.7 m/s ("near variable b385": the gyro bias link of a short IMU factor
    # carries an information of about 1e11, which we take to be the cause), and each failure
    # restarted the window from the IMU-propagated state: up to 24 restarts in 2 s and a VIO
    # 81 m off in a windy 5.7 m/s chase. QR factorizes the same system without squaring it and
    # never failed there, at 2.7x the back end's time (bench/vio.py). So a window starts on
    # `factorization` and every window restarted after a failure on `restart_factorization`.
    factorization: str = choice("CHOLESKY", "QR")
    restart_factorization: str = choice("QR", "CHOLESKY")


@dc.dataclass
class Observation:
    """One keypoint of a keyframe: track id, pixel (u, v), virtual-camera u (NaN without depth)
    and the back-projected point in the camera frame (NaN without depth)."""
    track: int
    uv: np.ndarray
    u_virtual: float
    p_C: np.ndarray


@dc.dataclass
class KeyframeState:
    t: float
    nav: gtsam.NavState
    bias: gtsam.imuBias.ConstantBias
    cov_pose: np.ndarray      # 6x6 [rotation, translation] in the body frame (GTSAM's tangent)
    cov_velocity: np.ndarray  # 3x3 in W

    @functools.cached_property
    def variances_W(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """R_WB and the variances in W of position, attitude and velocity (computed once: the
        IMU propagation reads them at every IMU sample until the next keyframe)."""
        R = self.nav.attitude().matrix()
        return R, np.diag(R @ self.cov_pose[3:, 3:] @ R.T), \
            np.diag(R @ self.cov_pose[:3, :3] @ R.T), np.diag(self.cov_velocity)

    @functools.cached_property
    def biases(self) -> tuple[np.ndarray, np.ndarray]:
        """The accelerometer and gyro biases b_a, b_g (read once, for the same reason)."""
        return self.bias.accelerometer(), self.bias.gyroscope()


class DivergedError(RuntimeError):
    """The optimizer failed or produced an implausible state; the window must be restarted."""


def imu_params(p: BackendParams) -> gtsam.PreintegrationCombinedParams:
    params = gtsam.PreintegrationCombinedParams.MakeSharedU(p.gravity)
    params.setAccelerometerCovariance(np.eye(3) * p.accel_noise_density ** 2)
    params.setGyroscopeCovariance(np.eye(3) * p.gyro_noise_density ** 2)
    params.setIntegrationCovariance(np.eye(3) * 1e-8)
    params.setBiasAccCovariance(np.eye(3) * p.accel_bias_random_walk ** 2)
    params.setBiasOmegaCovariance(np.eye(3) * p.gyro_bias_random_walk ** 2)
    return params


class FixedLagSmoother:
    """iSAM2 over a fixed lag, as `gtsam.IncrementalFixedLagSmoother`, with an elimination order
    that puts the newest keyframe at the root of the Bayes tree: variables to marginalize first,
    then the landmarks, the older keyframes, the newest keyframe's pose, velocity and bias last.
    The keyframe's marginal covariances are then the root clique's (0.15 ms each on a rendered
    landing; GTSAM's smoother orders by COLAMD and walked the tree for them: 27-47 ms each, 80 %
    of the back end's time). Every update re-eliminates the whole window, which the keyframe's
    landmarks reach almost entirely anyway; with the order above that keeps the variables to
    marginalize in leaf cliques, as `ISAM2.marginalizeLeaves` requires (GTSAM's smoother marks
    only the cliques between them and the leaves)."""

    # a gtsam.Symbol key holds its character in the top 8 bits (Symbol(key).chr(), without the
    # Symbol: 1.4 us a key, ~250 keys an update)
    _CHR_SHIFT = 56
    _LAST = (ord("x"), ord("v"), ord("b"))
    _LANDMARK = ord("l")

    def __init__(self, lag: float, params: gtsam.ISAM2Params):
        self._lag = lag
        self.isam = gtsam.ISAM2(params)
        self._stamps: dict[int, float] = {}   # key -> when last observed [s]
        # Kept from update to update (a binding call per key changed, not per key held: ~250
        # keys, ~15 change an update): every held key's group between updates (1 landmark,
        # 2 keyframe variable), and the held keys in the order of `_stamps` (first stamped first)
        self._groups, self._held = gtsam.KeyGroupMap(), gtsam.KeyList()

    def update(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
               stamps: dict[int, float]) -> None:
        """Adds the factors and new variables stamped `stamps`, optimizes, marginalizes what is
        older than the newest stamp minus the lag."""
        # the keys iSAM2 holds: every stamped key got its value in the update that stamped it
        # first, and stays until marginalized (a failed update discards the whole smoother), so
        # the keys first stamped now are new ones (in `values`), re-eliminated from the next on
        first = [key for key in stamps if key not in self._stamps]
        self._stamps.update(stamps)
        now = max(self._stamps.values())
        old = [key for key, t in self._stamps.items() if t < now - self._lag]
        shift, groups, held = self._CHR_SHIFT, self._groups, self._held
        for key in first:
            groups.insert2(key, 1 if key >> shift == self._LANDMARK else 2)
        # for this update: the keys to marginalize first (group 0), the newest keyframe's pose,
        # velocity and bias last (3)
        for key in old:
            groups.erase(key)
            groups.insert2(key, 0)
        last = [key for key, t in stamps.items()
                if t == now and key >> shift in self._LAST and groups.at(key) != 0]
        for key in last:
            groups.erase(key)
            groups.insert2(key, 3)
        self.isam.update(graph, values, [], groups, None, held, False)
        for key in last:
            groups.erase(key)
            groups.insert2(key, 2)
        for key in first:
            held.push_back(key)
        if old:
            leaves = gtsam.KeyList()
            for key in old:
                leaves.push_back(key)
                held.remove(key)
                groups.erase(key)
                del self._stamps[key]
            self.isam.marginalizeLeaves(leaves)


class SlidingWindow:
    """The fixed-lag smoother over keyframes. `start` puts priors on the first keyframe,
    `add_keyframe` adds one keyframe with its IMU factor and keypoint factors and optimizes."""

    def __init__(self, params: BackendParams, calibration: dict):
        self._p = params
        K = np.asarray(calibration["K"], float)
        self._K = gtsam.Cal3_S2(K[0, 0], K[1, 1], 0.0, K[0, 2], K[1, 2])
        self._K_stereo = gtsam.Cal3_S2Stereo(K[0, 0], K[1, 1], 0.0, K[0, 2], K[1, 2],
                                             float(calibration["baseline"]))
        self._X_BC = gtsam.Pose3(np.asarray(calibration["X_BC"], float))
        self._disparity_std = float(calibration.get("disparity_noise_std", 0.0))
        self.imu_params = imu_params(params)
        huber = gtsam.noiseModel.mEstimator.Huber.Create(params.huber_threshold)
        sigma = params.keypoint_noise_std
        self._mono_noise = gtsam.noiseModel.Robust.Create(
            huber, gtsam.noiseModel.Isotropic.Sigma(2, sigma))
        self._stereo_noise = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(
            np.array([sigma, np.hypot(sigma, self._disparity_std), sigma])))
        self._smoother = None
        self._k = -1
        self._landmarks: dict[int, float] = {}  # in the window: track -> last observed [s]
        self.state: KeyframeState | None = None

    @property
    def keyframes(self) -> int:
        return self._k + 1

    def landmark_count(self) -> int:
        return len(self._landmarks)

    def knows(self, track: int) -> bool:
        return track in self._landmarks

    def start(self, t: float, nav: gtsam.NavState, bias: gtsam.imuBias.ConstantBias,
              observations: list[Observation], position_std=None, attitude_std=None,
              velocity_std=None, factorization: str | None = None) -> KeyframeState:
        """A new window whose first keyframe at `t` has priors on pose, velocity and bias (the
        defaults: the initialization from rest; larger ones when restarting after a loss),
        factorized with `factorization` (default the parameters')."""
        p = self._p
        isam = gtsam.ISAM2Params()
        isam.setFactorization(factorization or p.factorization)
        self._smoother = FixedLagSmoother(p.lag, isam)
        self._landmarks = {}
        self._k += 1
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        att = np.radians(p.initial_attitude_std) if attitude_std is None else attitude_std
        pos = p.initial_position_std if position_std is None else position_std
        vel = p.initial_velocity_std if velocity_std is None else velocity_std
        k = self._k
        graph.add(gtsam.PriorFactorPose3(X(k), nav.pose(), gtsam.noiseModel.Diagonal.Sigmas(
            np.concatenate([np.broadcast_to(att, 3), np.broadcast_to(pos, 3)]))))
        graph.add(gtsam.PriorFactorVector(V(k), nav.velocity(),
                                          gtsam.noiseModel.Isotropic.Sigma(3, vel)))
        graph.add(gtsam.PriorFactorConstantBias(B(k), bias, gtsam.noiseModel.Diagonal.Sigmas(
            np.repeat([p.initial_accel_bias_std, p.initial_gyro_bias_std], 3))))
        values.insert(X(k), nav.pose())
        values.insert(V(k), nav.velocity())
        values.insert(B(k), bias)
        return self._update(t, graph, values, nav.pose(), observations)

    def add_keyframe(self, t: float, pim: gtsam.PreintegratedCombinedMeasurements,
                     observations: list[Observation]) -> KeyframeState:
        """Keyframe k+1 at `t`: the IMU factor from keyframe k (`pim` integrated over the frames
        between), the keypoint factors, one smoother update. Raises DivergedError."""
        previous = self.state
        predicted = pim.predict(previous.nav, previous.bias)
        self._k += 1
        k = self._k
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(gtsam.CombinedImuFactor(X(k - 1), V(k - 1), X(k), V(k), B(k - 1), B(k), pim))
        values.insert(X(k), predicted.pose())
        values.insert(V(k), predicted.velocity())
        values.insert(B(k), previous.bias)
        return self._update(t, graph, values, predicted.pose(), observations)

    def counts(self, tracks: list[int], u_virtual: list[float]) -> tuple[int, int]:
        """Of a frame's keypoints (track ids, virtual-camera u): how many are of landmarks in
        the window, and how many `selected` could take (those and the new ones with depth)."""
        landmarks = self._landmarks
        known = usable = 0
        for track, u in zip(tracks, u_virtual):
            if track in landmarks:
                known += 1
            elif not math.isfinite(u):
                continue
            usable += 1
        return known, usable

    def selected(self, observations: list[Observation]) -> list[Observation]:
        """The observations a keyframe adds: of landmarks in the window, then of new ones with
        depth (a landmark is created from its first observation with depth), `max_landmarks`
        in all. The window's landmarks come first: they tie the keyframe to the previous ones;
        a new track left out now is offered again at the next keyframe."""
        known = [o for o in observations if o.track in self._landmarks]
        new = [o for o in observations
               if o.track not in self._landmarks and math.isfinite(o.u_virtual)]
        return (known + new)[:self._p.max_landmarks]

    def _update(self, t, graph, values, X_WB: gtsam.Pose3, observations) -> KeyframeState:
        k = self._k
        timestamps = {key: t for key in (X(k), V(k), B(k))}
        X_WC = X_WB.compose(self._X_BC)
        landmarks = dict(self._landmarks)
        pose_key = X(k)
        for obs in self.selected(observations):
            key = L(obs.track)
            if obs.track not in self._landmarks:
                values.insert(key, X_WC.transformFrom(obs.p_C))
            if math.isfinite(obs.u_virtual):
                graph.add(gtsam.GenericStereoFactor3D(
                    gtsam.StereoPoint2(obs.uv[0], obs.u_virtual, obs.uv[1]), self._stereo_noise,
                    pose_key, key, self._K_stereo, self._X_BC))
            else:
                graph.add(gtsam.GenericProjectionFactorCal3_S2(
                    obs.uv, self._mono_noise, pose_key, key, self._K, self._X_BC))
            timestamps[key] = t
            landmarks[obs.track] = t
        try:
            self._smoother.update(graph, values, timestamps)
            isam = self._smoother.isam
            pose = isam.calculateEstimatePose3(X(k))
            velocity = isam.calculateEstimateVector(V(k))
            bias = isam.calculateEstimateConstantBias(B(k))
            cov_pose = isam.marginalCovariance(X(k))
            cov_velocity = isam.marginalCovariance(V(k))
        except RuntimeError as e:
            raise DivergedError(f"smoother update failed: {e}") from None
        if not (np.all(np.isfinite(pose.matrix())) and np.all(np.isfinite(velocity))
                and np.linalg.norm(velocity) < self._p.max_speed):
            raise DivergedError(f"implausible keyframe state: v = {velocity}")
        # The smoother marginalized every variable last stamped before (newest stamp - lag).
        cutoff = t - self._p.lag
        self._landmarks = {track: seen for track, seen in landmarks.items() if seen >= cutoff}
        self.state = KeyframeState(t, gtsam.NavState(pose, velocity), bias, cov_pose,
                                   cov_velocity)
        return self.state
