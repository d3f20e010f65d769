"""Flies waypoints with the landing paper's linear MPC on the simulated vehicle (`alight fly`)."""
import dataclasses as dc
from pathlib import Path

import numpy as np
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import ConstantVectorSource

from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.mocap import add_mocap
from alight.diagrams.running.run_log import RunLog, RunLoggers, add_run_logging, write_run_folder
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle
from alight.diagrams.running.simulation import DisarmedAfter, evaluate, simulate
from alight.models import model_path
from alight.systems.boundary import CONTROLLER_STATUS, REFERENCE, STATE_ESTIMATE
from alight.systems.control.arm_gate import ArmGate
from alight.systems.control.linear_model import LinearModelParams
from alight.systems.control.linear_mpc import MPC_DISTURBANCE, LinearMpc, LinearMpcParams
from alight.systems.mission.scripted_reference import ScriptedReference
from alight.systems.mission.waypoints import Phase, WaypointMission, WaypointMissionParams
from alight.systems.params import load_params
from alight.systems.sensors.mocap import MocapParams


def load_linear_model(filename: str = "linear_model.yaml") -> LinearModelParams:
    return load_params(LinearModelParams, model_path(filename))


def load_linear_mpc(filename: str = "linear_mpc.yaml") -> LinearMpcParams:
    return load_params(LinearMpcParams, model_path(filename))


def parse_waypoints(text: str) -> np.ndarray:
    """'0,0,5; 10,0,5' -> array of x,y,z rows; a clear error for anything else."""
    try:
        rows = [[float(v) for v in item.split(",")] for item in text.split(";") if item.strip()]
    except ValueError:
        raise ValueError(f"waypoints must look like '0,0,5; 10,0,5', got {text!r}") from None
    if not rows or any(len(r) != 3 for r in rows) or not np.all(np.isfinite(rows)):
        raise ValueError(f"waypoints must be finite x,y,z triples separated by ';', got {text!r}")
    return np.array(rows)


@dc.dataclass
class MpcLoop:
    """Handles to the parts of a closed MPC loop built by `add_mpc_loop`."""
    vehicle: object
    mpc: LinearMpc
    state_estimate_port: object
    command_port: object
    mpc_period: float


def mocap_odometry(params: MocapParams | None = None):
    """The default odometry source for `add_mpc_loop`: mocap (true pose + noise + latency)."""
    return lambda builder, vehicle: add_mocap(builder, vehicle.GetOutputPort("ground_truth"),
                                              params or MocapParams())


def add_mpc_loop(builder, config: SimVehicleConfig, reference_port, arm_port, meshcat=None,
                 mpc_params: LinearMpcParams | None = None,
                 model: LinearModelParams | None = None, odometry=None,
                 estimate_filter=None) -> MpcLoop:
    """The simulated vehicle of `config` closed by `add_mpc_control` (arguments as there)."""
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config, meshcat))
    return add_mpc_control(builder, vehicle, reference_port, arm_port, mpc_params, model,
                           odometry, estimate_filter)


def add_mpc_control(builder, vehicle, reference_port, arm_port,
                    mpc_params: LinearMpcParams | None = None,
                    model: LinearModelParams | None = None, odometry=None,
                    estimate_filter=None) -> MpcLoop:
    """Onboard: odometry + linear MPC (+ arm gate) following `reference_port` and commanding
    `vehicle` through its boundary ports only (the simulated or the MAVLink vehicle).
    `odometry(builder, vehicle) -> STATE_ESTIMATE port` builds the state estimate (default
    `mocap_odometry()`, simulation only; VIO, the estimator bank and the MAVLink side's channel
    mocap plug in here); an odometry with `connect_command(builder, port)` is also given the
    issued command; `estimate_filter(builder, port) -> port` may alter the estimate (fault
    injection in tests)."""
    estimate = (odometry or mocap_odometry())(builder, vehicle)
    if estimate_filter is not None:
        estimate = estimate_filter(builder, estimate)
    mpc_params = mpc_params or load_linear_mpc()
    mpc = builder.AddNamedSystem("linear_mpc", LinearMpc(model or load_linear_model(), mpc_params))
    gate = builder.AddNamedSystem("arm_gate", ArmGate())
    active = builder.AddNamedSystem("mpc_active", ConstantVectorSource([1.0]))
    builder.Connect(estimate, mpc.GetInputPort("state_estimate"))
    builder.Connect(reference_port, mpc.GetInputPort("reference"))
    builder.Connect(active.get_output_port(), mpc.GetInputPort("active"))
    builder.Connect(vehicle.GetOutputPort("fc_attitude"), mpc.GetInputPort("fc_attitude"))
    builder.Connect(mpc.GetOutputPort("fc_command"), gate.GetInputPort("fc_command"))
    builder.Connect(arm_port, gate.GetInputPort("arm"))
    builder.Connect(gate.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    builder.Connect(gate.GetOutputPort("fc_command"), mpc.GetInputPort("last_command"))
    if hasattr(odometry, "connect_command"):  # e.g. the estimator bank's acceleration input
        odometry.connect_command(builder, gate.GetOutputPort("fc_command"))
    return MpcLoop(vehicle, mpc, estimate, gate.GetOutputPort("fc_command"), mpc_params.period)


def add_mpc_logging(builder, loop: MpcLoop, reference_port) -> RunLoggers:
    """The vehicle's streams plus the estimate, the reference and the controller status."""
    loggers = add_run_logging(builder, loop.vehicle, loop.command_port)
    loggers.add(builder, "state_estimate", loop.state_estimate_port, STATE_ESTIMATE)
    loggers.add(builder, "reference", reference_port, REFERENCE)
    loggers.add(builder, "controller_status", loop.mpc.GetOutputPort("controller_status"),
                CONTROLLER_STATUS, period=loop.mpc_period)
    loggers.add(builder, "mpc_disturbance", loop.mpc.GetOutputPort("disturbance"),
                MPC_DISTURBANCE, period=loop.mpc_period)
    return loggers


@dc.dataclass
class WaypointOnboard:
    """Handles to the onboard side of `alight fly` built by `add_waypoint_onboard`."""
    mission: WaypointMission
    loop: MpcLoop
    loggers: RunLoggers

    def finished(self, rest: float = 1.0):
        """Stop condition: `rest` s after the mission landed and the flight controller disarmed."""
        return DisarmedAfter(lambda context: evaluate(self.mission, "phase", context)[0]
                             == Phase.LANDED, self.loop.vehicle, rest)


def add_waypoint_onboard(builder, vehicle, waypoints: np.ndarray,
                         mission: WaypointMissionParams | None = None,
                         odometry=None) -> WaypointOnboard:
    """The onboard side of `alight fly` on `vehicle`'s boundary ports (simulated or MAVLink):
    the waypoint mission, odometry and the linear MPC (`add_mpc_control`), and their logging."""
    mission_system = builder.AddNamedSystem("mission", WaypointMission(
        waypoints, mission or WaypointMissionParams()))
    loop = add_mpc_control(builder, vehicle, mission_system.GetOutputPort("reference"),
                           mission_system.GetOutputPort("arm"), odometry=odometry)
    builder.Connect(loop.state_estimate_port, mission_system.GetInputPort("state_estimate"))
    loggers = add_mpc_logging(builder, loop, mission_system.GetOutputPort("reference"))
    return WaypointOnboard(mission_system, loop, loggers)


def fly_waypoints(config: SimVehicleConfig, waypoints: np.ndarray, seed: int = 0,
                  run_dir=None, meshcat=None, record=None, realtime_rate: float = 0.0,
                  mission: WaypointMissionParams | None = None, max_duration: float = 300.0,
                  odometry=None, log=None) -> RunLog:
    """Takes off, visits the waypoints with the linear MPC, lands and disarms (`odometry` as in
    `add_mpc_control`; `log(builder, loggers)` may add streams of its own, e.g. the VIO's)."""
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config, meshcat))
    onboard = add_waypoint_onboard(builder, vehicle, waypoints, mission, odometry)
    if log is not None:
        log(builder, onboard.loggers)
    diagram = builder.Build()
    done = onboard.finished(rest=1.0)  # 1 s after landing, so that the logs show it at rest
    simulator = simulate(diagram, mission_duration(waypoints, max_duration), seed, meshcat,
                         record, realtime_rate, stop_when=done)
    duration = simulator.get_context().get_time()
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("fly", seed)
    write_run_folder(run_dir, onboard.loggers, simulator.get_context(), {
        "command": "fly", "seed": seed, "duration": duration, "config": config,
        "waypoints": waypoints, "landed": done.holds(simulator.get_context()),
        "mpc": load_linear_mpc(), "model": load_linear_model()})
    return RunLog(run_dir)


def fly_reference(config: SimVehicleConfig, fn, duration: float, run_dir, seed: int = 0,
                  mpc_params: LinearMpcParams | None = None, estimate_filter=None,
                  odometry=None, log=None) -> RunLog:
    """Arms, then follows the scripted reference `fn(t) -> (p_W, v_W)` with the MPC for
    `duration` s (experiments, tests and benchmarks of the closed loop; `odometry` and `log` as
    in `fly_waypoints`)."""
    builder = DiagramBuilder()
    reference = builder.AddNamedSystem("reference", ScriptedReference(fn))
    loop = add_mpc_loop(builder, config, reference.GetOutputPort("reference"),
                        reference.GetOutputPort("arm"), mpc_params=mpc_params,
                        estimate_filter=estimate_filter, odometry=odometry)
    loggers = add_mpc_logging(builder, loop, reference.GetOutputPort("reference"))
    if log is not None:
        log(builder, loggers)
    simulator = simulate(builder.Build(), duration, seed)
    write_run_folder(run_dir, loggers, simulator.get_context(), {
        "command": "fly_reference", "seed": seed, "duration": duration, "config": config,
        "mpc": mpc_params or load_linear_mpc()})
    return RunLog(run_dir)


def mission_duration(waypoints: np.ndarray, max_duration: float) -> float:
    """A generous time budget: climb, legs at 2 m/s, landing, plus settling."""
    legs = np.linalg.norm(np.diff(waypoints, axis=0), axis=1).sum() if len(waypoints) > 1 else 0.0
    return min(max_duration, 15.0 + np.linalg.norm(waypoints[0]) / 2 + legs / 2.0
               + waypoints[:, 2].max() / 0.6 + 5.0 * len(waypoints))
