"""Grey-box identification of the landing paper's linear model, L Sec. 6.1 and Fig. 6.

Output-error fits in the time domain (the paper fits in the frequency domain; both identify the
same grey-box parameters): the second-order closed-loop attitude model L(12) per axis, driven by
the commanded angle, and the damped translational model L(11) per axis, driven by the measured
attitude (g theta, -g phi) or the thrust acceleration. Fit quality is the variance accounted for,
VAF = 1 - var(y - y_model) / var(y), on a validation set that the fit never saw.
"""
import dataclasses as dc

import numpy as np
from scipy.optimize import least_squares

from alight.systems.control.linear_model import AttitudeModel, discretize


class IdentificationError(ValueError):
    """The data cannot identify the model; the message names what is missing."""


def vaf(measured: np.ndarray, simulated: np.ndarray) -> float:
    """Variance accounted for, in [.., 1] (1 = perfect)."""
    return float(1.0 - np.var(measured - simulated) / np.var(measured))


def simulate_attitude(model: AttitudeModel, reference: np.ndarray, dt: float,
                      initial: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """Angle response of L(12) to a zero-order-held reference sampled every dt."""
    A = np.array([[0.0, 1.0], [-model.stiffness, -model.damping]])
    B = np.array([[0.0], [model.gain]])
    Ad, Bd = discretize(A, B, dt)
    x = np.array(initial, float)
    out = np.empty(len(reference))
    for k, r in enumerate(reference):
        out[k] = x[0]
        x = Ad @ x + Bd[:, 0] * r
    return out


def simulate_damped_velocity(c: float, drive: np.ndarray, dt: float, v0: float) -> np.ndarray:
    """Velocity of v_dot = drive - c v (L(11) per axis) with a zero-order-held drive."""
    decay = np.exp(-c * dt)
    gain = (1.0 - decay) / c if c > 1e-9 else dt
    v = v0
    out = np.empty(len(drive))
    for k, d in enumerate(drive):
        out[k] = v
        v = decay * v + gain * d
    return out


def check_excitation(name: str, signal: np.ndarray, minimum_std: float, unit: str) -> None:
    std = float(np.std(signal))
    if not np.isfinite(std) or std < minimum_std:
        raise IdentificationError(
            f"{name} is not excited enough to identify the model: its standard deviation is "
            f"{std:.3g} {unit}, at least {minimum_std:g} {unit} is needed (fly steps or doublets "
            f"on this axis)")


def fit_attitude_axis(reference: np.ndarray, angle: np.ndarray, dt: float,
                      name: str = "attitude") -> AttitudeModel:
    """L(12) for one axis from a commanded angle and the achieved angle, both sampled every dt."""
    check_excitation(f"{name} reference", np.degrees(reference), 1.0, "deg")
    rate0 = (angle[1] - angle[0]) / dt

    def residual(log_params):
        stiffness, damping, gain = np.exp(log_params)
        model = AttitudeModel(stiffness, damping, gain)
        return simulate_attitude(model, reference, dt, (angle[0], rate0)) - angle

    start = np.log([40.0, 10.0, 40.0])
    solution = least_squares(residual, start, method="trf", x_scale=1.0)
    stiffness, damping, gain = np.exp(solution.x)
    model = AttitudeModel(float(stiffness), float(damping), float(gain))
    if vaf(angle, angle + solution.fun) < 0.5:
        raise IdentificationError(f"{name}: the second-order model does not explain the data "
                                  f"(VAF {100 * vaf(angle, angle + solution.fun):.0f} %)")
    return model


def damped_velocity_windows(c: float, drive: np.ndarray, velocity: np.ndarray, dt: float,
                            length: float = 5.0) -> np.ndarray:
    """The response of v_dot = drive - c v over windows of `length` s, each started from the
    initial velocity that best explains that window (initial conditions are nuisance parameters:
    a single noisy sample would bias the fit)."""
    out = np.empty(len(drive))
    for window in windows(len(drive), dt, length):
        forced = simulate_damped_velocity(c, drive[window], dt, 0.0)
        free = np.exp(-c * dt * np.arange(len(forced)))
        v0 = free @ (velocity[window] - forced) / (free @ free)
        out[window] = forced + v0 * free
    return out


def fit_damping(drive: np.ndarray, velocity: np.ndarray, dt: float, name: str,
                max_delay: float = 0.0) -> tuple[float, float]:
    """c of v_dot = drive - c v (L(11)) for one axis, output error over 5 s windows. With
    `max_delay`, the drive's delay (e.g. motor lag behind a commanded thrust, which L(11) neglects)
    is found too, by a search over whole samples. Returns (c, delay [s])."""
    check_excitation(f"{name} velocity", velocity, 0.05, "m/s")
    best = (np.inf, 0.0, 0.0)
    for shift in range(int(round(max_delay / dt)) + 1):
        delayed = np.concatenate([np.full(shift, drive[0]), drive[:len(drive) - shift]])
        solution = least_squares(
            lambda params: damped_velocity_windows(params[0], delayed, velocity, dt) - velocity,
            [0.2], bounds=([0.0], [10.0]))
        if solution.cost < best[0]:
            best = (solution.cost, float(solution.x[0]), shift * dt)
    return best[1], best[2]


@dc.dataclass
class AxisData:
    """Uniformly sampled signals of one flight (every dt) for identification."""
    dt: float
    pitch_ref: np.ndarray
    roll_ref: np.ndarray
    pitch: np.ndarray
    roll: np.ndarray
    velocity_N: np.ndarray | None = None   # (n, 3) velocity in N [m/s]
    thrust_acc: np.ndarray | None = None   # (n,) commanded thrust acceleration beyond g [m/s^2]


def windows(n: int, dt: float, length: float = 10.0) -> list[slice]:
    """Split a record into windows so that output-error simulations restart from measured
    initial conditions (drift of the integrating translational model stays bounded)."""
    step = max(int(length / dt), 2)
    return [slice(i, min(i + step, n)) for i in range(0, n - 1, step) if min(i + step, n) - i > 2]
