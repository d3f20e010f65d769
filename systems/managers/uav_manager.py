"""The UAV manager, M Sec. 7.6: take-off, land here, land home, land at a point, go to, fly a
trajectory, fly at a speed; each routine with the tracker and controller it uses.

It drives the control manager (M Sec. 7.2) through its request ports: arming, tracker and
controller switch requests, and one goal per kind of tracker goal (a point or trajectory
`TrackerGoal` for the flying tracker, a `LandoffGoal` for the take-off/landing tracker, a
`SpeedGoal` for the speed tracker). Commands arrive as `UavCommand` values with increasing ids on
the abstract `command` input (the mission API, alight.diagrams.running.mission, sets it); each is
either started or refused with a reason, and `uav_status` says when it is done. A command waits
for the first valid state estimate.

Routines (M Sec. 7.6): `takeoff` arms and climbs with the take-off tracker and controller, then
activates the flying tracker and controller holding the reached point; `goto` and `trajectory`
feed the flying tracker (done within `position_tolerance` and `speed_tolerance` of the last
point); `speed` activates the speed tracker; `land` lands here with the landing tracker and
controller and disarms once it reports touchdown (or the control manager has landed); `land_home`
flies to the take-off point at the current height first, `land_at` to a given point.
`switch_controller` / `switch_tracker` forward a user's switch request (the control manager
refuses what it cannot do). Routines that move the vehicle are refused while the control manager
is not in NORMAL mode (emergency landing, failsafe), and goals outside the safety area are refused
before they reach a tracker.
"""
import dataclasses as dc
import enum

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_STATUS, STATE_ESTIMATE, VectorLayout
from alight.systems.estimation.frames import reexpress_point
from alight.systems.managers.control_manager import MANAGER_STATUS, ManagerMode, SafetyArea
from alight.systems.params import bounded
from alight.systems.rotations import rotation_matrix
from alight.systems.state_copy import FieldwiseCopy
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.landoff_tracker import LandoffGoal
from alight.systems.tracking.speed_tracker import SpeedGoal


class Routine(enum.IntEnum):
    NONE = 0
    TAKEOFF = 1
    GOTO = 2
    TRAJECTORY = 3
    SPEED = 4
    LAND = 5
    LAND_HOME = 6
    LAND_AT = 7
    SWITCH_CONTROLLER = 8
    SWITCH_TRACKER = 9
    SET_CONSTRAINTS = 10     # a constraint group (M Sec. 7.5), through the constraint manager
    SET_GAINS = 11           # an SE(3) gain group (M Sec. 7.5)


class Phase(enum.IntEnum):
    IDLE = 0         # disarmed on the ground
    TAKING_OFF = 1
    FLYING = 2
    LANDING = 3
    EMERGENCY = 4    # the control manager left NORMAL mode: routines are refused


class UavRefusal(enum.IntEnum):
    NONE = 0
    NOT_IDLE = 1          # take-off while armed
    NOT_FLYING = 2        # a flight routine before take-off or during landing
    EMERGENCY = 3         # the control manager is in an emergency landing or the failsafe
    OUTSIDE_AREA = 4      # a goal outside the safety area
    UNKNOWN_NAME = 5      # a controller or tracker that is not loaded
    BAD_COMMAND = 6       # a command without the values its routine needs
    ARMING_DENIED = 7     # the flight controller did not arm within arm_timeout


@dc.dataclass(frozen=True)
class UavCommand:
    """One command for the UAV manager. `id` must grow with every new command. `position`
    [x, y, z] in E for goto / land_at, `heading` [rad] (None: keep), `height` above the take-off
    point for takeoff [m], `trajectory` a TrackerGoal whose t_start counts from the command's
    start, `speed` a SpeedGoal, `name` a controller, tracker, constraint or gain group for the
    switch routines."""
    id: int
    routine: Routine
    position: tuple | None = None
    heading: float | None = None
    height: float | None = None
    trajectory: TrackerGoal | None = None
    speed: SpeedGoal | None = None
    name: str = ""


# `uav_status`: Phase; the Routine and id of the last command; done (1 when that command has
# finished: reached, landed, switched); refusal (UavRefusal of the last command, 0 if started);
# home position (the take-off point) in E.
UAV_STATUS = VectorLayout("uav_status", [
    ("phase", 1), ("routine", 1), ("command_id", 1), ("done", 1), ("refusal", 1), ("home", 3)])


@dc.dataclass
class UavManagerParams:
    """Which tracker and controller each routine uses (names of the control manager's lists)
    and when a routine counts as done."""
    period: float = bounded(0.05, 0.001, 1.0, "s")               # 20 Hz, the mission rate
    takeoff_height: float = bounded(2.0, 0.3, 100.0, "m")        # default of `takeoff`
    takeoff_tracker: str = "landoff"
    takeoff_controller: str = "mpc"
    flying_tracker: str = "mpc_tracker"
    flying_controller: str = "se3"
    speed_tracker: str = "speed"
    landing_tracker: str = "landoff"
    landing_controller: str = "mpc"
    arm_timeout: float = bounded(5.0, 0.1, 60.0, "s")  # take-off: the flight controller arms
    position_tolerance: float = bounded(0.3, 0.01, 10.0, "m")
    speed_tolerance: float = bounded(0.3, 0.01, 10.0, "m/s")


@dc.dataclass
class UavMemory(FieldwiseCopy):
    """The manager's abstract state (copied field by field, `FieldwiseCopy`)."""
    phase: Phase = Phase.IDLE
    routine: Routine = Routine.NONE
    command_id: int = 0
    done: bool = True
    refusal: UavRefusal = UavRefusal.NONE
    home: np.ndarray = dc.field(default_factory=lambda: np.zeros(3))
    target: np.ndarray | None = None     # [x, y, z, heading] the routine waits for
    start: float = 0.0
    then_land: bool = False              # land_home / land_at: land once there
    arm: float = 0.0
    thrust_enable: float = 0.0          # thrust once the flight controller reports armed
    switch_id: int = 0
    switch_index: int = 0
    tracker_id: int = 0
    tracker_index: int = 0
    group_request: np.ndarray = dc.field(default_factory=lambda: np.zeros(4))
    trajectory: TrackerGoal | None = None
    landoff: LandoffGoal | None = None
    speed: SpeedGoal | None = None
    frame_counter: float = np.nan


def reexpress_rows(rows, estimate: np.ndarray) -> np.ndarray:
    """Rows [x, y, z(, heading)] of the old estimator frame in the new one, by the last switch's
    X_OldNew that `estimate` reports (M Sec. 3.5)."""
    return reexpress_point(np.array(rows, float, ndmin=2),
                           rotation_matrix(STATE_ESTIMATE.get(estimate, "q_OldNew")),
                           STATE_ESTIMATE.get(estimate, "p_OldNew"))


class UavManager(LeafSystem):
    """Inputs  `state_estimate` STATE_ESTIMATE; `command` (abstract UavCommand or None);
            `manager_status` MANAGER_STATUS; `landed` (1, optional: the landing tracker's
            touchdown, 1 once touched down); `fc_status` FC_STATUS (optional: take-off waits
            for the flight controller to report armed before the thrust is enabled)
    Outputs `arm` (2) [arm, thrust enable] for the control manager; `switch_request` and
            `tracker_request` (2) [id, index]; `trajectory_goal` (TrackerGoal or None),
            `landoff_goal` (LandoffGoal or None), `speed_goal` (SpeedGoal or None);
            `group_request` (4) for the constraint
            manager (M Sec. 7.5: [id, constraint group, id, gain group]); `uav_status` UAV_STATUS
    `constraint_groups` and `gain_groups` name the constraint manager's group indices.
    """

    def __init__(self, params: UavManagerParams, controllers: list[str], trackers: list[str],
                 safety_area: SafetyArea | None = None, constraint_groups: list[str] = (),
                 gain_groups: list[str] = ()):
        super().__init__()
        self.params, self.controllers, self.trackers = params, list(controllers), list(trackers)
        self.constraint_groups, self.gain_groups = list(constraint_groups), list(gain_groups)
        for key in ("takeoff_tracker", "flying_tracker", "landing_tracker"):
            if getattr(params, key) not in self.trackers:
                raise ValueError(f"uav manager: {key} {getattr(params, key)!r} is not one of the "
                                 f"loaded trackers {self.trackers}")
        for key in ("takeoff_controller", "flying_controller", "landing_controller"):
            if getattr(params, key) not in self.controllers:
                raise ValueError(f"uav manager: {key} {getattr(params, key)!r} is not one of "
                                 f"the loaded controllers {self.controllers}")
        self._area = safety_area
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._command = self.DeclareAbstractInputPort("command", AbstractValue.Make(None))
        self._manager = self.DeclareVectorInputPort("manager_status", MANAGER_STATUS.size)
        self._landed = self.DeclareVectorInputPort("landed", 1)
        self._fc_status = self.DeclareVectorInputPort("fc_status", FC_STATUS.size)
        self._memory = self.DeclareAbstractState(AbstractValue.Make(UavMemory()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, 0.0, self._update)
        state = {self.all_state_ticket()}
        self.DeclareVectorOutputPort("arm", 2, lambda c, o: o.SetFromVector(
            [self._read(c).arm, self._read(c).thrust_enable]), state)
        self.DeclareVectorOutputPort("switch_request", 2, lambda c, o: o.SetFromVector(
            [self._read(c).switch_id, self._read(c).switch_index]), state)
        self.DeclareVectorOutputPort("tracker_request", 2, lambda c, o: o.SetFromVector(
            [self._read(c).tracker_id, self._read(c).tracker_index]), state)
        self.DeclareVectorOutputPort("group_request", 4, lambda c, o: o.SetFromVector(
            self._read(c).group_request), state)
        self.DeclareAbstractOutputPort(
            "trajectory_goal", lambda: AbstractValue.Make(None), self._calc_trajectory_goal,
            {self.all_state_ticket(), self._estimate.ticket()})
        for name in ("landoff", "speed"):     # relative to the vehicle / re-expressed by the
            self.DeclareAbstractOutputPort(   # speed tracker itself
                f"{name}_goal", lambda: AbstractValue.Make(None),
                lambda c, o, name=name: o.set_value(getattr(self._read(c), name)), state)
        self.DeclareVectorOutputPort("uav_status", UAV_STATUS.size, self._calc_status, state)

    def _read(self, context) -> UavMemory:
        return context.get_abstract_state(int(self._memory)).get_value()

    def _calc_trajectory_goal(self, context, output):
        """The flying tracker's goal, in the estimate's frame even at the tick of a frame switch
        (the MPC tracker re-plans on it at that tick, before this manager's next update)."""
        memory = self._read(context)
        goal = memory.trajectory
        estimate = self._estimate.Eval(context)
        counter = STATE_ESTIMATE.get(estimate, "frame_counter")
        if goal is not None and np.isfinite(memory.frame_counter) and np.isfinite(counter) \
                and counter != memory.frame_counter:
            goal = dc.replace(goal, samples=reexpress_rows(goal.samples, estimate))
        output.set_value(goal)

    def _calc_status(self, context, output):
        m = self._read(context)
        output.SetFromVector(UAV_STATUS.pack(phase=m.phase, routine=m.routine,
                                             command_id=m.command_id, done=float(m.done),
                                             refusal=m.refusal, home=m.home))

    # --- the state machine --------------------------------------------------------------------

    def _update(self, context, state):
        memory = state.get_mutable_abstract_state(int(self._memory)).get_value()
        now = context.get_time()
        estimate = self._estimate.Eval(context)
        valid = STATE_ESTIMATE.get(estimate, "valid") > 0.5 and np.all(np.isfinite(estimate))
        mode = MANAGER_STATUS.get(self._manager.Eval(context), "mode")
        self._follow_manager(memory, mode)
        if valid:
            self._follow_frame(memory, estimate)
        command = self._command.Eval(context)
        if command is not None and command.id > memory.command_id and valid:
            self._start(memory, command, estimate, now)   # (waits for a valid estimate)
        if valid:
            self._progress(context, memory, estimate, now)

    @staticmethod
    def _follow_frame(memory: UavMemory, estimate: np.ndarray) -> None:
        """Goals, the routine's target and home in the new estimator frame (M Sec. 3.5, 7.2:
        references are transformed into the current control frame)."""
        counter = STATE_ESTIMATE.get(estimate, "frame_counter")
        previous, memory.frame_counter = memory.frame_counter, counter
        if not np.isfinite(previous) or counter == previous:
            return
        memory.home = reexpress_rows(memory.home, estimate)[0]
        if memory.target is not None:
            memory.target = reexpress_rows(memory.target, estimate)[0]
        if memory.trajectory is not None:
            memory.trajectory = dc.replace(memory.trajectory, samples=reexpress_rows(
                memory.trajectory.samples, estimate))

    def _follow_manager(self, memory: UavMemory, mode: float) -> None:
        """The control manager's emergency landing or failsafe ends the running routine
        (refusal EMERGENCY, not done); its touchdown disarms."""
        if mode in (ManagerMode.ELAND, ManagerMode.FAILSAFE, ManagerMode.LANDED) \
                and memory.phase != Phase.IDLE:
            if not memory.done:
                memory.refusal = UavRefusal.EMERGENCY
            memory.phase = Phase.EMERGENCY
        if mode == ManagerMode.LANDED and memory.phase == Phase.EMERGENCY:
            self._disarm(memory, done=memory.done)

    def _refuse(self, memory: UavMemory, command: UavCommand, reason: UavRefusal) -> None:
        memory.command_id, memory.routine = command.id, command.routine
        memory.refusal, memory.done = reason, False

    def _start(self, memory: UavMemory, command: UavCommand, estimate, now: float) -> None:
        R = Routine
        anytime = tuple(Phase)
        allowed = {R.TAKEOFF: (Phase.IDLE,), R.SWITCH_CONTROLLER: anytime,
                   R.SWITCH_TRACKER: anytime, R.SET_CONSTRAINTS: anytime,
                   R.SET_GAINS: anytime}.get(command.routine, (Phase.FLYING,))
        if memory.phase not in allowed:
            reason = UavRefusal.EMERGENCY if memory.phase == Phase.EMERGENCY else \
                UavRefusal.NOT_IDLE if command.routine == R.TAKEOFF else UavRefusal.NOT_FLYING
            return self._refuse(memory, command, reason)
        p = STATE_ESTIMATE.get(estimate, "p_EB")
        eta = STATE_ESTIMATE.get(estimate, "heading")
        eta_d = eta if command.heading is None else float(command.heading)
        target = None
        if command.routine in (R.GOTO, R.LAND_AT):
            if command.position is None or np.size(command.position) != 3 \
                    or not np.all(np.isfinite(command.position)):
                return self._refuse(memory, command, UavRefusal.BAD_COMMAND)
            xyz = np.asarray(command.position, float)
            if command.routine == R.LAND_AT:
                xyz = np.array([xyz[0], xyz[1], p[2]])
            target = np.append(xyz, eta_d)
        elif command.routine == R.LAND_HOME:
            target = np.array([memory.home[0], memory.home[1], p[2], eta_d])
        elif command.routine == R.TRAJECTORY:
            if command.trajectory is None:
                return self._refuse(memory, command, UavRefusal.BAD_COMMAND)
            target = command.trajectory.samples[-1]
            if not self._inside(command.trajectory.samples[:, :3]):
                return self._refuse(memory, command, UavRefusal.OUTSIDE_AREA)
        if target is not None and not self._inside(target[None, :3]):
            return self._refuse(memory, command, UavRefusal.OUTSIDE_AREA)
        names = {R.SWITCH_CONTROLLER: self.controllers, R.SWITCH_TRACKER: self.trackers,
                 R.SET_CONSTRAINTS: self.constraint_groups, R.SET_GAINS: self.gain_groups}
        if command.routine in names:
            if command.name not in names[command.routine]:
                return self._refuse(memory, command, UavRefusal.UNKNOWN_NAME)
        if command.routine == R.SPEED and command.speed is None:
            return self._refuse(memory, command, UavRefusal.BAD_COMMAND)
        if command.routine == R.TAKEOFF and command.height is not None and \
                not (np.isfinite(command.height) and command.height > 0.0):
            return self._refuse(memory, command, UavRefusal.BAD_COMMAND)
        memory.command_id, memory.routine = command.id, command.routine
        memory.refusal, memory.done, memory.start = UavRefusal.NONE, False, now
        memory.target, memory.then_land = target, command.routine in (R.LAND_HOME, R.LAND_AT)
        getattr(self, f"_begin_{command.routine.name.lower()}", self._begin_flight)(
            memory, command, p, eta_d, now)

    def _inside(self, points: np.ndarray) -> bool:
        if self._area is None:
            return True
        return all(self._area.check(point) == 0 for point in points)

    def _switch(self, memory: UavMemory, tracker: str | None = None,
                controller: str | None = None) -> None:
        if tracker is not None:
            memory.tracker_id += 1
            memory.tracker_index = self.trackers.index(tracker)
        if controller is not None:
            memory.switch_id += 1
            memory.switch_index = self.controllers.index(controller)

    def _begin_takeoff(self, memory, command, p, heading, now) -> None:
        height = self.params.takeoff_height if command.height is None else float(command.height)
        memory.home = p.copy()
        memory.target = np.array([p[0], p[1], p[2] + height, heading])
        memory.landoff = LandoffGoal.takeoff(height)
        memory.phase, memory.arm, memory.thrust_enable = Phase.TAKING_OFF, 1.0, 0.0
        self._switch(memory, self.params.takeoff_tracker, self.params.takeoff_controller)

    def _begin_flight(self, memory, command, p, heading, now) -> None:
        """goto, land_at, land_home (the flying part) and trajectory: the flying tracker."""
        if command.routine == Routine.TRAJECTORY:
            goal = command.trajectory
            memory.trajectory = TrackerGoal(goal.samples, now + goal.t_start, goal.dt)
        else:
            memory.trajectory = TrackerGoal(memory.target[None, :])
        self._switch(memory, self.params.flying_tracker)

    def _begin_speed(self, memory, command, p, heading, now) -> None:
        memory.speed = command.speed
        memory.done = True       # flies at that speed until the next command
        self._switch(memory, self.params.speed_tracker)

    def _begin_land(self, memory, command, p, heading, now) -> None:
        memory.landoff = LandoffGoal.land()
        memory.phase = Phase.LANDING
        self._switch(memory, self.params.landing_tracker, self.params.landing_controller)

    def _begin_switch_controller(self, memory, command, p, heading, now) -> None:
        self._switch(memory, controller=command.name)
        memory.done = True

    def _begin_switch_tracker(self, memory, command, p, heading, now) -> None:
        self._switch(memory, tracker=command.name)
        memory.done = True

    def _begin_set_constraints(self, memory, command, p, heading, now) -> None:
        request = memory.group_request
        request[0], request[1] = request[0] + 1, self.constraint_groups.index(command.name)
        memory.done = True

    def _begin_set_gains(self, memory, command, p, heading, now) -> None:
        request = memory.group_request
        request[2], request[3] = request[2] + 1, self.gain_groups.index(command.name)
        memory.done = True

    def _progress(self, context, memory: UavMemory, estimate, now: float) -> None:
        if memory.done or memory.refusal != UavRefusal.NONE or memory.phase == Phase.EMERGENCY:
            return  # a refused command is never done (the vehicle keeps the routine before it)
        if memory.phase == Phase.TAKING_OFF and memory.thrust_enable < 0.5:
            return self._arming(context, memory, now)
        if memory.phase == Phase.LANDING:
            landed = self._landed.HasValue(context) and self._landed.Eval(context)[0] > 0.5
            if landed:
                self._disarm(memory)
            return
        if memory.target is None or not self._reached(memory, estimate, now):
            return
        if memory.phase == Phase.TAKING_OFF:
            memory.phase = Phase.FLYING
            memory.trajectory = TrackerGoal(memory.target[None, :])
            self._switch(memory, self.params.flying_tracker, self.params.flying_controller)
            memory.done = True
        elif memory.then_land:
            self._begin_land(memory, None, None, memory.target[3], now)
        else:
            memory.done = True

    def _arming(self, context, memory: UavMemory, now: float) -> None:
        """Take-off: armed at zero thrust first; the thrust once the flight controller says
        armed (at once without `fc_status`)."""
        armed = not self._fc_status.HasValue(context) or \
            FC_STATUS.get(self._fc_status.Eval(context), "armed") > 0.5
        if armed:
            memory.thrust_enable = 1.0
        elif now - memory.start > self.params.arm_timeout:
            self._disarm(memory, done=False)
            memory.refusal = UavRefusal.ARMING_DENIED

    def _reached(self, memory: UavMemory, estimate, now: float) -> bool:
        if memory.trajectory is not None and memory.routine == Routine.TRAJECTORY and \
                now < memory.trajectory.t_start + memory.trajectory.duration:
            return False
        p = STATE_ESTIMATE.get(estimate, "p_EB")
        v = STATE_ESTIMATE.get(estimate, "v_EB")
        return bool(np.linalg.norm(p - memory.target[:3]) <= self.params.position_tolerance
                    and np.linalg.norm(v) <= self.params.speed_tolerance)

    @staticmethod
    def _disarm(memory: UavMemory, done: bool = True) -> None:
        """Idle on the ground, disarmed, no goals; `done` ends the running routine."""
        memory.phase, memory.arm, memory.thrust_enable, memory.done = Phase.IDLE, 0.0, 0.0, done
        memory.landoff = memory.trajectory = memory.speed = None
