"""The hover flights of the thrust-curve fit (`alight thrust-curve`, M(32)-(33)): the simulated body
gets each mass in turn and hovers under the SE(3) controller; diagrams/analysis/thrust_fit.py
fits."""
import dataclasses as dc
from pathlib import Path

import numpy as np

from alight.diagrams.analysis.thrust_fit import HoverPoint, ThrustFit, fit_thrust_curve
from alight.diagrams.running.track import TrackExperiment, fly_track
from alight.diagrams.world.sim_vehicle import SimVehicleConfig
from alight.systems.rotations import tilt_deg
from alight.systems.thrust_curve import GRAVITY


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
