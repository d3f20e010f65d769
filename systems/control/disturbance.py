"""Disturbance and mass estimation, M(35)-(37): integrators of the position error in the world frame
and in the heading frame, and the estimated mass.

    d_w = sum k_iw o e_p dt                        world disturbance [N], M(35)
    d_b = H_N sum k_ib o (H_n^T e_p) dt            body (heading-frame) disturbance [N], M(35)-(36)
    m_e = m + delta_m,  delta_m = -sum k_m e_z dt  estimated mass [kg], M(37)

with e_p = r - r_d. The x, y parts are the disturbance forces the controllers compensate with
-(d_w + d_b) o [1, 1, 0] (M(38), M(39)). The z parts of M(35) only enter through M(37); since the
heading rotation leaves z alone, their sum is one integrator, kept here as the mass difference
delta_m directly, with the sign that makes a vehicle that sags below its reference heavier (the
printed M(35)/(37) leave that sign to the reader). Each integrator is clamped to the limits of
`DisturbanceLimits` (anti-windup), and an error larger than `max_error` (horizontal norm, or the
vertical part) is not integrated at all: the integrators learn small steady forces, not the
transient of an estimator jump (a 5 m jump would otherwise wind them to their limits within a
second and push the vehicle away at 7 m/s, measured).
"""
import dataclasses as dc

import numpy as np

from alight.systems.boundary import VectorLayout
from alight.systems.params import bounded

# The integrators: world disturbance d_w (x, y) [N]; the un-rotated body sum of M(35) (x, y) [N];
# the mass difference delta_m [kg].
DISTURBANCE = VectorLayout("disturbance", [("world", 2), ("body_sum", 2), ("mass_difference", 1)])

# Published estimate: d_w (x, y), d_b = H_N body_sum (x, y) [N, in W]; m_e [kg].
DISTURBANCE_ESTIMATE = VectorLayout("disturbance_estimate", [("d_w", 2), ("d_b", 2), ("m_e", 1)])


@dc.dataclass
class DisturbanceGains:
    world: list[float] = bounded([1.0, 1.0], 0.0, 100.0, "N/(m s)")  # k_iw (x, y)
    body: list[float] = bounded([1.0, 1.0], 0.0, 100.0, "N/(m s)")   # k_ib (x, y)
    mass: float = bounded(0.3, 0.0, 100.0, "kg/(m s)")               # k_iw,z + k_ib,z


@dc.dataclass
class DisturbanceLimits:
    world: float = bounded(10.0, 0.0, 1000.0, "N")    # per axis
    body: float = bounded(10.0, 0.0, 1000.0, "N")     # per axis
    mass: float = bounded(2.0, 0.0, 1000.0, "kg")     # |delta_m|
    max_error: float = bounded(1.0, 0.0, 1000.0, "m")  # larger errors are not integrated


def heading_matrix(eta: float) -> np.ndarray:
    """M(36): rotation about e3 by the heading."""
    c, s = np.cos(eta), np.sin(eta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def integrate(state: np.ndarray, e_p: np.ndarray, eta: float, dt: float,
              gains: DisturbanceGains, limits: DisturbanceLimits) -> np.ndarray:
    """One step of M(35) and of the mass difference; returns the new DISTURBANCE vector."""
    L = DISTURBANCE
    new = np.array(state, dtype=float)
    horizontal = float(np.linalg.norm(e_p[:2]) <= limits.max_error)
    vertical = float(abs(e_p[2]) <= limits.max_error)
    world = L.get(state, "world") + horizontal * np.asarray(gains.world) * e_p[:2] * dt
    body = L.get(state, "body_sum") + horizontal * np.asarray(gains.body) \
        * (heading_matrix(eta).T @ e_p)[:2] * dt
    mass = L.get(state, "mass_difference") - vertical * gains.mass * e_p[2] * dt
    new[L.slice("world")] = np.clip(world, -limits.world, limits.world)
    new[L.slice("body_sum")] = np.clip(body, -limits.body, limits.body)
    new[L.slice("mass_difference")] = np.clip(mass, -limits.mass, limits.mass)
    return new


def measured_force(m_e: float, a_EB: np.ndarray, thrust_force: float, R_EB: np.ndarray
                   ) -> np.ndarray:
    """The horizontal external force (x, y) [N, in E] the measured acceleration shows, beyond
    M(35) (the flight stack's counterpart of the landing MPC's IMU disturbance): m_e a_EB - f(T) b3
    (gravity has no horizontal part). With the IMU's acceleration a_EB = R_EB f_IMU - g e3 it is
    m_e R_EB f_IMU - f(T) b3: drag, wind and thrust-model error, seen within a tick."""
    return m_e * np.asarray(a_EB, float)[:2] - thrust_force * np.asarray(R_EB)[:2, 2]


def resolve_source(source: str, estimator: str, otherwise: str) -> str:
    """A disturbance `source` with `auto` made `acceleration` on the VIO's odometry (its a_EB is
    the IMU's, measured; a mocap or bank a_EB is a differentiated position) and `otherwise` on
    any other; unchanged when not `auto`."""
    if source != "auto":
        return source
    return "acceleration" if estimator == "vio" else otherwise


def resolve_auto_source(params, estimator: str, otherwise: str):
    """`params` (a dataclass with `disturbance_source`) with its source resolved
    (`resolve_source`)."""
    return dc.replace(params, disturbance_source=resolve_source(params.disturbance_source,
                                                                estimator, otherwise))


def forces(state: np.ndarray, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """d_w and d_b = H_N * body_sum as 3-vectors in W with zero z (the o [1, 1, 0] of M(38))."""
    d_w = np.append(DISTURBANCE.get(state, "world"), 0.0)
    d_b = heading_matrix(eta) @ np.append(DISTURBANCE.get(state, "body_sum"), 0.0)
    return d_w, d_b


def estimated_mass(nominal: float, state: np.ndarray) -> float:
    """M(37): m_e = m + delta_m [kg]."""
    return nominal + float(DISTURBANCE.get(state, "mass_difference"))


def estimate_vector(nominal: float, state: np.ndarray, eta: float) -> np.ndarray:
    """The DISTURBANCE_ESTIMATE published by the controllers."""
    d_w, d_b = forces(state, eta)
    return DISTURBANCE_ESTIMATE.pack(d_w=d_w[:2], d_b=d_b[:2], m_e=estimated_mass(nominal, state))


def state_from_estimate(estimate: np.ndarray, nominal: float, eta: float,
                        limits: DisturbanceLimits) -> np.ndarray | None:
    """The integrator state that publishes `estimate` (DISTURBANCE_ESTIMATE) at heading `eta`:
    the inverse of `estimate_vector`, clipped to `limits`; None when `estimate` is not finite.
    How a controller takes over the previous one's estimates (M Sec. 7.2)."""
    estimate = np.asarray(estimate, dtype=float)
    if estimate.size != DISTURBANCE_ESTIMATE.size or not np.all(np.isfinite(estimate)):
        return None
    d_b = np.append(DISTURBANCE_ESTIMATE.get(estimate, "d_b"), 0.0)
    return DISTURBANCE.pack(
        world=np.clip(DISTURBANCE_ESTIMATE.get(estimate, "d_w"), -limits.world, limits.world),
        body_sum=np.clip((heading_matrix(eta).T @ d_b)[:2], -limits.body, limits.body),
        mass_difference=np.clip(DISTURBANCE_ESTIMATE.get(estimate, "m_e") - nominal,
                                -limits.mass, limits.mass))


def reexpress(state: np.ndarray, R_OldNew: np.ndarray) -> np.ndarray:
    """The integrators after the estimator frame changes from Old to New (M Sec. 3.5): the world
    disturbance is a vector in the frame and turns with it; the heading-frame sum and the mass
    difference are unchanged (the heading itself is re-estimated in the new frame)."""
    new = np.array(state, dtype=float)
    world = np.append(DISTURBANCE.get(state, "world"), 0.0)
    new[DISTURBANCE.slice("world")] = (R_OldNew.T @ world)[:2]
    return new
