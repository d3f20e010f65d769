"""The control manager, M Sec. 7.2: picks the active controller, holds the safety area, watches the
control error (emergency landing, failsafe) and forwards the active controller's command.

Controllers are `Controller`s (alight.systems.control.controller). The manager decides, at every
tick, which controller is active:

- a switch request on the `switch_request` input ([request id, controller index]: a new id > 0
  asks for the controller at that index of the YAML list; id 0 is no request) or a scheduled
  switch (time, name) given to the constructor (`--switch-controller-at T:NAME`) changes the
  active controller while the manager is in NORMAL mode;
- a control error |p_ref - p_EB| over `emergency.threshold` starts the emergency landing
  (mode ELAND): the `emergency_controller` follows a reference that holds the estimated position
  of that moment horizontally and descends at `emergency.descent_speed` (the landoff tracker's
  landing, M Sec. 4.2: the reference goes below the estimate); touchdown is when the apparent
  mass M(34) of the issued thrust stays under `touchdown_mass_fraction` of the vehicle's mass for
  `touchdown_time`; then the manager disarms (mode LANDED);
- no valid state estimate, an active controller reporting `valid = 0` on `controller_status`, a
  non-finite or out-of-range command, or a control error over `failsafe_threshold` switch to the
  feedforward `failsafe_controller` (M Sec. 5.10, mode FAILSAFE). There is no way back from
  FAILSAFE or LANDED. Until the first valid estimate (the odometry starting up, the vehicle on
  the ground) the manager watches nothing: it waits.

The switch timing is the activation contract's: the decision is a function of the inputs and the
manager's state at the tick, so the `NAME.active` outputs change at the same tick as the manager's
state, the newly active controller computes at that tick and reads, as `last_command`, the command
the previous one issued (the manager's `fc_command` output still forwards it until the update),
and, as `last_disturbance`, the previous one's disturbance and mass estimates (M Sec. 7.2: "the
newly activated plugin is given the last state and result of the previously-active plugin").

Safety area: the goal reference (`goal`, REFERENCE, in the estimator frame E) is checked sample
by sample against a polygon in x-y and height limits in z. The first sample outside is refused
with a reason (`manager_status.refusal`) and the vehicle holds at the last accepted reference
position (zero velocity, acceleration, jerk; heading kept) until the goal comes back inside within
`rejoin_distance` of the hold point.

Estimator frame changes (frame_counter, M Sec. 3.5): the hold point, the emergency landing's start
and the last issued reference are re-expressed in the new frame. The safety area is given in E.

Trackers (M Sec. 4 and 7.2; optional, `trackers` given to the constructor): the goal chi is then
the active tracker's `reference` instead of the `goal` input. Trackers are `Tracker`s
(alight.systems.tracking.tracker); they switch like controllers (`tracker_request` [id,
index]), only the active one computes (`NAME.active`), and it starts from the manager's
`reference` (their `last_reference`). A tracker whose status says it cannot produce a reference
(valid 0 for any reason but INACTIVE = 1) or whose reference is not finite makes the manager
hold, like a goal outside the safety area. Outside NORMAL mode no tracker is active.

Arming (optional `arm` input [arm, thrust enable]; unconnected means armed from the start): unless
both are 1 the manager is DISARMED: no controller or tracker is active, the command is level with
zero thrust and the `arm` flag of the input (the flight controller arms at zero thrust, as PX4
requires), the reference holds the estimate; when both are 1 the manager flies in NORMAL mode with
the selected controller and tracker, which start from that zero-thrust command and that reference
(the controller spools up from zero thrust). A disarm request is obeyed in any mode (the UAV
manager sends one only once landed).
"""
import dataclasses as dc
import enum
import functools
import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem, ValueProducer

from alight.systems.boundary import (CONTROLLER_STATUS, FC_COMMAND, REFERENCE, STATE_ESTIMATE,
                                     TRACKER_STATUS, VectorLayout, estimate_is_valid)
from alight.systems.control.controller import (ControllerReason, command_is_usable,
                                               controller_failed, level_command)
from alight.systems.control.disturbance import DISTURBANCE_ESTIMATE
from alight.systems.control.force_controller import VehicleModel
from alight.systems.control.touchdown import light_time
from alight.systems.estimation.frames import frame_switch, reexpress_point
from alight.systems.params import bounded
from alight.systems.rotations import all_finite, float_list, norm


class ManagerMode(enum.IntEnum):
    NORMAL = 0
    ELAND = 1      # emergency landing on the emergency controller
    FAILSAFE = 2   # the feedforward failsafe controller
    LANDED = 3     # touched down after the emergency landing: disarmed
    DISARMED = 4   # the `arm` input is not [1, 1]: nothing active, zero thrust


class Refusal(enum.IntEnum):
    """`manager_status.refusal`: why the last goal sample or switch request was refused."""
    NONE = 0
    OUTSIDE_POLYGON = 1
    BELOW_MIN_HEIGHT = 2
    ABOVE_MAX_HEIGHT = 3
    NOT_FINITE = 4
    UNKNOWN_CONTROLLER = 5    # switch request to an index not in the list
    NOT_IN_NORMAL_MODE = 6    # switch request during ELAND / FAILSAFE / LANDED
    UNKNOWN_TRACKER = 7       # tracker switch request to an index not in the list
    TRACKER_FAILED = 8        # the active tracker cannot produce a reference: holding


class FailsafeCause(enum.IntEnum):
    NONE = 0
    BAD_ESTIMATE = 1
    BAD_CONTROLLER = 2   # valid = 0 on controller_status, or an unusable command
    CONTROL_ERROR = 3
    FLIGHT_CONTROLLER = 4   # the flight controller flies its own failsafe (the failsafe switch)


# `manager_status`: index of the active controller; ManagerMode; Refusal of the last refused goal
# sample or switch request; held (1 while the safety area holds the vehicle); the control error
# |p_ref - p_EB| [m]; FailsafeCause; the number of controller switches so far; index of the active
# tracker (-1 without trackers) and the number of tracker switches.
MANAGER_STATUS = VectorLayout("manager_status", [
    ("active", 1), ("mode", 1), ("refusal", 1), ("held", 1), ("control_error", 1),
    ("failsafe_cause", 1), ("switches", 1), ("tracker", 1), ("tracker_switches", 1)],
    defaults={"tracker": -1.0, "tracker_switches": 0.0})


def gave_up(status: np.ndarray) -> bool:
    """A MANAGER_STATUS (the control manager's, or a direct stack's failsafe switch's) that has
    left NORMAL flight for good: the emergency landing, the failsafe, landed after them."""
    # (the mode as a Python float: a NumPy scalar compared with an IntEnum takes ~10 us)
    return float(MANAGER_STATUS.get(status, "mode")) in (ManagerMode.ELAND, ManagerMode.FAILSAFE,
                                                         ManagerMode.LANDED)


@dc.dataclass
class SafetyArea:
    """A polygon in x-y of the estimator frame E and height limits of z in E, M Sec. 7.2."""
    enabled: bool = True
    polygon: list[list[float]] = dc.field(
        default_factory=lambda: [[-50.0, -50.0], [50.0, -50.0], [50.0, 50.0], [-50.0, 50.0]])
    min_height: float = bounded(-1.0, -1e4, 1e4, "m")
    max_height: float = bounded(20.0, -1e4, 1e4, "m")
    rejoin_distance: float = bounded(0.5, 0.0, 1e3, "m")

    def validate(self) -> None:
        """Raises ValueError naming the key when the polygon or the height limits are unusable."""
        polygon = np.asarray(self.polygon, dtype=float)
        if polygon.ndim != 2 or polygon.shape[1] != 2 or len(polygon) < 3:
            raise ValueError(f"safety_area.polygon must be at least 3 [x, y] vertices, got "
                             f"{self.polygon}")
        if self.min_height >= self.max_height:
            raise ValueError(f"safety_area: min_height {self.min_height} must be below "
                             f"max_height {self.max_height}")

    def check(self, p: np.ndarray) -> Refusal:
        """Refusal.NONE when `p` [m, in E] is allowed."""
        if not self.enabled:
            return Refusal.NONE
        x, y, z = float_list(p)  # (per tick: Python floats, the same arithmetic as NumPy's)
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            return Refusal.NOT_FINITE
        if z < self.min_height:
            return Refusal.BELOW_MIN_HEIGHT
        if z > self.max_height:
            return Refusal.ABOVE_MAX_HEIGHT
        if not inside_polygon((x, y), self.polygon):
            return Refusal.OUTSIDE_POLYGON
        return Refusal.NONE


def inside_polygon(point, polygon) -> bool:
    """Even-odd ray casting; points on an edge count as inside. `point` [x, y], `polygon` a
    list (or array) of [x, y] vertices."""
    x, y = float_list(point)
    vertices = [(float(u), float(v)) for u, v in polygon]
    inside = False
    for (x0, y0), (x1, y1) in zip(vertices, vertices[1:] + vertices[:1]):
        cross = (x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)
        if cross == 0.0 and min(x0, x1) <= x <= max(x0, x1) and min(y0, y1) <= y <= max(y0, y1):
            return True
        if (y0 > y) != (y1 > y) and x < x0 + (y - y0) * (x1 - x0) / (y1 - y0):
            inside = not inside
    return inside


@dc.dataclass
class EmergencyParams:
    threshold: float = bounded(2.0, 0.1, 100.0, "m")          # control error -> ELAND
    failsafe_threshold: float = bounded(5.0, 0.1, 1000.0, "m")  # control error -> FAILSAFE
    descent_speed: float = bounded(0.5, 0.05, 5.0, "m/s")
    touchdown_mass_fraction: float = bounded(0.5, 0.05, 0.95)   # of the vehicle's mass, M(34)
    touchdown_time: float = bounded(0.5, 0.0, 30.0, "s")


_STATE = VectorLayout("control_manager_state", [
    ("active", 1), ("mode", 1), ("request_id", 1), ("next_scheduled", 1), ("refusal", 1),
    ("held", 1), ("hold_p", 3), ("hold_heading", 1), ("eland_start", 1), ("eland_p", 3),
    ("eland_heading", 1), ("quiet_time", 1), ("issued_p", 3), ("issued_heading", 1),
    ("frame_counter", 1), ("active_since", 1), ("failsafe_cause", 1), ("switches", 1),
    ("control_error", 1), ("estimate_seen", 1), ("tracker", 1), ("tracker_request_id", 1),
    ("tracker_switches", 1), ("tracker_since", 1), ("arm_flag", 1)])


@dc.dataclass
class _Decision:
    """What the manager does at this tick (a pure function of the context)."""
    x: np.ndarray            # the manager state after the tick
    reference: np.ndarray    # REFERENCE given to the controllers


class CommandSwitch(LeafSystem):
    """What the control manager and the failsafe switch (failsafe_switch.py) share: the
    activation contract of alight.systems.control.controller, a decision that is a function of
    the inputs and the state at the tick. `_declare_switching(period)` declares the last usable
    command issued (`_last_command`), the periodic `_update`, the tick's `_compute_decision`
    cached once per context change (`_decision`, read by the outputs and the update) and the
    `fc_command` output (`_calc_command`); subclasses implement the three methods."""

    def _declare_switching(self, period: float, command_prerequisites: set | None = None
                           ) -> set:
        """Returns the tickets of everything (inputs, state, time) the decision depends on.
        `command_prerequisites`: what `_calc_command` reads, when less than that (the outputs
        read between the ticks by the vehicle's flight controller are then not recomputed at
        every simulator step)."""
        self._last_command = self.DeclareDiscreteState(level_command(0.0, 0.0, 0.0, 0.0))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        everything = {self.all_input_ports_ticket(), self.all_state_ticket(), self.time_ticket()}
        self._decision = self.DeclareCacheEntry(
            "decision", ValueProducer(allocate=AbstractValue.Make(None).Clone,
                                      calc=lambda context, value: value.set_value(
                                          self._compute_decision(context))), everything)
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, self._calc_command,
                                     command_prerequisites or everything)
        return everything


class ControlManager(CommandSwitch):
    """Built from the fields of its config (ControlManagerConfig of
    alight.diagrams.onboard.control_manager), by keyword: `controllers` and `trackers` are the
    names of the YAML lists, in order (requests index them); the per-controller and per-tracker
    ports are named after them.

    Inputs  `state_estimate` STATE_ESTIMATE; `goal` REFERENCE (chi in E; only without
            trackers); `switch_request` (2) [request id, controller index] (optional:
            unconnected means no requests); `arm` (2) [arm, thrust enable] (optional:
            unconnected means armed and flying); per controller NAME: `NAME.fc_command`
            FC_COMMAND, `NAME.controller_status` CONTROLLER_STATUS, `NAME.disturbance_estimate`
            DISTURBANCE_ESTIMATE (optional, for controllers that estimate disturbances M(35)-(37));
            `NAME.desired_acceleration` (3, optional: controllers that output M(53));
            with trackers, `tracker_request` (2) [request id, tracker index] (optional) and per
            tracker NAME: `NAME.reference` REFERENCE, `NAME.tracker_status` TRACKER_STATUS
    Outputs `fc_command` FC_COMMAND (the active controller's command: the vehicle's command and
            every controller's `last_command`); `last_disturbance` DISTURBANCE_ESTIMATE (the
            active controller's, NaN when it has none: the next one takes them over);
            `desired_acceleration` (3) the active controller's unbiased desired acceleration
            M(53) [m/s^2, in E] (NaN when it has none: the estimator bank's input, M Sec. 3.1.1);
            `reference` REFERENCE (what the controllers track and every tracker's
            `last_reference`: the goal, the safety hold or the emergency descent);
            `tracker_status` TRACKER_STATUS (the active tracker's, NaN when none: controllers
            with that input hold their integrators while it is ADMITTANCE_HOLD); `NAME.active`
            (1) per controller and per tracker; `manager_status` MANAGER_STATUS
    Each `NAME.port` input is fed by that controller's or tracker's `port` output, and
    `NAME.active` feeds its `active` input. Updated every `period` (100 Hz by default), together
    with the controllers and trackers.
    """

    def __init__(self, *, controllers: list[str], initial_controller: str,
                 failsafe_controller: str, emergency_controller: str, vehicle: VehicleModel,
                 trackers: list[str] | None = None, initial_tracker: str | None = None,
                 safety_area: SafetyArea | None = None, emergency: EmergencyParams | None = None,
                 period: float = 0.01, schedule: list[tuple[float, str]] | None = None):
        super().__init__()
        self.names = list(controllers)
        self.trackers = list(trackers or [])
        shared = set(self.names) & set(self.trackers)
        if shared:
            raise ValueError(f"controllers and trackers share the names {sorted(shared)}: their "
                             f"ports (NAME.active) would collide")
        for role, name in (("initial", initial_controller), ("failsafe", failsafe_controller),
                           ("emergency", emergency_controller)):
            if name not in self.names:
                raise ValueError(f"{role} controller {name!r} is not in the list {self.names}")
        self._initial, self._failsafe = self.index(initial_controller), \
            self.index(failsafe_controller)
        self._emergency = self.index(emergency_controller)
        initial_tracker = initial_tracker or (self.trackers[0] if self.trackers else None)
        if self.trackers and initial_tracker not in self.trackers:
            raise ValueError(f"initial tracker {initial_tracker!r} is not in the list "
                             f"{self.trackers}")
        safety_area = safety_area or SafetyArea()
        safety_area.validate()
        self._area, self._e, self._vehicle, self._period = (
            safety_area, emergency or EmergencyParams(), vehicle, period)
        schedule = sorted(schedule or [], key=lambda item: item[0])
        self._schedule = [(float(t), self.index(name)) for t, name in schedule]
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._goal = None if self.trackers else \
            self.DeclareVectorInputPort("goal", REFERENCE.size)
        self._request = self.DeclareVectorInputPort("switch_request", 2)
        self._arm = self.DeclareVectorInputPort("arm", 2)
        self._commands, self._statuses, self._disturbances, self._accelerations = (
            [self.DeclareVectorInputPort(f"{name}.{port}", size) for name in self.names]
            for port, size in (("fc_command", FC_COMMAND.size),
                               ("controller_status", CONTROLLER_STATUS.size),
                               ("disturbance_estimate", DISTURBANCE_ESTIMATE.size),
                               ("desired_acceleration", 3)))
        self._tracker_request = self.DeclareVectorInputPort("tracker_request", 2) \
            if self.trackers else None
        self._tracker_references, self._tracker_statuses = (
            [self.DeclareVectorInputPort(f"{name}.{port}", size) for name in self.trackers]
            for port, size in (("reference", REFERENCE.size),
                               ("tracker_status", TRACKER_STATUS.size)))
        x0 = _STATE.pack(active=self._initial, mode=ManagerMode.NORMAL, request_id=0,
                         next_scheduled=0, refusal=Refusal.NONE, held=0, hold_p=np.zeros(3),
                         hold_heading=0, eland_start=0, eland_p=np.zeros(3), eland_heading=0,
                         quiet_time=0, issued_p=np.zeros(3), issued_heading=0,
                         frame_counter=np.nan, active_since=0.0, failsafe_cause=0, switches=0,
                         control_error=0, estimate_seen=0,
                         tracker=self.trackers.index(initial_tracker) if self.trackers else -1,
                         tracker_request_id=0, tracker_switches=0, tracker_since=0.0,
                         arm_flag=1.0)
        self._state = self.DeclareDiscreteState(x0)
        # The `NAME.active` and `reference` outputs and the update all read the decision.
        everything = self._declare_switching(period)
        self.DeclareVectorOutputPort("last_disturbance", DISTURBANCE_ESTIMATE.size,
                                     functools.partial(self._forward_active, self._disturbances),
                                     {self.all_input_ports_ticket(), self.all_state_ticket()})
        self.DeclareVectorOutputPort("desired_acceleration", 3, functools.partial(
            self._forward_active, self._accelerations),
                                     {self.all_input_ports_ticket(), self.all_state_ticket()})
        self.DeclareVectorOutputPort("reference", REFERENCE.size, self._calc_reference,
                                     everything)
        self.DeclareVectorOutputPort("tracker_status", TRACKER_STATUS.size,
                                     self._calc_tracker_status, everything)
        for i, name in enumerate(self.names):
            self.DeclareVectorOutputPort(
                f"{name}.active", 1, lambda context, output, i=i: output.SetFromVector(
                    [float(self._active_after(context) == i)]), everything)
        for k, name in enumerate(self.trackers):
            self.DeclareVectorOutputPort(
                f"{name}.active", 1, lambda context, output, k=k: output.SetFromVector(
                    [float(self._tracker_after(context) == k)]), everything)
        self.DeclareVectorOutputPort("manager_status", MANAGER_STATUS.size, self._calc_status,
                                     {self.all_state_ticket()})

    def index(self, name: str) -> int:
        if name not in self.names:
            raise ValueError(f"unknown controller {name!r}: expected one of {self.names}")
        return self.names.index(name)

    # --- outputs ------------------------------------------------------------------------------

    def _calc_command(self, context, output):
        x = context.get_discrete_state(self._state).get_value()
        mode = float(_STATE.get(x, "mode"))  # (a NumPy scalar against an IntEnum: ~10 us)
        if mode == ManagerMode.LANDED:
            return output.SetFromVector(level_command(
                context.get_time(), _STATE.get(x, "eland_heading"), 0.0, 0.0))
        if mode == ManagerMode.DISARMED:
            return output.SetFromVector(self._idle_command(context.get_time(), x))
        command = self._commands[int(x[_STATE.slice("active")][0])].Eval(context)
        if not command_is_usable(command):   # never forward a NaN; the failsafe takes over next
            command = context.get_discrete_state(self._last_command).get_value()
        output.SetFromVector(command)

    def _forward_active(self, ports, context, output):
        """The active controller's value on `ports` (one per controller), NaN where unconnected."""
        port = ports[int(context.get_discrete_state(self._state).get_value()[
            _STATE.slice("active")][0])]
        output.SetFromVector(port.Eval(context) if port.HasValue(context)
                             else np.full(port.size(), np.nan))

    def _calc_reference(self, context, output):
        output.SetFromVector(self._decide(context).reference)

    def _calc_tracker_status(self, context, output):
        """The status of the tracker whose reference `reference` forwards; NaN when none does
        (no trackers, the `goal` input, or outside NORMAL mode)."""
        k = self._tracker_after(context) if self.trackers else -1
        output.SetFromVector(self._tracker_statuses[k].Eval(context) if k >= 0
                             else np.full(TRACKER_STATUS.size, np.nan))

    def _calc_status(self, context, output):
        x = context.get_discrete_state(self._state).get_value()
        S = _STATE
        output.SetFromVector(MANAGER_STATUS.pack(
            active=S.get(x, "active"), mode=S.get(x, "mode"), refusal=S.get(x, "refusal"),
            held=S.get(x, "held"), control_error=S.get(x, "control_error"),
            failsafe_cause=S.get(x, "failsafe_cause"), switches=S.get(x, "switches"),
            tracker=S.get(x, "tracker"), tracker_switches=S.get(x, "tracker_switches")))

    def _active_after(self, context) -> int:
        """The controller that computes at this tick (-1: none, disarmed)."""
        x = self._decide(context).x
        if float(_STATE.get(x, "mode")) == ManagerMode.DISARMED:
            return -1
        return int(_STATE.get(x, "active"))

    def _tracker_after(self, context) -> int:
        """The tracker that computes at this tick (-1: none, outside NORMAL mode)."""
        x = self._decide(context).x
        if float(_STATE.get(x, "mode")) != ManagerMode.NORMAL:
            return -1
        return int(_STATE.get(x, "tracker"))

    def _update(self, context, discrete_state):
        decision = self._decide(context)
        discrete_state.set_value(self._state, decision.x)
        x = context.get_discrete_state(self._state).get_value()
        if float(_STATE.get(x, "mode")) == ManagerMode.DISARMED:
            discrete_state.set_value(self._last_command,
                                     self._idle_command(context.get_time(), x))
            return
        command = self._commands[int(_STATE.get(x, "active"))].Eval(context)
        if command_is_usable(command):
            discrete_state.set_value(self._last_command, command)

    # --- the decision -------------------------------------------------------------------------

    def _decide(self, context) -> _Decision:
        """This tick's decision (cached; do not modify it)."""
        return self._decision.Eval(context)

    def _compute_decision(self, context) -> _Decision:
        S = _STATE
        now = context.get_time()
        x = context.get_discrete_state(self._state).get_value().copy()
        estimate = self._estimate.Eval(context)
        estimate_ok = estimate_is_valid(estimate)
        # At the tick of a frame switch the control error mixes frames for the systems that
        # read this manager's outputs while the trackers update (before their update): it is not
        # watched at that tick.
        switching = estimate_ok and self._follow_frame(x, estimate)
        self._follow_arm(context, x, now)
        mode = ManagerMode(int(S.get(x, "mode")))
        selectable = mode in (ManagerMode.NORMAL, ManagerMode.DISARMED)
        self._switch_on_request(context, x, now, selectable)
        self._switch_tracker_on_request(context, x, now, selectable)
        if mode == ManagerMode.DISARMED:
            reference = self._disarmed_reference(x, estimate if estimate_ok else None, now)
            x[S.slice("issued_p")] = REFERENCE.get(reference, "p")
            x[S.slice("issued_heading")] = REFERENCE.get(reference, "heading")
            x[S.slice("held")], x[S.slice("control_error")] = 0.0, 0.0
            return _Decision(x, reference)
        watching = mode in (ManagerMode.NORMAL, ManagerMode.ELAND) and \
            S.get(x, "estimate_seen") > 0.5
        cause = self._failsafe_cause(context, x, estimate_ok, now) if watching \
            else FailsafeCause.NONE
        if estimate_ok:
            x[S.slice("estimate_seen")] = 1.0
        reference = self._reference(context, x, mode, now)
        error = norm(REFERENCE.get(reference, "p") - STATE_ESTIMATE.get(estimate, "p_EB")) \
            if estimate_ok else float("nan")
        x[S.slice("control_error")] = error if math.isfinite(error) else 0.0
        watching_error = watching and not switching
        if cause == FailsafeCause.NONE and mode == ManagerMode.NORMAL and watching_error and \
                error > self._e.failsafe_threshold:
            cause = FailsafeCause.CONTROL_ERROR
        if cause != FailsafeCause.NONE:
            x[S.slice("mode")] = ManagerMode.FAILSAFE
            x[S.slice("failsafe_cause")] = cause
            self._set_active(x, self._failsafe, now)
        elif mode == ManagerMode.NORMAL and watching_error and error > self._e.threshold:
            x[S.slice("mode")] = ManagerMode.ELAND
            x[S.slice("eland_start")] = now
            x[S.slice("eland_p")] = STATE_ESTIMATE.get(estimate, "p_EB")
            x[S.slice("eland_heading")] = STATE_ESTIMATE.get(estimate, "heading")
            x[S.slice("quiet_time")] = 0.0
            self._set_active(x, self._emergency, now)
            reference = self._reference(context, x, ManagerMode.ELAND, now)
        elif mode == ManagerMode.ELAND:
            self._detect_touchdown(context, x)
        x[S.slice("issued_p")] = REFERENCE.get(reference, "p")
        x[S.slice("issued_heading")] = REFERENCE.get(reference, "heading")
        return _Decision(x, reference)

    @staticmethod
    def _idle_command(now: float, x: np.ndarray) -> np.ndarray:
        """DISARMED: level, zero thrust, the arm flag asked for."""
        return level_command(now, _STATE.get(x, "issued_heading"), 0.0, _STATE.get(x, "arm_flag"))

    def _follow_arm(self, context, x: np.ndarray, now: float) -> None:
        """DISARMED unless the `arm` input is [1, 1]; flying starts NORMAL mode afresh."""
        if not self._arm.HasValue(context):
            return
        arm, thrust_enable = self._arm.Eval(context) > 0.5
        armed = bool(arm and thrust_enable)
        x[_STATE.slice("arm_flag")] = float(arm)
        disarmed = float(_STATE.get(x, "mode")) == ManagerMode.DISARMED
        if not armed and not disarmed:
            x[_STATE.slice("mode")] = ManagerMode.DISARMED
        elif armed and disarmed:
            x[_STATE.slice("mode")] = ManagerMode.NORMAL
            x[_STATE.slice("failsafe_cause")] = FailsafeCause.NONE
            x[_STATE.slice("held")] = 0.0
            x[_STATE.slice("active_since")] = now
            x[_STATE.slice("tracker_since")] = now

    def _disarmed_reference(self, x: np.ndarray, estimate, now: float) -> np.ndarray:
        """Disarmed: the reference rests at the estimate (trackers start from it)."""
        if estimate is None:
            return self._hold_reference(now, _STATE.get(x, "issued_p"),
                                        _STATE.get(x, "issued_heading"))
        return self._hold_reference(now, STATE_ESTIMATE.get(estimate, "p_EB"),
                                    STATE_ESTIMATE.get(estimate, "heading"))

    def _set_active(self, x: np.ndarray, index: int, now: float) -> None:
        if int(_STATE.get(x, "active")) != index:
            x[_STATE.slice("active")] = index
            x[_STATE.slice("active_since")] = now
            x[_STATE.slice("switches")] += 1

    @staticmethod
    def _new_request(context, port, x: np.ndarray, id_field: str, count: int):
        """(index or None, refused): a new [id, index] request on `port`."""
        if port is None or not port.HasValue(context):
            return None, False
        request_id, index = port.Eval(context)
        request_id, index = float(request_id), float(index)
        if not (math.isfinite(request_id) and request_id > 0
                and request_id != _STATE.get(x, id_field)):
            return None, False
        x[_STATE.slice(id_field)] = request_id
        if math.isfinite(index) and 0 <= int(index) < count and int(index) == index:
            return int(index), False
        return None, True

    def _switch_on_request(self, context, x: np.ndarray, now: float, allowed: bool) -> None:
        S = _STATE
        target = None
        k = int(S.get(x, "next_scheduled"))
        while k < len(self._schedule) and self._schedule[k][0] <= now + 1e-9:
            target, k = self._schedule[k][1], k + 1
        x[S.slice("next_scheduled")] = k
        requested, refused = self._new_request(context, self._request, x, "request_id",
                                               len(self.names))
        if refused:
            x[S.slice("refusal")] = Refusal.UNKNOWN_CONTROLLER
        target = requested if requested is not None else target
        if target is not None and not allowed:
            x[S.slice("refusal")] = Refusal.NOT_IN_NORMAL_MODE
        elif target is not None:
            self._set_active(x, target, now)

    def _switch_tracker_on_request(self, context, x: np.ndarray, now: float,
                                   allowed: bool) -> None:
        S = _STATE
        target, refused = self._new_request(context, self._tracker_request, x,
                                            "tracker_request_id", len(self.trackers))
        if refused:
            x[S.slice("refusal")] = Refusal.UNKNOWN_TRACKER
        elif target is not None and not allowed:
            x[S.slice("refusal")] = Refusal.NOT_IN_NORMAL_MODE
        elif target is not None and target != int(S.get(x, "tracker")):
            x[S.slice("tracker")] = target
            x[S.slice("tracker_since")] = now
            x[S.slice("tracker_switches")] += 1
            x[S.slice("held")] = 0.0

    def _failsafe_cause(self, context, x: np.ndarray, estimate_ok: bool,
                        now: float) -> FailsafeCause:
        if not estimate_ok:
            return FailsafeCause.BAD_ESTIMATE
        active = int(_STATE.get(x, "active"))
        if _STATE.get(x, "active_since") < now and controller_failed(   # it has computed
                self._statuses[active].Eval(context), self._commands[active].Eval(context)):
            return FailsafeCause.BAD_CONTROLLER
        return FailsafeCause.NONE

    def _chi(self, context, x: np.ndarray, now: float) -> tuple[np.ndarray, Refusal]:
        """The chi to follow: the `goal` input, or the active tracker's reference (with
        TRACKER_FAILED when that tracker cannot produce one). Trackers update with unrestricted
        update events, which Drake applies before the discrete updates of this manager and the
        controllers at the same tick: at the tick of an estimator frame switch the tracker has
        already re-expressed its state, and its reference is in the new frame."""
        if self._goal is not None:
            return self._goal.Eval(context), Refusal.NONE
        k = int(_STATE.get(x, "tracker"))
        reference = self._tracker_references[k].Eval(context)
        status = self._tracker_statuses[k].Eval(context)
        failed = TRACKER_STATUS.get(status, "valid") < 0.5 and \
            float(TRACKER_STATUS.get(status, "reason")) != ControllerReason.INACTIVE and \
            _STATE.get(x, "tracker_since") < now
        return reference, Refusal.TRACKER_FAILED if failed else Refusal.NONE

    def _reference(self, context, x: np.ndarray, mode: ManagerMode, now: float) -> np.ndarray:
        S = _STATE
        if mode in (ManagerMode.ELAND, ManagerMode.LANDED):
            descent = self._e.descent_speed
            p = S.get(x, "eland_p") - [0.0, 0.0, descent * (now - S.get(x, "eland_start"))]
            return REFERENCE.pack(stamp=now, p=p, v=[0.0, 0.0, -descent], a=0.0, j=0.0,
                                  heading=S.get(x, "eland_heading"), heading_rate=0.0)
        if mode == ManagerMode.FAILSAFE:
            return self._hold_reference(now, S.get(x, "issued_p"), S.get(x, "issued_heading"))
        goal, refusal = self._chi(context, x, now)
        if refusal == Refusal.NONE:
            refusal = self._area.check(REFERENCE.get(goal, "p")) \
                if all_finite(goal) else Refusal.NOT_FINITE
        held = S.get(x, "held") > 0.5
        if held and refusal == Refusal.NONE and norm(
                REFERENCE.get(goal, "p") - S.get(x, "hold_p")) <= self._area.rejoin_distance:
            held = False
        elif not held and refusal != Refusal.NONE:
            held = True
            x[S.slice("hold_p")] = S.get(x, "issued_p")
            x[S.slice("hold_heading")] = S.get(x, "issued_heading")
            x[S.slice("refusal")] = refusal
        x[S.slice("held")] = float(held)
        if held:
            return self._hold_reference(now, S.get(x, "hold_p"), S.get(x, "hold_heading"))
        return goal

    @staticmethod
    def _hold_reference(now: float, p: np.ndarray, eta: float) -> np.ndarray:
        return REFERENCE.pack(stamp=now, p=p, v=0.0, a=0.0, j=0.0, heading=eta, heading_rate=0.0)

    def _detect_touchdown(self, context, x: np.ndarray) -> None:
        """M(34): the apparent mass of the issued thrust on its tilt."""
        command = context.get_discrete_state(self._last_command).get_value()
        quiet = light_time(_STATE.get(x, "quiet_time"), command, self._vehicle,
                           self._e.touchdown_mass_fraction, self._period)
        x[_STATE.slice("quiet_time")] = quiet
        if quiet >= self._e.touchdown_time:
            x[_STATE.slice("mode")] = ManagerMode.LANDED

    def _follow_frame(self, x: np.ndarray, estimate: np.ndarray) -> bool:
        """Re-expresses the stored points when the estimator frame changes (M Sec. 3.5);
        True at the tick of a switch."""
        S = _STATE
        switch = frame_switch(estimate, S.get(x, "frame_counter"))
        x[S.slice("frame_counter")] = STATE_ESTIMATE.get(estimate, "frame_counter")
        if switch is None:
            return False
        for p, eta in (("hold_p", "hold_heading"), ("eland_p", "eland_heading"),
                       ("issued_p", "issued_heading")):
            x[S.slice(p)], x[S.slice(eta)] = np.split(reexpress_point(
                np.append(S.get(x, p), S.get(x, eta)), *switch), [3])
        return True
