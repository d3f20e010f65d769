"""The control manager's diagram, M Sec. 7.2: the controllers and trackers listed in
models/control_manager.yaml, each built by its factory, wired to one `ControlManager`
(systems/managers/control_manager.py).

Adding a controller is one `Controller` (alight.systems.control.controller; a tracker: one
`Tracker`, alight.systems.tracking.tracker) and one entry in the YAML list (`name`, `factory:
"module:function"`); docs/controllers.md has a worked example. The manager names its ports after
the entries (`se3.fc_command`, `mpc_tracker.reference`, `se3.active`). `fly_managed`
(alight.diagrams.running.flights) flies the simulated vehicle under the manager.
"""
import dataclasses as dc
import importlib

from pydrake.common.value import AbstractValue
from pydrake.systems.primitives import ConstantValueSource

from alight.diagrams.onboard.controllers import CONTROLLERS, ControllersConfig, make_controller
from alight.diagrams.running.run_log import RunLoggers, add_run_logging
from alight.models import model_path
from alight.systems.boundary import (CONTROLLER_INPUTS, CONTROLLER_OUTPUTS, CONTROLLER_STATUS,
                                     REFERENCE, STATE_ESTIMATE, TRACKER_INPUTS, TRACKER_OUTPUTS,
                                     TRACKER_STATUS)
from alight.systems.managers.control_manager import (MANAGER_STATUS, ControlManager,
                                                     EmergencyParams, SafetyArea)
from alight.systems.params import ConfigError, bounded, load_params, param_file
from alight.systems.tracking.constraints import check_constraint_groups
from alight.systems.tracking.landoff_tracker import LandoffTrackerParams, make_landoff_tracker
from alight.systems.tracking.mpc_tracker import MpcTrackerParams, make_mpc_tracker
from alight.systems.tracking.speed_tracker import SpeedTrackerParams, make_speed_tracker
from alight.systems.tracking.target_tracker import TargetTrackerParams, make_target_tracker


@dc.dataclass
class ControllerEntry:
    """One loaded controller: a built-in name (CONTROLLERS) or any name with a factory
    "package.module:function" taking the ControllersConfig and returning the LeafSystem."""
    name: str = ""
    factory: str = ""


# The built-in trackers (M Sec. 4, L Sec. 6.3) with the kind of goal they follow (the UAV
# manager's `<kind>_goal` output: a point/trajectory TrackerGoal, a LandoffGoal, a SpeedGoal; the
# landing mission's TargetGoal).
TRACKERS = {"mpc_tracker": "trajectory", "landoff": "landoff", "speed": "speed",
            "target": "target"}
GOAL_KINDS = ("trajectory", "landoff", "speed", "target")


@dc.dataclass
class TrackerEntry:
    """One loaded tracker: a built-in name (TRACKERS) or any name with a factory
    "package.module:function" taking the ControllersConfig and returning the LeafSystem, and
    the kind of goal it follows (GOAL_KINDS; a built-in's own kind when empty)."""
    name: str = ""
    factory: str = ""
    goal: str = ""

    @property
    def goal_kind(self) -> str:
        return self.goal or TRACKERS.get(self.name, "trajectory")


@dc.dataclass
class TrackersConfig:
    """The built-in trackers' parameters, by tracker name (TRACKERS), each from its models/ file."""
    mpc_tracker: MpcTrackerParams = param_file(MpcTrackerParams, "mpc_tracker.yaml")
    landoff: LandoffTrackerParams = param_file(LandoffTrackerParams, "landoff_tracker.yaml")
    speed: SpeedTrackerParams = param_file(SpeedTrackerParams, "speed_tracker.yaml")
    target: TargetTrackerParams = param_file(TargetTrackerParams, "target_tracker.yaml")


@dc.dataclass
class ControlManagerConfig:
    period: float = bounded(0.01, 0.001, 0.1, "s")
    controller_params: ControllersConfig = param_file(ControllersConfig, "controllers.yaml")
    tracker_params: TrackersConfig = dc.field(default_factory=TrackersConfig)
    controllers: list[ControllerEntry] = dc.field(default_factory=lambda: [
        ControllerEntry(name) for name in ("se3", "mpc", "failsafe")])
    initial_controller: str = "se3"
    failsafe_controller: str = "failsafe"
    emergency_controller: str = "se3"
    trackers: list[TrackerEntry] = dc.field(default_factory=lambda: [
        TrackerEntry(name) for name in TRACKERS])
    initial_tracker: str = "mpc_tracker"
    safety_area: SafetyArea = dc.field(default_factory=SafetyArea)
    emergency: EmergencyParams = dc.field(default_factory=EmergencyParams)

    @property
    def names(self) -> list[str]:
        return [entry.name for entry in self.controllers]

    @property
    def tracker_names(self) -> list[str]:
        return [entry.name for entry in self.trackers]


def load_control_manager_config(filename: str = "control_manager.yaml") -> ControlManagerConfig:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    path = model_path(filename)
    config = load_params(ControlManagerConfig, path)
    check_control_manager_config(config, str(path))
    return config


def check_control_manager_config(config: ControlManagerConfig, source: str = "<config>"):
    names = _check_entries(source, "controllers", config.controllers, CONTROLLERS)
    for key in ("initial_controller", "failsafe_controller", "emergency_controller"):
        if getattr(config, key) not in names:
            raise ConfigError(f"{source}: key '{key}' = {getattr(config, key)!r} is not one of "
                              f"the listed controllers {names}")
    trackers = _check_entries(source, "trackers", config.trackers, TRACKERS)
    shared = sorted(set(names) & set(trackers))
    if shared:
        raise ConfigError(f"{source}: keys 'controllers' and 'trackers' share the names {shared}: "
                          f"the manager names its ports after them")
    for entry in config.trackers:
        if entry.goal_kind not in GOAL_KINDS:
            raise ConfigError(f"{source}: key 'trackers': {entry.name!r} has goal "
                              f"{entry.goal!r}, expected one of {list(GOAL_KINDS)}")
    if config.initial_tracker not in trackers:
        raise ConfigError(f"{source}: key 'initial_tracker' = {config.initial_tracker!r} is not "
                          f"one of the listed trackers {trackers}")
    try:
        config.safety_area.validate()
    except ValueError as e:
        raise ConfigError(f"{source}: {e}") from None
    trackers = config.tracker_params
    check_constraint_groups(trackers.mpc_tracker.constraint_groups, source,
                            "tracker_params.mpc_tracker.constraint_groups.")
    trackers.landoff.profile.check(trackers.landoff.period, f"{source}: tracker_params.landoff")


def _check_entries(source: str, key: str, entries, builtins) -> list[str]:
    """The names of a YAML list of controllers or trackers: unique, built-in or with a factory."""
    names = [entry.name for entry in entries]
    if not names or len(set(names)) != len(names) or "" in names:
        raise ConfigError(f"{source}: key '{key}' needs unique, non-empty names: {names}")
    for entry in entries:
        if not entry.factory and entry.name not in builtins:
            raise ConfigError(f"{source}: key '{key}': {entry.name!r} is not a built-in "
                              f"{key[:-1]} {list(builtins)} and has no factory")
    return names


def build_controller(entry: ControllerEntry, controllers_config: ControllersConfig):
    """The LeafSystem of one YAML entry, checked against the controller contract."""
    if not entry.factory:
        return make_controller(entry.name, controllers_config)
    return _build_plugin("controller", entry.name, entry.factory, controllers_config,
                         CONTROLLER_INPUTS, CONTROLLER_OUTPUTS)


def make_tracker(name: str, controllers_config: ControllersConfig, tracker_params: TrackersConfig):
    """The LeafSystem of built-in tracker `name` (one of TRACKERS) with its `tracker_params`."""
    if name == "mpc_tracker":
        return make_mpc_tracker(tracker_params.mpc_tracker)
    if name == "landoff":
        return make_landoff_tracker(controllers_config.vehicle, tracker_params.landoff)
    if name == "speed":
        return make_speed_tracker(tracker_params.speed)
    if name == "target":
        return make_target_tracker(tracker_params.target)
    raise ValueError(f"unknown tracker {name!r}: expected one of {list(TRACKERS)}")


def build_tracker(entry: TrackerEntry, controllers_config: ControllersConfig,
                  tracker_params: TrackersConfig):
    """The LeafSystem of one YAML tracker entry (a built-in one with its `tracker_params`),
    checked against the tracker contract."""
    if not entry.factory:
        return make_tracker(entry.name, controllers_config, tracker_params)
    return _build_plugin("tracker", entry.name, entry.factory, controllers_config,
                         TRACKER_INPUTS, TRACKER_OUTPUTS)


def _build_plugin(role: str, name: str, factory_path: str, controllers_config, inputs, outputs):
    module_name, _, function_name = factory_path.partition(":")
    try:
        factory = getattr(importlib.import_module(module_name), function_name)
    except (ImportError, AttributeError, ValueError) as e:
        raise ConfigError(f"{role} {name!r}: cannot load factory {factory_path!r} (expected "
                          f"'package.module:function'): {e}") from None
    system = factory(controllers_config)
    missing = [f"input {p}" for p in inputs if not system.HasInputPort(p)] + \
        [f"output {p}" for p in outputs if not system.HasOutputPort(p)]
    if missing:
        raise ConfigError(f"{role} {name!r} from {factory_path!r} does not follow the {role} "
                          f"contract (alight.systems.boundary): missing {missing}")
    return system


def parse_switch(text: str, names: list[str]) -> tuple[float, str]:
    """`T:NAME` of `--switch-controller-at` -> (T [s], NAME)."""
    time_text, _, name = text.partition(":")
    try:
        t = float(time_text)
    except ValueError:
        raise ValueError(f"switch {text!r}: expected TIME:NAME, e.g. 12.5:mpc") from None
    if not t >= 0.0 or name not in names:
        raise ValueError(f"switch {text!r}: time must be >= 0 and the name one of {names}")
    return t, name


@dc.dataclass
class ManagedControllers:
    manager: ControlManager
    controllers: dict  # name -> LeafSystem
    trackers: dict = dc.field(default_factory=dict)  # name -> LeafSystem


def add_control_manager(builder, config: ControlManagerConfig,
                        controllers_config: ControllersConfig, state_estimate, goal=None,
                        switch_request=None, schedule: list[tuple[float, str]] | None = None,
                        goals: dict | None = None, fc_attitude=None,
                        target_estimate=None) -> ManagedControllers:
    """The listed controllers and the manager, fed by the `state_estimate` port and either a
    `goal` (REFERENCE) port (no trackers) or, with `goal` None, the listed trackers, each fed by
    `goals[kind]` (an abstract goal port per GOAL_KINDS; a kind not given holds). `fc_attitude`
    goes to the controllers that read it, `target_estimate` (TARGET_ESTIMATE) to the trackers
    that read it. Connect the manager's `fc_command` to the vehicle."""
    trackers = [] if goal is not None else config.trackers
    manager = builder.AddNamedSystem("control_manager", ControlManager(
        controllers=config.names, initial_controller=config.initial_controller,
        failsafe_controller=config.failsafe_controller,
        emergency_controller=config.emergency_controller, vehicle=controllers_config.vehicle,
        trackers=[entry.name for entry in trackers],
        initial_tracker=config.initial_tracker if trackers else None,
        safety_area=config.safety_area, emergency=config.emergency, period=config.period,
        schedule=schedule))
    builder.Connect(state_estimate, manager.GetInputPort("state_estimate"))
    if goal is not None:
        builder.Connect(goal, manager.GetInputPort("goal"))
    if switch_request is not None:
        builder.Connect(switch_request, manager.GetInputPort("switch_request"))
    controllers = {}
    for entry in config.controllers:
        controller = builder.AddNamedSystem(f"controller_{entry.name}",
                                            build_controller(entry, controllers_config))
        _connect_member(builder, manager, entry.name, controller)
        builder.Connect(state_estimate, controller.GetInputPort("state_estimate"))
        builder.Connect(manager.GetOutputPort("reference"), controller.GetInputPort("reference"))
        builder.Connect(manager.GetOutputPort("fc_command"),
                        controller.GetInputPort("last_command"))
        if controller.HasInputPort("last_disturbance"):
            builder.Connect(manager.GetOutputPort("last_disturbance"),
                            controller.GetInputPort("last_disturbance"))
        if controller.HasInputPort("tracker_status"):
            builder.Connect(manager.GetOutputPort("tracker_status"),
                            controller.GetInputPort("tracker_status"))
        if fc_attitude is not None and controller.HasInputPort("fc_attitude"):
            builder.Connect(fc_attitude, controller.GetInputPort("fc_attitude"))
        controllers[entry.name] = controller
    return ManagedControllers(manager, controllers, {
        entry.name: _add_tracker(builder, manager, entry, controllers_config,
                                 config.tracker_params, state_estimate, goals or {},
                                 target_estimate)
        for entry in trackers})


def _connect_member(builder, manager, name: str, system) -> None:
    """The manager's `NAME.active` to the controller's or tracker's `active`, and each of its
    outputs `port` the manager has a `NAME.port` input for to that input (the command and
    status; the reference; the optional disturbance estimate and desired acceleration M(53))."""
    builder.Connect(manager.GetOutputPort(f"{name}.active"), system.GetInputPort("active"))
    for i in range(system.num_output_ports()):
        output = system.get_output_port(i)
        if manager.HasInputPort(f"{name}.{output.get_name()}"):
            builder.Connect(output, manager.GetInputPort(f"{name}.{output.get_name()}"))


def connect_managed_vehicle(builder, managed: ManagedControllers, vehicle, arm, tracker_request,
                            odometry, estimate, command_filter=None) -> None:
    """What drives the manager (the `arm` [arm, thrust enable] and `tracker_request` ports of a
    mission or the UAV manager) and where its command goes (through `command_filter(builder,
    port) -> port` if given: the landing's level touchdown): the vehicle, and an odometry with
    `connect_command` (the estimator bank), which is also given the active controller's
    unbiased desired acceleration M(53) (M Sec. 3.1.1)."""
    manager = managed.manager
    builder.Connect(arm, manager.GetInputPort("arm"))
    builder.Connect(tracker_request, manager.GetInputPort("tracker_request"))
    command = manager.GetOutputPort("fc_command")
    if command_filter is not None:
        command = command_filter(builder, command)
    builder.Connect(command, vehicle.GetInputPort("fc_command"))
    if hasattr(odometry, "connect_command"):
        odometry.connect_command(builder, command, manager.GetOutputPort("desired_acceleration"),
                                 estimate)


def _add_tracker(builder, manager, entry: TrackerEntry, controllers_config, tracker_params,
                 state_estimate, goals: dict, target_estimate=None):
    tracker = builder.AddNamedSystem(f"tracker_{entry.name}",
                                     build_tracker(entry, controllers_config, tracker_params))
    _connect_member(builder, manager, entry.name, tracker)
    builder.Connect(state_estimate, tracker.GetInputPort("state_estimate"))
    builder.Connect(manager.GetOutputPort("reference"), tracker.GetInputPort("last_reference"))
    goal = goals.get(entry.goal_kind) or builder.AddSystem(
        ConstantValueSource(AbstractValue.Make(None))).get_output_port()   # no goal: hold
    builder.Connect(goal, tracker.GetInputPort("goal"))
    if tracker.HasInputPort("last_command"):      # e.g. the landoff tracker's touchdown M(34)
        builder.Connect(manager.GetOutputPort("fc_command"), tracker.GetInputPort("last_command"))
    if target_estimate is not None and tracker.HasInputPort("target_estimate"):
        builder.Connect(target_estimate, tracker.GetInputPort("target_estimate"))
    return tracker


def add_managed_logging(builder, vehicle, managed: ManagedControllers, state_estimate, goal,
                        period: float, command=None) -> RunLoggers:
    """The vehicle's streams and command (`command`, the port that drives the vehicle, if not
    the manager's own), the estimate, the goal and the issued reference, the manager's status
    and every controller's status."""
    manager = managed.manager
    loggers = add_run_logging(builder, vehicle, command or manager.GetOutputPort("fc_command"))
    loggers.add(builder, "state_estimate", state_estimate, STATE_ESTIMATE, period)
    loggers.add(builder, "goal", goal, REFERENCE, period)
    loggers.add(builder, "reference", manager.GetOutputPort("reference"), REFERENCE, period)
    loggers.add(builder, "manager_status", manager.GetOutputPort("manager_status"),
                MANAGER_STATUS, period)
    for name, controller in managed.controllers.items():
        loggers.add(builder, f"status_{name}", controller.GetOutputPort("controller_status"),
                    CONTROLLER_STATUS, period)
    for name, tracker in managed.trackers.items():
        loggers.add(builder, f"tracker_status_{name}", tracker.GetOutputPort("tracker_status"),
                    TRACKER_STATUS, period)
    return loggers
