"""The tracker role of the control manager, M Sec. 4 and 7.2, written once (as the MRS tracker
interface: activate with the last command, update, deactivate, switch the odometry source).

A tracker turns a goal into the full-state reference chi of M(16). The manager makes one tracker
active at a time (its `active` input) and only that one computes; an inactive one outputs the
manager's `last_reference`. At its first active tick a tracker starts from `last_reference` when
it is finite (M Sec. 7.2: the switch is imperceptible), else from the valid state estimate (with
neither it cannot start: BAD_START). When the state estimate's `frame_counter` changes (the
arbiter switched estimator frames, M Sec. 3.5), the tracker re-expresses its states in the new
frame before it computes.
"""
import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import REFERENCE, STATE_ESTIMATE, TRACKER_STATUS, estimate_is_valid
from alight.systems.estimation.frames import frame_switch
from alight.systems.state_copy import FieldwiseCopy
from alight.systems.timing import ComputeTimer

# `tracker_status.reason` codes every tracker shares (its own enum repeats them): the manager reads
# INACTIVE as "not computing"; BAD_START: active, but no finite last reference and no valid
# estimate to start from.
INACTIVE, BAD_START = 1, 4


@dc.dataclass
class TrackerMemory(FieldwiseCopy):
    """A tracker's abstract state: what the role keeps (active at the last tick; the frame counter
    of the estimator frame the states are in, NaN: none). Trackers extend it with their own.
    Copied field by field (`FieldwiseCopy`): Drake clones it twice per tick."""
    active: bool = dc.field(default=False, kw_only=True)
    frame_counter: float = dc.field(default=np.nan, kw_only=True)


def rest_at_estimate(estimate: np.ndarray, stamp: float) -> np.ndarray:
    """chi at rest at the estimated position and heading."""
    return REFERENCE.pack(stamp=stamp, p=STATE_ESTIMATE.get(estimate, "p_EB"), v=0.0, a=0.0,
                          j=0.0, heading=STATE_ESTIMATE.get(estimate, "heading"),
                          heading_rate=0.0)


def tracker_status(valid: float, reason: int, solver_status: float = 0.0) -> np.ndarray:
    return TRACKER_STATUS.pack(valid=valid, reason=reason, solver_status=solver_status)


class Tracker(LeafSystem):
    """The tracker contract of alight.systems.boundary (TRACKER_INPUTS, TRACKER_OUTPUTS).

    Inputs  `state_estimate` STATE_ESTIMATE; `goal` (abstract: the type of `goal_model`, or None:
            hold; another type raises TypeError at the first active tick); `active` (1: compute
            this tick); `last_reference` REFERENCE (the reference the manager issued last)
    Outputs `reference` REFERENCE (chi of M(16) in E; before the first computation the estimate
            at rest); `tracker_status` TRACKER_STATUS
    Updated every `period` with an unrestricted update: Drake applies those before the discrete
    updates of the manager and the controllers at the same tick, which read this tick's
    reference (at a frame switch, one already re-expressed). Active: `_activate` at the first
    active tick, `_switch_frame` when a valid estimate comes in a new frame, then `_update_active`.
    Subclasses implement `_activate` and `_update_active`, may time their computation with
    `compute_timer` (alight.systems.timing) and declare more ports.
    """

    def __init__(self, period: float, memory: TrackerMemory, goal_model):
        super().__init__()
        self.compute_timer = ComputeTimer()
        self.period, self._goal_type = period, type(goal_model)
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._goal = self.DeclareAbstractInputPort("goal", AbstractValue.Make(goal_model))
        self._active = self.DeclareVectorInputPort("active", 1)
        self._last = self.DeclareVectorInputPort("last_reference", REFERENCE.size)
        self._memory = self.DeclareAbstractState(AbstractValue.Make(memory))
        self._reference = self.DeclareDiscreteState(np.full(REFERENCE.size, np.nan))
        self._status = self.DeclareDiscreteState(tracker_status(0.0, INACTIVE))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._tick)
        # Not from `last_reference`: the control manager computes that from this output.
        self.DeclareVectorOutputPort(
            "reference", REFERENCE.size, self._calc_reference,
            {self.all_state_ticket(), self.input_port_ticket(self._estimate.get_index())})
        self.DeclareStateOutputPort("tracker_status", self._status)

    def memory(self, context) -> TrackerMemory:
        return context.get_abstract_state(int(self._memory)).get_value()

    # --- the role's hooks ---------------------------------------------------------------------

    def _activate(self, context, memory: TrackerMemory, last_reference, estimate) -> None:
        """The first active tick: start from `last_reference` (None when not finite) or, without
        one, from `estimate` (None when not valid; never both None)."""
        raise NotImplementedError

    def _update_active(self, context, memory: TrackerMemory, goal, estimate
                       ) -> tuple[np.ndarray, np.ndarray]:
        """This tick's (reference, status) toward `goal` (None: hold). `estimate` is None when
        it is not valid; `memory.active` is still False at the first active tick."""
        raise NotImplementedError

    def _switch_frame(self, memory: TrackerMemory, R_OldNew: np.ndarray,
                      p_OldNew: np.ndarray) -> None:
        """Re-expresses the states kept in the estimator frame in the new frame (M Sec. 3.5);
        `memory.frame_counter` is still the old frame's."""

    # --- the tick -----------------------------------------------------------------------------

    def _calc_reference(self, context, output):
        reference = context.get_discrete_state(self._reference).get_value()
        if np.all(np.isfinite(reference)):
            return output.SetFromVector(reference)
        estimate = self._estimate.Eval(context)       # never computed: the estimate at rest
        output.SetFromVector(rest_at_estimate(estimate, context.get_time())
                             if estimate_is_valid(estimate) else
                             REFERENCE.pack(stamp=context.get_time(), p=0.0, v=0.0, a=0.0, j=0.0,
                                            heading=0.0, heading_rate=0.0))

    def _tick(self, context, state):
        memory = state.get_mutable_abstract_state(int(self._memory)).get_value()
        if self._active.Eval(context)[0] < 0.5:
            memory.active = False
            return self._set(state, self._last.Eval(context), tracker_status(0.0, INACTIVE))
        estimate = self._estimate.Eval(context)
        estimate = estimate if estimate_is_valid(estimate) else None
        if not memory.active:
            last = self._last.Eval(context)
            last = last if np.all(np.isfinite(last)) else None
            if last is None and estimate is None:
                return self._set(state, None, tracker_status(0.0, BAD_START))
            self._activate(context, memory, last, estimate)
            memory.frame_counter = np.nan
        elif estimate is not None and (switch := frame_switch(estimate, memory.frame_counter)):
            self._switch_frame(memory, *switch)
        if estimate is not None:
            memory.frame_counter = STATE_ESTIMATE.get(estimate, "frame_counter")
        reference, status = self._update_active(context, memory, self._goal_value(context),
                                                estimate)
        memory.active = True
        self._set(state, reference, status)

    def _goal_value(self, context):
        goal = self._goal.Eval(context)
        if goal is not None and not isinstance(goal, self._goal_type):
            raise TypeError(f"{type(self).__name__}: the goal must be a "
                            f"{self._goal_type.__name__} or None, got {type(goal).__name__}")
        return goal

    def _set(self, state, reference, status: np.ndarray) -> None:
        """Writes this tick's reference (None: kept) and status."""
        if reference is not None:
            state.get_mutable_discrete_state(int(self._reference)).SetFromVector(reference)
        state.get_mutable_discrete_state(int(self._status)).SetFromVector(status)
