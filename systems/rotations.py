"""Small rotation helpers on (w, x, y, z) quaternions, in plain NumPy for per-tick speed.

pydrake.math (`RotationMatrix`, `RollPitchYaw`) is the reference; these avoid constructing Drake
objects inside callbacks that run at every plant step. Tests check them against pydrake.
"""
import numpy as np


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """R_WB of the unit quaternion q_WB = (w, x, y, z) (normalized here)."""
    w, x, y, z = np.asarray(q) / np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (w, x, y, z) quaternions."""
    w1, v1, w2, v2 = a[0], a[1:], b[0], b[1:]
    return np.concatenate([[w1 * w2 - v1 @ v2], w1 * v2 + w2 * v1 + cross(v1, v2)])


def conjugate(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc quaternion rotating unit vector a onto unit vector b."""
    q = np.concatenate([[1.0 + a @ b], cross(a, b)])
    norm = np.linalg.norm(q)
    if norm < 1e-9:  # opposite vectors: half a turn about any perpendicular axis
        axis = cross(a, np.array([1.0, 0.0, 0.0]))
        if np.linalg.norm(axis) < 1e-6:
            axis = cross(a, np.array([0.0, 1.0, 0.0]))
        return np.concatenate([[0.0], axis / np.linalg.norm(axis)])
    return q / norm


def quaternion_from_rotation_vector(r: np.ndarray) -> np.ndarray:
    angle = np.linalg.norm(r)
    if angle < 1e-12:
        return np.array([1.0, 0.5 * r[0], 0.5 * r[1], 0.5 * r[2]])
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * r / angle])


def heading(R_WB: np.ndarray) -> float:
    """M(3)-(5): the heading, the azimuth of b1 projected to the horizontal plane."""
    return float(np.arctan2(R_WB[1, 0], R_WB[0, 0]))


def heading_quaternion(eta: float) -> np.ndarray:
    """Level orientation with heading eta."""
    return np.array([np.cos(eta / 2), 0.0, 0.0, np.sin(eta / 2)])


def tilt_deg(q: np.ndarray) -> np.ndarray:
    """Tilt [deg]: the angle between z_B and z_W, for (w, x, y, z) quaternions (rows)."""
    q = np.atleast_2d(q)
    return np.degrees(np.arccos(np.clip(1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1, 1)))
