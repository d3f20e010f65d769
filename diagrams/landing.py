"""The landing mission end to end (L Sec. 6-7): scenario files, the onboard landing stack
(`add_landing_onboard`: odometry, target perception, the mission state machine L Sec. 6.4 with its
reference generation L Sec. 6.3, the linear MPC) on any vehicle, the simulated vehicle in the
scenario's world (`vehicle_config`: the moving target, the down camera, wind) and `run_landing`.
`alight hil --mission land` puts the same onboard stack on the MAVLink vehicle (hw/hil.py).
"""
import dataclasses as dc
from pathlib import Path

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.estimation import scenario_odometry
from alight.diagrams.fly import MpcLoop, add_mpc_control, add_mpc_logging, load_linear_mpc
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.perception import TargetPerceptionPorts, add_target_perception
from alight.diagrams.running.run_log import RunLog, RunLoggers, write_run_folder
from alight.diagrams.world.sim_vehicle import (SimVehicleConfig, load_sim_vehicle_config,
                                               make_sim_vehicle)
from alight.diagrams.running.simulation import DisarmedAfter, evaluate, simulate
from alight.models import model_path
from alight.systems.boundary import TARGET_ESTIMATE
from alight.systems.mission.landing import (MISSION_STATUS, LandingMission, LandingMissionParams,
                                            Mode, Reason)
from alight.systems.params import bounded, choice, load_params, validate
from alight.systems.plant.wind import WindParams
from alight.systems.sensors.camera_faults import CameraBlackout
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.target.vehicle import load_target_params

SCENARIOS = {"mbzirc": "scenario_mbzirc.yaml", "field": "scenario_field.yaml"}


@dc.dataclass
class ImpactLimits:
    """What the airframe survives at touchdown (relative to the platform)."""
    vertical_speed: float = bounded(3.0, 0.1, 20.0, "m/s")
    horizontal_speed: float = bounded(2.0, 0.1, 20.0, "m/s")


@dc.dataclass
class LandingScenario:
    """A landing run: vehicle, target, camera, wind, mission and scoring limits (models/scenario_*)."""
    name: str = "field"
    vehicle: str = "sim_vehicle.yaml"
    vehicle_position: list[float] = bounded([0.0, -8.0], -1e4, 1e4, "m")  # take-off point, x y
    target: str = "target.yaml"
    target_profile: str = choice("field_test", "figure_eight", "straight")
    target_speed: float = bounded(3.0, 0.0, 20.0, "m/s")   # the profile's (mean) speed
    target_heading: float = bounded(90.0, -360.0, 360.0, "deg")
    # The target starts target_speed * approach_time before the waypoint along its heading, so
    # that it passes under the waypoint when the vehicle is there (figure eight: at the crossing).
    approach_time: float = bounded(20.0, 0.0, 600.0, "s")
    target_speed_std: float = bounded(0.3, 0.0, 10.0, "m/s")          # field test speed spread
    target_turn_rate_std: float = bounded(3.0, 0.0, 180.0, "deg/s")   # field test wander
    target_pull_rate: float = bounded(0.3, 0.0, 60.0, "1/min")        # field test sharp pulls
    target_pull_times: list[float] = dc.field(default_factory=list)   # s, pulls at fixed times
    camera: str = choice("geometric", "rendered")
    camera_file: str = "down_camera.yaml"
    camera_blackouts: list[list[float]] = dc.field(default_factory=list)  # [[start, end], ...] s
    wind: WindParams = dc.field(default_factory=WindParams)
    mission: LandingMissionParams = dc.field(default_factory=LandingMissionParams)
    mpc: str = "linear_mpc.yaml"    # the MPC's tuning (models/)
    # The odometry flown on: mocap, `vio` (L Sec. 5.1: the forward RGB-D camera `rgbd_camera`
    # and the VIO of `vio`, its frame placed at the take-off point: a surveyed start), or the
    # estimator bank of `estimator_bank` (M Sec. 3.5): `bank` (its arbiter) or one of its
    # filters by name (diagrams/estimation.py)
    estimator: str = "mocap"
    estimator_bank: str = "estimator_bank.yaml"
    rgbd_camera: str = "rgbd_camera_landing.yaml"
    vio: str = "vio.yaml"
    impact: ImpactLimits = dc.field(default_factory=ImpactLimits)
    max_duration: float = bounded(90.0, 5.0, 3600.0, "s")
    settle_time: float = bounded(2.0, 0.5, 30.0, "s")  # after disarming, to judge the rest


def load_scenario(name_or_file: str = "field") -> LandingScenario:
    """A scenario by name (`mbzirc`, `field`) or YAML file (a path, or a file name in models/);
    a ConfigError names the file and the key (also an unknown `estimator`)."""
    path = model_path(SCENARIOS.get(name_or_file, name_or_file))
    scenario = load_params(LandingScenario, path)
    check_estimator(scenario, str(path))
    return scenario


def check_estimator(scenario: LandingScenario, where: str = "<scenario>") -> None:
    """Raises ConfigError naming `where` and the key when `estimator` names no odometry."""
    if scenario.estimator != "vio":
        scenario_odometry(scenario.estimator, scenario.estimator_bank, where, others=("vio",))


def landing_odometry(scenario: LandingScenario):
    """The `odometry` hook of the scenario's `estimator` (None: mocap)."""
    if scenario.estimator != "vio":
        return scenario_odometry(scenario.estimator, scenario.estimator_bank)
    from alight.diagrams.vio import VioRun, load_vio_params
    params = load_vio_params(scenario.vio)
    start = [*scenario.vehicle_position, params.initial_position[2]]
    return VioRun(dc.replace(params, initial_position=start))


def vehicle_config(scenario: LandingScenario) -> SimVehicleConfig:
    """The simulated vehicle with the scenario's target, down camera and wind."""
    config = load_sim_vehicle_config(scenario.vehicle)
    target = load_target_params(scenario.target)
    heading = np.radians(scenario.target_heading)
    waypoint = np.asarray(scenario.mission.waypoint[:2])
    start = waypoint - scenario.target_speed * scenario.approach_time * np.array(
        [np.cos(heading), np.sin(heading)])
    if scenario.target_profile == "figure_eight":
        start = waypoint  # the track starts at its crossing point
        motion = {"figure_eight": dc.replace(target.figure_eight, speed=scenario.target_speed)}
    elif scenario.target_profile == "straight":
        motion = {"straight": dc.replace(target.straight, speed=scenario.target_speed)}
    else:
        motion = {"field_test": dc.replace(
            target.field_test, mean_speed=scenario.target_speed,
            speed_std=scenario.target_speed_std,
            turn_rate_std=scenario.target_turn_rate_std, pull_rate=scenario.target_pull_rate,
            pull_times=list(scenario.target_pull_times))}
    target = dc.replace(target, profile=scenario.target_profile, initial_position=list(start),
                        initial_heading=scenario.target_heading, **motion)
    camera = dc.replace(load_params(DownCameraParams, model_path(scenario.camera_file)),
                        source=scenario.camera)
    config = dc.replace(config, target=target, down_camera=camera, wind=scenario.wind,
                        initial_position=list(scenario.vehicle_position))
    if scenario.estimator == "vio":    # the VIO's forward RGB-D camera
        from alight.diagrams.vio import load_rgbd_camera_params
        config = dc.replace(config, rgbd_camera=load_rgbd_camera_params(scenario.rgbd_camera))
    validate(config, f"scenario {scenario.name}")
    return config


@dc.dataclass
class LandingOnboard:
    """Handles to the onboard landing stack built by `add_landing_onboard`."""
    mission: LandingMission
    loop: MpcLoop
    perception: TargetPerceptionPorts
    loggers: RunLoggers

    def finished(self, settle_time: float) -> DisarmedAfter:
        """Stop condition: `settle_time` s after the mission landed and the flight controller
        disarmed."""
        return landed_and_disarmed(self.mission, self.loop.vehicle, settle_time)


def landed_and_disarmed(mission: LandingMission, vehicle, settle_time: float) -> DisarmedAfter:
    """Stop condition: `settle_time` s after `mission` landed and `vehicle` disarmed."""
    return DisarmedAfter(lambda context: MISSION_STATUS.get(evaluate(
        mission, "mission_status", context), "mode") == Mode.LANDED, vehicle, settle_time)


def add_down_camera_perception(builder: DiagramBuilder, scenario: LandingScenario, vehicle,
                               state_estimate) -> TargetPerceptionPorts:
    """Target perception on `vehicle`'s `down_image` with the scenario's camera blackouts."""
    image = vehicle.GetOutputPort("down_image")
    if scenario.camera_blackouts:
        blackout = builder.AddNamedSystem("camera_blackout",
                                          CameraBlackout(scenario.camera_blackouts))
        builder.Connect(image, blackout.get_input_port())
        image = blackout.get_output_port()
    return add_target_perception(builder, image, state_estimate)


def add_mission_logging(builder: DiagramBuilder, loggers: RunLoggers, mission: LandingMission,
                        target_estimate, period: float) -> None:
    """The mission's status and the target estimate, at the mission's `period`."""
    loggers.add(builder, "mission_status", mission.GetOutputPort("mission_status"),
                MISSION_STATUS, period=period)
    loggers.add(builder, "target_estimate", target_estimate, TARGET_ESTIMATE, period=period)


def add_landing_onboard(builder: DiagramBuilder, scenario: LandingScenario, vehicle,
                        odometry=None) -> LandingOnboard:
    """The onboard landing stack on `vehicle`'s boundary ports (the simulated or the MAVLink
    vehicle): the mission state machine L Sec. 6.4 with its reference L Sec. 6.3, odometry and
    the linear MPC (`add_mpc_control`), target perception on `down_image` (with the scenario's
    camera blackouts) and the run logging. `odometry` as in `add_mpc_control`."""
    mission = builder.AddNamedSystem("mission", LandingMission(scenario.mission))
    loop = add_mpc_control(builder, vehicle, mission.GetOutputPort("reference"),
                           mission.GetOutputPort("arm"), odometry=odometry,
                           mpc_params=load_linear_mpc(scenario.mpc))
    perception = add_down_camera_perception(builder, scenario, vehicle, loop.state_estimate_port)
    builder.Connect(loop.state_estimate_port, mission.GetInputPort("state_estimate"))
    builder.Connect(perception.target_estimate, mission.GetInputPort("target_estimate"))
    loggers = add_mpc_logging(builder, loop, mission.GetOutputPort("reference"))
    add_mission_logging(builder, loggers, mission, perception.target_estimate,
                        scenario.mission.period)
    return LandingOnboard(mission, loop, perception, loggers)


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
    trackers and `controller` (diagrams/landing_managed.py, issue 11)."""
    if stack not in STACKS:
        raise ValueError(f"landing stack {stack!r}: expected one of {list(STACKS)}")
    if stack == "direct" and controller != "linear_mpc":
        raise ValueError(f"controller {controller!r}: the direct stack flies linear_mpc only; "
                         f"use stack 'managed'")
    if odometry is None:   # the scenario's `estimator` (None: mocap)
        odometry = landing_odometry(scenario)
    builder = DiagramBuilder()
    if stack == "managed":
        from alight.diagrams.landing_managed import build_landing_managed
        config, onboard = build_landing_managed(builder, scenario, meshcat, odometry, controller)
    else:
        config, onboard = build_landing(builder, scenario, meshcat, odometry)
    if hasattr(odometry, "log"):   # the bank's or the VIO's own streams
        odometry.log(builder, onboard.loggers)
    diagram = builder.Build()
    simulator = simulate(diagram, scenario.max_duration, seed, meshcat, record, realtime_rate,
                         stop_when=onboard.finished(scenario.settle_time))
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("land", seed)
    write_run_folder(run_dir, onboard.loggers, simulator.get_context(), {
        "command": "land", "seed": seed, "duration": simulator.get_context().get_time(),
        "scenario": scenario, "config": config, "stack": stack, "controller": controller,
        "trackers": list(onboard.managed.trackers) if stack == "managed" else []})
    return RunLog(run_dir)


def mission_transitions(run: RunLog) -> list[tuple[float, Mode, Reason]]:
    """Every mode transition of a landing run: (time [s], new mode, reason)."""
    status = run["mission_status"]
    changed = status[status["transitions"].diff().fillna(status["transitions"]) != 0]
    return [(float(r["time"]), Mode(int(r["mode"])), Reason(int(r["reason"])))
            for _, r in changed.iterrows()]
