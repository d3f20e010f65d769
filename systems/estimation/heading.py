"""Heading maths of the flight-stack paper: the orientation with an estimated heading M(12)-(14)
and the heading rate from body rates M(15). The heading itself is M(3)-(5)
(`alight.systems.rotations.heading`); no yaw from Euler angles is used here.
"""
import numpy as np

from alight.systems.rotations import heading


def rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def wrap_angle(angle):
    """Angle(s) wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle), 2.0 * np.pi)


def with_heading(R_o: np.ndarray, eta: float) -> np.ndarray:
    """M(12)-(14): the flight controller's orientation R_o turned about e3 to heading eta."""
    return rotation_z(eta - heading(R_o)) @ R_o


def heading_rate(R: np.ndarray, w_B: np.ndarray) -> float:
    """M(15): the heading rate from the body rates w_B, through R_dot = R Omega (M(2)).
    Only defined while |e3^T b1| < 1 (b1 not vertical); returns 0 there."""
    R_dot = R @ np.array([[0.0, -w_B[2], w_B[1]], [w_B[2], 0.0, -w_B[0]],
                          [-w_B[1], w_B[0], 0.0]])
    norm2 = R[0, 0] ** 2 + R[1, 0] ** 2
    if norm2 < 1e-9:
        return 0.0
    return float((-R[1, 0] * R_dot[0, 0] + R[0, 0] * R_dot[1, 0]) / norm2)
