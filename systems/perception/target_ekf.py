"""The target EKF, L(5)-(10) and Appendix A, L(28)-(35).

State x_T = [p_WT, q_WT, v_WT] (L(5)); error state [dp, dalpha, dv] (9) with the orientation error in
the tangent space, q_WT = exp(dalpha) * q_bar (L(10), global perturbation); constant-velocity,
constant-orientation prediction (L(6)-(8), (28)-(31)) with the paper's noise densities
sigma_rot = [0.02, 0.02, 0.2] rad/sqrt(Hz), sigma_vel = [0.1, 0.1, 0.1] m/s/sqrt(Hz) (L Sec. 5.2.2);
the discrete noise is the exact integral of the white-noise acceleration model (variance
sigma^2 dt on the velocity, sigma^2 dt^3/3 and sigma^2 dt^2/2 on position and position-velocity;
the paper writes the variance as sigma dt). Updates: one keypoint at a time (L Appendix A), with
h_t = u(T_CW T_WT r_t) (L(9)) in the rectified pinhole image, L(32), whose Jacobian is L(33)-(35) with
D = I; for the global perturbation d(R_WT r_t)/d alpha = -[R_WT r_t]x (L(35) prints the opposite
sign); Joseph-form covariance update; multiplicative orientation update q+ = exp(dalpha) * q-.
Residuals failing the chi-square test (d^2 > 9, L Sec. 5.2.2) are rejected.

Beyond the paper (issue 23): with `sigma_acc` > 0 the state also holds the target's acceleration
a_WT (error state [dp, dalpha, dv, da], 12), predicted constant with white-noise jerk of density
sigma_acc: p += v dt + a dt^2 / 2, v += a dt. A car in a turn accelerates sideways; the paper's
constant-velocity model then lets the velocity estimate lag the car's turning velocity (0.1 m/s
sideways on the MBZIRC curve, the vehicle drifting to the outside of the turn). sigma_acc zero:
the paper's 9-state filter, exactly.
"""
import dataclasses as dc

import numpy as np

from alight.systems.params import bounded
from alight.systems.rotations import (quaternion_from_rotation_vector, quaternion_product,
                                      rotation_matrix)


@dc.dataclass
class TargetEkfParams:
    sigma_rot: list[float] = bounded([0.02, 0.02, 0.2], 0.0, 10.0, "rad/sqrt(Hz)")
    sigma_vel: list[float] = bounded([0.1, 0.1, 0.1], 0.0, 100.0, "m/s/sqrt(Hz)")
    # white-noise jerk density of the acceleration state; all zero: no such state (the paper)
    sigma_acc: list[float] = bounded([0.0, 0.0, 0.0], 0.0, 100.0, "m/s^2/sqrt(Hz)")
    keypoint_noise_std: float = bounded(5.0, 0.01, 100.0, "px")        # L Sec. 5.2.2
    chi2_threshold: float = bounded(9.0, 0.1, 1000.0)                   # L Sec. 5.2.2
    initial_position_std: float = bounded(0.03, 0.0, 1.0)   # x range, from a detection
    initial_position_std_min: float = bounded(0.05, 0.0, 10.0, "m")
    initial_rotation_std: float = bounded(5.0, 0.0, 180.0, "deg")
    initial_velocity_std: float = bounded(5.0, 0.0, 100.0, "m/s")
    initial_acceleration_std: float = bounded(1.0, 0.0, 100.0, "m/s^2")


_I3 = np.eye(3)


def skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0.0]])


@dc.dataclass
class KeypointPrediction:
    """h_t and its Jacobian for one keypoint at the current state."""
    uv: np.ndarray      # (2,) rectified pixels
    H: np.ndarray       # (2, n): n = 9, or 12 with the acceleration state
    p_CK: np.ndarray    # (3,) the keypoint in the camera frame


class TargetEkf:
    """The filter's state at time `t`: p, q (w, x, y, z), v, a (zero without the acceleration
    state) in W (= the state estimate's frame), P (n x n)."""

    def __init__(self, params: TargetEkfParams):
        self.params = params
        self.n = 12 if np.any(np.asarray(params.sigma_acc) > 0) else 9
        self._I = np.eye(self.n)
        self.t = float("nan")
        self.p = np.zeros(3)
        self.q = np.array([1.0, 0.0, 0.0, 0.0])
        self.v = np.zeros(3)
        self.a = np.zeros(3)
        self.P = np.eye(self.n)
        self._R = params.keypoint_noise_std ** 2 * np.eye(2)

    @property
    def initialized(self) -> bool:
        return np.isfinite(self.t)

    @property
    def horizontal_velocity_std(self) -> float:
        """The larger of the x and y velocity standard deviations [m/s]."""
        return float(np.sqrt(np.max(np.diag(self.P)[6:8])))

    def initialize(self, t: float, p_WT: np.ndarray, q_WT: np.ndarray, range_m: float,
                   motion: tuple[np.ndarray, np.ndarray, float] | None = None) -> None:
        """From a full detection at time t: velocity zero (L Sec. 5.2.2), or `motion` (v, a and
        the velocity's std [m/s]: a re-initialization that keeps a known motion, beyond the
        paper)."""
        k = self.params
        self.t = float(t)
        self.p = np.array(p_WT, float)
        self.q = np.array(q_WT, float) / np.linalg.norm(q_WT)
        v, a, sv = (np.zeros(3), np.zeros(3), k.initial_velocity_std) if motion is None \
            else (np.array(motion[0], float), np.array(motion[1], float), float(motion[2]))
        self.v, self.a = v, a
        sp = max(k.initial_position_std * range_m, k.initial_position_std_min)
        self.P = np.diag([sp ** 2] * 3 + [np.radians(k.initial_rotation_std) ** 2] * 3
                         + [sv ** 2] * 3 + [k.initial_acceleration_std ** 2] * (self.n - 9))

    # --- prediction, L(28)-(31) ---------------------------------------------------------------
    def transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """F_d (L(31)) and the discrete process noise Q over dt (white-noise acceleration on v;
        with the acceleration state also white-noise jerk on a, integrated exactly)."""
        n = self.n
        F = np.eye(n)
        F[0:3, 6:9] = dt * _I3
        s_vel2 = np.square(self.params.sigma_vel)
        Q = np.zeros((n, n))
        Q[0:3, 0:3] = np.diag(s_vel2 * dt ** 3 / 3)
        Q[0:3, 6:9] = Q[6:9, 0:3] = np.diag(s_vel2 * dt ** 2 / 2)
        Q[6:9, 6:9] = np.diag(s_vel2 * dt)
        Q[3:6, 3:6] = np.diag(np.square(self.params.sigma_rot) * dt)
        if n == 12:
            F[0:3, 9:12] = dt * dt / 2 * _I3
            F[6:9, 9:12] = dt * _I3
            s_acc2 = np.square(self.params.sigma_acc)
            blocks = {(0, 0): dt ** 5 / 20, (0, 6): dt ** 4 / 8, (0, 9): dt ** 3 / 6,
                      (6, 6): dt ** 3 / 3, (6, 9): dt ** 2 / 2, (9, 9): dt}
            for (i, j), c in blocks.items():
                Q[i:i + 3, j:j + 3] += np.diag(s_acc2 * c)
                if i != j:
                    Q[j:j + 3, i:i + 3] += np.diag(s_acc2 * c)
        return F, Q

    def predicted(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(p, q, v, P) predicted to t >= self.t without changing the filter."""
        dt = max(0.0, t - self.t)
        F, Q = self.transition(dt)
        return (self.p + (self.v + self.a * (dt / 2)) * dt, self.q.copy(), self.v + self.a * dt,
                F @ self.P @ F.T + Q)

    def predict(self, t: float) -> None:
        if t > self.t:
            self.p, self.q, self.v, self.P = self.predicted(t)
            self.t = float(t)

    # --- keypoint update, L(9), (32)-(35) -----------------------------------------------------
    def keypoint(self, p_TK: np.ndarray, R_WC: np.ndarray, p_WC: np.ndarray,
                 K: np.ndarray) -> KeypointPrediction | None:
        """The predicted rectified pixel of keypoint p_TK seen by a camera at (R_WC, p_WC) with
        rectified intrinsics K, and H = d h / d x (None behind the camera)."""
        R_WT = rotation_matrix(self.q)
        r_W = R_WT @ p_TK
        R_CW = R_WC.T
        p_CK = R_CW @ (self.p + r_W - p_WC)
        if p_CK[2] <= 1e-3:
            return None
        x, y, z = p_CK
        U = np.array([[K[0, 0] / z, 0.0, -K[0, 0] * x / z ** 2],
                      [0.0, K[1, 1] / z, -K[1, 1] * y / z ** 2]])   # L(34), D = I
        J = np.hstack([_I3, -skew(r_W)])                             # L(35)
        H = np.zeros((2, self.n))
        H[:, 0:6] = U @ R_CW @ J                                     # L(33)
        uv = np.array([K[0, 0] * x / z + K[0, 2], K[1, 1] * y / z + K[1, 2]])
        return KeypointPrediction(uv, H, p_CK)

    def mahalanobis2(self, prediction: KeypointPrediction, uv: np.ndarray) -> float:
        r = np.asarray(uv, float) - prediction.uv
        S = prediction.H @ self.P @ prediction.H.T + self._R
        return float(r @ np.linalg.solve(S, r))

    def update(self, prediction: KeypointPrediction, uv: np.ndarray) -> tuple[bool, float]:
        """One keypoint measurement: accepted (passes the chi-square test) and its d^2."""
        H = prediction.H
        r = np.asarray(uv, float) - prediction.uv
        HP = H @ self.P
        S = HP @ H.T + self._R
        d2 = float(r @ np.linalg.solve(S, r))
        if not np.isfinite(d2) or d2 > self.params.chi2_threshold:
            return False, d2
        K = np.linalg.solve(S, HP).T
        dx = K @ r
        self.p = self.p + dx[0:3]
        self.q = quaternion_product(quaternion_from_rotation_vector(dx[3:6]), self.q)
        self.q /= np.linalg.norm(self.q)
        self.v = self.v + dx[6:9]
        if self.n == 12:
            self.a = self.a + dx[9:12]
        A = self._I - K @ H
        self.P = A @ self.P @ A.T + K @ self._R @ K.T
        self.P = (self.P + self.P.T) / 2
        return True, d2
