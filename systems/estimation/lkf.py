"""The linear Kalman filter of the flight-stack paper, M Sec. 3.1-3.2, on the decoupled model
M(6)-(11): x = [x, x', x'', y, y', y'', z, z', z'', eta, eta'], x[t] = A x[t-1] + B u[t].

The translational axes each follow A_r(dt, p) / B_r(dt, 1 - p) of M(10) (p1 horizontal, p2
vertical), the heading A_eta(dt, p3) of M(11) with no input (M Sec. 3.1.1). The input u is the
unbiased desired acceleration a_d of M(53). As M Sec. 3.1 says, the subsystems are kept apart:
the state is stored per axis (3 x 3 and 2) so every operation uses 3 x 3 matrices at most; the
bank's filters are stored together (`DecoupledKfBank`), so that one NumPy operation updates every
filter that fuses a measurement.

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


class DecoupledKfBank:
    """F hypotheses stepped together, each its own decoupled filter: translational states `x`
    (F x 3 axes x [p, v, a]) with covariances `P` (F x 3 x 3 x 3), heading states `eta`
    (F x [eta, eta']) with covariances `P_eta` (F x 2 x 2). Every operation takes the rows
    (filters) it applies to and is one NumPy operation over them: the same 3 x 3 (and 2 x 2)
    algebra per filter and axis as M Sec. 3.1 keeps apart, not a Python loop per filter."""

    def __init__(self, params: list[FilterModelParams], dt: float):
        self.params = list(params)
        self.dt = dt
        p = np.array([m.p for m in self.params]).reshape(-1, 3)
        axes_p = p[:, [0, 0, 1]]                                          # p1, p1, p2 per axis
        self._A = np.stack([np.stack([_A_r(dt, a) for a in row]) for row in axes_p])  # M(10)
        self._b = 1.0 - axes_p                                            # B_r of M(10)
        self._A_eta = np.stack([np.array([[1.0, dt], [0.0, p3]]) for p3 in p[:, 2]])  # M(11)
        g = np.array([dt * dt / 2, dt, 1.0])
        noise = np.array([np.array(m.acceleration_noise)[[0, 0, 1]] ** 2 * dt
                          for m in self.params]).reshape(-1, 3)
        self._Q = noise[:, :, None, None] * np.outer(g, g)
        gh = np.outer([dt / 2, 1.0], [dt / 2, 1.0])
        self._Q_eta = np.stack([m.heading_rate_noise ** 2 * dt * gh for m in self.params])
        self.reset()

    def __len__(self) -> int:
        return len(self.params)

    def reset(self) -> None:
        n = len(self)
        self.x = np.zeros((n, 3, 3))
        self.P = np.zeros((n, 3, 3, 3))
        self.eta = np.zeros((n, 2))
        self.P_eta = np.zeros((n, 2, 2))
        for i, s in enumerate(self.params):
            self.P[i] = np.diag([s.initial_position_std ** 2, s.initial_velocity_std ** 2, 1.0])
            self.P_eta[i] = np.diag([np.radians(s.initial_heading_std) ** 2, 0.1])
        self.positioned = np.zeros((n, 3), bool)  # per filter and axis: position measured
        self.observed = np.zeros((n, 3), bool)    # per filter and axis: any measurement fused

    def copy(self) -> "DecoupledKfBank":
        other = object.__new__(DecoupledKfBank)
        other.__dict__.update(self.__dict__)
        for name in ("x", "P", "eta", "P_eta", "positioned", "observed"):
            setattr(other, name, getattr(self, name).copy())
        return other

    def predict(self, u: np.ndarray) -> None:
        """M(7): one step of dt of every filter, each with its unbiased desired acceleration
        u (F x 3) in its own frame."""
        self.x = np.einsum("faij,faj->fai", self._A, self.x)
        self.x[:, :, 2] += self._b * u
        self.P = np.einsum("faij,fajk,falk->fail", self._A, self.P, self._A) + self._Q
        self.eta = np.einsum("fij,fj->fi", self._A_eta, self.eta)
        self.eta[:, 0] = wrap_angle(self.eta[:, 0])
        self.P_eta = self._A_eta @ self.P_eta @ self._A_eta.transpose(0, 2, 1) + self._Q_eta

    def set_position(self, rows, axes, position, variance) -> None:
        """Initialization or reset of the position of `axes` in filters `rows` (position and
        variance: rows x axes; velocity kept, covariance reset)."""
        rows, axes = np.asarray(rows), list(axes)
        r, a = np.ix_(rows, axes)
        self.x[r, a, POSITION] = position
        self.P[r, a, 0, :] = 0.0
        self.P[r, a, :, 0] = 0.0
        self.P[r, a, 0, 0] = variance
        self.positioned[r, a] = True
        self.observed[r, a] = True

    def correct(self, rows, axes, order: int, z, variance, age: float = 0.0,
                gate: float | None = None, gated=True, clip: bool = False
                ) -> tuple[np.ndarray, np.ndarray]:
        """Position (order 0) or velocity (order 1) of `axes` in filters `rows`, measured `age` s
        ago (z, variance: rows x axes). Returns per row (within the gate, NIS); with `gate`, in
        the rows where `gated`, a measurement whose NIS exceeds it changes nothing, or with
        `clip` is fused with its innovation scaled down to NIS = gate."""
        h = np.array([1.0, -age, age * age / 2]) if order == POSITION else \
            np.array([0.0, 1.0, -age])
        r, a = np.ix_(np.asarray(rows), list(axes))
        P = self.P[r, a]                                   # (n, k, 3, 3)
        Ph = P @ h                                         # (n, k, 3)
        S = Ph @ h + np.asarray(variance, float)           # (n, k)
        innovation = np.asarray(z, float) - self.x[r, a] @ h
        nis = np.sum(innovation * innovation / S, axis=1)
        passed = np.ones(len(nis), bool) if gate is None else ~(gated & ~(nis <= gate))
        fused = passed if not clip else np.ones(len(nis), bool)
        if not passed.all() and clip:
            innovation = np.where(passed[:, None], innovation,
                                  innovation * np.sqrt(gate / nis)[:, None])
        r = r[fused]
        K = Ph[fused] / S[fused][:, :, None]
        self.x[r, a] += K * innovation[fused][:, :, None]
        self.P[r, a] = P[fused] - K[:, :, :, None] * Ph[fused][:, :, None, :]
        self.observed[r, a] = True
        return passed, nis

    def correct_heading(self, rows, z, variance, order: int = 0, gate: float | None = None
                        ) -> np.ndarray:
        """The heading (order 0, M(3)) or the heading rate (order 1, M(15)) of filters `rows`
        (z, variance: per row). Returns per row whether it was within the gate."""
        rows = np.asarray(rows)
        h = np.eye(2)[order]
        Ph = self.P_eta[rows] @ h                          # (n, 2)
        S = Ph @ h + np.asarray(variance, float)
        innovation = wrap_angle(z - self.eta[rows, 0]) if order == 0 else \
            z - self.eta[rows, 1]
        nis = innovation * innovation / S
        passed = np.ones(len(rows), bool) if gate is None else ~(nis > gate)
        rows, Ph, S, innovation = rows[passed], Ph[passed], S[passed], innovation[passed]
        K = Ph / S[:, None]
        eta = self.eta[rows] + K * innovation[:, None]
        eta[:, 0] = wrap_angle(eta[:, 0])
        self.eta[rows] = eta
        self.P_eta[rows] = self.P_eta[rows] - K[:, :, None] * Ph[:, None, :]
        return passed

    def covariance_traces(self) -> np.ndarray:
        """The arbiter's criterion (M Sec. 3.5), per filter, on the position block: the
        hypotheses differ by their position sources; adding (m/s)^2 to m^2 would let velocity
        noise decide."""
        return self.P[:, :, 0, 0].sum(axis=1)

    def variances(self, i: int) -> np.ndarray:
        """[var p (3), var v (3)] of filter `i`."""
        return np.concatenate([self.P[i, :, 0, 0], self.P[i, :, 1, 1]])

    @staticmethod
    def initial_variances(params: FilterModelParams) -> tuple[np.ndarray, float]:
        """[var p (3), var v (3)] and the heading variance of a filter just reset."""
        return (np.repeat([params.initial_position_std ** 2, params.initial_velocity_std ** 2],
                          3), float(np.radians(params.initial_heading_std) ** 2))


def _A_r(dt: float, a: float) -> np.ndarray:
    return np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, a]])
