"""One runner for every simulated scenario (`alight land`, `campaign`, `hover`, waypoint flights):
`run(scenario)` builds the scenario's simulated vehicle in its world and its onboard stack with
logging (diagrams/stacks.py), simulates until the stack's stop condition or its duration, and
writes the run folder: the streams, `metadata.json` and the fully resolved `scenario.yaml`, with
which `alight land --scenario RUN/scenario.yaml` flies the same run again, stream for stream.
"""
from pathlib import Path

import numpy as np

from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import RunLog, open_run_folder, write_run_folder
from alight.diagrams.running.simulation import simulate
from alight.diagrams.scenario import Scenario, vehicle_config, write_scenario
from alight.diagrams.stacks import OnboardStack, add_onboard
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.diagrams.world.visualization import add_flight_view, add_vehicle_flight_view
from alight.systems.mission.landing import MISSION_STATUS, Mode


def build(builder: DiagramBuilder, scenario: Scenario, meshcat=None,
          odometry=None) -> OnboardStack:
    """The scenario's simulated vehicle ("vehicle") with its onboard stack on it; with a
    `meshcat`, the flight view (diagrams/world/visualization.py) on the vehicle, the car and the
    mission's mode (the flight controller's without a mission)."""
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(vehicle_config(scenario),
                                                                 meshcat))
    stack = add_onboard(builder, scenario, vehicle, odometry)
    if meshcat is not None:
        mission = getattr(stack.parts, "mission", None)
        if mission is None:
            add_vehicle_flight_view(builder, meshcat, vehicle)
        else:
            add_flight_view(builder, meshcat, vehicle.GetOutputPort("ground_truth"),
                            mission.GetOutputPort("mission_status"), MISSION_STATUS, "mode", Mode)
    return stack


def run(scenario: Scenario, run_dir=None, meshcat=None, record=None,
        realtime_rate: float = 0.0, odometry=None, command: str = "run", prepare=None,
        duration: float | None = None) -> RunLog:
    """Flies `scenario` (seeded by its `random_seed`) and writes its run folder (default
    runs/<time>-<command>-s<seed>). `odometry` replaces the scenario's estimator (tests, fault
    injection); `prepare(root_context)` may change the seeded context; `duration` replaces the
    stack's own (a time limit, or the profile's length; by default that, capped by the
    scenario's `simulator.max_duration`). Returns the run folder read back."""
    builder = DiagramBuilder()
    stack = build(builder, scenario, meshcat, odometry)
    diagram = builder.Build()
    if duration is None:
        duration = min(stack.duration or np.inf, scenario.simulator.max_duration)
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir(command,
                                                                        scenario.random_seed)
    metadata = {"command": command, "scenario_name": scenario.name,
                "seed": scenario.random_seed, "controller": scenario.onboard.controller,
                "estimator": scenario.onboard.estimator, **stack.metadata}
    open_run_folder(run_dir, stack.loggers, diagram, metadata)  # streams written as it flies
    write_scenario(run_dir, scenario)
    simulator = simulate(diagram, duration, scenario.random_seed, meshcat, record,
                         realtime_rate, stop_when=stack.finished, prepare=prepare)
    context = simulator.get_context()
    finished = stack.finished is not None and stack.finished.holds(context)
    write_run_folder(run_dir, stack.loggers, simulator, {
        **metadata, "duration": context.get_time(), "landed": finished})
    return RunLog(run_dir)
