"""Fitting the thrust curve M(32)-(33) from hover flights (`alight thrust-curve`).

The paper weighs the vehicle with several payloads and reads the hover thrust of each. Here the
simulated vehicle's body gets each mass in turn and hovers under the SE(3) controller (whose mass
estimate M(37) makes it hold altitude whatever its own curve says); the mean normalized thrust
over the last seconds of a steady hover, with the known hover force m g / cos(tilt), gives one
point of T = a_t sqrt(f) + b_t, and a least-squares line in sqrt(f) gives a_t and b_t.
"""
import dataclasses as dc
from pathlib import Path

import numpy as np

from alight.diagrams.world.sim_vehicle import SimVehicleConfig
from alight.diagrams.track import TrackExperiment, fly_track
from alight.systems.rotations import tilt_deg
from alight.systems.thrust_curve import GRAVITY, ThrustCurve


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


def hover_point(config: SimVehicleConfig, mass: float, seed: int, run_dir: Path,
                hover_time: float = 4.0, window: float = 2.0) -> HoverPoint:
    """Hovers the simulated vehicle at `mass` and reads its steady hover thrust."""
    experiment = TrackExperiment(trajectory="hover", controller="se3", altitude=1.0,
                                 settle=0.0, hover_time=hover_time)
    run = fly_track(config, experiment, seed=seed, run_dir=run_dir, vehicle_mass=mass,
                    plots=False)
    command, truth = run["fc_command"], run["ground_truth"]
    end = truth["time"].iloc[-1]
    in_command = command["time"] >= end - window
    in_truth = (truth["time"] >= end - window).to_numpy()
    tilt = np.radians(tilt_deg(run.field("ground_truth", "q_WB").to_numpy()[in_truth]))
    v_z = run.field("ground_truth", "v_WB").to_numpy()[in_truth, 2]
    return HoverPoint(mass, float(command["thrust"][in_command].mean()),
                      float(np.mean(mass * GRAVITY / np.cos(tilt))), float(np.abs(v_z).mean()))


def run_thrust_curve(config: SimVehicleConfig, masses, seed: int, run_dir: Path,
                     hover_time: float = 4.0) -> ThrustFit:
    """Flies one hover per mass (wind off) and fits the curve; one run folder per mass."""
    config = dc.replace(config, wind=dc.replace(config.wind, mean_speed=0.0, gust_std=0.0,
                                                vertical_gust_std=0.0))
    points = [hover_point(config, float(m), seed, Path(run_dir) / f"mass_{m:.2f}", hover_time)
              for m in masses]
    curve, residual = fit_thrust_curve([p.thrust for p in points], [p.force for p in points])
    return ThrustFit(curve, points, residual)
