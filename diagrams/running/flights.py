"""The runners of the simulated flights: each builds the simulated vehicle with an onboard stack,
flies it and writes the run folder (`alight hover`, `alight fly`, `alight vio-eval`, and the
experiments, tests and benchmarks of the MPC loop, the estimator bank, the control manager and the
landoff tracker)."""
import dataclasses as dc
from pathlib import Path

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.analysis.flight import HoverSummary, summarize_hover
from alight.diagrams.onboard.control_manager import (ControlManagerConfig, add_control_manager,
                                                     add_managed_logging,
                                                     load_control_manager_config)
from alight.diagrams.onboard.controllers import ControllersConfig, load_controllers_config
from alight.diagrams.onboard.estimation import BankOdometry
from alight.diagrams.onboard.landoff import LANDED, add_landoff_loop
from alight.diagrams.onboard.mpc_loop import (MpcLoop, add_mpc_control, add_mpc_logging,
                                              load_failsafe_switch, load_linear_model,
                                              load_linear_mpc, mocap_odometry)
from alight.diagrams.onboard.track import add_faulty_mocap
from alight.diagrams.onboard.uav import FlightPlan, load_uav_manager_params
from alight.diagrams.onboard.vio import VioRun, load_rgbd_camera_params, load_vio_params
from alight.diagrams.running.mission import Mission
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import (RunLog, add_run_logging, open_run_folder,
                                             write_run_folder)
from alight.diagrams.running.runner import run
from alight.diagrams.running.simulation import simulate
from alight.diagrams.scenario import (Onboard, Scenario, Scoring, SimulatorSettings,
                                      WaypointPlan)
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle
from alight.systems.boundary import CONTROLLER_STATUS, REFERENCE, STATE_ESTIMATE, TRACKER_STATUS
from alight.systems.control import analytic_reference as ref
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import LinearMpcParams
from alight.systems.control.scripted_pilot import PilotProfile
from alight.systems.estimation.bank import BankParams
from alight.systems.managers.failsafe_switch import FailsafeSwitchParams
from alight.systems.mission.scripted_reference import ScriptedReference
from alight.systems.mission.waypoints import WaypointMissionParams
from alight.systems.sensors.estimate_faults import EstimateFaultParams
from alight.systems.sensors.mocap import MocapParams
from alight.systems.sensors.rgbd_camera import RgbdCameraParams
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.landoff_tracker import (LandoffTrackerParams,
                                                     load_landoff_tracker_params)
from alight.systems.vio.estimator import VioParams


def add_mpc_loop(builder, config: SimVehicleConfig, reference_port, arm_port,
                 mpc_params: LinearMpcParams, model: LinearModelParams, odometry,
                 fallback: FailsafeSwitchParams, meshcat=None, estimate_filter=None,
                 command_filter=None) -> MpcLoop:
    """The simulated vehicle of `config` closed by `add_mpc_control` (arguments as there)."""
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config, meshcat))
    return add_mpc_control(builder, vehicle, reference_port, arm_port, mpc_params, model,
                           odometry, fallback, estimate_filter, command_filter)


def vehicle_scenario(config: SimVehicleConfig, stack: str, mission, seed: int = 0,
                     max_duration: float = 300.0, settle_time: float = 1.0,
                     vio_camera: RgbdCameraParams | None = None) -> Scenario:
    """A scenario of the simulated vehicle `config` flying `stack` on mocap (tests, benches).
    `vio_camera`: the forward RGB-D camera the vehicle carries for the VIO (`vehicle_config`
    puts `onboard.vio_camera` on it; default the scenario's)."""
    onboard = Onboard(stack=stack, linear_mpc=load_linear_mpc(), linear_model=load_linear_model())
    if vio_camera is not None:
        onboard = dc.replace(onboard, vio_camera=vio_camera)
    return Scenario(name=stack, random_seed=seed, vehicle=config, onboard=onboard,
                    mission=mission, scoring=Scoring(settle_time=settle_time),
                    simulator=SimulatorSettings(max_duration=max_duration))


def fly_waypoints(config: SimVehicleConfig, waypoints: np.ndarray, seed: int = 0,
                  run_dir=None, meshcat=None, record=None, realtime_rate: float = 0.0,
                  mission: WaypointMissionParams | None = None, max_duration: float = 300.0,
                  odometry=None, vio_camera: RgbdCameraParams | None = None) -> RunLog:
    """Takes off, visits the waypoints with the linear MPC, lands and disarms, stopping 1 s
    after (so that the logs show it at rest): the `waypoints` stack through the runner
    (`odometry` as in `add_mpc_control`, default mocap; its own streams are logged;
    `vio_camera` as in `vehicle_scenario`)."""
    plan = WaypointPlan(np.asarray(waypoints, float).tolist(), mission or WaypointMissionParams())
    return run(vehicle_scenario(config, "waypoints", plan, seed, max_duration,
                                vio_camera=vio_camera), run_dir, meshcat,
               record, realtime_rate, odometry, command="fly")


def fly_reference(config: SimVehicleConfig, fn, duration: float, run_dir, seed: int = 0,
                  mpc_params: LinearMpcParams | None = None, estimate_filter=None,
                  odometry=None, log=None, model: LinearModelParams | None = None,
                  fallback: FailsafeSwitchParams | None = None,
                  command_filter=None) -> RunLog:
    """Arms, then follows the scripted reference `fn(t) -> (p_W, v_W)` with the MPC for
    `duration` s (experiments, tests and benchmarks of the closed loop; `odometry` and `log` as
    in `fly_waypoints`, the filters as in `add_mpc_control`; the MPC's `mpc_params` and `model`
    and its `fallback` to the failsafe default to models/linear_mpc.yaml,
    models/linear_model.yaml and models/failsafe_switch.yaml)."""
    mpc_params = load_linear_mpc() if mpc_params is None else mpc_params
    model = load_linear_model() if model is None else model
    fallback = load_failsafe_switch() if fallback is None else fallback
    odometry = mocap_odometry(MocapParams()) if odometry is None else odometry
    builder = DiagramBuilder()
    reference = builder.AddNamedSystem("reference", ScriptedReference(fn))
    loop = add_mpc_loop(builder, config, reference.GetOutputPort("reference"),
                        reference.GetOutputPort("arm"), mpc_params, model, odometry, fallback,
                        estimate_filter=estimate_filter, command_filter=command_filter)
    loggers = add_mpc_logging(builder, loop, reference.GetOutputPort("reference"))
    if log is not None:
        log(builder, loggers)
    diagram = builder.Build()
    metadata = {"command": "fly_reference", "seed": seed, "duration": duration,
                "config": config, "mpc": mpc_params}
    open_run_folder(run_dir, loggers, diagram, metadata)
    simulator = simulate(diagram, duration, seed)
    write_run_folder(run_dir, loggers, simulator, metadata)
    return RunLog(run_dir)


def fly_bank(config, params: BankParams, duration: float, run_dir, seed: int = 0,
             hold=(0.0, 0.0, 3.0), request: str | None = None, sensors: dict | None = None):
    """Takes off to `hold` (in the anchor frame) and holds it for `duration` s with the linear
    MPC on the bank's estimate (tests, bench, notebook). Returns the RunLog, with the streams
    `bank_estimate` and `bank_status` besides the MPC loop's."""
    model = load_linear_model()
    odometry = BankOdometry(params, model, request=request, sensors=sensors)
    p_hold = np.asarray(hold, float)
    return fly_reference(config, lambda t: (p_hold, np.zeros(3)), duration, run_dir, seed,
                         odometry=odometry, log=odometry.log, model=model)


def fly_vio(config, waypoints, seed: int = 0, run_dir=None, closed_loop: bool = True,
            camera: RgbdCameraParams | None = None, params: VioParams | None = None,
            blackouts=None):
    """Flies `waypoints` (`fly_waypoints`) with the VIO (`params`, default models/vio.yaml) on
    the forward camera (`camera`, default models/rgbd_camera.yaml) in the loop, or beside mocap
    (`closed_loop=False`); a rendered camera sees the scene under the light of `seed`."""
    config = dc.replace(config, rgbd_camera=camera or load_rgbd_camera_params(),
                        lighting=dc.replace(config.lighting, seed=seed))
    params = load_vio_params() if params is None else params
    if config.rgbd_camera.source == "none":
        raise ValueError("the VIO needs the forward RGB-D camera: rgbd_camera.source is none")
    return fly_waypoints(config, waypoints, seed=seed, run_dir=run_dir,
                         odometry=VioRun(params, closed_loop, blackouts, MocapParams()),
                         vio_camera=config.rgbd_camera)


def fly_profile(config: SimVehicleConfig, profile: PilotProfile, seed: int = 0,
                run_dir: str | Path | None = None, meshcat=None, record=None,
                realtime_rate: float = 0.0, duration: float | None = None,
                pilot_stops_at: float | None = None, command: str = "hover") -> RunLog:
    """Flies `profile` with the scripted pilot (the `hover` stack) on the simulated vehicle for
    `duration` (default the profile's); returns the run log. `pilot_stops_at` freezes the
    pilot's output from that time (a companion computer that dies)."""
    if pilot_stops_at is not None:
        profile = dc.replace(profile, stop_at=pilot_stops_at)
    scenario = vehicle_scenario(config, "hover", profile, seed, max_duration=3600.0)
    return run(scenario, run_dir, meshcat, record, realtime_rate, command=command,
               duration=duration)


def run_hover(config: SimVehicleConfig, profile: PilotProfile, seed: int = 0,
              run_dir: str | Path | None = None, meshcat=None, record=None,
              realtime_rate: float = 0.0) -> HoverSummary:
    """The hover demo (`alight hover`): flies the profile and summarizes the flight."""
    run = fly_profile(config, profile, seed, run_dir, meshcat, record, realtime_rate)
    return summarize_hover(run, profile)


def fly_plan(plan: FlightPlan, vehicle_config: SimVehicleConfig | None = None, seed: int = 0,
             run_dir=None, meshcat=None, record=None, realtime_rate: float = 0.0,
             controller: str | None = None, tracker: str | None = None, **stack) -> RunLog:
    """`alight fly` on the managed stack: take-off, the plan, landing, through the mission API.
    `controller` / `tracker` replace the UAV manager's flying pair; `stack` as
    `Mission.simulated` (odometry, schedule, log, ...)."""
    params = load_uav_manager_params()
    params = dc.replace(params, flying_controller=controller or params.flying_controller,
                        flying_tracker=tracker or params.flying_tracker)
    mission = Mission.simulated(vehicle_config, seed, run_dir, meshcat, record, realtime_rate,
                                strict=False, uav_params=params, **stack)
    with mission:
        if mission.takeoff(plan.takeoff_height):
            if plan.samples is not None:
                mission.trajectory(TrackerGoal(plan.samples, 0.0, plan.sample_period))
            else:
                mission.fly_through(plan.waypoints, plan.constraints)
            mission.land()
        mission.metadata.update({"command": "fly", "plan": plan, "controller":
                                 params.flying_controller, "tracker": params.flying_tracker})
    return mission.run_log


def fly_managed(vehicle_config: SimVehicleConfig, trajectory: ref.Trajectory, seed: int = 0,
                run_dir=None, config: ControlManagerConfig | None = None,
                controllers_config: ControllersConfig | None = None,
                faults: EstimateFaultParams | None = None,
                schedule: list[tuple[float, str]] | None = None, duration: float | None = None,
                switch_request_source=None, meshcat=None, realtime_rate: float = 0.0) -> RunLog:
    """Flies the analytic `trajectory` (the goal) under the control manager and writes a run
    folder. `switch_request_source(builder)` may return a port for `switch_request`."""
    config = config or load_control_manager_config()
    controllers_config = controllers_config or config.controller_params
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(vehicle_config, meshcat))
    _, estimate = add_faulty_mocap(builder, vehicle, config.period, faults, MocapParams())
    goal = builder.AddNamedSystem("goal", ref.AnalyticReference(trajectory, config.period))
    request = switch_request_source(builder) if switch_request_source else None
    managed = add_control_manager(builder, config, controllers_config, estimate,
                                  goal.GetOutputPort("reference"), request, schedule,
                                  fc_attitude=vehicle.GetOutputPort("fc_attitude"))
    builder.Connect(managed.manager.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    loggers = add_managed_logging(builder, vehicle, managed, estimate,
                                  goal.GetOutputPort("reference"), config.period)
    diagram = builder.Build()
    duration = trajectory.duration if duration is None else duration
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("managed", seed)
    metadata = {"command": "managed", "seed": seed, "duration": duration,
                "marks": trajectory.marks, "controllers": config.names,
                "schedule": schedule or [], "faults": faults, "control_manager": config,
                "vehicle_config": vehicle_config, "controllers_config": controllers_config}
    open_run_folder(run_dir, loggers, diagram, metadata)
    simulator = simulate(diagram, duration, seed, meshcat, realtime_rate=realtime_rate)
    write_run_folder(run_dir, loggers, simulator, metadata)
    return RunLog(run_dir)


def fly_landoff(vehicle_config: SimVehicleConfig, schedule: list[tuple[float, object]],
                duration: float, seed: int = 0, run_dir=None,
                tracker_params: LandoffTrackerParams | None = None, controller: str = "se3",
                controllers_config: ControllersConfig | None = None, meshcat=None) -> RunLog:
    """Flies the goal `schedule` ([(time, LandoffGoal)]) for `duration` s; the run folder has the
    vehicle's streams, `state_estimate`, `reference`, `tracker_status`, `landed` and
    `controller_status`."""
    controllers_config = controllers_config or load_controllers_config()
    tracker_params = tracker_params or load_landoff_tracker_params()
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(vehicle_config, meshcat))
    estimate, tracker, feedback, command = add_landoff_loop(
        builder, vehicle, controllers_config, tracker_params, schedule, MocapParams(), controller)
    period = tracker_params.period
    loggers = add_run_logging(builder, vehicle, command, period)
    loggers.add(builder, "state_estimate", estimate, STATE_ESTIMATE, period)
    loggers.add(builder, "reference", tracker.GetOutputPort("reference"), REFERENCE, period)
    loggers.add(builder, "tracker_status", tracker.GetOutputPort("tracker_status"),
                TRACKER_STATUS, period)
    loggers.add(builder, "landed", tracker.GetOutputPort("landed"), LANDED, period)
    loggers.add(builder, "controller_status", feedback.GetOutputPort("controller_status"),
                CONTROLLER_STATUS, period)
    diagram = builder.Build()
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("landoff", seed)
    metadata = {"command": "landoff", "seed": seed, "duration": duration,
                "controller": controller, "schedule": [[t, repr(goal)] for t, goal in schedule],
                "tracker": tracker_params, "vehicle_config": vehicle_config,
                "controllers_config": controllers_config}
    open_run_folder(run_dir, loggers, diagram, metadata)
    simulator = simulate(diagram, duration, seed, meshcat)
    write_run_folder(run_dir, loggers, simulator, metadata)
    return RunLog(run_dir)
