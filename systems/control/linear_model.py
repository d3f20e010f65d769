"""The landing paper's linear model of the attitude-controlled vehicle, L(11)-(18).

State x = [r_N (3), v_N (3), theta, phi, theta_dot, phi_dot] in the navigation frame N (W rotated
by the heading, L Sec. 6.1); input u = [theta_r, phi_r, T_r] (pitch and roll references [rad] and
the thrust acceleration beyond gravity [m/s^2]).

    v_dot = [g theta - c_x v_x, -g phi - c_y v_y, T - c_z v_z]                     L(11)
    theta_ddot = -b_theta theta - b_theta_dot theta_dot + b_theta_r theta_r         L(12)
    phi_ddot   = -b_phi phi - b_phi_dot phi_dot + b_phi_r phi_r

Euler angles (ZYX: heading = yaw for this convention) appear only here, as the paper's model uses
them; the rest of alight uses the heading of M(3)-(5).
"""
import dataclasses as dc
import math

import numpy as np
from scipy.linalg import expm

from alight.systems.params import bounded
from alight.systems.rotations import float_list, unit_floats

GRAVITY = 9.81
NUM_STATES = 10
NUM_INPUTS = 3


@dc.dataclass
class AttitudeModel:
    """One axis of L(12): x_ddot = -stiffness x - damping x_dot + gain x_ref."""
    stiffness: float = bounded(40.0, 0.0, 1e4, "1/s^2")
    damping: float = bounded(10.0, 0.0, 1e3, "1/s")
    gain: float = bounded(40.0, 0.0, 1e4, "1/s^2")

    def dc_gain(self) -> float:
        return self.gain / self.stiffness if self.stiffness > 0 else np.inf


@dc.dataclass
class LinearModelParams:
    """Identified parameters (written by `alight sysid`)."""
    c_x: float = bounded(0.12, 0.0, 10.0, "1/s")
    c_y: float = bounded(0.12, 0.0, 10.0, "1/s")
    c_z: float = bounded(0.2, 0.0, 10.0, "1/s")
    pitch: AttitudeModel = dc.field(default_factory=AttitudeModel)
    roll: AttitudeModel = dc.field(default_factory=AttitudeModel)
    mass: float = bounded(2.5, 0.05, 100.0, "kg")      # for the thrust's gravity feedforward
    thrust_a: float = bounded(0.1512, 1e-3, 10.0)      # thrust curve M(32): T = a sqrt(f) + b
    thrust_b: float = bounded(-0.1111, -1.0, 1.0)


def continuous_model(p: LinearModelParams) -> tuple[np.ndarray, np.ndarray]:
    """A, B of L(13)-(16) in the state ordering [r, v, theta, phi, theta_dot, phi_dot]."""
    A = np.zeros((NUM_STATES, NUM_STATES))
    B = np.zeros((NUM_STATES, NUM_INPUTS))
    A[0:3, 3:6] = np.eye(3)
    A[3, 3], A[3, 6] = -p.c_x, GRAVITY
    A[4, 4], A[4, 7] = -p.c_y, -GRAVITY
    A[5, 5] = -p.c_z
    A[6, 8] = A[7, 9] = 1.0
    A[8, 6], A[8, 8], B[8, 0] = -p.pitch.stiffness, -p.pitch.damping, p.pitch.gain
    A[9, 7], A[9, 9], B[9, 1] = -p.roll.stiffness, -p.roll.damping, p.roll.gain
    B[5, 2] = 1.0
    return A, B


def discretize(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold discretization L(18), via the exponential of the augmented matrix."""
    n, m = B.shape
    augmented = np.zeros((n + m, n + m))
    augmented[:n, :n], augmented[:n, n:] = A, B
    phi = expm(augmented * dt)
    return phi[:n, :n], phi[:n, n:]


def euler_pitch_roll_yaw(q_WB: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (pitch theta, roll phi, yaw psi) of q_WB; for ZYX, yaw equals the heading."""
    return euler_angles(*float_list(q_WB))


def euler_angles(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """`euler_pitch_roll_yaw` of q_WB = (w, x, y, z) given as floats: the operations of
    `rotation_matrix` on the five elements it uses, without the matrix (np.clip of a scalar as
    min/max, which give the same value, NaN included)."""
    unit = unit_floats(w, x, y, z)
    if unit is None:  # (rotation_matrix's NaN matrix)
        R00 = R10 = R20 = R21 = R22 = math.nan
    else:
        w, x, y, z = unit
        R00, R10 = 1 - 2 * (y * y + z * z), 2 * (x * y + w * z)
        R20, R21, R22 = 2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)
    theta = float(np.arcsin(min(max(-R20, -1.0), 1.0)))
    phi = float(np.arctan2(R21, R22))
    psi = float(np.arctan2(R10, R00))
    return theta, phi, psi


def euler_rates(phi: float, theta: float, w_B: np.ndarray) -> tuple[float, float]:
    """L(17): roll and pitch rates from body rates."""
    sin_phi, cos_phi, tan_theta = float(np.sin(phi)), float(np.cos(phi)), float(np.tan(theta))
    w_x, w_y, w_z = float_list(w_B)
    phi_dot = w_x + sin_phi * tan_theta * w_y + cos_phi * tan_theta * w_z
    theta_dot = cos_phi * w_y - sin_phi * w_z
    return phi_dot, theta_dot


def rotate_to_navigation(vector_W: np.ndarray, yaw: float) -> np.ndarray:
    """A world vector expressed in the navigation frame N (W rotated by the heading)."""
    return np.array(to_navigation(float_list(vector_W), float(np.cos(yaw)), float(np.sin(yaw))))


def to_navigation(v_W: list[float], cos_yaw: float, sin_yaw: float) -> list[float]:
    """`rotate_to_navigation` of a vector given as 3 floats, with np.cos(yaw) and np.sin(yaw)
    (computed once per yaw by the caller) as floats: the same operations."""
    x, y, z = v_W
    return [cos_yaw * x + sin_yaw * y, -sin_yaw * x + cos_yaw * y, z]


def model_state(p_WB, v_WB, q_WB, w_B, p_ref=np.zeros(3)) -> tuple[np.ndarray, float]:
    """The model state x (position relative to p_ref) and the yaw that defines N. q_WB and w_B
    should come from the same, freshest attitude source (the flight controller's estimate):
    pairing a delayed angle with current rates makes the attitude state inconsistent."""
    theta, phi, psi = euler_pitch_roll_yaw(q_WB)
    phi_dot, theta_dot = euler_rates(phi, theta, w_B)
    x = np.concatenate([rotate_to_navigation(np.asarray(p_WB) - p_ref, psi),
                        rotate_to_navigation(v_WB, psi), [theta, phi, theta_dot, phi_dot]])
    return x, psi
