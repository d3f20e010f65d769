"""Multirotor mixer with saturation handling (PX4's desaturation logic, in thrust-force space).

Collective thrust (thrust curve M(32)-(34)) and torque demand are allocated to rotor thrusts through
the pseudo-inverse of the allocation matrix; when the rotors cannot deliver it, authority is given
up in a fixed order: first yaw, then collective thrust, and roll/pitch are scaled down last (keeping
their direction). Rotor thrusts are then turned into ESC commands by the inverse rotor curve.
"""
import math

import numpy as np

from alight.systems.autopilot.setpoint import SETPOINT
from alight.systems.plant.hexacopter import Airframe


def allocation_matrix(airframe: Airframe) -> np.ndarray:
    """Maps rotor thrusts to [collective force, torque x, torque y, torque z] in B."""
    x, y = airframe.p_BR[:, 0], airframe.p_BR[:, 1]
    return np.vstack([np.ones(airframe.num_rotors), y, -x, airframe.yaw_moment])


class MixerSolution:
    """Rotor thrusts [N] and how much of each demand survived (1 = fully delivered)."""

    def __init__(self, rotor_thrust, roll_pitch_scale, yaw_scale, collective_shift):
        self.rotor_thrust = rotor_thrust
        self.roll_pitch_scale = roll_pitch_scale
        self.yaw_scale = yaw_scale
        self.collective_shift = collective_shift


def mix(force: float, torque, pinv: np.ndarray, f_min: float, f_max: float) -> MixerSolution:
    """Rotor thrusts within [f_min, f_max] for a collective force [N] and torque [N m] (3 floats,
    a list or an array)."""
    # On Python floats (NumPy's per-call overhead dominates on 6-vectors), the collective and yaw
    # columns too (one product per element, as NumPy's); the roll/pitch allocation keeps NumPy's
    # matrix product (BLAS may round differently).
    force, yaw_torque = float(force), float(torque[2])
    collective_column, yaw_column = pinv[:, 0].tolist(), pinv[:, 3].tolist()
    base = [p * force for p in collective_column]
    roll_pitch = (pinv[:, 1:3] @ torque[:2]).tolist()
    yaw = [p * yaw_torque for p in yaw_column]
    low, high = _extent(roll_pitch)
    span = high - low
    rp_scale = min(1.0, (f_max - f_min) / span) if span > 0 else 1.0
    # Shift the collective (up or down) as little as possible to fit roll and pitch.
    fitted = [b + rp * rp_scale for b, rp in zip(base, roll_pitch)]
    lowest, highest = _extent(fitted)
    lo = f_min - lowest
    hi = f_max - highest
    shift = min(max(0.0, lo), hi)
    thrust = [f + shift for f in fitted]
    yaw_scale = 1.0
    for f, dy in zip(thrust, yaw):  # largest yaw fraction that keeps every rotor in range
        if dy > 1e-12:
            yaw_scale = min(yaw_scale, (f_max - f) / dy)
        elif dy < -1e-12:
            yaw_scale = min(yaw_scale, (f_min - f) / dy)
    yaw_scale = max(yaw_scale, 0.0)
    thrust = [min(max(f + yaw_scale * dy, f_min), f_max) for f, dy in zip(thrust, yaw)]
    return MixerSolution(np.array(thrust), rp_scale, yaw_scale, shift * len(thrust))


def _extent(values: list[float]) -> tuple[float, float]:
    """(min, max) of values, both NaN if one is NaN (as ndarray.min and max)."""
    if any(v != v for v in values):
        return math.nan, math.nan
    return min(values), max(values)


class Mixer:
    """Collective thrust (SETPOINT, in [0, 1]) and torque demand [N m, in B] -> ESC commands in
    [0, 1] (zero while disarmed), for the inner loop (inner_loop.py)."""

    def __init__(self, airframe: Airframe):
        self._pinv = np.linalg.pinv(allocation_matrix(airframe))
        self._collective = airframe.thrust_curve
        self._rotor = airframe.rotor_curve
        self._f_min = airframe.min_thrust
        self._f_max = airframe.max_thrust
        self._stopped = np.zeros(airframe.num_rotors)

    def motor_commands(self, setpoint: np.ndarray, torque) -> np.ndarray:
        if setpoint[_ARMED] < 0.5:
            return self._stopped
        force = self._collective.force(setpoint[_THRUST])
        solution = mix(force, torque, self._pinv, self._f_min, self._f_max)
        return np.array(self._rotor.thrust_floats(solution.rotor_thrust.tolist()))


_ARMED, _THRUST = SETPOINT.slice("armed").start, SETPOINT.slice("thrust").start
