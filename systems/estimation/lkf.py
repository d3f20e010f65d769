"""The linear Kalman filter of the flight-stack paper, M Sec. 3.1-3.2, on the decoupled model
M(6)-(11): x = [x, x', x'', y, y', y'', z, z', z'', eta, eta'], x[t] = A x[t-1] + B u[t].

The translational axes each follow A_r(dt, p) / B_r(dt, 1 - p) of M(10) (p1 horizontal, p2
vertical), the heading A_eta(dt, p3) of M(11) with no input (M Sec. 3.1.1). The input u is the
unbiased desired acceleration a_d of M(53). As M Sec. 3.1 says, the subsystems are kept apart:
the state is stored per axis (3 x 3 and 2) so every operation uses 3 x 3 matrices at most.

Corrections are scalar per axis (the subsystems are decoupled, so a measurement of several axes
is a sum of independent scalar updates and its normalized innovation squared (NIS) is the sum of
theirs). A measurement `age` seconds old is compared with the state propagated back along the
model (H = [1, -age, age^2 / 2] for a position): cheap latency compensation without a buffer.
Innovation gating: a measurement whose NIS exceeds the chi-square quantile `gate` is rejected,
or, for a precise source whose prediction may be the wrong one (a rangefinder against a model
input the ground contradicts), clipped: fused with its innovation scaled onto the gate, so that a
spike moves the state by at most the gate's worth and a drifting prediction is still pulled back
(rejecting it would leave the axis to the wrong input and the gap would only grow).
"""
import dataclasses as dc

import numpy as np

from alight.systems.estimation.heading import wrap_angle
from alight.systems.params import bounded

POSITION, VELOCITY = 0, 1  # the derivative order a translational measurement observes


@dc.dataclass
class FilterModelParams:
    """The three free parameters of M(8)-(9) and the process noise (the paper gives no values:
    tuned on the simulated F550 at 100 Hz)."""
    p: list[float] = bounded([0.9, 0.9, 0.99], 0.0, 0.9999)   # p1, p2, p3 of M(8)-(9)
    # white-noise drive of the acceleration states (horizontal, vertical) [m/s^2 / sqrt(s)]
    acceleration_noise: list[float] = bounded([3.0, 3.0], 1e-6, 1e3)
    heading_rate_noise: float = bounded(1.0, 1e-6, 1e3, "rad/s / sqrt(s)")
    initial_position_std: float = bounded(1.0, 1e-3, 1e4, "m")
    initial_velocity_std: float = bounded(0.3, 1e-3, 1e3, "m/s")
    initial_heading_std: float = bounded(10.0, 1e-3, 180.0, "deg")


class DecoupledKf:
    """One hypothesis: translational states `x` (3 axes x [p, v, a]) with covariances `P`
    (3 x 3 x 3), heading states `eta` [eta, eta'] with covariance `P_eta` (2 x 2)."""

    def __init__(self, params: FilterModelParams, dt: float):
        self.params = params
        self.dt = dt
        p1, p2, p3 = params.p
        self._A = np.stack([_A_r(dt, p) for p in (p1, p1, p2)])          # M(10), per axis
        self._b = np.array([1.0 - p1, 1.0 - p1, 1.0 - p2])               # B_r of M(10)
        self._A_eta = np.array([[1.0, dt], [0.0, p3]])                  # M(11)
        g = np.array([dt * dt / 2, dt, 1.0])
        noise = np.array(params.acceleration_noise)[[0, 0, 1]] ** 2 * dt
        self._Q = noise[:, None, None] * np.outer(g, g)[None]
        self._Q_eta = params.heading_rate_noise ** 2 * dt * np.outer([dt / 2, 1.0], [dt / 2, 1.0])
        self.reset()

    def reset(self) -> None:
        s = self.params
        self.x = np.zeros((3, 3))
        self.P = np.stack([np.diag([s.initial_position_std ** 2, s.initial_velocity_std ** 2,
                                    1.0])] * 3)
        self.eta = np.zeros(2)
        self.P_eta = np.diag([np.radians(s.initial_heading_std) ** 2, 0.1])
        self.positioned = np.zeros(3, bool)  # per axis: position set from a measurement
        self.observed = np.zeros(3, bool)    # per axis: any measurement fused

    def copy(self) -> "DecoupledKf":
        other = object.__new__(DecoupledKf)
        other.__dict__.update(self.__dict__)
        other.x, other.P = self.x.copy(), self.P.copy()
        other.eta, other.P_eta = self.eta.copy(), self.P_eta.copy()
        other.positioned, other.observed = self.positioned.copy(), self.observed.copy()
        return other

    def predict(self, u: np.ndarray) -> None:
        """M(7): one step of dt with the unbiased desired acceleration u (3) in this frame."""
        self.x = np.einsum("aij,aj->ai", self._A, self.x)
        self.x[:, 2] += self._b * u
        self.P = np.einsum("aij,ajk,alk->ail", self._A, self.P, self._A) + self._Q
        self.eta = self._A_eta @ self.eta
        self.eta[0] = wrap_angle(self.eta[0])
        self.P_eta = self._A_eta @ self.P_eta @ self._A_eta.T + self._Q_eta

    def set_position(self, axes, position, variance) -> None:
        """Initialization or reset of the position of `axes` (velocity kept, covariance reset)."""
        for i, axis in enumerate(axes):
            self.x[axis, POSITION] = position[i]
            self.P[axis, 0, :] = self.P[axis, :, 0] = 0.0
            self.P[axis, 0, 0] = variance[i]
        self.positioned[list(axes)] = True
        self.observed[list(axes)] = True

    def correct(self, axes, order: int, z, variance, age: float = 0.0,
                gate: float | None = None, clip: bool = False) -> tuple[bool, float]:
        """Position (order 0) or velocity (order 1) of `axes`, measured `age` s ago. Returns
        (within the gate, NIS); with `gate`, a measurement whose NIS exceeds it changes nothing,
        or with `clip` is fused with its innovation scaled down to NIS = gate."""
        h = np.array([1.0, -age, age * age / 2]) if order == POSITION else \
            np.array([0.0, 1.0, -age])
        axes = list(axes)
        P = self.P[axes]                                   # (k, 3, 3)
        Ph = P @ h                                         # (k, 3)
        S = Ph @ h + np.asarray(variance, float)           # (k,)
        innovation = np.asarray(z, float) - self.x[axes] @ h
        nis = float(np.sum(innovation * innovation / S))
        passed = gate is None or nis <= gate
        if not passed and not clip:
            return False, nis
        if not passed:
            innovation = innovation * np.sqrt(gate / nis)
        K = Ph / S[:, None]
        self.x[axes] += K * innovation[:, None]
        self.P[axes] = P - K[:, :, None] * Ph[:, None, :]
        self.observed[axes] = True
        return passed, nis

    def correct_heading(self, z: float, variance: float, order: int = 0,
                        gate: float | None = None) -> tuple[bool, float]:
        """The heading (order 0, M(3)) or the heading rate (order 1, M(15))."""
        h = np.eye(2)[order]
        Ph = self.P_eta @ h
        S = float(h @ Ph + variance)
        innovation = float(wrap_angle(z - self.eta[0])) if order == 0 else z - self.eta[1]
        nis = innovation * innovation / S
        if gate is not None and nis > gate:
            return False, nis
        K = Ph / S
        self.eta = self.eta + K * innovation
        self.eta[0] = wrap_angle(self.eta[0])
        self.P_eta = self.P_eta - np.outer(K, Ph)
        return True, nis

    def covariance_trace(self) -> float:
        """The arbiter's criterion (M Sec. 3.5), on the position block: the hypotheses differ by
        their position sources; adding (m/s)^2 to m^2 would let velocity noise decide."""
        return float(self.P[:, 0, 0].sum())

    def variances(self) -> np.ndarray:
        """[var p (3), var v (3)]."""
        return np.concatenate([self.P[:, 0, 0], self.P[:, 1, 1]])


def _A_r(dt: float, a: float) -> np.ndarray:
    return np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, a]])
