"""Small rotation helpers on (w, x, y, z) quaternions, in plain NumPy for per-tick speed.

pydrake.math (`RotationMatrix`, `RollPitchYaw`) is the reference; these avoid constructing Drake
objects inside callbacks that run at every plant step. Tests check them against pydrake.
The per-tick ones compute on Python floats (`float_list`): on 3- and 4-vectors that is several times
faster than NumPy array arithmetic, whose per-call overhead dominates at this size. `norm` and
`all_finite` are such per-tick stand-ins for np.linalg.norm and np.all(np.isfinite(...)).
"""
import math

import numpy as np


def float_list(v) -> list[float]:
    """The elements of a short vector (array, list or tuple) as Python floats."""
    return v.tolist() if isinstance(v, np.ndarray) else [float(e) for e in v]


def norm(v: np.ndarray) -> float:
    """np.linalg.norm of a 1-D float array, the same value (its sqrt(v.dot(v))) without its
    per-call overhead."""
    return math.sqrt(v.dot(v))


def all_finite(v: np.ndarray) -> bool:
    """np.all(np.isfinite(v)) of a short 1-D array, without NumPy's per-call overhead."""
    return all(map(math.isfinite, v.tolist()))


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a1, a2, a3 = float_list(a)
    b1, b2, b3 = float_list(b)
    return np.array([a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1])


def unit_floats(w: float, x: float, y: float, z: float) -> tuple[float, ...] | None:
    """(w, x, y, z) normalized, as floats; None for the zero quaternion (no rotation)."""
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if norm == 0.0:
        return None
    return w / norm, x / norm, y / norm, z / norm


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """R_WB of the unit quaternion q_WB = (w, x, y, z) (normalized here)."""
    unit = unit_floats(*float_list(q))
    if unit is None:
        return np.full((3, 3), np.nan)
    w, x, y, z = unit
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def quaternion_product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of (w, x, y, z) quaternions."""
    return np.array(product_floats(*float_list(a), *float_list(b)))


def product_floats(w1: float, x1: float, y1: float, z1: float,
                   w2: float, x2: float, y2: float, z2: float) -> list[float]:
    """`quaternion_product` of two quaternions given as floats, as floats."""
    return [w1 * w2 - (x1 * x2 + y1 * y2 + z1 * z2),
            w1 * x2 + w2 * x1 + (y1 * z2 - z1 * y2),
            w1 * y2 + w2 * y1 + (z1 * x2 - x1 * z2),
            w1 * z2 + w2 * z1 + (x1 * y2 - y1 * x2)]


def conjugate(q: np.ndarray) -> np.ndarray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc quaternion rotating unit vector a onto unit vector b."""
    a1, a2, a3 = float_list(a)
    b1, b2, b3 = float_list(b)
    q = [1.0 + (a1 * b1 + a2 * b2 + a3 * b3), a2 * b3 - a3 * b2, a3 * b1 - a1 * b3,
         a1 * b2 - a2 * b1]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if norm < 1e-9:  # opposite vectors: half a turn about any perpendicular axis
        axis = cross(a, np.array([1.0, 0.0, 0.0]))
        if np.linalg.norm(axis) < 1e-6:
            axis = cross(a, np.array([0.0, 1.0, 0.0]))
        return np.concatenate([[0.0], axis / np.linalg.norm(axis)])
    return np.array([q[0] / norm, q[1] / norm, q[2] / norm, q[3] / norm])


def quaternion_from_rotation_vector(r: np.ndarray) -> np.ndarray:
    x, y, z = float_list(r)
    angle = math.sqrt(x * x + y * y + z * z)
    if not math.isfinite(angle):
        return np.full(4, np.nan)
    if angle < 1e-12:
        return np.array([1.0, 0.5 * x, 0.5 * y, 0.5 * z])
    scale = math.sin(angle / 2) / angle
    return np.array([math.cos(angle / 2), scale * x, scale * y, scale * z])


def heading(R_WB: np.ndarray) -> float:
    """M(3)-(5): the heading, the azimuth of b1 projected to the horizontal plane."""
    return float(np.arctan2(R_WB[1, 0], R_WB[0, 0]))


def quaternion_heading(w: float, x: float, y: float, z: float) -> float:
    """`heading(rotation_matrix(q))` of q = (w, x, y, z) given as floats, without the matrix: the
    same operations on its two elements."""
    unit = unit_floats(w, x, y, z)
    if unit is None:  # (rotation_matrix's NaN matrix)
        return float(np.arctan2(math.nan, math.nan))
    w, x, y, z = unit
    return float(np.arctan2(2 * (x * y + w * z), 1 - 2 * (y * y + z * z)))


def heading_quaternion(eta: float) -> np.ndarray:
    """Level orientation with heading eta."""
    return np.array([np.cos(eta / 2), 0.0, 0.0, np.sin(eta / 2)])


def tilt_deg(q: np.ndarray) -> np.ndarray:
    """Tilt [deg]: the angle between z_B and z_W, for (w, x, y, z) quaternions (rows)."""
    q = np.atleast_2d(q)
    return np.degrees(np.arccos(np.clip(1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2), -1, 1)))
