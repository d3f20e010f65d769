"""Fitting the thrust curve M(32)-(33) from hover flights (`alight thrust-curve`).

The paper weighs the vehicle with several payloads and reads the hover thrust of each. Here the
simulated vehicle's body gets each mass in turn and hovers under the SE(3) controller (whose mass
estimate M(37) makes it hold altitude whatever its own curve says; diagrams/running/thrust_curve.py);
the mean normalized thrust over the last seconds of a steady hover, with the known hover force
m g / cos(tilt), gives one point of T = a_t sqrt(f) + b_t, and a least-squares line in sqrt(f) gives
a_t and b_t.
"""
import dataclasses as dc

import numpy as np

from alight.systems.thrust_curve import ThrustCurve


@dc.dataclass
class HoverPoint:
    mass: float          # kg, the simulated body's mass
    thrust: float        # mean normalized thrust command in steady hover
    force: float         # N, m g / cos(tilt): the thrust force that held it
    vertical_speed: float  # m/s, mean |v_z| over the window (steadiness check)


@dc.dataclass
class ThrustFit:
    curve: ThrustCurve
    points: list[HoverPoint]
    rms_residual: float  # of T over the points

    def lines(self, reference: ThrustCurve | None = None) -> list[str]:
        lines = [f"mass {p.mass:5.2f} kg   hover thrust {p.thrust:.4f}   force {p.force:6.2f} N"
                 for p in self.points]
        lines.append(f"fit  a_t = {self.curve.a_t:.4f}   b_t = {self.curve.b_t:.4f}   "
                     f"rms residual {self.rms_residual:.2e}")
        if reference is not None:
            lines.append(f"true a_t = {reference.a_t:.4f}   b_t = {reference.b_t:.4f} "
                         "(the simulated rotors)")
        return lines


def fit_thrust_curve(thrusts, forces) -> tuple[ThrustCurve, float]:
    """Least squares of T = a_t sqrt(f) + b_t (M(32)) over >= 2 points; (curve, rms residual)."""
    thrusts, forces = np.asarray(thrusts, float), np.asarray(forces, float)
    if thrusts.shape != forces.shape or thrusts.size < 2:
        raise ValueError("need at least two (thrust, force) points of equal count")
    if np.any(forces <= 0) or not np.all(np.isfinite(thrusts)) or not np.all(np.isfinite(forces)):
        raise ValueError(f"forces must be positive and finite: {forces}, thrusts {thrusts}")
    A = np.column_stack([np.sqrt(forces), np.ones_like(forces)])
    (a_t, b_t), *_ = np.linalg.lstsq(A, thrusts, rcond=None)
    residual = thrusts - A @ [a_t, b_t]
    return ThrustCurve(float(a_t), float(b_t)), float(np.sqrt(np.mean(residual ** 2)))
