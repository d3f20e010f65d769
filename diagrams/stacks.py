"""One registry of onboard stacks, built by one function on any vehicle (DESIGN.md "The onboard
stack"): `add_onboard(builder, scenario, vehicle)` adds the scenario's stack (`onboard.stack`)
with its odometry and run logging on `vehicle`'s boundary ports. Simulation
(diagrams/running/runner.py) puts it on the simulated vehicle, `alight hil` (hw/hil.py) on the
MAVLink vehicle, with the same scenario.

Adding a stack is one function `(builder, scenario, vehicle, odometry) -> OnboardStack` here and
its mission kind in diagrams/scenario.py `STACK_MISSIONS`.
"""
import dataclasses as dc
from typing import Callable

import numpy as np

from alight.diagrams.onboard.controllers import resolve_force_disturbance
from alight.diagrams.onboard.estimation import scenario_odometry
from alight.diagrams.onboard.faults import command_filter, faulty_odometry
from alight.diagrams.onboard.landing import add_landing_onboard
from alight.diagrams.onboard.landing_managed import add_landing_managed
from alight.diagrams.onboard.mpc_loop import mocap_odometry
from alight.diagrams.onboard.pilot import add_pilot_onboard, pilot_model
from alight.diagrams.onboard.vio import vio_from_start
from alight.diagrams.onboard.waypoints import add_waypoint_onboard, mission_duration
from alight.diagrams.running.run_log import RunLoggers
from alight.diagrams.scenario import Scenario
from alight.systems.control.linear_mpc import resolve_disturbance


@dc.dataclass
class OnboardStack:
    """What `add_onboard` built: the run loggers, how long the mission may run [s] (None: until
    stopped), the stop condition on the root context (None: the duration), metadata for the
    run folder and the stack's own handles (`parts`)."""
    loggers: RunLoggers
    duration: float | None
    finished: Callable | None = None
    metadata: dict = dc.field(default_factory=dict)
    parts: object = None


def scenario_estimator(scenario: Scenario, anchored: bool = True):
    """The odometry hook `(builder, vehicle) -> STATE_ESTIMATE port` of `onboard.estimator` in
    simulation: the VIO (its frame at the take-off point, a surveyed start), mocap (sensor
    model) or the estimator bank (`anchored`: as `scenario_odometry`)."""
    onboard = scenario.onboard
    if onboard.estimator == "vio":
        return vio_from_start(onboard.vio, scenario.vehicle.initial_position)
    return scenario_odometry(onboard.estimator, onboard.estimator_bank, onboard.linear_model,
                             f"scenario {scenario.name}", anchored=anchored, others=("vio",),
                             key="onboard.estimator") or mocap_odometry(onboard.mocap)


def _linear_mpc(onboard):
    """The scenario's linear MPC parameters for its odometry (`resolve_disturbance`)."""
    return resolve_disturbance(onboard.linear_mpc, onboard.estimator)


def _landing(builder, scenario: Scenario, vehicle, odometry) -> OnboardStack:
    onboard = scenario.onboard
    parts = add_landing_onboard(builder, vehicle, scenario.mission, _linear_mpc(onboard),
                                onboard.linear_model, odometry, onboard.perception,
                                onboard.failsafe_switch, scenario.camera_blackouts,
                                command_filter(scenario.faults.command), onboard.touchdown)
    return OnboardStack(parts.loggers, scenario.simulator.max_duration,
                        parts.finished(scenario.scoring.settle_time), {"trackers": []}, parts)


def _control_manager(onboard):
    """The scenario's control manager with its force controllers resolved for its odometry
    (`resolve_force_disturbance`)."""
    manager = onboard.control_manager
    return dc.replace(manager, controller_params=resolve_force_disturbance(
        manager.controller_params, onboard.estimator))


def _landing_managed(builder, scenario: Scenario, vehicle, odometry) -> OnboardStack:
    onboard = scenario.onboard
    parts = add_landing_managed(builder, vehicle, scenario.mission, _control_manager(onboard),
                                onboard.controller, _linear_mpc(onboard), odometry,
                                onboard.perception, scenario.camera_blackouts, onboard.touchdown)
    return OnboardStack(parts.loggers, scenario.simulator.max_duration,
                        parts.finished(scenario.scoring.settle_time),
                        {"trackers": list(parts.managed.trackers)}, parts)


def _waypoints(builder, scenario: Scenario, vehicle, odometry) -> OnboardStack:
    onboard, waypoints = scenario.onboard, np.asarray(scenario.mission.waypoints, float)
    parts = add_waypoint_onboard(builder, vehicle, waypoints, scenario.mission.params, odometry,
                                 _linear_mpc(onboard), onboard.linear_model,
                                 onboard.failsafe_switch, command_filter(scenario.faults.command))
    return OnboardStack(parts.loggers, mission_duration(waypoints,
                                                        scenario.simulator.max_duration),
                        parts.finished(rest=scenario.scoring.settle_time), {}, parts)


def _hover(builder, scenario: Scenario, vehicle, odometry) -> OnboardStack:
    loggers = add_pilot_onboard(builder, vehicle, scenario.mission,
                                pilot_model(scenario.vehicle.airframe))
    return OnboardStack(loggers, scenario.mission.duration)


STACKS: dict[str, Callable[..., OnboardStack]] = {
    "landing": _landing, "landing_managed": _landing_managed, "waypoints": _waypoints,
    "hover": _hover}
# Stacks that fly on a position estimate (hover flies an open-loop attitude/thrust profile).
NEEDS_ODOMETRY = {"landing", "landing_managed", "waypoints"}


def add_onboard(builder, scenario: Scenario, vehicle, odometry=None) -> OnboardStack:
    """The scenario's onboard stack on `vehicle`'s ports, flying on `odometry` (default: the
    scenario's estimator, `scenario_estimator`; the MAVLink side passes its own), with the
    odometry's own streams logged when it has any (the VIO's, the bank's), and the scenario's
    estimate faults after it (`faults.estimate`, simulation's fault injection)."""
    if odometry is None and scenario.onboard.stack in NEEDS_ODOMETRY:
        odometry = scenario_estimator(scenario)
    odometry = faulty_odometry(odometry, scenario.faults.estimate)
    stack = STACKS[scenario.onboard.stack](builder, scenario, vehicle, odometry)
    if hasattr(odometry, "log"):
        odometry.log(builder, stack.loggers)
    stack.metadata = {"stack": scenario.onboard.stack, **stack.metadata}
    return stack
