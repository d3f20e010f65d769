"""One typed scenario tree per run (DESIGN.md "Scenarios, parameters and errors"), modelled on
manipulation's `Scenario` / `LoadScenario` and Drake's hardware_sim (a scenario file plus YAML
overrides).

A `Scenario` is the whole run as typed objects: the simulated vehicle in its world
(`vehicle`: airframe, flight controller, sensors, wind, the target car), how the target drives
(`target_motion`), the onboard stack (`onboard`: which stack, its odometry, controller and
tunings), the mission (`mission`: a tagged union of the missions the stacks fly), scoring,
`random_seed` and the simulator's settings. `load_scenario(filename=..., data=...,
overrides=[...])` resolves every referenced parameter file once (systems/params.py), applies the
overrides ('key.sub: value') and validates with the range checks. A run folder stores the result
as `scenario.yaml` (`dump_scenario`): loading it back reproduces the run without any file of
models/.
"""
import dataclasses as dc
from pathlib import Path

import numpy as np
from pydrake.common.yaml import yaml_dump_typed

from alight.diagrams.onboard.control_manager import (ControlManagerConfig,
                                                     check_control_manager_config)
from alight.diagrams.onboard.estimation import scenario_odometry
from alight.diagrams.world.sim_vehicle import SimVehicleConfig
from alight.models import model_path
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import LinearMpcParams
from alight.systems.control.scripted_pilot import PilotProfile
from alight.systems.control.touchdown_level import TouchdownLevelParams
from alight.systems.managers.failsafe_switch import FailsafeSwitchParams
from alight.systems.estimation.bank import BankParams, check_bank
from alight.systems.mission.landing import LandingMissionParams
from alight.systems.mission.waypoints import WaypointMissionParams
from alight.systems.params import (ConfigError, bounded, choice, load_params, param_file,
                                   validate)
from alight.systems.perception.target_estimator import TargetEstimatorParams
from alight.systems.sensors.command_faults import CommandFaultParams
from alight.systems.sensors.estimate_faults import EstimateFaultParams
from alight.systems.sensors.mocap import MocapParams
from alight.systems.sensors.rgbd_camera import RgbdCameraParams
from alight.systems.vio.estimator import VioParams

SCENARIOS = {name: f"scenario_{name}.yaml"
             for name in ("field", "mbzirc", "field_hil", "waypoints", "hover")}


@dc.dataclass
class TargetMotion:
    """How the car drives: the profile of systems/target/motion.py at `speed` along `heading`,
    placed so that it passes under the mission's waypoint `approach_time` after the start
    (the figure eight starts at its crossing point, the waypoint)."""
    profile: str = choice("field_test", "figure_eight", "straight")
    speed: float = bounded(3.0, 0.0, 20.0, "m/s")               # the profile's (mean) speed
    heading: float = bounded(90.0, -360.0, 360.0, "deg")
    approach_time: float = bounded(20.0, 0.0, 600.0, "s")
    speed_std: float = bounded(0.3, 0.0, 10.0, "m/s")           # field test speed spread
    turn_rate_std: float = bounded(3.0, 0.0, 180.0, "deg/s")    # field test wander
    pull_rate: float = bounded(0.3, 0.0, 60.0, "1/min")         # field test sharp pulls
    pull_times: list[float] = dc.field(default_factory=list)    # s, pulls at fixed times


@dc.dataclass
class Onboard:
    """The onboard stack (diagrams/stacks.py `STACKS`) and its parts' parameters. `estimator`:
    vio (the default, L Sec. 5.1: the forward RGB-D camera `vio_camera`, its frame at the
    take-off point), mocap (the idealization: true pose plus noise and delay, an explicit
    option as DESIGN.md asks), bank (M Sec. 3.5: the arbiter) or a filter of the bank."""
    stack: str = choice("landing", "landing_managed", "waypoints", "hover")
    estimator: str = "vio"
    controller: str = "linear_mpc"       # landing_managed: a controller of `control_manager`
    linear_mpc: LinearMpcParams = param_file(LinearMpcParams, "linear_mpc.yaml")
    linear_model: LinearModelParams = param_file(LinearModelParams, "linear_model.yaml")
    # landing, waypoints: the fallback to the failsafe (the managed stacks: control_manager's)
    failsafe_switch: FailsafeSwitchParams = param_file(FailsafeSwitchParams,
                                                       "failsafe_switch.yaml")
    mocap: MocapParams = dc.field(default_factory=MocapParams)
    # landing stacks: the attitude command levelled for the touchdown (height 0: off)
    touchdown: TouchdownLevelParams = param_file(TouchdownLevelParams, "touchdown_level.yaml")
    perception: TargetEstimatorParams = param_file(TargetEstimatorParams,
                                                   "target_perception.yaml")  # landing stacks
    estimator_bank: BankParams = param_file(BankParams, "estimator_bank.yaml")
    vio: VioParams = param_file(VioParams, "vio.yaml")
    vio_camera: RgbdCameraParams = param_file(RgbdCameraParams, "rgbd_camera_landing.yaml")
    control_manager: ControlManagerConfig = param_file(ControlManagerConfig,
                                                       "control_manager.yaml")


@dc.dataclass
class WaypointPlan:
    """The waypoint mission of the `waypoints` stack: rows x, y, z in W [m]."""
    waypoints: list[list[float]] = dc.field(default_factory=lambda: [[0.0, 0.0, 2.0],
                                                                     [3.0, 0.0, 2.0]])
    params: WaypointMissionParams = dc.field(default_factory=WaypointMissionParams)


@dc.dataclass
class ImpactLimits:
    """What the airframe survives at touchdown (relative to the platform)."""
    vertical_speed: float = bounded(3.0, 0.1, 20.0, "m/s")
    horizontal_speed: float = bounded(2.0, 0.1, 20.0, "m/s")


@dc.dataclass
class Scoring:
    impact: ImpactLimits = dc.field(default_factory=ImpactLimits)
    settle_time: float = bounded(2.0, 0.5, 30.0, "s")   # at rest after disarming, to judge


@dc.dataclass
class SimulatorSettings:
    max_duration: float = bounded(90.0, 1.0, 3600.0, "s")


@dc.dataclass
class Faults:
    """Injected faults (simulation only; bench/faults.py, issue 21): a bad localization system
    after the odometry (`estimate`: loss for a time, jump, noise) and a broken linear MPC
    (`command`: NaN or out-of-range commands; the direct stacks `landing`, `waypoints`). The
    vehicle's own faults are `vehicle.motor_fault`, the down camera's `camera_blackouts`."""
    estimate: EstimateFaultParams = dc.field(default_factory=EstimateFaultParams)
    command: CommandFaultParams = dc.field(default_factory=CommandFaultParams)


@dc.dataclass
class Scenario:
    """A run (models/scenario_*.yaml); see the module text."""
    name: str = "field"
    random_seed: int = 0
    vehicle: SimVehicleConfig = param_file(SimVehicleConfig, "sim_vehicle.yaml")
    target_motion: TargetMotion = dc.field(default_factory=TargetMotion)
    camera_blackouts: list[list[float]] = dc.field(default_factory=list)  # down camera [s]
    faults: Faults = dc.field(default_factory=Faults)
    onboard: Onboard = dc.field(default_factory=Onboard)
    mission: LandingMissionParams | WaypointPlan | PilotProfile = dc.field(
        default_factory=LandingMissionParams)
    scoring: Scoring = dc.field(default_factory=Scoring)
    simulator: SimulatorSettings = dc.field(default_factory=SimulatorSettings)


def scenario_file(name_or_file: str | Path) -> Path:
    """A scenario by name (SCENARIOS) or file (a path, or a file in models/)."""
    name = str(name_or_file)
    path = Path(name)
    return path if path.is_file() else model_path(SCENARIOS.get(name, name))


def load_scenario(filename: str | Path | None = None, data: str | None = None,
                  overrides: list[str] | tuple = ()) -> Scenario:
    """The scenario of a file (or name, see `scenario_file`) or YAML string, with `overrides`
    ('key.sub: value' each) applied; every referenced file resolved and everything validated,
    once. Raises ConfigError naming the file (or override), the key and the allowed range."""
    source = scenario_file(filename) if filename is not None else None
    scenario = load_params(Scenario, source, data=data, overrides=overrides)
    check_scenario(scenario, str(source or "<yaml string>"))
    return scenario


# The mission each onboard stack flies (diagrams/stacks.py builds them).
STACK_MISSIONS = {"landing": LandingMissionParams, "landing_managed": LandingMissionParams,
                  "waypoints": WaypointPlan, "hover": PilotProfile}


# The stacks whose linear MPC command `faults.command` can garble, and those on an estimate.
COMMAND_FAULT_STACKS = {"landing", "waypoints"}
ODOMETRY_STACKS = {"landing", "landing_managed", "waypoints"}


def check_scenario(scenario: Scenario, where: str) -> None:
    """What the range checks cannot say: the stack flies the scenario's kind of mission, the
    estimator exists, the direct landing stack flies the linear MPC. ConfigError names `where`
    and the key."""
    onboard = scenario.onboard
    check_control_manager_config(onboard.control_manager, f"{where}: onboard.control_manager")
    check_bank(onboard.estimator_bank, f"{where}: onboard.estimator_bank")
    kind = STACK_MISSIONS[onboard.stack]
    if not isinstance(scenario.mission, kind):
        raise ConfigError(f"{where}: key 'mission' is a {type(scenario.mission).__name__}; the "
                          f"'{onboard.stack}' stack (key 'onboard.stack') flies a "
                          f"{kind.__name__} (tag it !{kind.__name__})")
    if onboard.estimator == "vio" and abs(onboard.vio.period - scenario.vehicle.imu.period) > 1e-9:
        raise ConfigError(f"{where}: key 'onboard.vio.period' = {onboard.vio.period} s: the VIO "
                          f"integrates each IMU sample over its period, and the vehicle's IMU "
                          f"samples every {scenario.vehicle.imu.period} s (key "
                          f"'vehicle.imu.period'): give both the same period")
    if onboard.estimator != "vio":
        scenario_odometry(onboard.estimator, onboard.estimator_bank, onboard.linear_model,
                          where, others=("vio",), key="onboard.estimator")
    if scenario.faults.command.active and onboard.stack not in COMMAND_FAULT_STACKS:
        raise ConfigError(f"{where}: key 'faults.command': the '{onboard.stack}' stack (key "
                          f"'onboard.stack') has no linear MPC command to inject it into (only "
                          f"{sorted(COMMAND_FAULT_STACKS)})")
    if scenario.faults.estimate.active and onboard.stack not in ODOMETRY_STACKS:
        raise ConfigError(f"{where}: key 'faults.estimate': the '{onboard.stack}' stack (key "
                          f"'onboard.stack') flies without a state estimate")
    if onboard.stack == "landing" and onboard.controller != "linear_mpc":
        raise ConfigError(f"{where}: key 'onboard.controller' = {onboard.controller!r}: the "
                          f"direct landing stack flies linear_mpc only (onboard.stack: "
                          f"landing_managed flies the control manager's controllers)")


def dump_scenario(scenario: Scenario) -> str:
    """The fully resolved scenario as YAML (what a run folder's scenario.yaml holds)."""
    return yaml_dump_typed(scenario)


def placed_target(scenario: Scenario):
    """The vehicle's target car with the scenario's motion, placed to pass under the waypoint."""
    motion, car = scenario.target_motion, scenario.vehicle.target
    heading = np.radians(motion.heading)
    waypoint = np.asarray(scenario.mission.waypoint[:2])
    start = waypoint - motion.speed * motion.approach_time * np.array(
        [np.cos(heading), np.sin(heading)])
    if motion.profile == "figure_eight":
        start = waypoint   # the track starts at its crossing point
        profile = {"figure_eight": dc.replace(car.figure_eight, speed=motion.speed)}
    elif motion.profile == "straight":
        profile = {"straight": dc.replace(car.straight, speed=motion.speed)}
    else:
        # the car's speed clip (a pulled target's 8 m/s) never cuts into the requested spread:
        # a mean of 8 m/s drove at 7.78, 10 m/s at 7.97
        max_speed = max(car.field_test.max_speed, motion.speed + 4.0 * motion.speed_std)
        profile = {"field_test": dc.replace(
            car.field_test, mean_speed=motion.speed, speed_std=motion.speed_std,
            max_speed=max_speed, turn_rate_std=motion.turn_rate_std,
            pull_rate=motion.pull_rate, pull_times=list(motion.pull_times))}
    return dc.replace(car, profile=motion.profile, initial_position=list(start),
                      initial_heading=motion.heading, **profile)


def vehicle_config(scenario: Scenario, vio_camera: bool = True) -> SimVehicleConfig:
    """The simulated vehicle of the scenario: the rendered scene's light drawn from its
    `random_seed`; with a landing mission, the target car placed by `target_motion`; with VIO
    odometry (and `vio_camera`), the forward RGB-D camera `onboard.vio_camera`."""
    config = dc.replace(scenario.vehicle, lighting=dc.replace(scenario.vehicle.lighting,
                                                               seed=scenario.random_seed))
    if isinstance(scenario.mission, LandingMissionParams):
        config = dc.replace(config, target=placed_target(scenario))
    if scenario.onboard.estimator == "vio" and vio_camera:
        config = dc.replace(config, rgbd_camera=scenario.onboard.vio_camera)
    validate(config, f"scenario {scenario.name}")
    return config


SCENARIO_FILE = "scenario.yaml"   # in a run folder


def write_scenario(run_dir: str | Path, scenario: Scenario) -> Path:
    """Writes the fully resolved scenario into a run folder (what `alight land --scenario
    RUN/scenario.yaml` reads to fly the run again)."""
    path = Path(run_dir) / SCENARIO_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(dump_scenario(scenario))
    return path
