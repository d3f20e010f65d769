"""What the landoff tracker (M Sec. 4.2), the speed tracker (M Sec. 4.3) and the target tracker
(L Sec. 6.3) share: a tracker (alight.systems.tracking.tracker) around a virtual vehicle whose
state is the reference chi of M(16), advanced by one period at every tick (stamped one period
ahead, like the MPC tracker's).

On activation the virtual vehicle starts from `last_reference` (advanced from its stamp to the
tick, M Sec. 7.2: the switch is imperceptible) or, without a finite one, at rest at the state
estimate. When the estimate's `frame_counter` changes, chi and the subclass's stored points are
re-expressed in the new frame (M Sec. 3.5). A step that gives a non-finite chi keeps the previous
one (reason NOT_FINITE): no NaN leaves the tracker.
"""
import dataclasses as dc
import enum

import numpy as np

from alight.systems.boundary import ADMITTANCE_HOLD, REFERENCE
from alight.systems.control.force_controller import advance_reference
from alight.systems.estimation.frames import reexpress_point
from alight.systems.estimation.heading import wrap_angle
from alight.systems.rotations import heading
from alight.systems.tracking.tracker import (Tracker, TrackerMemory, rest_at_estimate,
                                             tracker_status)


class ChiReason(enum.IntEnum):
    """`tracker_status.reason` of the chi trackers (INACTIVE and BAD_START: tracker.py's)."""
    OK = 0            # following the goal, or holding it once reached
    INACTIVE = 1
    NO_GOAL = 2       # active without a goal: holds (speed: stops) where it started
    NOT_FINITE = 3    # the step gave a non-finite chi: the previous one is kept
    BAD_START = 4     # cannot start: no finite last reference and no valid estimate
    BAD_GOAL = 5      # a goal the parameters refuse (named in the docstrings): ignored, holding
    TAKING_OFF = 6
    ADMITTANCE = ADMITTANCE_HOLD  # the take-off reference is held: too far from the estimate
    LANDING = 8
    LANDED = 9        # touchdown detected (M(34)): disarm
    SATURATED = 10    # a speed goal clipped to the tracker's limits


@dc.dataclass
class ChiMemory(TrackerMemory):
    """Abstract state: chi of the virtual vehicle (REFERENCE, stamp = the time it is for), the
    goal being followed as received. Trackers extend it."""
    chi: np.ndarray = dc.field(default_factory=lambda: np.full(REFERENCE.size, np.nan))
    goal: object = None


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


class ChiTracker(Tracker):
    """Inputs  as `Tracker`: `state_estimate`, `goal` (the type of `goal_model`, or None),
            `active`, `last_reference`
    Outputs `reference` REFERENCE (chi of M(16) in E, stamped one period ahead);
            `tracker_status` TRACKER_STATUS (reason: ChiReason)
    Subclasses implement `_begin` (a new goal), `_step` (one period of the virtual vehicle) and,
    when they store points, extend `_switch_frame`; they may declare more ports. `compute_timer`
    records the wall-clock time of each active tick's goal and step (alight.systems.timing).
    """

    # --- subclass interface -------------------------------------------------------------------

    def _begin(self, context, memory: ChiMemory, goal, estimate) -> ChiReason:
        """Takes up `goal` (a new one, or None), from memory.chi; returns OK or BAD_GOAL."""
        raise NotImplementedError

    def _step(self, context, memory: ChiMemory, estimate) -> ChiReason:
        """Advances memory.chi by one period toward memory.goal. `estimate` is None when it is
        not valid."""
        raise NotImplementedError

    # --- the role's hooks (alight.systems.tracking.tracker) -----------------------------------

    def _activate(self, context, memory: ChiMemory, last_reference, estimate) -> None:
        """chi from `last_reference` advanced from its stamp to now (at most 0.1 s), else at rest
        at the estimate."""
        now = context.get_time()
        if last_reference is not None:
            memory.chi = advance_reference(last_reference, float(np.clip(
                now - REFERENCE.get(last_reference, "stamp"), 0.0, 0.1)))
        else:
            memory.chi = rest_at_estimate(estimate, now)
        memory.chi[REFERENCE.slice("stamp")] = now

    def _switch_frame(self, memory: ChiMemory, R_OldNew, p_OldNew) -> None:
        memory.chi = reexpress_reference(memory.chi, R_OldNew, p_OldNew)

    def _update_active(self, context, memory: ChiMemory, goal, estimate):
        now = context.get_time()
        with self.compute_timer.measure(now):
            refused = ChiReason.OK
            if not memory.active or goal != memory.goal:
                refused = self._begin(context, memory, goal, estimate)
                if refused == ChiReason.OK:
                    memory.goal = goal
                elif not memory.active:          # a refused first goal: hold where it starts
                    memory.goal = None
                    self._begin(context, memory, None, estimate)
            previous = memory.chi.copy()
            reason = self._step(context, memory, estimate)
            if not np.all(np.isfinite(memory.chi)):
                memory.chi, reason = previous, ChiReason.NOT_FINITE
                for field in ("v", "a", "j", "heading_rate"):
                    memory.chi[REFERENCE.slice(field)] = 0.0
            memory.chi[REFERENCE.slice("stamp")] = now + self.period
            if refused != ChiReason.OK:
                reason = refused
            elif memory.goal is None and reason == ChiReason.OK:
                reason = ChiReason.NO_GOAL
        return memory.chi.copy(), tracker_status(1.0, reason)
