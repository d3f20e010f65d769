"""The M Sec. 8 experiments with the flight-stack controllers (`alight track`): take off, fly a step
sequence (M Sec. 8.1) or the 5 m circle (M Sec. 8.2) with the SE(3) or the MPC force-feedback
controller, optionally under estimator noise (M Sec. 8.3) or an estimator jump (M Sec. 8.4), and
score the run against the simulation's ground truth.

The diagram: simulated vehicle -> mocap odometry -> (fault injector) -> controllers, switched by a
`TimedSwitch` (the control manager's stand-in) -> vehicle. `linear_mpc` is the landing paper's
linear MPC (L Sec. 6.1-6.2, attitude+thrust at 20 Hz, `alight fly`'s controller) on the same
reference (it reads chi's position, velocity and heading), armed through an `ArmGate` like in
`alight fly`, for the side-by-side comparison. The controllers also read the flight
controller's attitude `fc_attitude` for their orientation, as the paper's controllers use the
Pixhawk's (M footnote 18): closing the attitude loop on the 30 ms old mocap orientation made it
oscillate on the 7 m/s circle with the heading to the centre. The reference chi is analytic
(alight.systems.control.analytic_reference) until the trackers exist.
"""
import dataclasses as dc
from pathlib import Path

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.analysis.track import score
from alight.diagrams.onboard.controllers import (CONTROLLERS, ControllersConfig,
                                                 load_controllers_config)
from alight.diagrams.onboard.track import add_controller_loop, add_loop_logging
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import RunLog, open_run_folder, write_run_folder
from alight.diagrams.running.simulation import simulate
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle
from alight.diagrams.world.visualization import add_vehicle_flight_view
from alight.systems.boundary import GROUND_TRUTH
from alight.systems.control import analytic_reference as ref
from alight.systems.params import bounded, choice
from alight.systems.sensors.estimate_faults import EstimateFaultParams
from alight.systems.sensors.mocap import MocapParams

TRAJECTORIES = ("circle", "steps", "hover")
TRACK_CONTROLLERS = ("se3", "mpc", "linear_mpc")


@dc.dataclass
class TrackExperiment:
    """One `alight track` experiment (the command line's options)."""
    trajectory: str = choice(*TRAJECTORIES)
    controller: str = choice(*TRACK_CONTROLLERS)
    radius: float = bounded(5.0, 0.5, 100.0, "m")        # circle, M Sec. 8.2
    speed: float = bounded(7.0, 0.1, 20.0, "m/s")
    heading: str = choice("center", "constant")
    laps: float = bounded(3.0, 0.25, 100.0)             # the last is scored
    ramp: float = bounded(3.0, 0.5, 30.0, "s")           # circle's angular-speed ramp
    altitude: float = bounded(3.0, 0.5, 100.0, "m")
    climb_limits: list[float] = bounded([1.5, 1.5, 4.0], 0.1, 100.0)  # v, a, j of the take-off
    step_sizes: list[float] = bounded([1.0, 2.0, 4.0], -50.0, 50.0, "m")  # along x, M Sec. 8.1
    step_axes: str = choice("x", "xyz")                  # single axis (Fig. 7) or 3D (Fig. 8)
    step_hold: float = bounded(3.0, 0.5, 60.0, "s")
    step_limits: list[float] = bounded([9.0, 12.0, 50.0], 0.1, 1000.0)  # v, a, j of M Sec. 8.1
    hover_time: float = bounded(10.0, 0.0, 3600.0, "s")  # `hover` trajectory, and the settle time
    settle: float = bounded(2.0, 0.0, 60.0, "s")         # hold before the experiment starts
    estimator_noise: float = bounded(0.0, 0.0, 10.0, "m, m/s")  # M Fig. 12, from the start mark
    estimator_jump: float = bounded(0.0, -100.0, 100.0, "m")     # M Fig. 13, along x
    jump_delay: float = bounded(2.0, 0.0, 60.0, "s")     # after the experiment start
    failsafe_at: float = bounded(0.0, 0.0, 1e4, "s")     # > 0: switch to the failsafe then

    def __post_init__(self):
        if self.trajectory == "circle" and self.speed ** 2 / self.radius > 12.0:
            raise ValueError(f"circle of radius {self.radius} m at {self.speed} m/s needs "
                             f"{self.speed ** 2 / self.radius:.1f} m/s^2: at most 12 m/s^2")


SPOOL_TIME = 2.0                 # s on the ground while the controller ramps its thrust up


def make_trajectory(experiment: TrackExperiment, p_ground: np.ndarray) -> ref.Trajectory:
    """Take-off from `p_ground` (turning to the experiment's first heading), `settle`, the
    experiment, hold. Marks: `start` and `end` of the scored part (for the circle, its last
    constant-speed lap: the integrators learn the drag on the laps before)."""
    e = experiment
    eta = np.pi if e.trajectory == "circle" and e.heading == "center" else 0.0
    pieces = ref.takeoff(p_ground, e.altitude, 0.0, eta, SPOOL_TIME, tuple(e.climb_limits))
    p_top = np.asarray(p_ground, float) + [0.0, 0.0, e.altitude]
    pieces.append(ref.hold(p_top, eta, e.settle))
    start = sum(p.duration for p in pieces)
    if e.trajectory == "circle":
        centre = p_top - [e.radius, 0.0, 0.0]        # the circle passes through p_top
        circle = ref.Circle(centre, e.radius, e.speed, e.ramp, e.laps, e.heading == "center",
                            eta)
        pieces.append(circle)
        lap = 2 * np.pi / circle.omega
        end = start + e.ramp + circle.cruise
        marks = {"start": max(start + e.ramp, end - lap), "end": end}
        last = circle.sample(circle.duration)
        pieces.append(ref.hold(last.p, last.heading, e.settle))
    elif e.trajectory == "steps":
        sizes = np.asarray(e.step_sizes, float)
        directions = np.ones(3) if e.step_axes == "xyz" else np.array([1.0, 0.0, 0.0])
        # Out and back for each size: p_top + s d, p_top.
        offsets = np.concatenate([[s * directions, np.zeros(3)] for s in sizes])
        pieces += ref.steps(p_top, eta, offsets, e.step_hold, tuple(e.step_limits))
        marks = {"start": start, "end": sum(p.duration for p in pieces)}
    else:
        pieces.append(ref.hold(p_top, eta, e.hover_time))
        marks = {"start": start, "end": start + e.hover_time}
    return ref.Trajectory(pieces, marks)


def resting_position(vehicle_diagram) -> np.ndarray:
    """p_WB of the vehicle at rest on the ground, from its default context."""
    context = vehicle_diagram.CreateDefaultContext()
    return GROUND_TRUTH.get(vehicle_diagram.GetOutputPort("ground_truth").Eval(context), "p_WB")


def set_vehicle_mass(diagram, vehicle_config: SimVehicleConfig, root_context, mass: float
                     ) -> None:
    """Gives the simulated body of the diagram's `vehicle` the mass `mass` [kg] (its inertia
    scales with it): a heavier payload than the controllers know of."""
    plant = diagram.GetSubsystemByName("vehicle").GetSubsystemByName("plant")
    body = plant.GetBodyByName(vehicle_config.airframe.body)
    body.SetMass(plant.GetMyMutableContextFromRoot(root_context), mass)


def fly_track(vehicle_config: SimVehicleConfig, experiment: TrackExperiment, seed: int = 0,
              run_dir=None, controllers_config: ControllersConfig | None = None, meshcat=None,
              record=None, realtime_rate: float = 0.0, duration: float | None = None,
              vehicle_mass: float | None = None, plots: bool = True) -> RunLog:
    """Flies `experiment` and writes its run folder (with plots like M Fig. 7-13 if `plots`).
    `vehicle_mass` [kg] replaces the simulated body's mass (the controllers are not told)."""
    controllers_config = controllers_config or load_controllers_config()
    vehicle_diagram = make_sim_vehicle(vehicle_config, meshcat)
    trajectory = make_trajectory(experiment, resting_position(vehicle_diagram))
    start = trajectory.marks["start"]
    faults = EstimateFaultParams(noise_std=experiment.estimator_noise, noise_start=start,
                                 jump=[experiment.estimator_jump, 0.0, 0.0],
                                 jump_time=start + experiment.jump_delay)
    names, starts = [experiment.controller], [0.0]
    if experiment.failsafe_at > 0.0:
        names, starts = names + ["failsafe"], starts + [experiment.failsafe_at]
    builder = DiagramBuilder()
    loop = add_controller_loop(builder, vehicle_diagram, controllers_config, trajectory, names,
                               starts, faults, MocapParams())
    loggers = add_loop_logging(builder, loop, controllers_config.period)
    if meshcat is not None:
        add_vehicle_flight_view(builder, meshcat, loop.vehicle)
    diagram = builder.Build()
    if duration is None:
        duration = trajectory.duration + (30.0 if experiment.failsafe_at > 0 else 0.0)
    prepare = None if vehicle_mass is None else \
        lambda context: set_vehicle_mass(diagram, vehicle_config, context, vehicle_mass)
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("track", seed)
    metadata = {"command": "track", "seed": seed, "duration": duration, "experiment": experiment,
                "marks": trajectory.marks, "controllers": names, "controller_starts": starts,
                "vehicle_config": vehicle_config, "controllers_config": controllers_config,
                "vehicle_mass": vehicle_mass}
    open_run_folder(run_dir, loggers, diagram, metadata)
    simulator = simulate(diagram, duration, seed, meshcat, record, realtime_rate, prepare=prepare)
    write_run_folder(run_dir, loggers, simulator, metadata)
    run = RunLog(run_dir)
    if plots:
        from alight.diagrams.analysis.track_plots import plot_track
        plot_track(run)
    return run


def section8_experiments(controller: str, short: bool = False) -> dict[str, TrackExperiment]:
    """The M Sec. 8 experiments for `controller`: steps (8.1, Fig. 7), the 5 m circle at 7 m/s
    with the heading to the centre (8.2, Fig. 9), 1 m estimator noise (8.3, Fig. 12) and a 5 m
    estimator jump (8.4, Fig. 13) in hover. `short`: cut down for the test suite (one 2 m step,
    half a lap, 2 s of hover), with the same speeds and faults."""
    common = dict(controller=controller, altitude=1.5, settle=1.0)
    hover = dict(trajectory="hover", hover_time=2.0 if short else 10.0, **common)
    return {
        "steps": TrackExperiment(trajectory="steps", step_sizes=[2.0] if short else [1.0, 2.0, 4.0],
                                 step_hold=1.5 if short else 3.0, **common),
        "circle": TrackExperiment(trajectory="circle", radius=5.0, speed=7.0, heading="center",
                                  laps=0.5 if short else 3.0, ramp=2.0, **common),
        "noise 1 m": TrackExperiment(estimator_noise=1.0, **hover),
        "jump 5 m": TrackExperiment(estimator_jump=5.0, jump_delay=0.3 if short else 2.0, **hover),
    }


def compare_controllers(vehicle_config: SimVehicleConfig, controllers, root, seed: int = 7,
                        short: bool = False):
    """Flies `section8_experiments` for each controller (run folders under `root`) and scores
    them over the experiment (the hover ones to the end of the run): ({(experiment,
    controller): RunLog}, pandas DataFrame of the `TrackScore`s, one row per run)."""
    import pandas as pd
    runs, rows = {}, []
    for controller in controllers:
        for name, experiment in section8_experiments(controller, short).items():
            run = fly_track(vehicle_config, experiment, seed=seed, plots=False,
                            run_dir=Path(root) / f"{name.split()[0]}-{controller}")
            end = run["ground_truth"]["time"].iloc[-1] if experiment.trajectory == "hover" \
                else None
            result = score(run, end=end)
            runs[name, controller] = run
            rows.append({"experiment": name, "controller": controller,
                         **{k: v for k, v in dc.asdict(result).items() if k != "window"}})
    return runs, pd.DataFrame(rows).set_index(["experiment", "controller"])


__all__ = ["CONTROLLERS", "TRACK_CONTROLLERS", "TrackExperiment", "fly_track", "score",
           "section8_experiments", "compare_controllers", "make_trajectory",
           "add_controller_loop"]
