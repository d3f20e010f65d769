"""The visual-inertial estimator of L Sec. 5.1 without the Drake wrapper: initialization from rest,
front end (`frontend`), keyframes into the sliding-window back end (`backend`, L(1)-(4)), and the
IMU-propagated state between keyframes for control.

States (`VioStatus`): INITIALIZING until a camera frame arrives after `init_duration` s of IMU data
at rest (roll and pitch from gravity, heading 0: the estimator frame E is the start pose's heading,
gyro bias from the mean rate, accelerometer bias along gravity from the specific-force magnitude);
TRACKING while keyframes are added; IMU_ONLY while frames have too few usable keypoints (the state
is propagated by the IMU alone, its covariance growing); LOST after `max_imu_only` s without a
keyframe (the estimate is reported invalid). When keypoints come back the window restarts from the
propagated state with priors as wide as its covariance (recovery), in the same frame E, factorized
with `backend.restart_factorization` (QR: the failures at speed were Cholesky's, backend.py).

Each keyframe moves the propagated position (the smoother's new window, 5-20 cm at 8 m/s);
`correction` sums those moves (STATE_ESTIMATE `p_EO`), so that consumers holding a state measured
relative to the vehicle (the target estimator) move it along instead of reading the jump as motion.
"""
import bisect
import dataclasses as dc
import enum
import itertools
import math

import gtsam
import numpy as np

from alight.systems.boundary import CameraFrame, ImuSamples
from alight.systems.params import bounded
from alight.systems.rotations import heading, quaternion_product, rotation_between, rotation_matrix
from alight.systems.timing import ComputeTimer
from alight.systems.vio.backend import (BackendParams, DivergedError, Observation, SlidingWindow)
from alight.systems.vio.frontend import (FrontendParams, KltTracker, Keypoints, is_keyframe,
                                         keypoints_of, virtual_stereo)


def _diagonal_blocks(M: np.ndarray) -> np.ndarray:
    """The first three 3x3 diagonal blocks of the contiguous matrix M, as a (3, 3, 3) view."""
    s0, s1 = M.strides
    return np.ndarray((3, 3, 3), M.dtype, M, 0, (3 * (s0 + s1), s0, s1))


class VioStatus(enum.IntEnum):
    INITIALIZING = 0
    TRACKING = 1
    IMU_ONLY = 2
    LOST = 3


@dc.dataclass
class VioParams:
    period: float = bounded(0.004, 0.0005, 0.1, "s")               # the IMU period
    initial_position: list[float] = bounded([0.0, 0.0, 0.22], -1e4, 1e4, "m")  # p_EB at rest
    init_duration: float = bounded(0.5, 0.05, 10.0, "s")
    rest_accel_std: float = bounded(1.0, 0.01, 10.0, "m/s^2")      # at rest: spread below this,
    rest_accel_offset: float = bounded(0.5, 0.01, 10.0, "m/s^2")   # mean within this of g
    rest_gyro: float = bounded(0.05, 0.001, 1.0, "rad/s")          # and mean rate below this
    min_features: int = bounded(10, 3, 1000)                       # usable keypoints per keyframe
    imu_only_after: float = bounded(0.25, 0.0, 10.0, "s")          # no keyframe: status IMU_ONLY
    max_imu_only: float = bounded(2.0, 0.1, 60.0, "s")             # no keyframe: status LOST
    frontend: FrontendParams = dc.field(default_factory=FrontendParams)
    backend: BackendParams = dc.field(default_factory=BackendParams)


@dc.dataclass
class Estimate:
    """The propagated state at `stamp` in E: position, velocity, q_EB, acceleration, biases,
    standard deviations of position, attitude (in E) and velocity, and the body rate."""
    stamp: float
    p: np.ndarray
    v: np.ndarray
    q: np.ndarray
    a: np.ndarray
    w: np.ndarray
    b_g: np.ndarray
    b_a: np.ndarray
    var_p: np.ndarray
    var_rot: np.ndarray
    var_v: np.ndarray


class VioEstimator:
    """`add_imu(samples)` with every IMU sample once, `add_frame(frame)` with every new camera
    frame, `estimate()` for the latest propagated state (None before initialization). `timer`
    records the front-end time of every frame and the back-end time of every keyframe (parts
    "frontend", "backend", at the frame's stamp)."""

    def __init__(self, params: VioParams, timer: ComputeTimer | None = None):
        self.p = params
        self.timer = timer if timer is not None else ComputeTimer()
        self.status = VioStatus.INITIALIZING
        self.restarts = 0
        self.failed_restarts = 0       # restarts whose smoother update failed as well
        self._needs_restart = False
        self.tracked = 0
        self._tracker = KltTracker(params.frontend)
        self._window: SlidingWindow | None = None
        self._samples: list[tuple[float, np.ndarray, np.ndarray]] = []  # since the last keyframe
        self._pim_out = None   # pre-integration from the last keyframe to the newest sample
        self._t_out = -np.inf  # end of what _pim_out covers
        self._last_frame = -np.inf
        self._g = np.array([0.0, 0.0, params.backend.gravity])  # -gravity in E (z up) [m/s^2]
        # p_EO: the sum of the keyframes' corrections of the propagated position (STATE_ESTIMATE)
        self.correction = np.zeros(3)

    @property
    def window(self) -> SlidingWindow | None:
        return self._window

    # --- IMU ------------------------------------------------------------------------------
    def add_imu(self, samples: ImuSamples) -> None:
        self._samples += zip(samples.t.tolist(), np.asarray(samples.accel, float),
                             np.asarray(samples.gyro, float))
        if self._pim_out is None:  # not initialized: keep what initialization needs
            horizon = self._samples[-1][0] - 2 * self.p.init_duration if self._samples else 0.0
            self._samples = [s for s in self._samples if s[0] >= horizon]
            return
        t_end = self._samples[-1][0] + self.p.period if self._samples else self._t_out
        self._integrate(self._pim_out, self._t_out, t_end)
        self._t_out = t_end
        self._update_status(t_end)

    def _integrate(self, pim, t_a: float, t_b: float) -> None:
        """Each sample holds for one period from its stamp; integrates the part in [t_a, t_b)."""
        # the samples (in time order) that end before t_a, by a margin far above rounding, add
        # nothing: skipped without a look (IMU-only, the list grows until the next keyframe).
        # Searched with the 1-tuple (t,): a sample (t, f, w) compares by its stamp alone, and one
        # stamped t exactly sorts after it (the shorter tuple), as bisect_left on the stamps.
        period = self.p.period
        first = bisect.bisect_left(self._samples, (t_a - period - 1e-6,))
        for t, f, w in itertools.islice(self._samples, first, None):
            dt = min(t + period, t_b) - max(t, t_a)
            if dt > 1e-9:
                pim.integrateMeasurement(f, w, dt)

    def _update_status(self, t: float) -> None:
        if self._window is None or self._window.state is None:
            return
        age = t - self._window.state.t
        if age > self.p.max_imu_only:
            self.status = VioStatus.LOST
        elif age > self.p.imu_only_after:
            self.status = VioStatus.IMU_ONLY

    # --- frames -------------------------------------------------------------------------------
    def add_frame(self, frame: CameraFrame) -> None:
        if not frame.valid or frame.stamp <= self._last_frame or frame.calibration is None:
            return
        self._last_frame = frame.stamp
        with self.timer.measure(frame.stamp, "frontend"):
            keypoints = keypoints_of(frame, self._tracker)
        self.tracked = len(keypoints)
        if self._window is None:
            self._window = SlidingWindow(self.p.backend, frame.calibration)
            self._calibration = frame.calibration
        if self.status == VioStatus.INITIALIZING:
            self._initialize(frame.stamp, keypoints)
            return
        window = self._window
        stereo = self._stereo(keypoints)
        # (counted on the lists: the Observations are made for keyframes only, a third of frames)
        known, usable = window.counts(stereo[0], stereo[1])
        # the overlap counts against what a keyframe can hold (the back end's max_landmarks)
        if not is_keyframe(self.p.frontend, frame.stamp, window.state.t, known,
                           min(usable, self.p.backend.max_landmarks)):
            return
        if usable < self.p.min_features:
            self._update_status(frame.stamp)
            return
        observations = self._observations(keypoints, stereo)
        before = self._propagated_position()
        try:
            with self.timer.measure(frame.stamp, "backend"):
                pim = gtsam.PreintegratedCombinedMeasurements(window.imu_params,
                                                              window.state.bias)
                self._integrate(pim, window.state.t, frame.stamp)
                if self.status == VioStatus.LOST or self._needs_restart:
                    self._restart(frame.stamp, pim, observations)
                else:
                    try:
                        window.add_keyframe(frame.stamp, pim, observations)
                    except DivergedError:
                        self._restart(frame.stamp, pim, observations)
        except DivergedError:   # the restart failed too (e.g. too few constrained landmarks):
            self.failed_restarts += 1   # bridge on the IMU from the last good keyframe and
            self._needs_restart = True  # restart at the next keyframe; LOST after max_imu_only
            return self._update_status(frame.stamp)
        self._needs_restart = False
        self.status = VioStatus.TRACKING
        t_before = self._t_out
        self._after_keyframe()
        if before is not None and self._t_out == t_before:
            self.correction = self.correction + (self._propagated_position() - before)

    def _stereo(self, keypoints: Keypoints) -> tuple[list[int], list[float], np.ndarray]:
        """The keypoints' track ids, virtual-camera u (L(2)) and back-projected points p_C."""
        K = np.asarray(self._calibration["K"], float)
        u_virtual, p_C = virtual_stereo(keypoints.uv, keypoints.depth, K,
                                        float(self._calibration["baseline"]))
        # (tolist: the ids and u as Python ints and floats at once, not one conversion each)
        return keypoints.ids.tolist(), u_virtual.tolist(), p_C

    @staticmethod
    def _observations(keypoints: Keypoints, stereo) -> list[Observation]:
        ids, u_virtual, p_C = stereo
        return [Observation(i, uv, uv_v, pc) for i, uv, uv_v, pc
                in zip(ids, keypoints.uv, u_virtual, p_C)]

    def _initialize(self, stamp: float, keypoints: Keypoints) -> None:
        rest = [s for s in self._samples if stamp - self.p.init_duration <= s[0] <= stamp]
        if not self._samples or self._samples[0][0] > stamp - self.p.init_duration + \
                self.p.period or len(rest) < 3:
            return
        f = np.array([s[1] for s in rest])
        w = np.array([s[2] for s in rest])
        norm = np.linalg.norm(f, axis=1)
        if norm.std() > self.p.rest_accel_std or \
                abs(norm.mean() - self.p.backend.gravity) > self.p.rest_accel_offset or \
                np.linalg.norm(w.mean(axis=0)) > self.p.rest_gyro:
            return
        f_mean = f.mean(axis=0)
        q = rotation_between(f_mean / np.linalg.norm(f_mean), np.array([0.0, 0.0, 1.0]))
        eta = heading(rotation_matrix(q))
        q = quaternion_product(np.array([np.cos(eta / 2), 0, 0, -np.sin(eta / 2)]), q)
        R_WB = rotation_matrix(q)
        b_a = f_mean - R_WB.T @ self._g
        nav = gtsam.NavState(gtsam.Rot3(R_WB), np.asarray(self.p.initial_position, float),
                             np.zeros(3))
        bias = gtsam.imuBias.ConstantBias(b_a, w.mean(axis=0))
        observations = self._observations(keypoints, self._stereo(keypoints))
        if sum(math.isfinite(o.u_virtual) for o in observations) < self.p.min_features:
            return
        self._window.start(stamp, nav, bias, observations)
        self.status = VioStatus.TRACKING
        self._after_keyframe()

    def _restart(self, stamp: float, pim, observations) -> None:
        """Recovery: a new window from the IMU-propagated state, priors as wide as its spread."""
        state = self._window.state
        propagated = pim.predict(state.nav, state.bias)
        estimate = self._propagated_covariance(state, pim)
        self.restarts += 1
        self._window.start(stamp, propagated, state.bias, observations,
                           position_std=float(np.clip(np.sqrt(estimate[0].max()), 0.05, 50.0)),
                           attitude_std=float(np.clip(np.sqrt(estimate[1].max()), 0.005, 0.5)),
                           velocity_std=float(np.clip(np.sqrt(estimate[2].max()), 0.05, 20.0)),
                           factorization=self.p.backend.restart_factorization)

    def _after_keyframe(self) -> None:
        t_kf = self._window.state.t
        self._samples = [s for s in self._samples if s[0] + self.p.period > t_kf]
        self._pim_out = gtsam.PreintegratedCombinedMeasurements(self._window.imu_params,
                                                                self._window.state.bias)
        t_end = self._samples[-1][0] + self.p.period if self._samples else t_kf
        self._integrate(self._pim_out, t_kf, t_end)
        self._t_out = max(t_end, t_kf)

    # --- output -------------------------------------------------------------------------------
    def _propagated(self) -> gtsam.NavState | None:
        """The state propagated to the newest IMU sample (None before initialization)."""
        if self._window is None or self._window.state is None or self._pim_out is None:
            return None
        state = self._window.state
        return self._pim_out.predict(state.nav, state.bias)

    def _propagated_position(self) -> np.ndarray | None:
        nav = self._propagated()
        return None if nav is None else nav.position()

    def _propagated_covariance(self, state, pim):
        """Variances (in E) of position, attitude and velocity after propagating the keyframe's
        marginals through `pim`: keyframe covariance, velocity uncertainty times time, the
        pre-integrated IMU noise, and gravity mis-compensated by the attitude error."""
        R, var_p0, var_rot0, var_v0 = state.variances_W
        dt = pim.deltaTij()
        # R P R^T of the pre-integrated rotation, position and velocity blocks P at once: one
        # batched matmul makes the same BLAS call per block as R @ P @ R.T does, in 2 calls, not 6
        rotated = (R @ _diagonal_blocks(pim.preintMeasCov()) @ R.T).diagonal(axis1=1, axis2=2)
        tilt = var_rot0[0] + var_rot0[1]
        g = self.p.backend.gravity
        var_p = var_p0 + var_v0 * dt ** 2 + rotated[1] + tilt * (0.5 * g * dt ** 2) ** 2
        var_v = var_v0 + rotated[2] + tilt * (g * dt) ** 2
        var_rot = var_rot0 + rotated[0]
        return var_p, var_rot, var_v

    def estimate(self) -> Estimate | None:
        nav = self._propagated()
        if nav is None:
            return None
        state = self._window.state
        var_p, var_rot, var_v = self._propagated_covariance(state, self._pim_out)
        # R, p and v from the NavState's 5x5 matrix [R p v; 0 I] in one call (not three)
        M = nav.matrix()
        R = M[:3, :3]
        b_a, b_g = state.biases
        f, w = (self._samples[-1][1], self._samples[-1][2]) if self._samples else (
            R.T @ self._g + b_a, b_g)
        a = R @ (f - b_a) - self._g
        q = nav.attitude().toQuaternion()
        return Estimate(self._t_out, M[:3, 3], M[:3, 4],
                        np.array([q.w(), q.x(), q.y(), q.z()]), a, w - b_g, b_g, b_a, var_p,
                        var_rot, var_v)
