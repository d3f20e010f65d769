"""Body-rate PID controller: rate error -> torque demand, as PX4's rate controller.

alpha = Kp e + Ki integral(e) - Kd d(w)/dt (derivative on measurement), torque = J alpha + w x J w.
The integrator is clamped and reset while disarmed or landed, like PX4's.
"""
import dataclasses as dc

import numpy as np

from alight.systems.params import bounded
from alight.systems.rotations import cross


@dc.dataclass
class RateControlParams:
    kp: list[float] = bounded([14.0, 14.0, 8.0], 0.0, 200.0, "1/s")
    ki: list[float] = bounded([10.0, 10.0, 5.0], 0.0, 500.0, "1/s^2")
    kd: list[float] = bounded([0.25, 0.25, 0.0], 0.0, 10.0, "")
    integrator_limit: list[float] = bounded([3.0, 3.0, 2.0], 0.0, 50.0, "rad/s^2")


class RatePid:
    """The rate PID's law and memory (the integral of the rate error (3) and the previous
    measured rate (3), updated every `period`), for the inner loop (inner_loop.py).
    Vectors are sequences of Python floats: on 3-vectors NumPy's per-call overhead dominates."""

    def __init__(self, params: RateControlParams, inertia: np.ndarray, period: float):
        self._J = np.asarray(inertia, float).tolist()
        self._period = period
        self._kp = np.asarray(params.kp, float).tolist()
        self._kd = np.asarray(params.kd, float).tolist()
        self._ki_dt = (np.asarray(params.ki, float) * period).tolist()
        self._limit = np.asarray(params.integrator_limit, float).tolist()

    def torque(self, rate_setpoint, w, memory) -> list[float]:
        """Torque demand [N m, in B] for the setpoint and the measured rate w [rad/s, in B]."""
        dt = self._period
        alpha = [kp * (r - v) + i - kd * (v - v0) / dt for kp, r, v, i, kd, v0
                 in zip(self._kp, rate_setpoint, w, memory[:3], self._kd, memory[3:])]
        gyroscopic = cross(w, [j * v for j, v in zip(self._J, w)]).tolist()
        return [j * a + g for j, a, g in zip(self._J, alpha, gyroscopic)]

    def updated(self, rate_setpoint, w, armed: bool, memory) -> list[float]:
        """The memory after one period: the clamped integral (reset while disarmed) and w."""
        if not armed:
            return [0.0, 0.0, 0.0, *w]
        return [min(max(i + k * (r - v), -limit), limit) for i, k, r, v, limit
                in zip(memory[:3], self._ki_dt, rate_setpoint, w, self._limit)] + list(w)
