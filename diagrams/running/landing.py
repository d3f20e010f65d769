"""Runs the landing mission end to end (`alight land`): the simulated vehicle in the scenario's
world (diagrams/scenario.py `vehicle_config`) with the direct (diagrams/onboard/landing.py) or the
managed (diagrams/onboard/landing_managed.py) onboard stack, simulated until it rests, and the run
folder."""
from pathlib import Path

from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.landing import LandingOnboard, add_landing_onboard
from alight.diagrams.onboard.landing_managed import LandingManagedOnboard, add_landing_managed
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import RunLog, write_run_folder
from alight.diagrams.running.simulation import simulate
from alight.diagrams.scenario import LandingScenario, landing_odometry, vehicle_config
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle


def build_landing(builder: DiagramBuilder, scenario: LandingScenario, meshcat=None,
                  odometry=None) -> tuple[SimVehicleConfig, LandingOnboard]:
    """The simulated vehicle in the scenario's world with the onboard landing stack on it."""
    config = vehicle_config(scenario)
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config, meshcat))
    return config, add_landing_onboard(builder, scenario, vehicle, odometry)


STACKS = ("direct", "managed")   # the mission drives the linear MPC / the control manager


def run_landing(scenario: LandingScenario, seed: int = 0, run_dir=None, meshcat=None,
                record=None, realtime_rate: float = 0.0, odometry=None, stack: str = "direct",
                controller: str = "linear_mpc") -> RunLog:
    """Flies one landing mission; stops `settle_time` after the disarm (or at `max_duration`) and
    writes the run folder (streams, metadata with the scenario). `stack` "direct": the mission
    drives the linear MPC (`add_landing_onboard`); "managed": the control manager with its
    trackers and `controller` (diagrams/onboard/landing_managed.py, issue 11)."""
    if stack not in STACKS:
        raise ValueError(f"landing stack {stack!r}: expected one of {list(STACKS)}")
    if stack == "direct" and controller != "linear_mpc":
        raise ValueError(f"controller {controller!r}: the direct stack flies linear_mpc only; "
                         f"use stack 'managed'")
    if odometry is None:   # the scenario's `estimator` (None: mocap)
        odometry = landing_odometry(scenario)
    builder = DiagramBuilder()
    if stack == "managed":
        config, onboard = build_landing_managed(builder, scenario, meshcat, odometry, controller)
    else:
        config, onboard = build_landing(builder, scenario, meshcat, odometry)
    if hasattr(odometry, "log"):   # the bank's or the VIO's own streams
        odometry.log(builder, onboard.loggers)
    diagram = builder.Build()
    simulator = simulate(diagram, scenario.max_duration, seed, meshcat, record, realtime_rate,
                         stop_when=onboard.finished(scenario.settle_time))
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("land", seed)
    write_run_folder(run_dir, onboard.loggers, simulator, {
        "command": "land", "seed": seed, "duration": simulator.get_context().get_time(),
        "scenario": scenario, "config": config, "stack": stack, "controller": controller,
        "trackers": list(onboard.managed.trackers) if stack == "managed" else []})
    return RunLog(run_dir)


def build_landing_managed(builder: DiagramBuilder, scenario: LandingScenario, meshcat=None,
                          odometry=None, controller: str = "linear_mpc"
                          ) -> tuple[SimVehicleConfig, LandingManagedOnboard]:
    """The simulated vehicle in the scenario's world with the managed landing stack on it."""
    config = vehicle_config(scenario)
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config, meshcat))
    return config, add_landing_managed(builder, scenario, vehicle, odometry, controller)
