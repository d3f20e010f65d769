"""SO(3) force tracking, M(17)-(31) and M Sec. 5.3: a desired force and heading become body rates.

- `desired_orientation`: R_d from the desired force f_d and heading eta_d, either the original
  construction M(18)-(20) (b1 is the orthogonal projection of the heading vector onto the plane
  normal to b3: the heading is not kept when tilted) or the heading-compliant one M(21)-(23) (b1 is
  the oblique projection of the heading vector along e3 onto that plane: heading(R_d) = eta_d).
- `rotation_error`: e_R of M(24).
- `jerk_feedforward`: omega_j of M(26), the body rates that turn b3 with the desired force when the
  reference has jerk. Printed M(26) reads ||f_d|| / m_e and [e3]_x^T; its units and sign only work
  out as m_e / ||f_d|| and [e3]_x (d b3 / dt = (I - b3 b3^T) m_e jerk / ||f_d||, and
  R^T d b3 / dt = omega x e3): that is what is implemented, and a test checks it against finite
  differences of R_d along a trajectory.
- `yaw_rate_for_heading_rate`: M(27)-(31), the rate about b3 that produces a heading rate.
- `heading_rate`: M(15), the heading rate that body rates produce (used for the parasitic heading
  rate of M Sec. 5.3).
- `body_rate_command`: M(25) with the feedforward yaw rate of M Sec. 5.2 and the parasitic
  heading-rate compensation of M Sec. 5.3.

Plain NumPy (per-tick speed); rotation helpers come from alight.systems.rotations.
"""
import dataclasses as dc

import numpy as np

from alight.systems.params import bounded, choice
from alight.systems.rotations import cross

E3 = np.array([0.0, 0.0, 1.0])
_P_XY = np.array([[1.0, 0.0], [0.0, 1.0], [0.0, 0.0]])  # P = [e1, e2] of M(22)


@dc.dataclass
class So3Params:
    """SO(3) force tracking and its output limits (models/controllers.yaml, `so3`)."""
    orientation: str = choice("heading_compliant", "original")  # M(21)-(23) or M(18)-(20)
    k_R: list[float] = bounded([6.0, 6.0, 3.0], 0.0, 100.0, "1/s")     # M(25)
    max_rate: list[float] = bounded([3.5, 3.5, 3.0], 0.1, 6.0, "rad/s")  # the FC refuses > 6
    max_tilt: float = bounded(60.0, 5.0, 85.0, "deg")  # of the desired force
    thrust_limits: list[float] = bounded([0.0, 1.0], 0.0, 1.0)  # normalized thrust T_d
    thrust_ramp_rate: float = bounded(0.5, 0.01, 20.0, "1/s")   # T_d slew after activation


def heading_vector(eta: float) -> np.ndarray:
    """M(17): the unit heading vector h_d = [cos eta, sin eta, 0]."""
    return np.array([np.cos(eta), np.sin(eta), 0.0])


def desired_orientation(f_d: np.ndarray, eta_d: float, heading_compliant: bool = True
                        ) -> np.ndarray:
    """R_d (3x3) with b3 along f_d (which must point up: f_d[2] > 0) and b1 from the heading."""
    b3 = f_d / np.linalg.norm(f_d)
    h = heading_vector(eta_d)
    if heading_compliant:
        # M(22): b1 = O (P^T O)^-1 P^T h, O = first two columns of the projector I - b3 b3^T.
        O = (np.eye(3) - np.outer(b3, b3))[:, :2]
        b1 = O @ np.linalg.solve(_P_XY.T @ O, _P_XY.T @ h)
        b1 /= np.linalg.norm(b1)
        return np.column_stack([b1, cross(b3, b1), b3])        # M(21), M(23)
    p2 = cross(b3, h)
    p2 /= np.linalg.norm(p2)
    return np.column_stack([cross(p2, b3), p2, b3])            # M(18)-(19)


def limit_tilt(f_d: np.ndarray, max_tilt: float, min_vertical: float) -> np.ndarray:
    """f_d with its vertical part at least `min_vertical` [N] and its angle from e3 at most
    `max_tilt` [rad] (the horizontal part is scaled down, keeping its direction)."""
    f = np.array(f_d, dtype=float)
    f[2] = max(f[2], min_vertical)
    horizontal = np.hypot(f[0], f[1])
    limit = f[2] * np.tan(max_tilt)
    if horizontal > limit:
        f[:2] *= limit / horizontal
    return f


def rotation_error(R_d: np.ndarray, R: np.ndarray) -> np.ndarray:
    """M(24): e_R = vee(1/2 (R_d^T R - R^T R_d)), in B."""
    E = 0.5 * (R_d.T @ R - R.T @ R_d)
    return np.array([E[2, 1], E[0, 2], E[1, 0]])


def jerk_feedforward(f_d_norm: float, m_e: float, R_d: np.ndarray, jerk: np.ndarray
                     ) -> np.ndarray:
    """M(26) (units and sign as derived in the module docstring): omega_j in B [rad/s]."""
    u = (m_e / f_d_norm) * (R_d.T @ jerk)
    return np.array([-u[1], u[0], 0.0])


def heading_rate(R: np.ndarray, omega: np.ndarray) -> float:
    """M(15): the heading rate [rad/s] that body rates omega [rad/s, in B] give at orientation R."""
    R_dot = R @ np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]],
                          [-omega[1], omega[0], 0.0]])
    norm2 = R[0, 0] ** 2 + R[1, 0] ** 2
    if norm2 < 1e-9:
        return 0.0
    return float((-R[1, 0] * R_dot[0, 0] + R[0, 0] * R_dot[1, 0]) / norm2)


def yaw_rate_for_heading_rate(R: np.ndarray, eta_rate: float) -> float:
    """M(27)-(31): the body rate about b3 [rad/s] that turns the heading at `eta_rate` [rad/s]."""
    h = np.array([R[0, 0], R[1, 0], 0.0])                      # M(4)
    norm_h = np.linalg.norm(h)
    if norm_h < 1e-6 or eta_rate == 0.0:
        return 0.0
    h_dot = cross(np.array([0.0, 0.0, eta_rate]), h)           # M(27)
    axis = cross(E3, h / norm_h)
    p = axis * (axis @ R[:, 1])                                # M(28)-(29)
    norm_p = np.linalg.norm(p)
    if norm_p < 1e-6:
        return 0.0
    return float(np.sign(h_dot @ p) * np.linalg.norm(h_dot) / norm_p)  # M(30)-(31)


def body_rate_command(R: np.ndarray, R_d: np.ndarray, params: So3Params, omega_j: np.ndarray,
                      eta_rate_d: float) -> np.ndarray:
    """M(25): omega_d = -k_R o e_R + omega_j + [0, 0, omega_3d] - omega_c, clipped to max_rate.

    omega_3d realizes the reference heading rate (M Sec. 5.2); omega_c cancels the heading rate
    that the roll/pitch part of the command would cause on its own (M Sec. 5.3)."""
    omega = -np.asarray(params.k_R) * rotation_error(R_d, R) + omega_j
    parasitic = heading_rate(R, np.array([omega[0], omega[1], 0.0]))
    omega[2] += yaw_rate_for_heading_rate(R, eta_rate_d) - yaw_rate_for_heading_rate(R, parasitic)
    return np.clip(omega, -np.asarray(params.max_rate), params.max_rate)
