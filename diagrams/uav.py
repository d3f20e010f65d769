"""The managed flight stack of M Sec. 7 on any vehicle's boundary ports, and the mission API.

`add_managed_onboard` builds odometry -> control manager (its trackers and controllers from
models/control_manager.yaml, M Sec. 7.2) -> `fc_command`, driven by the UAV manager (M Sec. 7.6)
whose `command` input is exported as the diagram's `uav_command`. `Mission` is the small class a
user script or notebook drives:

    with Mission.simulated(seed=0) as mission:
        mission.takeoff(2.0)
        mission.goto([5.0, 0.0, 2.0])
        mission.trajectory(goal)               # a TrackerGoal, e.g. from trajectory generation
        mission.switch_controller("mpc")
        mission.land()
    run = mission.run_log                      # the run folder, written on exit

Each call sends one `UavCommand` and advances the simulation until the UAV manager reports it
done, refused, or the call's timeout; it returns a `RoutineResult`.
"""
import dataclasses as dc
import functools
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.control_manager import (GOAL_KINDS, ControlManagerConfig, ManagedControllers,
                                             add_control_manager, add_managed_logging,
                                             connect_managed_vehicle,
                                             load_control_manager_config)
from alight.diagrams.controllers import ControllersConfig, load_controllers_config
from alight.diagrams.fly import mocap_odometry
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import RunLog, RunLoggers, write_run_folder
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle
from alight.diagrams.running.simulation import evaluate, finish_recording, start_simulation
from alight.models import model_path
from alight.systems.mission.uav_manager import (UAV_STATUS, Routine, UavCommand, UavManager,
                                                UavManagerParams, UavRefusal)
from alight.systems.control.constraint_manager import (CONSTRAINT_STATUS, ConstraintManager,
                                                       GroupRefusal, make_constraint_manager)
from alight.systems.params import ConfigError, load_params
from alight.systems.rotations import tilt_deg
from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.trajectory_generation import make_trajectory_generator


def load_uav_manager_params(filename: str = "uav_manager.yaml") -> UavManagerParams:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    return load_params(UavManagerParams, model_path(filename))


@dc.dataclass
class ManagedOnboard:
    """Handles to the managed stack built by `add_managed_onboard`."""
    vehicle: object
    state_estimate: object           # the STATE_ESTIMATE port the stack flies on
    managed: ManagedControllers
    uav: UavManager
    loggers: RunLoggers
    groups: ConstraintManager


def add_managed_onboard(builder, vehicle, config: ControlManagerConfig | None = None,
                        controllers_config: ControllersConfig | None = None,
                        uav_params: UavManagerParams | None = None, odometry=None,
                        schedule: list[tuple[float, str]] | None = None,
                        estimate_filter=None) -> ManagedOnboard:
    """The managed stack on `vehicle`'s boundary ports (simulated or MAVLink). `odometry`
    as in diagrams/fly.py `add_mpc_control` (default mocap); `schedule` the control manager's
    timed controller switches; `estimate_filter(builder, port) -> port` may alter the estimate
    (fault injection in tests). Exports the UAV manager's command input as `uav_command`."""
    config = config or load_control_manager_config()
    controllers_config = controllers_config or load_controllers_config(config.controllers_file)
    estimate = (odometry or mocap_odometry())(builder, vehicle)
    if estimate_filter is not None:
        estimate = estimate_filter(builder, estimate)
    groups = builder.AddNamedSystem("constraint_manager", make_constraint_manager())
    uav = builder.AddNamedSystem("uav_manager", UavManager(
        uav_params or load_uav_manager_params(), config.names, config.tracker_names,
        config.safety_area if config.safety_area.enabled else None,
        groups.constraint_group_names, groups.gain_group_names))
    managed = add_control_manager(
        builder, config, controllers_config, estimate,
        switch_request=uav.GetOutputPort("switch_request"), schedule=schedule,
        goals={kind: uav.GetOutputPort(f"{kind}_goal") for kind in GOAL_KINDS
               if uav.HasOutputPort(f"{kind}_goal")},   # not its kinds (target) hold
        fc_attitude=vehicle.GetOutputPort("fc_attitude"))
    manager = managed.manager
    _connect_groups(builder, groups, estimate, uav, managed)
    builder.Connect(estimate, uav.GetInputPort("state_estimate"))
    builder.Connect(vehicle.GetOutputPort("fc_status"), uav.GetInputPort("fc_status"))
    builder.Connect(manager.GetOutputPort("manager_status"), uav.GetInputPort("manager_status"))
    landing = managed.trackers[uav.params.landing_tracker]
    if landing.HasOutputPort("landed"):
        builder.Connect(landing.GetOutputPort("landed"), uav.GetInputPort("landed"))
    connect_managed_vehicle(builder, managed, vehicle, uav.GetOutputPort("arm"),
                            uav.GetOutputPort("tracker_request"), odometry, estimate)
    builder.ExportInput(uav.GetInputPort("command"), "uav_command")
    loggers = add_managed_logging(builder, vehicle, managed, estimate,
                                  manager.GetOutputPort("reference"), config.period)
    loggers.add(builder, "uav_status", uav.GetOutputPort("uav_status"), UAV_STATUS,
                uav.params.period)
    loggers.add(builder, "constraint_status", groups.GetOutputPort("constraint_status"),
                CONSTRAINT_STATUS, uav.params.period)
    return ManagedOnboard(vehicle, estimate, managed, uav, loggers, groups)


def _connect_groups(builder, groups: ConstraintManager, estimate, uav, managed) -> None:
    """The constraint manager (M Sec. 7.5) between the UAV manager's requests and the trackers'
    `constraint_group` / controllers' `gain_group` inputs."""
    builder.Connect(estimate, groups.GetInputPort("state_estimate"))
    builder.Connect(uav.GetOutputPort("group_request"), groups.GetInputPort("request"))
    for name, tracker in managed.trackers.items():
        if tracker.HasInputPort("constraint_group"):
            if list(getattr(tracker, "group_names", [])) != groups.constraint_group_names:
                raise ConfigError(f"tracker {name!r} indexes constraint groups "
                                  f"{getattr(tracker, 'group_names', None)}, the constraint "
                                  f"manager {groups.constraint_group_names}: use one "
                                  f"constraints file")
            builder.Connect(groups.GetOutputPort("constraint_group"),
                            tracker.GetInputPort("constraint_group"))
    for controller in managed.controllers.values():
        if controller.HasInputPort("gain_group"):
            builder.Connect(groups.GetOutputPort("gain_group"),
                            controller.GetInputPort("gain_group"))


@dc.dataclass
class RoutineResult:
    """What one mission call came to: done (reached, landed, switched), the refusal reason if
    the UAV manager refused it, the simulated time it took, and whether it timed out."""
    routine: str
    done: bool
    refusal: str
    duration: float
    timed_out: bool

    def __bool__(self) -> bool:
        return self.done


class MissionError(RuntimeError):
    """A mission call that was refused or timed out, with `strict=True`."""


class Mission:
    """A user's mission against the managed stack (M Sec. 7.6 routines); see the module text.
    `strict` raises MissionError on a refused or timed-out call instead of returning it."""

    def __init__(self, diagram, onboard: ManagedOnboard, simulator: Simulator, run_dir: Path,
                 metadata: dict | None = None, strict: bool = True, step: float = 0.05):
        self.diagram, self.onboard, self.simulator = diagram, onboard, simulator
        self.run_dir, self.metadata, self.strict, self.step = Path(run_dir), metadata or {}, \
            strict, step
        self.context = simulator.get_mutable_context()
        self._port = diagram.GetInputPort("uav_command")
        self._next_id = 1
        self._port.FixValue(self.context, AbstractValue.Make(None))
        self.results: list[RoutineResult] = []
        self.run_log: RunLog | None = None
        self.generated = None      # the last trajectory of `fly_through`
        # How simulated time advances (real-time pacing on a MAVLink vehicle), and what
        # `close` does first (the final safe command and closing the link; writing a replay).
        self.advance_to = simulator.AdvanceTo
        self.closers: list = []

    @classmethod
    def simulated(cls, vehicle_config: SimVehicleConfig | None = None, seed: int = 0,
                  run_dir=None, meshcat=None, record=None, realtime_rate: float = 0.0,
                  strict: bool = True, log=None, **stack) -> "Mission":
        """The managed stack on the simulated vehicle (`stack`: arguments of
        `add_managed_onboard`, e.g. odometry, schedule, config, uav_params); `log(builder,
        loggers)` may add streams; with `meshcat` and `record` (FILE.html) the replay is written
        on `close`."""
        vehicle_config = vehicle_config or SimVehicleConfig()
        builder = DiagramBuilder()
        vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(vehicle_config, meshcat))
        onboard = add_managed_onboard(builder, vehicle, **stack)
        if log is not None:
            log(builder, onboard.loggers)
        diagram = builder.Build()
        simulator = start_simulation(diagram, seed, meshcat, record, realtime_rate)
        run_dir = Path(run_dir) if run_dir is not None else default_run_dir("mission", seed)
        mission = cls(diagram, onboard, simulator, run_dir,
                      {"seed": seed, "vehicle_config": vehicle_config}, strict)
        if meshcat is not None and record is not None:
            mission.closers.append(lambda: finish_recording(meshcat, record))
        return mission

    # --- routines (M Sec. 7.6) ---------------------------------------------------------------

    def takeoff(self, height: float | None = None, timeout: float = 30.0) -> RoutineResult:
        return self._call(Routine.TAKEOFF, timeout, height=height)

    def goto(self, position, heading: float | None = None,
             timeout: float = 60.0) -> RoutineResult:
        return self._call(Routine.GOTO, timeout, position=tuple(np.asarray(position, float)),
                          heading=heading)

    def trajectory(self, goal: TrackerGoal, timeout: float | None = None) -> RoutineResult:
        """Flies a sampled trajectory (its t_start counts from now)."""
        timeout = goal.t_start + goal.duration + 30.0 if timeout is None else timeout
        return self._call(Routine.TRAJECTORY, timeout, trajectory=goal)

    def fly_through(self, waypoints, constraints: str | None = None,
                    heading: float | None = None) -> RoutineResult:
        """Generates a trajectory (M Sec. 6) from the current estimate through `waypoints` (rows
        [x, y, z] or [x, y, z, heading] in E) under a constraint group (default: the trajectory
        generator's) and flies it; `heading` for rows without one (None: the current)."""
        estimate = self.estimate()
        here = np.append(STATE_ESTIMATE.get(estimate, "p_EB"),
                         STATE_ESTIMATE.get(estimate, "heading"))
        rows = np.atleast_2d(np.asarray(waypoints, float))
        if rows.shape[1] == 3:
            rows = np.column_stack([rows, np.full(len(rows), here[3] if heading is None
                                                  else heading)])
        self.generated = self.generator.generate(np.vstack([here, rows]), constraints)
        return self.trajectory(self.generated.goal())

    def speed(self, goal, hold: float = 0.0) -> RoutineResult:
        """Flies the speed tracker's `goal` (a SpeedGoal) for `hold` s."""
        result = self._call(Routine.SPEED, 1.0, speed=goal)
        self.wait(hold)
        return result

    def land(self, timeout: float = 60.0, rest: float = 1.0) -> RoutineResult:
        """Lands here and disarms; then waits `rest` s (the logs show the vehicle at rest)."""
        return self._landed(self._call(Routine.LAND, timeout), rest)

    def land_home(self, timeout: float = 120.0, rest: float = 1.0) -> RoutineResult:
        """Flies back over the take-off point at the current height, lands and disarms."""
        return self._landed(self._call(Routine.LAND_HOME, timeout), rest)

    def land_at(self, position, timeout: float = 120.0, rest: float = 1.0) -> RoutineResult:
        """Flies over `position` [x, y, (z ignored)] at the current height, lands, disarms."""
        return self._landed(self._call(Routine.LAND_AT, timeout,
                                       position=tuple(np.asarray(position, float))), rest)

    def _landed(self, result: RoutineResult, rest: float) -> RoutineResult:
        if result.done:
            self.wait(rest)
        return result

    def switch_controller(self, name: str) -> RoutineResult:
        return self._call(Routine.SWITCH_CONTROLLER, 1.0, name=name)

    def switch_tracker(self, name: str) -> RoutineResult:
        return self._call(Routine.SWITCH_TRACKER, 1.0, name=name)

    def set_constraints(self, name: str) -> RoutineResult:
        """A constraint group (M Sec. 7.5); refused when the active estimator does not allow
        it (models/constraint_manager.yaml)."""
        return self._group_call(Routine.SET_CONSTRAINTS, name, "constraint_refusal")

    def set_gains(self, name: str) -> RoutineResult:
        """An SE(3) gain group (M Sec. 7.5), under the same rules."""
        return self._group_call(Routine.SET_GAINS, name, "gain_refusal")

    def wait(self, seconds: float) -> None:
        self.advance_to(self.context.get_time() + seconds)

    @property
    def time(self) -> float:
        return self.context.get_time()

    def status(self) -> np.ndarray:
        """The UAV manager's UAV_STATUS now."""
        return evaluate(self.onboard.uav, "uav_status", self.context)

    def estimate(self) -> np.ndarray:
        """The STATE_ESTIMATE the stack flies on, now."""
        return self.onboard.state_estimate.Eval(
            self.onboard.state_estimate.get_system().GetMyContextFromRoot(self.context))

    @functools.cached_property
    def generator(self):
        """The trajectory generator (models/trajectory_generation.yaml) of `fly_through`."""
        return make_trajectory_generator()

    # --- plumbing ----------------------------------------------------------------------------

    def _call(self, routine: Routine, timeout: float, **values) -> RoutineResult:
        command = UavCommand(self._next_id, routine, **values)
        self._next_id += 1
        self._port.FixValue(self.context, AbstractValue.Make(command))
        start = self.time
        status = self.status()
        while self.time - start < timeout:
            self.advance_to(self.time + self.step)
            status = self.status()
            if UAV_STATUS.get(status, "command_id") == command.id and (
                    UAV_STATUS.get(status, "done") > 0.5 or UAV_STATUS.get(status, "refusal") > 0):
                break
        mine = UAV_STATUS.get(status, "command_id") == command.id
        refusal = UavRefusal(int(UAV_STATUS.get(status, "refusal"))) if mine \
            else UavRefusal.NONE
        done = mine and UAV_STATUS.get(status, "done") > 0.5
        result = RoutineResult(routine.name.lower(), bool(done),
                               refusal.name.lower() if refusal else "", self.time - start,
                               not done and refusal == UavRefusal.NONE)
        self.results.append(result)
        if self.strict and not done:
            raise MissionError(f"{result.routine}: " + (f"refused ({result.refusal})"
                                                        if result.refusal else
                                                        f"not done within {timeout:.1f} s"))
        return result

    def _group_call(self, routine: Routine, name: str, refusal_field: str) -> RoutineResult:
        strict, self.strict = self.strict, False
        try:
            result = self._call(routine, 1.0, name=name)
        finally:
            self.strict = strict
        if result.done:           # the constraint manager decides on its next tick
            self.wait(self.step)
            status = evaluate(self.onboard.groups, "constraint_status", self.context)
            refusal = GroupRefusal(int(CONSTRAINT_STATUS.get(status, refusal_field)))
            if refusal != GroupRefusal.NONE:
                result = dc.replace(result, done=False, refusal=refusal.name.lower())
                self.results[-1] = result
        if self.strict and not result.done:
            raise MissionError(f"{result.routine} {name}: refused ({result.refusal})")
        return result

    def close(self) -> RunLog:
        """Runs the closers (MAVLink: the final safe command; a replay), writes the run folder
        (logs of the whole mission) and returns it."""
        while self.closers:
            self.metadata.setdefault("closed", []).append(str(self.closers.pop(0)()))
        if self.run_log is None:
            write_run_folder(self.run_dir, self.onboard.loggers, self.context, {
                "command": "mission", "duration": self.time, **self.metadata,
                "routines": [dc.asdict(r) for r in self.results]})
            self.run_log = RunLog(self.run_dir)
        return self.run_log

    def __enter__(self) -> "Mission":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# --- `alight fly` --------------------------------------------------------------------------

def read_trajectory_file(path) -> tuple[np.ndarray, float | None]:
    """A CSV file with a header: columns x, y, z (and heading) are waypoints a trajectory is
    generated through (M Sec. 6); with a column t [s, uniformly spaced] the rows are a sampled
    trajectory flown as it is. Returns (rows [x, y, z, heading], sample period or None);
    raises ValueError naming the file and what is wrong."""
    import pandas as pd
    try:
        table = pd.read_csv(path, skipinitialspace=True)
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read the trajectory CSV: {e}") from None
    missing = [c for c in ("x", "y", "z") if c not in table.columns]
    if missing or len(table) < 1:
        raise ValueError(f"{path}: a header with columns x, y, z (heading, t optional) and at "
                         f"least one row is needed; missing {missing}")
    heading = table["heading"] if "heading" in table.columns else 0.0
    rows = np.column_stack([table["x"], table["y"], table["z"],
                            np.broadcast_to(heading, len(table))]).astype(float)
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"{path}: every x, y, z, heading must be a finite number")
    if "t" not in table.columns:
        return rows, None
    t = table["t"].to_numpy(float)
    steps = np.diff(t)
    if len(t) < 2 or not np.all(np.isfinite(t)) or steps.min() <= 0 \
            or np.ptp(steps) > 1e-6 * max(1.0, steps.mean()):
        raise ValueError(f"{path}: column t must be at least two increasing, uniformly "
                         f"spaced times [s]")
    return rows, float(steps.mean())


@dc.dataclass
class FlightPlan:
    """What `alight fly` flies: take off to `takeoff_height`, then through `waypoints` (rows
    x, y, z(, heading), a generated trajectory) or a sampled trajectory (`samples` every
    `sample_period` s), then land here."""
    waypoints: np.ndarray | None = None
    samples: np.ndarray | None = None
    sample_period: float | None = None
    takeoff_height: float = 2.0
    constraints: str | None = None      # the trajectory's constraint group (M Sec. 7.5)


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


def summarize_managed_flight(run: RunLog) -> list[str]:
    """Printed after `alight fly`: each routine's outcome, closest approach to the plan's
    points, speed, tilt, and the controllers' and trackers' tick times."""
    p = run.field("ground_truth", "p_WB").to_numpy()
    plan = run.metadata["plan"]
    points = np.asarray(plan["waypoints"] if plan["waypoints"] is not None
                        else plan["samples"], float)[:, :3]
    if plan["waypoints"] is None:
        points = points[[0, -1]]
    closest = [float(np.min(np.linalg.norm(p - w, axis=1))) for w in points]
    tilt = tilt_deg(run.field("ground_truth", "q_WB").to_numpy())
    lines = [f"{r['routine']:12s}  " + ("done" if r["done"] else
                                        f"refused ({r['refusal']})" if r["refusal"] else
                                        "timed out") + f" after {r['duration']:.1f} s"
             for r in run.metadata["routines"]]
    lines += [f"landed and disarmed   {bool(run['fc_status']['armed'].iloc[-1] < 0.5)}"
              f" after {run['ground_truth']['time'].iloc[-1]:.1f} s",
              "closest approach      " + ", ".join(f"{d:.2f} m" for d in closest),
              f"max speed / tilt      "
              f"{np.linalg.norm(run.field('ground_truth', 'v_WB'), axis=1).max():.2f} m/s / "
              f"{tilt.max():.1f} deg"]
    for stream in sorted(s for s in run.streams if s.startswith(("status_", "tracker_status_"))):
        table = run[stream]
        busy = table["compute_time"][table["valid"] > 0.5] * 1e3
        if len(busy) and busy.max() > 0:
            lines.append(f"{stream + ' tick':34s} mean {busy.mean():.2f} ms, "
                         f"max {busy.max():.2f} ms")
    return lines + [f"run folder            {run.path}"]
