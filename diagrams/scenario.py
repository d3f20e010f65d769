"""Landing scenarios (L Sec. 6-7): the scenario files (`load_scenario`), the odometry a scenario's
`estimator` names (`landing_odometry`) and the simulated vehicle in the scenario's world
(`vehicle_config`: the moving target, the down camera, wind). The onboard landing stack that flies a
scenario is diagrams/onboard/landing.py, its runner diagrams/running/landing.py `run_landing`.
"""
import dataclasses as dc

import numpy as np

from alight.diagrams.onboard.estimation import scenario_odometry
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, load_sim_vehicle_config
from alight.models import model_path
from alight.systems.mission.landing import LandingMissionParams
from alight.systems.params import bounded, choice, load_params, validate
from alight.systems.plant.wind import WindParams
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
    # filters by name (diagrams/onboard/estimation.py)
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
    from alight.diagrams.onboard.vio import VioRun, load_vio_params
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
        from alight.diagrams.onboard.vio import load_rgbd_camera_params
        config = dc.replace(config, rgbd_camera=load_rgbd_camera_params(scenario.rgbd_camera))
    validate(config, f"scenario {scenario.name}")
    return config
