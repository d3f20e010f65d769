"""The mission API: the small class a user script or notebook drives against the managed stack
(diagrams/onboard/uav.py `add_managed_onboard`, M Sec. 7), on the simulated vehicle
(`Mission.simulated`) or on a MAVLink flight controller (`mavlink_mission`):

    with Mission.simulated(seed=0) as mission:
        mission.takeoff(2.0)
        mission.goto([5.0, 0.0, 2.0])
        mission.trajectory(goal)               # a TrackerGoal, e.g. from trajectory generation
        mission.switch_controller("mpc")
        mission.land()
    run = mission.run_log                      # the run folder, written on exit

Each call sends one `UavCommand` and advances the simulation until the UAV manager reports it
done, refused, or the call's timeout; it returns a `RoutineResult`.

`mavlink_mission("udp:127.0.0.1:14540", frame_address=...)` puts the same managed stack on the
MAVLink vehicle's boundary ports, advanced against the wall clock. Between calls the diagram does
not advance, so a script should chain its calls (the flight controller keeps the last setpoint
stream only while the diagram runs: a pause longer than its offboard timeout is an offboard loss,
and PX4 fails safe). `close` (or leaving the `with` block) sends the final safe command of the
real-time runner (disarm on the ground, failsafe descent in the air), closes the link and writes
the run folder.
"""
import dataclasses as dc
import functools
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.control_manager import load_control_manager_config
from alight.diagrams.onboard.mpc_loop import mocap_odometry
from alight.diagrams.onboard.uav import ManagedOnboard, add_managed_onboard, load_uav_manager_params
from alight.diagrams.onboard.vio import load_rgbd_camera_params, load_vio_params, vio_from_start
from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import RunLog, open_run_folder, write_run_folder
from alight.diagrams.running.simulation import evaluate, finish_recording, start_simulation
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle
from alight.diagrams.world.visualization import add_flight_view
from alight.hw.channel_odometry import channel_odometry
from alight.hw.frame_channel import FrameSubscriber
from alight.hw.hil import MissionUnavailable
from alight.hw.link import MavlinkLink
from alight.hw.mavlink_vehicle import (LINK_STATUS, MavlinkVehicleParams, command_sender,
                                       load_mavlink_vehicle_params, make_mavlink_vehicle)
from alight.hw.realtime import Pacer, RealtimeMeter, WallClock
from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.managers.constraint_manager import (CONSTRAINT_STATUS, GroupRefusal,
                                                        load_constraint_manager_params)
from alight.systems.managers.uav_manager import (UAV_STATUS, Phase, Routine, UavCommand,
                                                UavRefusal)
from alight.systems.sensors.mocap import MocapParams
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.trajectory_generation import (load_trajectory_generation_params,
                                                           make_trajectory_generator)


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
        open_run_folder(self.run_dir, onboard.loggers, diagram, {"command": "mission",
                                                                  **self.metadata})

    @classmethod
    def simulated(cls, vehicle_config: SimVehicleConfig | None = None, seed: int = 0,
                  run_dir=None, meshcat=None, record=None, realtime_rate: float = 0.0,
                  strict: bool = True, log=None, estimator: str = "vio",
                  **stack) -> "Mission":
        """The managed stack on the simulated vehicle (`stack`: arguments of
        `add_managed_onboard`, e.g. odometry, schedule, config, uav_params; `managed_stack`
        fills in the ones not given); without an `odometry`, it flies on the `estimator`: vio
        (L Sec. 5.1, the default; the forward RGB-D camera of models/rgbd_camera_landing.yaml
        unless `vehicle_config` has one) or mocap (the idealization, an explicit option).
        `log(builder, loggers)` may add streams; with `meshcat` the flight view labels the UAV
        manager's phase, and with `record` (FILE.html) the replay is written on `close`."""
        vehicle_config = vehicle_config or SimVehicleConfig()
        odometry = "given" if stack.get("odometry") is not None else estimator
        if odometry != "given":
            vehicle_config, stack["odometry"] = simulated_odometry(vehicle_config, estimator)
            log = _both(log, getattr(stack["odometry"], "log", None))
        stack = managed_stack(stack)
        builder = DiagramBuilder()
        vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(vehicle_config, meshcat))
        onboard = add_managed_onboard(builder, vehicle, **stack)
        if log is not None:
            log(builder, onboard.loggers)
        if meshcat is not None:
            add_flight_view(builder, meshcat, vehicle.GetOutputPort("ground_truth"),
                            onboard.uav.GetOutputPort("uav_status"), UAV_STATUS, "phase", Phase)
        diagram = builder.Build()
        simulator = start_simulation(diagram, seed, meshcat, record, realtime_rate)
        run_dir = Path(run_dir) if run_dir is not None else default_run_dir("mission", seed)
        mission = cls(diagram, onboard, simulator, run_dir,
                      {"seed": seed, "vehicle_config": vehicle_config, "estimator": odometry},
                      strict)
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
        self.generated = self.generator.generate(np.vstack([here, rows]), constraints,
                                                 stamp=self.time)
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
        """The trajectory generator (models/trajectory_generation.yaml) of `fly_through`; its
        compute times go to the run folder's `timing` stream."""
        generator = make_trajectory_generator(load_trajectory_generation_params())
        self.onboard.loggers.timers["trajectory_generator"] = generator.compute_timer
        return generator

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
            write_run_folder(self.run_dir, self.onboard.loggers, self.simulator, {
                "command": "mission", "duration": self.time, **self.metadata,
                "routines": [dc.asdict(r) for r in self.results]})
            self.run_log = RunLog(self.run_dir)
        return self.run_log

    def __enter__(self) -> "Mission":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


# The shipped parameters (models/) of the managed stack's parts a caller does not give.
STACK_FILES = {"config": load_control_manager_config, "uav_params": load_uav_manager_params,
               "constraint_params": load_constraint_manager_params}


def simulated_odometry(config: SimVehicleConfig, estimator: str):
    """(the vehicle config, the odometry hook) of `Mission.simulated`'s `estimator`."""
    if estimator == "mocap":
        return config, mocap_odometry(MocapParams())
    if estimator != "vio":
        raise ValueError(f"Mission.simulated: estimator {estimator!r} is not 'vio' or 'mocap'")
    if config.rgbd_camera.source == "none":
        config = dc.replace(config, rgbd_camera=load_rgbd_camera_params("rgbd_camera_landing.yaml"))
    return config, vio_from_start(load_vio_params(), config.initial_position)


def _both(first, second):
    """One `log(builder, loggers)` calling both (either may be None)."""
    if first is None or second is None:
        return first or second
    return lambda builder, loggers: (first(builder, loggers), second(builder, loggers))


def managed_stack(stack: dict, **defaults) -> dict:
    """`stack` (arguments of `add_managed_onboard`) with each one it does not give (or gives as
    None) made here, once: by `defaults` (name: function making it), else from its models/
    file (STACK_FILES)."""
    make = {**STACK_FILES, **defaults}
    return {**stack, **{key: made() for key, made in make.items() if stack.get(key) is None}}


# --- `alight fly` --------------------------------------------------------------------------


def mavlink_mission(connect: str, frame_address: str | None = None,
                    params: MavlinkVehicleParams | None = None, wait: float = 10.0,
                    realtime_rate: float = 1.0, follow_autopilot_clock: bool = False,
                    seed: int = 0, run_dir=None, strict: bool = True, tick: float = 0.01,
                    **stack) -> Mission:
    """Connects (as `alight hil`: heartbeat, TIMESYNC, message rates), builds the managed stack on
    the MAVLink vehicle and returns the Mission. The state estimate is `stack["odometry"]`, or
    the simulated autopilot's mocap on the frame channel at `frame_address`.
    `follow_autopilot_clock` (simulated autopilots only) also paces each `tick` on the autopilot's
    clock, as `alight hil --follow-autopilot-clock`."""
    params = params or load_mavlink_vehicle_params()
    clock = WallClock(realtime_rate)
    link = MavlinkLink.open(connect, params.link, clock)
    frames = FrameSubscriber(frame_address) if frame_address else None
    try:
        if "odometry" not in stack:
            if frames is None:
                raise MissionUnavailable("the mission API needs a position estimate: pass "
                                         "odometry=..., or frame_address for the simulated "
                                         "autopilot's mocap")
            stack["odometry"] = channel_odometry(frames, link, params.channel_odometry)
        stack = managed_stack(stack)
        builder = DiagramBuilder()
        vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(link, params, frames))
        onboard = add_managed_onboard(builder, vehicle, **stack)
        onboard.loggers.add(builder, "link_status", vehicle.GetOutputPort("link_status"),
                            LINK_STATUS)
        diagram = builder.Build()
        sender = command_sender(diagram.GetSubsystemByName("vehicle"))
        link.wait_for_autopilot(wait)
        rates = link.request_message_rates()
        if follow_autopilot_clock:
            link.follow_autopilot_clock()
        clock.restart()   # onboard time starts with the simulation
        simulator = start_simulation(diagram, seed, realtime_rate=clock.rate)
    except BaseException:
        _close(link, frames)
        raise
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir("mission-mavlink", seed)
    mission = Mission(diagram, onboard, simulator, run_dir, {
        "seed": seed, "connect": connect, "vehicle": params, "message_rates": rates,
        "realtime_rate": realtime_rate, "follow_autopilot_clock": follow_autopilot_clock},
        strict)
    pacer = Pacer(link.autopilot_time, stall=1.0) if follow_autopilot_clock else None
    meter = RealtimeMeter(clock, tolerance=0.02, warn_period=5.0,
                          note=" (paced by the autopilot's clock)" if pacer else "")
    mission.advance_to = lambda t: _advance(simulator, t, tick, pacer, meter)

    def safe_stop() -> str:
        answer = "FAILED"
        try:
            sender.wait_idle()
            answer = link.safe_stop()
            return answer
        except Exception as e:   # recorded as run_realtime records it, then raised
            answer = f"FAILED: {e}"
            raise
        finally:
            _close(link, frames)
            # How the onboard side kept real time (run folder `metadata.json` "realtime"):
            # a tick that ends behind the wall clock ran late (a loaded companion computer).
            mission.metadata["realtime"] = dc.asdict(meter.report(mission.time, safe_stop=answer))
    mission.closers.append(safe_stop)
    return mission


def _advance(simulator: Simulator, t_end: float, tick: float, pacer: Pacer | None,
             meter: RealtimeMeter) -> None:
    """AdvanceTo in `tick` steps (the real-time rate paces them), each also waiting for the
    autopilot's clock when `pacer` is given; `meter` counts how late each tick ends."""
    t = simulator.get_context().get_time()
    while t < t_end - 1e-9:
        t = min(t + tick, t_end)
        if pacer is not None:
            meter.paced_wait += pacer.wait_until(t)
        simulator.AdvanceTo(t)
        meter.tick(t)


def _close(link: MavlinkLink, frames: FrameSubscriber | None) -> None:
    link.close()
    if frames is not None:
        frames.close()
