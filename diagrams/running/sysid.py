"""The excitation flights of system identification (`alight sysid`, L Sec. 6.1): one flight exciting
each axis alone (fit set), one exciting all at once (validation set), then the fit of
diagrams/analysis/sysid.py and the YAML file the MPC reads."""
import dataclasses as dc
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.analysis.sysid import SysidReport, axis_data, identify, plot_validation
from alight.diagrams.onboard.mocap import add_mocap
from alight.diagrams.onboard.pilot import pilot_model
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import (RunLog, add_run_logging, open_run_folder,
                                             write_run_folder)
from alight.diagrams.running.simulation import simulate
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle
from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.control.excitation_pilot import (ExcitationParams, ExcitationPilot,
                                                     ExcitationSegment)
from alight.systems.control.identification import AxisData
from alight.systems.sensors.mocap import MocapParams


def fly_excitation(config: SimVehicleConfig, params: ExcitationParams, seed: int,
                   run_dir: Path) -> RunLog:
    """One excitation flight with mocap odometry, logged to `run_dir`."""
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config))
    estimate = add_mocap(builder, vehicle.GetOutputPort("ground_truth"), MocapParams())
    model = pilot_model(config.airframe)
    pilot = builder.AddNamedSystem("pilot", ExcitationPilot(params, model.mass, model.curve))
    builder.Connect(estimate, pilot.GetInputPort("state_estimate"))
    builder.Connect(pilot.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    loggers = add_run_logging(builder, vehicle, pilot.GetOutputPort("fc_command"))
    loggers.add(builder, "state_estimate", estimate, STATE_ESTIMATE)
    diagram = builder.Build()
    metadata = {"command": "sysid", "seed": seed, "duration": params.duration, "config": config,
                "excitation": params}
    open_run_folder(run_dir, loggers, diagram, metadata)
    simulator = simulate(diagram, params.duration, seed)
    write_run_folder(run_dir, loggers, simulator, metadata)
    return RunLog(run_dir)


FIT_FLIGHT = [ExcitationSegment(25.0, "pitch"), ExcitationSegment(25.0, "roll"),
              ExcitationSegment(20.0, "thrust")]


VALIDATION_FLIGHT = [ExcitationSegment(30.0, "all")]


def run_sysid(config: SimVehicleConfig, seed: int = 0, run_dir: Path | None = None,
              output: Path | None = None, excitation: ExcitationParams | None = None,
              fit_segments=FIT_FLIGHT, validation_segments=VALIDATION_FLIGHT) -> SysidReport:
    """Flies the fit and validation flights, identifies, writes the YAML and the Fig. 6 plot."""
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("sysid", seed)
    base = excitation or ExcitationParams()
    fit_params = dc.replace(base, seed=base.seed, segments=list(fit_segments))
    validation_params = dc.replace(base, seed=base.seed + 1, segments=list(validation_segments))
    fit_run = fly_excitation(config, fit_params, seed, run_dir / "fit")
    validation_run = fly_excitation(config, validation_params, seed + 1, run_dir / "validation")
    model = pilot_model(config.airframe)
    fit, start = {}, fit_params.takeoff_time
    for segment in fit_params.segments:
        fit[segment.axes] = axis_data(fit_run, start, start + segment.duration, model.mass,
                                      model.curve)
        start += segment.duration
    validation = axis_data(validation_run, validation_params.takeoff_time,
                           validation_params.duration, model.mass, model.curve)
    report = identify(fit, validation, model.mass, model.curve)
    plot_validation(report, run_dir / "sysid_validation.png")
    if output is not None:
        Path(output).write_text(yaml_dump_typed(report.params))
    return report


def effective_damping(config: SimVehicleConfig, data: AxisData) -> np.ndarray:
    """The plant's drag (linear + quadratic, per body axis) as the best linear damping [1/s] over
    the velocities of `data`: c = (c1 E[v^2] + c2 E[|v|^3]) / (m E[v^2])."""
    params = config.airframe
    v = data.velocity_N
    c1, c2 = np.asarray(params.drag_linear), np.asarray(params.drag_quadratic)
    mass = pilot_model(config.airframe).mass
    return (c1 * np.mean(v**2, axis=0) + c2 * np.mean(np.abs(v)**3, axis=0)) \
        / (mass * np.mean(v**2, axis=0))
