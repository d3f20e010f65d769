"""Position hold of the simulated PX4 (Hold and Position modes without sticks, and the
offboard-loss failsafe with a valid local position): PX4's multicopter position control cascade,
MPC_* gains, on the autopilot's local position (systems/autopilot/ev_fusion.py).

Position error -> velocity setpoint (MPC_XY_P, MPC_Z_P, limited to the hold speeds) -> acceleration
(MPC_XY_VEL_P_ACC / _I_ACC, MPC_Z_VEL_P_ACC / _I_ACC) -> thrust vector a + g z_W, tilted at most
MPC_TILTMAX_AIR, with PX4's normalisation collective thrust = |a + g| MPC_THR_HOVER / g ->
attitude (thrust direction and the held heading) + thrust: an attitude+thrust `fc_command`.
"""
import dataclasses as dc
import math

import numpy as np
from pydrake.math import RotationMatrix

from alight.systems.params import bounded
from alight.systems.thrust_curve import GRAVITY


@dc.dataclass
class PositionHoldParams:
    """PX4's position-controller parameters (names without the MPC_ prefix)."""
    xy_p: float = bounded(0.95, 0.0, 5.0, "1/s")          # MPC_XY_P
    z_p: float = bounded(1.0, 0.0, 5.0, "1/s")            # MPC_Z_P
    xy_vel_p_acc: float = bounded(1.8, 0.0, 10.0, "1/s")  # MPC_XY_VEL_P_ACC
    xy_vel_i_acc: float = bounded(0.4, 0.0, 10.0, "1/s^2")  # MPC_XY_VEL_I_ACC
    z_vel_p_acc: float = bounded(4.0, 0.0, 20.0, "1/s")   # MPC_Z_VEL_P_ACC
    z_vel_i_acc: float = bounded(2.0, 0.0, 20.0, "1/s^2")  # MPC_Z_VEL_I_ACC
    xy_vel_max: float = bounded(2.0, 0.1, 20.0, "m/s")    # hold speed limit (MPC_VEL_MANUAL-like)
    z_vel_max: float = bounded(1.0, 0.1, 5.0, "m/s")      # MPC_Z_VEL_MAX_DN
    tiltmax_air: float = bounded(45.0, 1.0, 89.0, "deg")  # MPC_TILTMAX_AIR


class PositionHold:
    """Holds `p_hold` (W, z up) at `heading`; `command(p, v, dt)` -> (q_WD, thrust)."""

    def __init__(self, params: PositionHoldParams, hover_thrust: float):
        self._p, self._hover = params, hover_thrust
        self.p_hold = np.zeros(3)
        self.heading = 0.0
        self._integral = np.zeros(3)

    def reset(self, p_hold, heading: float) -> None:
        self.p_hold, self.heading = np.array(p_hold, dtype=float), float(heading)
        self._integral = np.zeros(3)

    def command(self, p, v, dt: float) -> tuple[np.ndarray, float]:
        P = self._p
        gains_p = np.array([P.xy_p, P.xy_p, P.z_p])
        v_sp = gains_p * (self.p_hold - np.asarray(p))
        horizontal = np.linalg.norm(v_sp[:2])
        if horizontal > P.xy_vel_max:
            v_sp[:2] *= P.xy_vel_max / horizontal
        v_sp[2] = np.clip(v_sp[2], -P.z_vel_max, P.z_vel_max)
        error = v_sp - np.asarray(v)
        self._integral += error * dt
        acc = np.array([P.xy_vel_p_acc, P.xy_vel_p_acc, P.z_vel_p_acc]) * error \
            + np.array([P.xy_vel_i_acc, P.xy_vel_i_acc, P.z_vel_i_acc]) * self._integral
        force = acc + np.array([0.0, 0.0, GRAVITY])
        force[2] = max(force[2], 0.1 * GRAVITY)  # never ask for a thrust pointing down
        max_horizontal = force[2] * math.tan(math.radians(P.tiltmax_air))
        horizontal = np.linalg.norm(force[:2])
        if horizontal > max_horizontal:
            force[:2] *= max_horizontal / horizontal
        thrust = float(np.clip(np.linalg.norm(force) * self._hover / GRAVITY, 0.0, 1.0))
        z_D = force / np.linalg.norm(force)
        x_C = np.array([math.cos(self.heading), math.sin(self.heading), 0.0])
        y_D = np.cross(z_D, x_C)
        y_D /= np.linalg.norm(y_D)
        R_WD = RotationMatrix(np.column_stack([np.cross(y_D, z_D), y_D, z_D]))
        return R_WD.ToQuaternion().wxyz(), thrust
