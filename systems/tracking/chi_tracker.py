"""What the landoff tracker (M Sec. 4.2) and the speed tracker (M Sec. 4.3) share: the tracker
contract of alight.systems.boundary around a virtual vehicle whose state is the reference chi of
M(16), advanced by one period at every tick (stamped one period ahead, like the MPC tracker's).

Only the active tracker computes; on activation the virtual vehicle starts from `last_reference`
(advanced from its stamp to the tick, M Sec. 7.2: the switch is imperceptible) or, without a
finite one, at rest at the state estimate. When the estimate's `frame_counter` changes, chi and
the subclass's stored points are re-expressed in the new frame (M Sec. 3.5). A step that gives a
non-finite chi keeps the previous one (reason NOT_FINITE): no NaN leaves the tracker.
"""
import dataclasses as dc
import enum

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import REFERENCE, STATE_ESTIMATE, TRACKER_STATUS
from alight.systems.control.force_controller import advance_reference
from alight.systems.estimation.frames import reexpress_point
from alight.systems.estimation.heading import wrap_angle
from alight.systems.rotations import heading, rotation_matrix
from alight.systems.timing import ComputeTimer


class ChiReason(enum.IntEnum):
    """`tracker_status.reason` of the landoff and speed trackers (0-4 as the MPC tracker's)."""
    OK = 0            # following the goal, or holding it once reached
    INACTIVE = 1
    NO_GOAL = 2       # active without a goal: holds (speed: stops) where it started
    NOT_FINITE = 3    # the step gave a non-finite chi: the previous one is kept
    BAD_START = 4     # cannot start: no finite last reference and no valid estimate
    BAD_GOAL = 5      # a goal the parameters refuse (named in the docstrings): ignored, holding
    TAKING_OFF = 6
    ADMITTANCE = 7    # the take-off reference is held: it would run too far from the estimate
    LANDING = 8
    LANDED = 9        # touchdown detected (M(34)): disarm
    SATURATED = 10    # a speed goal clipped to the tracker's limits


@dc.dataclass
class ChiMemory:
    """Abstract state: chi of the virtual vehicle (REFERENCE, stamp = the time it is for), the
    goal being followed as received, bookkeeping. Trackers extend it."""
    chi: np.ndarray = dc.field(default_factory=lambda: np.full(REFERENCE.size, np.nan))
    goal: object = None
    active: bool = False
    frame_counter: float = np.nan


def reexpress_reference(chi: np.ndarray, R_OldNew: np.ndarray, p_OldNew: np.ndarray
                        ) -> np.ndarray:
    """REFERENCE chi in the new estimator frame: the position as a point, its derivatives
    rotated, the heading less the frames' yaw."""
    out = np.array(chi, float)
    out[REFERENCE.slice("p")] = reexpress_point(REFERENCE.get(chi, "p"), R_OldNew, p_OldNew)
    for field in ("v", "a", "j"):
        out[REFERENCE.slice(field)] = R_OldNew.T @ REFERENCE.get(chi, field)
    out[REFERENCE.slice("heading")] = wrap_angle(REFERENCE.get(chi, "heading")
                                                 - heading(R_OldNew))
    return out


def estimate_is_valid(estimate: np.ndarray) -> bool:
    return STATE_ESTIMATE.get(estimate, "valid") > 0.5 and bool(np.all(np.isfinite(estimate)))


def rest_at_estimate(estimate: np.ndarray, stamp: float) -> np.ndarray:
    """chi at rest at the estimated position and heading."""
    return REFERENCE.pack(stamp=stamp, p=STATE_ESTIMATE.get(estimate, "p_EB"), v=0.0, a=0.0,
                          j=0.0, heading=STATE_ESTIMATE.get(estimate, "heading"),
                          heading_rate=0.0)


class ChiTracker(LeafSystem):
    """Inputs  `state_estimate` STATE_ESTIMATE; `goal` (abstract: `goal_type` or None);
            `active` (1); `last_reference` REFERENCE
    Outputs `reference` REFERENCE (chi of M(16) in E, stamped one period ahead);
            `tracker_status` TRACKER_STATUS (reason: ChiReason)
    Subclasses implement `_begin` (a new goal), `_step` (one period of the virtual vehicle) and,
    when they store points, `_reexpress`; they may declare more ports. `compute_timer` records
    the wall-clock time of each active tick's goal and step (alight.systems.timing).
    """

    def __init__(self, period: float, memory: ChiMemory, goal_type: type):
        super().__init__()
        self.compute_timer = ComputeTimer()
        self.period, self._goal_type = period, goal_type
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._goal = self.DeclareAbstractInputPort("goal", AbstractValue.Make(None))
        self._active = self.DeclareVectorInputPort("active", 1)
        self._last = self.DeclareVectorInputPort("last_reference", REFERENCE.size)
        self._memory = self.DeclareAbstractState(AbstractValue.Make(memory))
        self._reference = self.DeclareDiscreteState(np.full(REFERENCE.size, np.nan))
        self._status = self.DeclareDiscreteState(TRACKER_STATUS.pack(
            valid=0.0, reason=ChiReason.INACTIVE, solver_status=0.0))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._update)
        # Not from `last_reference`: the control manager computes that from this output.
        self.DeclareVectorOutputPort(
            "reference", REFERENCE.size, self._calc_reference,
            {self.all_state_ticket(), self.input_port_ticket(self._estimate.get_index())})
        self.DeclareStateOutputPort("tracker_status", self._status)

    # --- subclass interface -------------------------------------------------------------------

    def _begin(self, context, memory: ChiMemory, goal, estimate) -> ChiReason:
        """Takes up `goal` (a new one, or None), from memory.chi; returns OK or BAD_GOAL."""
        raise NotImplementedError

    def _step(self, context, memory: ChiMemory, estimate) -> ChiReason:
        """Advances memory.chi by one period toward memory.goal. `estimate` is None when it is
        not valid."""
        raise NotImplementedError

    def _reexpress(self, memory: ChiMemory, R_OldNew: np.ndarray, p_OldNew: np.ndarray):
        """Re-expresses the subclass's stored points in the new estimator frame."""

    def memory(self, context) -> ChiMemory:
        return context.get_abstract_state(int(self._memory)).get_value()

    # --- the tick -----------------------------------------------------------------------------

    def _calc_reference(self, context, output):
        for candidate in (context.get_discrete_state(self._reference).get_value(),
                          self._fallback(context)):
            if candidate is not None and np.all(np.isfinite(candidate)):
                return output.SetFromVector(candidate)
        output.SetFromVector(REFERENCE.pack(stamp=context.get_time(), p=0.0, v=0.0, a=0.0,
                                            j=0.0, heading=0.0, heading_rate=0.0))

    def _fallback(self, context):
        """Never computed: the estimate at rest (None without a valid one)."""
        estimate = self._estimate.Eval(context)
        if estimate_is_valid(estimate):
            return rest_at_estimate(estimate, context.get_time())
        return None

    def _update(self, context, state):
        memory = state.get_mutable_abstract_state(int(self._memory)).get_value()
        now = context.get_time()
        if self._active.Eval(context)[0] < 0.5:
            memory.active = False
            state.get_mutable_discrete_state(int(self._reference)).SetFromVector(
                self._last.Eval(context))
            return self._set_status(state, 0.0, ChiReason.INACTIVE)
        estimate = self._estimate.Eval(context)
        valid = estimate_is_valid(estimate)
        if not memory.active:
            if not self._start(context, memory, estimate if valid else None, now):
                return self._set_status(state, 0.0, ChiReason.BAD_START)
        elif valid:
            self._follow_frame(memory, estimate)
        goal = self._goal.Eval(context)
        if goal is not None and not isinstance(goal, self._goal_type):
            raise TypeError(f"{type(self).__name__}: the goal must be a "
                            f"{self._goal_type.__name__} or None, got {type(goal).__name__}")
        estimate = estimate if valid else None
        with self.compute_timer.measure(now):
            refused = ChiReason.OK
            if not memory.active or goal != memory.goal:
                refused = self._begin(context, memory, goal, estimate)
                if refused == ChiReason.OK:
                    memory.goal = goal
                elif not memory.active:          # a refused first goal: hold where it starts
                    memory.goal = None
                    self._begin(context, memory, None, estimate)
            memory.active = True
            previous = memory.chi.copy()
            reason = self._step(context, memory, estimate)
            if not np.all(np.isfinite(memory.chi)):
                memory.chi, reason = previous, ChiReason.NOT_FINITE
                for field in ("v", "a", "j", "heading_rate"):
                    memory.chi[REFERENCE.slice(field)] = 0.0
            memory.chi[REFERENCE.slice("stamp")] = now + self.period
            state.get_mutable_discrete_state(int(self._reference)).SetFromVector(memory.chi)
            if refused != ChiReason.OK:
                reason = refused
            elif memory.goal is None and reason == ChiReason.OK:
                reason = ChiReason.NO_GOAL
        self._set_status(state, 1.0, reason)

    def _start(self, context, memory: ChiMemory, estimate, now: float) -> bool:
        last = self._last.Eval(context)
        if np.all(np.isfinite(last)):
            memory.chi = advance_reference(last, float(np.clip(
                now - REFERENCE.get(last, "stamp"), 0.0, 0.1)))
        elif estimate is not None:
            memory.chi = rest_at_estimate(estimate, now)
        else:
            return False
        memory.chi[REFERENCE.slice("stamp")] = now
        memory.frame_counter = STATE_ESTIMATE.get(estimate, "frame_counter") \
            if estimate is not None else np.nan
        return True

    def _follow_frame(self, memory: ChiMemory, estimate: np.ndarray) -> None:
        counter = STATE_ESTIMATE.get(estimate, "frame_counter")
        if np.isfinite(memory.frame_counter) and counter != memory.frame_counter:
            R_OldNew = rotation_matrix(STATE_ESTIMATE.get(estimate, "q_OldNew"))
            p_OldNew = STATE_ESTIMATE.get(estimate, "p_OldNew")
            memory.chi = reexpress_reference(memory.chi, R_OldNew, p_OldNew)
            self._reexpress(memory, R_OldNew, p_OldNew)
        memory.frame_counter = counter

    def _set_status(self, state, valid: float, reason: ChiReason) -> None:
        state.get_mutable_discrete_state(int(self._status)).SetFromVector(TRACKER_STATUS.pack(
            valid=valid, reason=reason, solver_status=0.0))
