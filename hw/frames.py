"""Frame conversions between the MAVLink wire and DESIGN.md's frames: the only place in alight
where NED and FRD appear.

On the wire (MAVLink common messages) the world frame is the flight controller's local NED
(x north, y east, z down) and the body frame is FRD (x forward, y right, z down); quaternions are
q_NF = (w, x, y, z), rotating FRD into NED. On the ports the world frame W is z up and the body
frame B is x forward, y left, z up.

W is chosen as NED turned half a turn about its north axis (x_W north, y_W west, z_W up) and B is
FRD turned half a turn about its forward axis. One constant rotation X = R_x(pi) then relates both
pairs: v_W = X v_N, v_B = X v_F and R_WB = X R_NF X (X is its own inverse), so every conversion here
is its own inverse too. A heading eta (M(3)-(5), counter-clockwise from x_W) is minus the NED yaw.
"""
import numpy as np

from alight.systems.rotations import conjugate, quaternion_product, rotation_matrix

# R_x(pi) exactly (pydrake's RotationMatrix.MakeXRotation(np.pi) differs by 1e-16; tests compare).
X_HALF_TURN = np.diag([1.0, -1.0, -1.0])
_Q_HALF_TURN = np.array([0.0, 1.0, 0.0, 0.0])  # the same rotation as a (w, x, y, z) quaternion


def ned_to_w(v_N) -> np.ndarray:
    """A world vector (position, velocity, acceleration) from NED to W."""
    return X_HALF_TURN @ np.asarray(v_N, dtype=float)


def w_to_ned(v_W) -> np.ndarray:
    return X_HALF_TURN @ np.asarray(v_W, dtype=float)


def frd_to_b(v_F) -> np.ndarray:
    """A body vector (body rates, specific force) from FRD to B."""
    return X_HALF_TURN @ np.asarray(v_F, dtype=float)


def b_to_frd(v_B) -> np.ndarray:
    return X_HALF_TURN @ np.asarray(v_B, dtype=float)


def q_nf_to_wb(q_NF) -> np.ndarray:
    """The wire quaternion q_NF (w, x, y, z) as q_WB: q_WB = q_X * q_NF * q_X^-1."""
    q = np.asarray(q_NF, dtype=float)
    return quaternion_product(quaternion_product(_Q_HALF_TURN, q), conjugate(_Q_HALF_TURN))


def q_wb_to_nf(q_WB) -> np.ndarray:
    """q_WB (w, x, y, z) as the wire quaternion q_NF."""
    q = np.asarray(q_WB, dtype=float)
    return quaternion_product(quaternion_product(conjugate(_Q_HALF_TURN), q), _Q_HALF_TURN)


def ned_yaw_to_heading(yaw: float) -> float:
    """NED yaw (clockwise from north, seen from above) as the heading in W (counter-clockwise)."""
    return -float(yaw)


def world_to_body_frd(v_W, q_WB) -> np.ndarray:
    """A vector in W (a velocity, a relative position) in the body frame FRD (ODOMETRY's child
    frame MAV_FRAME_BODY_FRD): v_F = X R_WB^T v_W."""
    return b_to_frd(rotation_matrix(q_WB).T @ np.asarray(v_W, dtype=float))


def body_frd_to_world(v_F, q_WB) -> np.ndarray:
    """The inverse of `world_to_body_frd`."""
    return rotation_matrix(q_WB) @ frd_to_b(v_F)


def body_variances(var_W, q_WB) -> np.ndarray:
    """Per-axis variances in W as per-axis variances in B (or FRD: the half turn keeps them): the
    diagonal of R^T diag(var) R, the cross terms dropped as ODOMETRY's diagonal does."""
    return (rotation_matrix(q_WB).T ** 2) @ np.asarray(var_W, dtype=float)


def world_variances(var_B, q_WB) -> np.ndarray:
    """The inverse of `body_variances`: the diagonal of R diag(var) R^T."""
    return (rotation_matrix(q_WB) ** 2) @ np.asarray(var_B, dtype=float)
