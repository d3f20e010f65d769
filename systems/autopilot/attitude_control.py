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
from alight.systems.rotations import conjugate, quaternion_product, rotation_between


@dc.dataclass
class AttitudeControlParams:
    gain: list[float] = bounded([6.0, 6.0, 2.8], 0.0, 50.0, "1/s")  # roll, pitch, yaw
    yaw_weight: float = bounded(0.4, 0.0, 1.0)
    max_rate: list[float] = bounded([3.8, 3.8, 3.5], 0.1, 20.0, "rad/s")  # PX4 MC_*RATE_MAX


def attitude_rate_setpoint(q_WB: np.ndarray, q_WD: np.ndarray, params: AttitudeControlParams):
    """Body-rate setpoint [rad/s, in B] that turns the estimated attitude toward the desired one."""
    q_WB = q_WB / math.sqrt(q_WB @ q_WB)
    q_WD = q_WD / math.sqrt(q_WD @ q_WD)
    z_B = _z_axis(q_WB)
    z_D = _z_axis(q_WD)
    q_reduced = quaternion_product(rotation_between(z_B, z_D), q_WB)  # tilt corrected only
    q_mix = quaternion_product(conjugate(q_reduced), q_WD)            # remaining rotation (yaw)
    if q_mix[0] < 0:
        q_mix = -q_mix
    w_mix = min(max(float(q_mix[0]), -1.0), 1.0)
    z_mix = min(max(float(q_mix[3]), -1.0), 1.0)
    q_mix = np.array([math.cos(params.yaw_weight * math.acos(w_mix)), 0.0, 0.0,
                      math.sin(params.yaw_weight * math.asin(z_mix))])
    q_target = quaternion_product(q_reduced, q_mix)
    q_error = quaternion_product(conjugate(q_WB), q_target)
    sign = -2.0 if q_error[0] < 0 else 2.0
    max_rate = params.max_rate
    return np.array([min(max(sign * float(q_error[i + 1]) * params.gain[i], -max_rate[i]),
                         max_rate[i]) for i in range(3)])


def _z_axis(q: np.ndarray) -> np.ndarray:
    """The third column of rotation_matrix(q) for a unit quaternion q = (w, x, y, z)."""
    w, x, y, z = q.tolist()
    return np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])


def rate_setpoint(setpoint: np.ndarray, fc_attitude: np.ndarray, params: AttitudeControlParams,
                  max_rate: np.ndarray) -> np.ndarray:
    """The body-rate setpoint [rad/s, in B] of a SETPOINT: the commanded rates (clipped to
    `max_rate`) in rates+thrust mode, `attitude_rate_setpoint` toward q_WD otherwise."""
    if int(SETPOINT.get(setpoint, "mode")) == CommandMode.RATES_THRUST:
        return np.minimum(np.maximum(SETPOINT.get(setpoint, "w_D"), -max_rate), max_rate)
    return attitude_rate_setpoint(FC_ATTITUDE.get(fc_attitude, "q_WB"),
                                  SETPOINT.get(setpoint, "q_WD"), params)
