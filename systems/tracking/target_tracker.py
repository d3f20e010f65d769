"""The landing paper's reference generator (L Sec. 6.3, Fig. 8) as a tracker of the managed stack
(M Sec. 4, 7.2), at 100 Hz: the target estimate predicted by t_prediction with its velocity, then
first-order low-pass filters on position and velocity (L Table 2 cut-offs), at a commanded height.

Horizontally the reference follows the filtered target (plus the goal's offset) as a critically
damped second-order system driven by a bounded acceleration: with o and o' its position and
velocity less the filtered target's, o' follows -o / `catch_up_time` (at most `catch_up_speed`
relative to the target) within catch_up_time / 4, with |o''| at most `catch_up_acceleration`,
output as the reference's acceleration. It starts from `last_reference` in position *and
velocity* (M Sec. 7.2: no jump), and its velocity stays continuous while the target EKF's settles
after a detection: the reference a vehicle hovering over a passing car gets is one it can fly (it
speeds up to the car, falls behind, then closes the gap), not a velocity step. So the controllers
that bound their error dynamics (the MPC force controller, M(48)-(51)) follow it too, and the
control manager's control-error watch does not take the catch-up for an emergency.

Once caught up (within `caught_up_distance` and `caught_up_speed` of the filtered target) the
reference is the L Fig. 8 filtered target itself plus the catch-up's own offset (o, o'), which
then evolves by the same law alone, undisturbed, and stays at zero: the target estimate's
position and velocity pass through as they do to the landing mission's reference. Before, the
law stayed on the reference's own position and velocity, and every jump of the target EKF's
velocity (up to 1 m/s in the last 2 m of a 5 m/s descent, with the pattern close to the camera)
drove it at its acceleration limit, ringing +-2.5 m/s^2 with the reference up to 1 m ahead of
the target estimate at the touchdown (the managed `linear_mpc`, which moves the reference on at
that acceleration over its 1 s horizon, hit the car 0.7-0.8 m off in 3 of 20 runs at 5 m/s). A
change of the goal's offset is taken into the offset (no jump); a target lost and found again
starts the chase again.

Vertically (`TargetGoal`) its speed relative to the target moves to the goal's with at most
`vertical_acceleration` (output as the reference's vertical acceleration), so a descent starts
without a velocity step either:
- `descent_rate` 0: the height where it started is held (L Sec. 6.4 Follow);
- `descent_rate` > 0 without `height`: descends at that rate (Landing Phase 1/2), never more than
  `press_depth` below the target (pressed onto the platform, not through it), with the vertical
  velocity the target's less the rate, as the landing mission's (L Sec. 6.4);
- `descent_rate` > 0 with `height`: goes at that rate to `height` above the target (braking onto
  it) and follows it.
A descent waits until the reference has caught up with the target (below): one requested while
the reference still chases it (Landing Phase 1 entered on the mission's 0.8 m / 0.8 m/s
thresholds at the end of a catch-up) holds the height until then.

A descent onto the platform (`descent_rate` > 0 without `height`) leads the target by the level
touchdown's drift, a_held t^2 / 2 (`level_lead_time`, ramped in from `level_lead_start` down to
`level_lead_height` above the target, at most `max_level_lead`; a_held the horizontal
acceleration the vehicle's tilt holds against the air, low-passed), as the landing mission's
reference does (reference_generator.level_lead).

Without a usable target estimate (not valid, not finite, or in an estimator frame other than the
current one or the one just left) the reference stops where it is and holds (TARGET_INVALID);
when the target returns it starts again from there. A target estimate one frame switch behind
is re-expressed with that switch; the filter states are re-expressed with chi.
"""
import dataclasses as dc
import enum

import numpy as np

from alight.models import model_path
from alight.systems.boundary import REFERENCE, STATE_ESTIMATE, TARGET_ESTIMATE
from alight.systems.mission.reference_generator import (filter_held_acceleration,
                                                      filter_reference, level_lead,
                                                      predict_target)
from alight.systems.params import bounded, load_params
from alight.systems.rotations import rotation_matrix
from alight.systems.estimation.frames import reexpress_point
from alight.systems.tracking.chi_tracker import ChiMemory, ChiReason, ChiTracker
from alight.systems.tracking.speed_tracker import clip_norm


class TargetReason(enum.IntEnum):
    """`tracker_status.reason`: ChiReason's 0-5, then the target tracker's own."""
    OK = 0
    INACTIVE = 1
    NO_GOAL = 2          # active without a goal: holds
    NOT_FINITE = 3
    BAD_START = 4
    BAD_GOAL = 5         # descent rate over `max_descent_rate`: ignored, holding
    TARGET_INVALID = 11  # no usable target estimate: holds
    DESCENDING = 12      # going down toward the platform or the goal's height


@dc.dataclass(frozen=True)
class TargetGoal:
    """descent_rate [m/s] >= 0 (0: hold the height); height [m] above the target or None (down
    to the platform); offset [m] x, y in E from the target. Raises ValueError when invalid."""
    descent_rate: float = 0.0
    height: float | None = None
    offset: tuple = (0.0, 0.0)

    def __post_init__(self):
        if not (np.isfinite(self.descent_rate) and self.descent_rate >= 0.0):
            raise ValueError(f"target goal: descent_rate {self.descent_rate} must be finite and "
                             f">= 0 m/s")
        if self.height is not None and not (np.isfinite(self.height) and self.descent_rate > 0):
            raise ValueError(f"target goal: height {self.height} must be finite, with a "
                             f"descent_rate > 0 to get there")
        offset = np.asarray(self.offset, dtype=float)
        if offset.shape != (2,) or not np.all(np.isfinite(offset)):
            raise ValueError(f"target goal: offset must be 2 finite numbers [x, y], got "
                             f"{self.offset!r}")
        object.__setattr__(self, "offset", (float(offset[0]), float(offset[1])))

    @staticmethod
    def follow() -> "TargetGoal":
        return TargetGoal()

    @staticmethod
    def descend(rate: float) -> "TargetGoal":
        return TargetGoal(descent_rate=float(rate))


@dc.dataclass
class TargetTrackerParams:
    """Defaults: L Table 2 (prediction, cut-offs) and L Sec. 6.4 (press depth)."""
    period: float = bounded(0.01, 0.001, 0.1, "s")                # 100 Hz
    t_prediction: float = bounded(0.1, 0.0, 5.0, "s")             # t_Prediction
    cutoff_position: float = bounded(30.0, 0.01, 1000.0, "Hz")    # f_CutOffPosition
    cutoff_velocity: float = bounded(30.0, 0.01, 1000.0, "Hz")    # f_CutOffVelocity
    press_depth: float = bounded(0.5, 0.0, 5.0, "m")              # below the target, at most
    catch_up_speed: float = bounded(2.0, 0.05, 20.0, "m/s")       # relative to the target
    catch_up_time: float = bounded(0.5, 0.01, 10.0, "s")          # offset time constant
    catch_up_acceleration: float = bounded(2.5, 0.1, 30.0, "m/s^2")  # |o''| at most
    vertical_acceleration: float = bounded(2.0, 0.1, 30.0, "m/s^2")  # on the vertical speed
    # The level touchdown's lead (as the landing mission's, reference_generator.level_lead): a
    # descent to the platform leads the target by a_held t^2 / 2 (t this time; 0: none) ...
    level_lead_time: float = bounded(0.5, 0.0, 5.0, "s")
    # ... ramped in from this height above the target (the mission's landing_p2_offset) ...
    level_lead_start: float = bounded(2.5, 0.0, 50.0, "m")
    # ... to this one (the level touchdown's), a_held low-passed at tilt_cutoff
    level_lead_height: float = bounded(1.0, 0.0, 50.0, "m")
    max_level_lead: float = bounded(0.4, 0.0, 5.0, "m")          # the lead's length at most
    tilt_cutoff: float = bounded(1.0, 0.01, 100.0, "Hz")
    max_descent_rate: float = bounded(5.0, 0.05, 20.0, "m/s")     # larger goals are refused
    # Caught up (module text): the reference within this of the filtered target (plus the
    # goal's offset and the lead) ...
    caught_up_distance: float = bounded(0.1, 0.0, 10.0, "m")
    # ... and moving within this of its velocity
    caught_up_speed: float = bounded(0.2, 0.0, 10.0, "m/s")


@dc.dataclass
class TargetMemory(ChiMemory):
    """The L Fig. 8 filter states (predicted target position, velocity, in E), the reference's
    vertical speed relative to the target, whether the filters must start again on the target,
    the frame counter before the last switch; once caught up, the catch-up's horizontal offset
    from the filtered target and its rate (NaN while chasing)."""
    p_filtered: np.ndarray = dc.field(default_factory=lambda: np.zeros(3))
    v_filtered: np.ndarray = dc.field(default_factory=lambda: np.zeros(3))
    vertical_speed: float = 0.0          # m/s, the reference's relative to the target
    a_held: np.ndarray = dc.field(default_factory=lambda: np.zeros(3))   # low-passed, in E
    v_estimate: np.ndarray = dc.field(default_factory=lambda: np.full(3, np.nan))  # last v_EB
    restart: bool = True
    old_frame_counter: float = np.nan
    offset: np.ndarray = dc.field(default_factory=lambda: np.full(2, np.nan))
    offset_rate: np.ndarray = dc.field(default_factory=lambda: np.zeros(2))

    @property
    def caught_up(self) -> bool:
        return bool(np.all(np.isfinite(self.offset)))


class TargetTracker(ChiTracker):
    """Inputs  as `Tracker`, with `goal` a TargetGoal (None: hold); `target_estimate`
            TARGET_ESTIMATE (in E; unconnected: no target)
    Outputs `reference` REFERENCE (chi of M(16) in E: position, velocity, the catch-up's
            acceleration; jerk zero; heading held; stamped one period ahead); `tracker_status`
            TRACKER_STATUS
            (reason: TargetReason)
    """

    def __init__(self, params: TargetTrackerParams):
        super().__init__(params.period, TargetMemory(), TargetGoal.follow())
        self.params = params
        self._target = self.DeclareVectorInputPort("target_estimate", TARGET_ESTIMATE.size)

    def _begin(self, context, memory: TargetMemory, goal, estimate) -> ChiReason:
        if goal is not None and goal.descent_rate > self.params.max_descent_rate:
            return ChiReason.BAD_GOAL
        if not memory.active:
            memory.restart = True
        elif memory.caught_up and memory.goal is not None and goal is not None:
            # the new offset is reached by the catch-up's law, not by a jump
            memory.offset = memory.offset - np.subtract(goal.offset, memory.goal.offset)
        return ChiReason.OK

    def _switch_frame(self, memory: TargetMemory, R_OldNew, p_OldNew) -> None:
        super()._switch_frame(memory, R_OldNew, p_OldNew)
        memory.p_filtered = reexpress_point(memory.p_filtered, R_OldNew, p_OldNew)
        memory.v_filtered = R_OldNew.T @ memory.v_filtered
        memory.a_held = R_OldNew.T @ memory.a_held
        memory.v_estimate = R_OldNew.T @ memory.v_estimate
        memory.offset = (R_OldNew.T @ [*memory.offset, 0.0])[:2]
        memory.offset_rate = (R_OldNew.T @ [*memory.offset_rate, 0.0])[:2]
        memory.old_frame_counter = memory.frame_counter

    def _step(self, context, memory: TargetMemory, estimate) -> TargetReason:
        target = self._target_in_frame(context, memory, estimate)
        chi, P = memory.chi, REFERENCE
        if memory.goal is None or target is None:
            memory.restart = True
            for field in ("v", "a", "j", "heading_rate"):
                chi[P.slice(field)] = 0.0
            return TargetReason.OK if target is not None else TargetReason.TARGET_INVALID
        p_T, v_T = target
        params = self.params
        lead = self._lead(memory, estimate, p_T)
        if memory.restart:   # on from chi: its position and velocity (M Sec. 7.2)
            memory.p_filtered = predict_target(p_T, v_T, params.t_prediction)
            memory.v_filtered = np.array(v_T, dtype=float)
            memory.vertical_speed = float(REFERENCE.get(chi, "v")[2] - v_T[2])
            memory.offset = np.full(2, np.nan)      # chasing again
        memory.p_filtered, memory.v_filtered = filter_reference(
            memory.p_filtered, memory.v_filtered, p_T, v_T, params.t_prediction,
            params.cutoff_position, params.cutoff_velocity, self.period)
        memory.restart = False
        p_xy, v_xy, a_xy = self._catch_up(memory, lead)
        z, v_z, a_z, descending = self._vertical(memory, memory.p_filtered[2],
                                                 memory.v_filtered[2])
        chi[P.slice("p")] = [*p_xy, z]
        chi[P.slice("v")] = [*v_xy, v_z]
        chi[P.slice("a")] = [*a_xy, a_z]
        for field in ("j", "heading_rate"):
            chi[P.slice(field)] = 0.0
        return TargetReason.DESCENDING if descending else TargetReason.OK

    def _catch_up(self, memory: TargetMemory,
                  lead: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One period of the catch-up's second-order law (module docstring) toward the filtered
        target plus the goal's offset and the lead: the reference's horizontal (position,
        velocity, acceleration). Chasing, the law moves chi, the last reference (its velocity
        continuous also while the target EKF's settles after a detection); caught up, it moves
        its own offset from the filtered target."""
        params, chi, dt = self.params, memory.chi, self.period
        # the filtered target one period on (the reference is stamped there; against the target
        # now it trailed a 5 m/s car by 5 cm), plus the goal's offset and the lead
        aim = memory.p_filtered[:2] + memory.v_filtered[:2] * dt + memory.goal.offset + lead
        v_aim = memory.v_filtered[:2]
        if memory.caught_up:
            offset, rate = memory.offset, memory.offset_rate
        else:
            offset = REFERENCE.get(chi, "p")[:2] - (aim - v_aim * dt)
            rate = REFERENCE.get(chi, "v")[:2] - v_aim
        wanted = -clip_norm((offset + rate * dt) / params.catch_up_time, params.catch_up_speed)
        acceleration = clip_norm((wanted - rate) / (params.catch_up_time / 4.0),
                                 params.catch_up_acceleration)
        rate = rate + acceleration * dt
        offset = offset + rate * dt
        if memory.caught_up or (np.linalg.norm(offset) <= params.caught_up_distance
                                and np.linalg.norm(rate) <= params.caught_up_speed):
            memory.offset, memory.offset_rate = offset, rate
        return aim + offset, v_aim + rate, acceleration

    def _lead(self, memory: TargetMemory, estimate, p_T: np.ndarray) -> np.ndarray:
        """The level touchdown's horizontal lead of a descent onto the platform (zero in Follow,
        toward a goal height or without an estimate), with the held acceleration's low pass
        stepped in `memory`."""
        params, goal = self.params, memory.goal
        if estimate is None:
            return np.zeros(2)
        v_B = STATE_ESTIMATE.get(estimate, "v_EB")
        memory.a_held = filter_held_acceleration(
            memory.a_held, memory.v_estimate, v_B, STATE_ESTIMATE.get(estimate, "q_EB"),
            params.tilt_cutoff, self.period)
        memory.v_estimate = np.array(v_B, dtype=float)
        if goal.descent_rate == 0.0 or goal.height is not None:
            return np.zeros(2)
        height = STATE_ESTIMATE.get(estimate, "p_EB")[2] - p_T[2]
        return level_lead(memory.a_held, params.level_lead_time, height, params.level_lead_start,
                          params.level_lead_height, params.max_level_lead)[:2]

    def _vertical(self, memory: TargetMemory, z_T: float,
                  v_z_T: float) -> tuple[float, float, float, bool]:
        """(height, vertical velocity, vertical acceleration, descending) of the reference after
        one period: its vertical speed relative to the target moves toward the goal's (0 held,
        -descent_rate, or braking onto the goal's height) by at most `vertical_acceleration`
        per second, a descent only once caught up; a descent stops `press_depth` below the
        target."""
        goal, dt = memory.goal, self.period
        z, speed = REFERENCE.get(memory.chi, "p")[2], memory.vertical_speed
        rate, brake = goal.descent_rate, self.params.vertical_acceleration
        if rate == 0.0:
            wanted = 0.0
        elif goal.height is None:
            wanted = -rate
        else:
            gap = z_T + goal.height - z
            # the speed from which steps shrinking by brake dt stop on the gap: v (v + a dt) / 2a
            stop = 0.5 * (np.sqrt((brake * dt) ** 2 + 8.0 * brake * abs(gap)) - brake * dt)
            wanted = float(np.sign(gap)) * min(rate, stop, abs(gap) / dt)
        if not memory.caught_up:
            wanted = max(wanted, 0.0)    # no descent while the reference still chases the target
        change = float(np.clip(wanted - speed, -brake * dt, brake * dt))
        memory.vertical_speed = speed + change
        z_new = z + memory.vertical_speed * dt
        floor = z_T - self.params.press_depth
        if rate > 0.0 and goal.height is None and z_new <= floor:   # pressed: stopped there
            z_new, change, memory.vertical_speed = floor, -speed, 0.0
        descending = (rate > 0.0 and goal.height is None) or memory.vertical_speed < 0.0
        return z_new, v_z_T + memory.vertical_speed, change / dt, descending

    def _target_in_frame(self, context, memory: TargetMemory, estimate):
        """(p_WT, v_WT) in the current estimator frame, or None when not usable."""
        if not self._target.HasValue(context):
            return None
        target = self._target.Eval(context)
        p_T, v_T = TARGET_ESTIMATE.get(target, "p_WT"), TARGET_ESTIMATE.get(target, "v_WT")
        if TARGET_ESTIMATE.get(target, "valid") < 0.5 or not (
                np.all(np.isfinite(p_T)) and np.all(np.isfinite(v_T))):
            return None
        counter = TARGET_ESTIMATE.get(target, "frame_counter")
        if not np.isfinite(memory.frame_counter) or counter == memory.frame_counter:
            return p_T, v_T
        if counter == memory.old_frame_counter and estimate is not None:
            R_OldNew = rotation_matrix(STATE_ESTIMATE.get(estimate, "q_OldNew"))
            return (reexpress_point(p_T, R_OldNew, STATE_ESTIMATE.get(estimate, "p_OldNew")),
                    R_OldNew.T @ v_T)
        return None


def load_target_tracker_params(filename: str = "target_tracker.yaml") -> TargetTrackerParams:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    return load_params(TargetTrackerParams, model_path(filename))


def make_target_tracker(params: TargetTrackerParams) -> TargetTracker:
    return TargetTracker(params)
