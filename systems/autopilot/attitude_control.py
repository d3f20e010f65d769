"""Attitude controller: attitude error -> body-rate setpoint, as PX4's quaternion controller.

The tilt (z_B) error is corrected first and the heading error only with weight `yaw_weight`
(reduced-attitude priority of Brescianini et al., used by PX4), then a proportional law on the
vector part of the error quaternion gives the rate setpoint, clipped to the rate limits.
In rates+thrust mode the commanded body rates pass through (clipped). The flight controller's
inner loop (inner_loop.py) calls `rate_setpoint` every tick.
"""
import dataclasses as dc
import math

import numpy as np

from alight.systems.autopilot.setpoint import SETPOINT
from alight.systems.boundary import FC_ATTITUDE, CommandMode
from alight.systems.params import bounded
from alight.systems.rotations import product_floats, rotation_between


@dc.dataclass
class AttitudeControlParams:
    gain: list[float] = bounded([6.0, 6.0, 2.8], 0.0, 50.0, "1/s")  # roll, pitch, yaw
    yaw_weight: float = bounded(0.4, 0.0, 1.0)
    max_rate: list[float] = bounded([3.8, 3.8, 3.5], 0.1, 20.0, "rad/s")  # PX4 MC_*RATE_MAX


def attitude_rate_setpoint(q_WB: np.ndarray, q_WD: np.ndarray,
                           params: AttitudeControlParams) -> list[float]:
    """Body-rate setpoint [rad/s, in B] that turns the estimated attitude toward the desired one."""
    # On Python floats: on 4-vectors NumPy's per-call overhead dominates. The norms keep NumPy's
    # dot product (its summation may round differently from plain floats).
    norm_B, norm_D = math.sqrt(q_WB @ q_WB), math.sqrt(q_WD @ q_WD)
    q_WB = [e / norm_B for e in q_WB.tolist()]
    q_WD = [e / norm_D for e in q_WD.tolist()]
    q_reduced = product_floats(*rotation_between(_z_axis(*q_WB), _z_axis(*q_WD)).tolist(),
                               *q_WB)                       # tilt corrected only
    q_mix = product_floats(*_conjugate(*q_reduced), *q_WD)  # remaining rotation (yaw)
    if q_mix[0] < 0:
        q_mix = [-e for e in q_mix]
    w_mix = min(max(q_mix[0], -1.0), 1.0)
    z_mix = min(max(q_mix[3], -1.0), 1.0)
    q_target = product_floats(*q_reduced, math.cos(params.yaw_weight * math.acos(w_mix)), 0.0,
                              0.0, math.sin(params.yaw_weight * math.asin(z_mix)))
    q_error = product_floats(*_conjugate(*q_WB), *q_target)
    sign = -2.0 if q_error[0] < 0 else 2.0
    max_rate = params.max_rate
    return [min(max(sign * q_error[i + 1] * params.gain[i], -max_rate[i]), max_rate[i])
            for i in range(3)]


def _z_axis(w: float, x: float, y: float, z: float) -> list[float]:
    """The third column of rotation_matrix(q) for a unit quaternion q = (w, x, y, z)."""
    return [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]


def _conjugate(w: float, x: float, y: float, z: float) -> tuple[float, ...]:
    return w, -x, -y, -z


def rate_setpoint(setpoint: np.ndarray, fc_attitude: np.ndarray, params: AttitudeControlParams,
                  max_rate: list[float]) -> list[float]:
    """The body-rate setpoint [rad/s, in B] of a SETPOINT: the commanded rates (clipped to
    `max_rate`) in rates+thrust mode, `attitude_rate_setpoint` toward q_WD otherwise."""
    if int(setpoint[_MODE]) == CommandMode.RATES_THRUST:
        return [min(max(w, -m), m) for w, m in zip(setpoint[_W_D].tolist(), max_rate)]
    return attitude_rate_setpoint(fc_attitude[_Q_WB], setpoint[_Q_WD], params)


_MODE = SETPOINT.slice("mode").start
_Q_WD, _W_D = SETPOINT.slice("q_WD"), SETPOINT.slice("w_D")
_Q_WB = FC_ATTITUDE.slice("q_WB")
