"""The landing paper's mission state machine, L Sec. 6.4 and Fig. 9, with its reference generation
(L Sec. 6.3): Idle -> Taking Off -> Waypoint -> Follow -> Landing Phase 1 -> Landing Phase 2 ->
Landed, with the return to Waypoint when the target is lost and the return to Follow when the
landing is predicted to miss (beyond the paper, its future work, L Sec. 8; docs/landing.md).

Target loss as a tracker handles it: the target estimate (the target EKF, L(5)-(8)) is its
constant-velocity prediction with a covariance that grows while no measurement comes. The target
is *tracked* while seen (a fresh detection) or while the estimate is valid and its predicted
horizontal position is known within `lost_radius` at `sigma_k` standard deviations (k sigma_xy,
sigma_xy^2 = var_x + var_y); during a short loss the mission keeps pursuing the predicted
position and the detector searches around it. Only a target no longer tracked is lost (L's fixed
t_DetectionTimeOut only gates the first Follow). A lost target is still pursued (issue 23: the
paper's return to the waypoint left a car driving at 5.7 m/s behind for good): Follow flies on
along the target's last filtered motion (constant velocity, at Follow's height) until
`pursuit_time` after the last detection, and only then returns to the waypoint to search; a
detection meanwhile is followed again.

Predicted miss at touchdown: |e_xy| (the horizontal tracking error now) + k sigma_xy(t_blind), the
target's horizontal position uncertainty propagated over the blind end of the descent (from
`blind_height` above the target, where the pattern no longer fits the down camera's view, to
touchdown) with the constant-velocity model (var_p + var_v t^2 + q^2 t^3 / 3 per axis, q the EKF's
velocity noise density; the position-velocity cross-covariance is not in the estimate).

- Idle: disarmed, zero thrust. On the first valid state estimate: Taking Off.
- Taking Off: arm (rotors idle for `arm_time`), climb to `takeoff_height` above the start at
  `takeoff_velocity`. Then Waypoint.
- Waypoint: fly to and hover at the waypoint. On a detection (a valid target estimate whose last
  accepted measurement is younger than `detection_timeout`, and tracked): Follow.
- Follow: position and velocity references from the target (predicted, low-pass filtered), at the
  waypoint's height (climbing back to it at `climb_rate` after an abort). Target lost: the
  references go on along its last filtered motion; not seen for `pursuit_time`: Waypoint.
  Back at the waypoint's height with the horizontal position and velocity errors under
  `position_threshold`, `velocity_threshold` and k sigma_xy(t_go) under `miss_limit`: Phase 1.
- Landing Phase 1: as Follow, descending at `descending_p1`; target lost: Follow (climbing back,
  pursuing); k sigma_xy(t_go) over `miss_limit` for `uncertain_abort_time`: Follow (abort; a
  re-initialized target EKF is that uncertain for a tick or two, 0.5 m/s velocity std, and at
  5-6 m/s most of 40 aborts came with a predicted miss of 0.2-0.4 m a tick before). Height
  above the target under `landing_p2_offset`: Landing Phase 2 if the predicted miss is under
  `miss_limit`, else Follow.
- Landing Phase 2: descending at `descending_p2`; no timeout (the paper's cannot be cancelled;
  here only a miss the rangefinder sees, below). Height above the target under `landed_offset`:
  Landed (confirmed by the rangefinder).
  In both landing phases the horizontal reference leads the target by a_held t^2 / 2
  (`level_lead_time`, ramped in from `landing_p2_offset` down to `level_lead_height`, at most
  `max_level_lead`), a_held the horizontal acceleration the vehicle's tilt holds against the
  air (g tan(tilt) less its own acceleration, low-passed): levelled for the last
  metre (alight.systems.control.touchdown_level) the vehicle loses it and drifts back with the
  air by about that much (reference_generator.level_lead; docs/landing.md "Level touchdown
  lead").
- Landed: disarm.

Beyond the paper (its field tests end the flight by hand; a vehicle must not hover at the waypoint
until its battery dies):
- Waypoint for `search_timeout` without a detection (the first search, or after a loss):
  Returning: fly to `takeoff_height` above the take-off point (within `landed_offset`, slower
  than `home_speed`), then Landing Home: descend at `takeoff_velocity`
  to the ground, Landed when the estimate is within `home_touchdown` of the take-off height and
  slower than `home_touchdown` per s vertically. A detection while Returning resumes Follow;
  Landing Home is not cancelled.
- Touchdown confirmed by the downward rangefinder (`range`), the extra sensor L Sec. 8 names
  against unsuccessful landing attempts: with a fresh valid range (younger than `range_timeout`)
  Landed needs the estimated height above the target and the range both under `touchdown_range`
  and one of them under `landed_offset`; an estimate at the landed height over a range beyond
  `touchdown_range` is a vehicle beside the car (it disarmed 1.3 m above the road in a 5 m/s
  campaign, VIO): Follow, climbing back (reason MISSED_PLATFORM); so is, earlier, a range longer
  than the estimated height by `range_miss_margin` once the vehicle is below `blind_height` (the
  camera no longer sees the pattern there; found at the landed height only, the go-around began
  with the body below the platform's top, beside its corner, and the airframe struck the car).
  It climbs first: until it is `go_around_clearance` above the target the horizontal reference
  goes on at the velocity it had (the car re-acquired beside it is closed on only from above the
  platform: closing at once ran the legs into the platform's edge as the car pulled away).
  Without a fresh range (none fitted, out of range, tilted), the paper's rule on the estimate
  alone.

Every transition is counted and published with its time and reason on `mission_status`.
Positions are those of the state estimate's frame E, in which the target estimate is expressed.
"""
import dataclasses as dc
import enum
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import (RANGE, REFERENCE, STATE_ESTIMATE, TARGET_ESTIMATE,
                                     VectorLayout)
from alight.systems.mission.reference_generator import (filter_acceleration,
                                                      filter_held_acceleration,
                                                      filter_reference, level_lead)
from alight.systems.params import bounded
from alight.systems.rotations import all_finite, norm


@dc.dataclass
class LandingMissionParams:
    """Defaults: L Table 2, except the waypoint (the scenario's) and the timings of arming."""
    period: float = bounded(0.05, 0.005, 1.0, "s")              # 20 Hz (DESIGN.md)
    waypoint: list[float] = bounded([0.0, 0.0, 5.2], -1e4, 1e4, "m")
    takeoff_height: float = bounded(5.2, 0.5, 100.0, "m")       # z_TakeOffHeight
    takeoff_velocity: float = bounded(0.5, 0.05, 5.0, "m/s")    # z_dot_TakeOffVelocity
    cutoff_position: float = bounded(30.0, 0.01, 1000.0, "Hz")  # f_CutOffPosition
    cutoff_velocity: float = bounded(30.0, 0.01, 1000.0, "Hz")  # f_CutOffVelocity
    # The target's horizontal acceleration (a turning car's), from its filtered velocity, fed
    # to the reference (module text); 0: none, the paper's constant-velocity reference
    cutoff_acceleration: float = bounded(0.5, 0.0, 1000.0, "Hz")
    max_target_acceleration: float = bounded(3.0, 0.0, 30.0, "m/s^2")  # larger ones clipped
    # ... learned only while the EKF's horizontal velocity std is under this: its velocity
    # converging after a detection (3 -> 0.06 m/s std in 0.6 s) is not the car's acceleration
    acceleration_velocity_std: float = bounded(0.1, 0.001, 10.0, "m/s")
    # Following, once the target EKF has known the horizontal velocity within this std, a
    # velocity it no longer knows (a re-initialized EKF starts at zero velocity, 5 m/s std)
    # does not reach the reference: the filtered one goes on (at 8 m/s the reference's
    # velocity dropped to zero for a tick or two in the descent, the MPC braked, and the
    # vehicle hit the car 0.9 m behind its centre; 1 m/s let through a re-initialized EKF's
    # velocity still 4 m/s off). Until then (the first frames after a detection) the
    # converging velocity is fed as it comes.
    max_velocity_std: float = bounded(0.3, 0.001, 100.0, "m/s")
    t_prediction: float = bounded(0.1, 0.0, 5.0, "s")           # t_Prediction
    detection_timeout: float = bounded(0.5, 0.05, 60.0, "s")    # t_DetectionTimeOut (to Follow)
    sigma_k: float = bounded(3.0, 0.5, 10.0)                    # k of the k-sigma bounds below
    lost_radius: float = bounded(1.5, 0.05, 50.0, "m")          # k sigma_xy now: lost beyond
    miss_limit: float = bounded(0.6, 0.01, 10.0, "m")           # predicted miss: abort beyond
    blind_height: float = bounded(1.0, 0.0, 50.0, "m")          # the pattern unseen below
    target_velocity_noise: float = bounded(0.1, 0.0, 10.0, "m/s/sqrt(Hz)")  # EKF's, L Sec. 5.2.2
    climb_rate: float = bounded(1.3, 0.05, 10.0, "m/s")         # back to Follow's height
    position_threshold: float = bounded(0.8, 0.05, 20.0, "m")   # d_PositionThreshold
    velocity_threshold: float = bounded(0.8, 0.05, 20.0, "m/s")  # d_VelocityThreshold
    landing_p2_offset: float = bounded(2.5, 0.1, 50.0, "m")     # z_LandingP2Offset
    landed_offset: float = bounded(0.35, 0.0, 5.0, "m")         # z_SuccessfulLandingOffset
    descending_p1: float = bounded(1.3, 0.05, 10.0, "m/s")      # z_dot_DescendingP1
    descending_p2: float = bounded(1.8, 0.05, 10.0, "m/s")      # z_dot_DescendingP2
    takeoff_tolerance: float = bounded(0.3, 0.02, 5.0, "m")     # take-off height reached within
    start_delay: float = bounded(1.0, 0.0, 60.0, "s")           # settle before arming
    arm_time: float = bounded(0.5, 0.0, 10.0, "s")              # rotors idle before lift-off
    heading: float = bounded(0.0, -360.0, 360.0, "deg")         # psi_r (zero in the paper)
    search_timeout: float = bounded(30.0, 1.0, 3600.0, "s")     # at the waypoint, then home
    # a lost target pursued along its last motion until this long after the last detection,
    # then Waypoint (0: the paper's return as soon as it is lost)
    pursuit_time: float = bounded(3.0, 0.0, 60.0, "s")
    home_touchdown: float = bounded(0.1, 0.01, 1.0, "m")         # on the ground at home within
    # over home (Returning -> Landing Home) only this slow: on the managed stack the landoff
    # tracker lands where its reference stops, 0.47 m past home from 0.8 m/s (measured)
    home_speed: float = bounded(0.2, 0.01, 5.0, "m/s")
    # the rangefinder's confirmation of Landed (module text): both readings under this [m] (the
    # landed offset plus the range's lag and noise at 1.8 m/s); 0: the paper's rule alone
    touchdown_range: float = bounded(0.65, 0.0, 50.0, "m")
    # going around after MISSED_PLATFORM: the vehicle climbs this high above the target (by the
    # estimate) on the motion it had before it closes on the car again (module text); 0: at once
    go_around_clearance: float = bounded(0.6, 0.0, 50.0, "m")
    # below `blind_height` a range longer than the estimated height above the target by more
    # than this is the ground beside the car (the platform stands 1 m above it): go around
    # then, not only at the landed height (0: only there)
    range_miss_margin: float = bounded(0.5, 0.0, 50.0, "m")
    # Landing Phase 1 aborts on the target's uncertainty only once it has lasted this long (the
    # Phase 2 gate judges the predicted miss at once); 0: at the first uncertain tick
    uncertain_abort_time: float = bounded(0.3, 0.0, 10.0, "s")
    range_timeout: float = bounded(0.2, 0.0, 5.0, "s")           # an older range is not used
    # The level touchdown's drift led (module text): in the landing phases the horizontal
    # reference leads the target by a_held t^2 / 2, a_held the horizontal acceleration the
    # vehicle's tilt holds against the air (low-passed at `tilt_cutoff`), t this time (0: no
    # lead) ...
    level_lead_time: float = bounded(0.5, 0.0, 5.0, "s")
    # ... ramped in from `landing_p2_offset` to this height above the target (the
    # TouchdownLevelParams height, where the attitude command goes level), at most this long
    level_lead_height: float = bounded(1.0, 0.0, 50.0, "m")
    max_level_lead: float = bounded(0.4, 0.0, 5.0, "m")
    tilt_cutoff: float = bounded(1.0, 0.01, 100.0, "Hz")


def horizontal_sigma(target: np.ndarray, t_ahead: float, velocity_noise: float) -> float:
    """Std [m] of the target's horizontal position predicted `t_ahead` [s] past the estimate with
    the EKF's constant-velocity model, L(6)-(8): the square root of the sum over x, y of
    var_p + var_v t^2 + q^2 t^3 / 3 (q: `velocity_noise`, white-noise acceleration)."""
    var_p = TARGET_ESTIMATE.get(target, "var_p")[:2]
    var_v = TARGET_ESTIMATE.get(target, "var_v")[:2]
    return float(np.sqrt(np.sum(var_p + var_v * t_ahead ** 2
                                + velocity_noise ** 2 * t_ahead ** 3 / 3.0)))


def time_to_touchdown(height: float, p: LandingMissionParams) -> float:
    """Remaining descent time [s] from `height` above the target: Landing Phase 1 at
    `descending_p1` down to `landing_p2_offset`, then Phase 2 at `descending_p2` (L Table 2)."""
    phase_1 = max(height - p.landing_p2_offset, 0.0) / p.descending_p1
    phase_2 = max(min(height, p.landing_p2_offset) - p.landed_offset, 0.0) / p.descending_p2
    return phase_1 + phase_2


class Mode(enum.IntEnum):
    IDLE = 0
    TAKING_OFF = 1
    WAYPOINT = 2
    FOLLOW = 3
    LANDING_P1 = 4
    LANDING_P2 = 5
    LANDED = 6
    RETURNING = 7     # beyond the paper: to the take-off point after `search_timeout`
    LANDING_HOME = 8


class Reason(enum.IntEnum):
    NONE = 0
    ESTIMATE_VALID = 1        # Idle -> Taking Off
    TAKEOFF_HEIGHT = 2        # Taking Off -> Waypoint
    DETECTION = 3             # Waypoint -> Follow
    TARGET_LOST = 4           # Landing Phase 1 -> Follow: k sigma_xy > lost_radius; Follow ->
                              # Waypoint: lost and not seen for pursuit_time
    CAUGHT_UP = 5             # Follow -> Landing Phase 1
    BELOW_P2_OFFSET = 6       # Landing Phase 1 -> Landing Phase 2
    BELOW_LANDED_OFFSET = 7   # Landing Phase 2 -> Landed
    PREDICTED_MISS = 8        # Landing Phase 1 -> Follow: predicted miss over miss_limit
    SEARCH_TIMEOUT = 9        # Waypoint -> Returning: no detection for search_timeout
    OVER_HOME = 10            # Returning -> Landing Home
    ON_THE_GROUND = 11        # Landing Home -> Landed
    MISSED_PLATFORM = 12      # Landing Phase 2 -> Follow: at the landed height by the estimate,
                              # the rangefinder sees no platform under the vehicle


# Output `mission_status`: mode (Mode); reason (Reason) and time [s] of the last transition; the
# number of transitions so far; time of the first detection [s] (nan before); time of the target
# estimate's last accepted measurement [s]; estimated horizontal distance to the target [m],
# the target's horizontal position std now [m] and the predicted miss at touchdown [m] (nan while
# the target is not tracked).
MISSION_STATUS = VectorLayout("mission_status", [
    ("mode", 1), ("reason", 1), ("transition_time", 1), ("transitions", 1),
    ("first_detection", 1), ("last_detection", 1), ("e_xy", 1), ("sigma_xy", 1),
    ("predicted_miss", 1)])

# Discrete state: the status fields above, then the reference (with the time of the tick that
# computed it), the filtered target reference, the low-passed acceleration the tilt holds, the
# last estimated velocity (its rate, nan before), the start position, since when the predicted
# miss is uncertain, and whether the target EKF has known the velocity since Follow began.
_FOLLOWING = (Mode.FOLLOW, Mode.LANDING_P1, Mode.LANDING_P2)  # the reference on the target
_STATE = VectorLayout("landing_mission_state", [
    *MISSION_STATUS.fields, ("ref_stamp", 1), ("p_ref", 3), ("v_ref", 3), ("a_ref", 3),
    ("p_filtered", 3), ("a_held", 3), ("v_estimate", 3),
    ("v_filtered", 3), ("a_filtered", 3), ("start", 3), ("uncertain_since", 1),
    ("velocity_known", 1)])


class LandingMission(LeafSystem):
    """Inputs  `state_estimate` STATE_ESTIMATE; `target_estimate` TARGET_ESTIMATE; `range` RANGE
            (the vehicle's downward rangefinder; unconnected: the paper's touchdown rule)
    Outputs `reference` REFERENCE (position, velocity, heading) for the MPC; `arm` (2: arm request,
            thrust enable) for the arm gate; `mission_status` MISSION_STATUS
    """

    def __init__(self, params: LandingMissionParams):
        super().__init__()
        self._p = params
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._target = self.DeclareVectorInputPort("target_estimate", TARGET_ESTIMATE.size)
        self._range = self.DeclareVectorInputPort("range", RANGE.size)
        initial = np.zeros(_STATE.size)
        initial[_STATE.slice("first_detection")] = np.nan
        initial[_STATE.slice("last_detection")] = np.nan
        for name in ("e_xy", "sigma_xy", "predicted_miss", "uncertain_since", "v_estimate"):
            initial[_STATE.slice(name)] = np.nan
        self._xd = self.DeclareDiscreteState(initial)
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        state = {self.xd_ticket()}
        self.DeclareVectorOutputPort("reference", REFERENCE.size, self._calc_reference,
                                     prerequisites_of_calc=state)
        self.DeclareVectorOutputPort("arm", 2, self._calc_arm, prerequisites_of_calc=state)
        self.DeclareVectorOutputPort(
            "mission_status", MISSION_STATUS.size,
            lambda c, o: o.SetFromVector(self._x(c)[:MISSION_STATUS.size]),
            prerequisites_of_calc=state)

    def _x(self, context) -> np.ndarray:
        return context.get_discrete_state(self._xd).get_value()

    def _mode(self, context) -> Mode:
        return Mode(int(_STATE.get(self._x(context), "mode")))

    def _calc_reference(self, context, output):
        """The reference of the last tick, stamped with that tick's time: a controller ticking
        with the mission reads it one period later (Drake's simultaneous discrete updates) and
        moves it along its velocity from the stamp (stamped with the reading time instead, the
        reference trailed a 4.5 m/s car by 22 cm, docs/landing.md)."""
        x = self._x(context)
        output.SetFromVector(REFERENCE.pack(
            stamp=_STATE.get(x, "ref_stamp"), p=_STATE.get(x, "p_ref"), v=_STATE.get(x, "v_ref"),
            a=_STATE.get(x, "a_ref"), j=np.zeros(3), heading=np.radians(self._p.heading),
            heading_rate=0.0))

    def _calc_arm(self, context, output):
        mode = self._mode(context)
        airborne = mode not in (Mode.IDLE, Mode.LANDED)
        lift_off = context.get_time() >= _STATE.get(self._x(context), "transition_time") \
            + self._p.arm_time or mode != Mode.TAKING_OFF
        output.SetFromVector([float(airborne), float(airborne and lift_off)])

    def _usable(self, target: np.ndarray) -> bool:
        """A valid, finite target estimate that has had a measurement."""
        return bool(TARGET_ESTIMATE.get(target, "valid") > 0.5
                    and math.isfinite(TARGET_ESTIMATE.get(target, "last_measurement"))
                    and all_finite(target[TARGET_ESTIMATE.slice("p_WT")])
                    and all_finite(target[TARGET_ESTIMATE.slice("v_WT")]))

    def _detected(self, now: float, target: np.ndarray) -> bool:
        """A fresh detection: the last accepted measurement younger than t_DetectionTimeOut."""
        return self._usable(target) and \
            now - TARGET_ESTIMATE.get(target, "last_measurement") <= self._p.detection_timeout

    def _tracked(self, now: float, target: np.ndarray) -> bool:
        """Seen (a fresh detection), or predicted by the EKF through a loss with the horizontal
        position known within lost_radius at sigma_k standard deviations. (A fresh detection
        counts whatever the covariance: a re-initialized EKF's velocity is uncertain for a few
        frames, its position is not.)"""
        p = self._p
        return self._detected(now, target) or (
            self._usable(target)
            and p.sigma_k * horizontal_sigma(target, 0.0, 0.0) <= p.lost_radius)

    def _fresh_range(self, context, now: float) -> float | None:
        """The rangefinder's distance [m] if a valid one is younger than `range_timeout` (None:
        unconnected, stale, invalid or confirmation off)."""
        if self._p.touchdown_range <= 0.0 or not self._range.HasValue(context):
            return None
        reading = self._range.Eval(context)
        distance = float(RANGE.get(reading, "range"))
        fresh = now - RANGE.get(reading, "stamp") <= self._p.range_timeout
        return distance if RANGE.get(reading, "valid") > 0.5 and fresh and \
            math.isfinite(distance) else None

    def _touchdown(self, height: float, distance: float | None) -> Reason | None:
        """Landed (BELOW_LANDED_OFFSET), a miss (MISSED_PLATFORM) or neither yet (None), from
        the estimated height above the target and the rangefinder's distance (module text)."""
        p = self._p
        if distance is None:
            return Reason.BELOW_LANDED_OFFSET if height <= p.landed_offset else None
        if max(height, distance) <= p.touchdown_range and \
                min(height, distance) <= p.landed_offset:
            return Reason.BELOW_LANDED_OFFSET
        if height <= p.landed_offset:   # the estimate is down, the range sees no platform
            return Reason.MISSED_PLATFORM
        if 0.0 < p.range_miss_margin < distance - height and height <= p.blind_height:
            return Reason.MISSED_PLATFORM   # blind, over the ground beside the car
        return None

    def _update(self, context, discrete_state):
        p = self._p
        now = context.get_time()
        x = self._x(context).copy()
        estimate, target = self._estimate.Eval(context), self._target.Eval(context)
        p_B, v_B = STATE_ESTIMATE.get(estimate, "p_EB"), STATE_ESTIMATE.get(estimate, "v_EB")
        estimate_ok = STATE_ESTIMATE.get(estimate, "valid") > 0.5 and \
            all_finite(p_B) and all_finite(v_B)
        fresh, tracked = self._detected(now, target), self._tracked(now, target)
        p_T, v_T = TARGET_ESTIMATE.get(target, "p_WT"), TARGET_ESTIMATE.get(target, "v_WT")
        if fresh:
            x[_STATE.slice("last_detection")] = TARGET_ESTIMATE.get(target, "last_measurement")
            if np.isnan(_STATE.get(x, "first_detection")):
                x[_STATE.slice("first_detection")] = now
        mode = Mode(int(_STATE.get(x, "mode")))
        velocity_std = float(np.sqrt(np.max(TARGET_ESTIMATE.get(target, "var_v")[:2])))
        if not tracked:
            # No usable estimate now: continue on the last filtered target motion.
            v_T = _STATE.get(x, "v_filtered")
            p_T = _STATE.get(x, "p_filtered") + v_T * p.period - p.t_prediction * v_T
        elif mode in _FOLLOWING:
            if velocity_std <= p.max_velocity_std:
                x[_STATE.slice("velocity_known")] = 1.0
            elif _STATE.get(x, "velocity_known"):
                v_T = _STATE.get(x, "v_filtered")   # unknown again: the filtered one goes on
        # (lost: the last motion continues, its acceleration decays in the low pass)
        velocity_settled = not tracked or velocity_std <= p.acceleration_velocity_std
        height = p_B[2] - p_T[2]
        t_blind = time_to_touchdown(min(height, p.blind_height), p)
        sigma_go = horizontal_sigma(target, t_blind, p.target_velocity_noise) \
            if tracked else np.nan
        e_xy = norm(p_B[:2] - p_T[:2]) if tracked else np.nan
        x[_STATE.slice("e_xy")] = e_xy
        x[_STATE.slice("sigma_xy")] = horizontal_sigma(target, 0.0, 0.0) if tracked else np.nan
        x[_STATE.slice("predicted_miss")] = e_xy + p.sigma_k * sigma_go
        certain = bool(p.sigma_k * sigma_go <= p.miss_limit)   # False when not tracked (nan)
        if certain:
            x[_STATE.slice("uncertain_since")] = np.nan
        elif np.isnan(_STATE.get(x, "uncertain_since")):
            x[_STATE.slice("uncertain_since")] = now
        long_uncertain = not certain and \
            now - _STATE.get(x, "uncertain_since") >= p.uncertain_abort_time - 1e-9
        if estimate_ok:
            x[_STATE.slice("a_held")] = filter_held_acceleration(
                _STATE.get(x, "a_held"), _STATE.get(x, "v_estimate"), v_B,
                STATE_ESTIMATE.get(estimate, "q_EB"), p.tilt_cutoff, p.period)
            x[_STATE.slice("v_estimate")] = v_B
        reference_before = _STATE.get(x, "p_ref").copy(), _STATE.get(x, "v_ref").copy()

        def go(new_mode: Mode, reason: Reason):
            nonlocal mode
            mode = new_mode
            x[_STATE.slice("mode")] = new_mode
            x[_STATE.slice("reason")] = reason
            x[_STATE.slice("transition_time")] = now
            x[_STATE.slice("transitions")] += 1

        def set_reference(position, velocity, acceleration=(0.0, 0.0, 0.0)):
            x[_STATE.slice("ref_stamp")] = now
            x[_STATE.slice("p_ref")] = position
            x[_STATE.slice("v_ref")] = velocity
            x[_STATE.slice("a_ref")] = acceleration

        def follow_target(descent_rate: float):
            """L Fig. 8 reference: filtered predicted target horizontally; the altitude held
            (Follow; climbing back to the waypoint's height after an abort) or descending toward
            the target (landing phases). The vertical velocity is the height profile's own rate
            (0 held, the climb or the descent), not the target's: a target EKF that diverged
            vertically after a bad re-acquisition (its z velocity -4.6 m/s at 5 m/s, VIO
            campaign) made Follow's reference sink at a held height and flew the vehicle into
            the ground."""
            v_before = _STATE.get(x, "v_filtered")
            p_f, v_f = filter_reference(_STATE.get(x, "p_filtered"), v_before,
                                        p_T, v_T, p.t_prediction, p.cutoff_position,
                                        p.cutoff_velocity, p.period)
            a_f = filter_acceleration(_STATE.get(x, "a_filtered"), v_before, v_f,
                                      p.cutoff_acceleration, p.max_target_acceleration,
                                      p.period) if velocity_settled else np.zeros(3)
            x[_STATE.slice("p_filtered")], x[_STATE.slice("v_filtered")] = p_f, v_f
            x[_STATE.slice("a_filtered")] = a_f
            if descent_rate > 0.0:
                p_f = p_f + level_lead(_STATE.get(x, "a_held"), p.level_lead_time, height,
                                       p.landing_p2_offset, p.level_lead_height,
                                       p.max_level_lead)
            z_ref, ceiling = _STATE.get(x, "p_ref")[2], p.waypoint[2]
            if descent_rate > 0.0 or z_ref >= ceiling:
                z = max(z_ref - descent_rate * p.period, p_T[2] - 0.5)  # not through the plate
            else:   # climbing back to Follow's height after an abort
                z = min(z_ref + p.climb_rate * p.period, ceiling)
            set_reference([p_f[0], p_f[1], z], [v_f[0], v_f[1], (z - z_ref) / p.period],
                          [a_f[0], a_f[1], 0.0])

        def climb_clear():
            """Going around (MISSED_PLATFORM): below `go_around_clearance` above the target the
            horizontal reference moves on at its own velocity instead of closing on the car."""
            if Reason(int(_STATE.get(x, "reason"))) != Reason.MISSED_PLATFORM or \
                    height >= p.go_around_clearance:
                return
            p_before, v_before = reference_before
            x[_STATE.slice("p_ref")][:2] = p_before[:2] + v_before[:2] * p.period
            x[_STATE.slice("v_ref")][:2] = v_before[:2]
            x[_STATE.slice("a_ref")][:2] = 0.0

        def start_following():
            x[_STATE.slice("velocity_known")] = 0.0   # a new EKF's velocity converging: fed
            x[_STATE.slice("p_filtered")] = p_T + p.t_prediction * v_T
            x[_STATE.slice("v_filtered")] = v_T
            x[_STATE.slice("a_filtered")] = 0.0

        if not estimate_ok and mode != Mode.IDLE:
            # No odometry: hold the last reference (the controller reports the bad estimate and
            # the flight controller's failsafe takes over if commands stop).
            discrete_state.set_value(self._xd, x)
            return
        if mode == Mode.IDLE:
            if estimate_ok:
                set_reference(p_B, np.zeros(3))
                x[_STATE.slice("start")] = p_B
                if now >= p.start_delay:
                    go(Mode.TAKING_OFF, Reason.ESTIMATE_VALID)
        elif mode == Mode.TAKING_OFF:
            start = _STATE.get(x, "start")
            goal = start[2] + p.takeoff_height
            if now < _STATE.get(x, "transition_time") + p.arm_time:
                set_reference(start, np.zeros(3))
            else:
                z = min(_STATE.get(x, "p_ref")[2] + p.takeoff_velocity * p.period, goal)
                set_reference([start[0], start[1], z],
                              [0.0, 0.0, p.takeoff_velocity if z < goal else 0.0])
                if z >= goal and abs(p_B[2] - goal) < p.takeoff_tolerance:
                    go(Mode.WAYPOINT, Reason.TAKEOFF_HEIGHT)
        elif mode in (Mode.WAYPOINT, Mode.RETURNING):
            home = _STATE.get(x, "start") + [0.0, 0.0, p.takeoff_height]
            set_reference(p.waypoint if mode == Mode.WAYPOINT else home, np.zeros(3))
            if fresh:
                go(Mode.FOLLOW, Reason.DETECTION)
                start_following()
                follow_target(0.0)
            elif mode == Mode.WAYPOINT and now - _STATE.get(x, "transition_time") \
                    >= p.search_timeout:
                go(Mode.RETURNING, Reason.SEARCH_TIMEOUT)
                set_reference(home, np.zeros(3))
            elif mode == Mode.RETURNING and np.linalg.norm(p_B - home) <= p.landed_offset \
                    and np.linalg.norm(v_B) <= p.home_speed:
                go(Mode.LANDING_HOME, Reason.OVER_HOME)
        elif mode == Mode.LANDING_HOME:
            start = _STATE.get(x, "start")
            floor = start[2] - 0.5   # pressed on the ground, not through it
            z = max(_STATE.get(x, "p_ref")[2] - p.takeoff_velocity * p.period, floor)
            set_reference([start[0], start[1], z],
                          [0.0, 0.0, -p.takeoff_velocity if z > floor else 0.0])
            if p_B[2] - start[2] <= p.home_touchdown and abs(v_B[2]) <= p.home_touchdown:
                go(Mode.LANDED, Reason.ON_THE_GROUND)
        elif mode in (Mode.FOLLOW, Mode.LANDING_P1):
            unseen = now - _STATE.get(x, "last_detection")
            if not tracked and unseen > p.pursuit_time:
                # really lost: search from the waypoint (L Sec. 6.4)
                go(Mode.WAYPOINT, Reason.TARGET_LOST)
                set_reference(p.waypoint, np.zeros(3))
            elif not tracked:   # pursue its last filtered motion, at Follow's height
                if mode == Mode.LANDING_P1:
                    go(Mode.FOLLOW, Reason.TARGET_LOST)
                follow_target(0.0)
                climb_clear()
            elif mode == Mode.FOLLOW:
                follow_target(0.0)
                climb_clear()
                e_v = np.linalg.norm(v_B[:2] - v_T[:2])
                at_height = _STATE.get(x, "p_ref")[2] >= p.waypoint[2]
                if at_height and e_xy <= p.position_threshold and \
                        e_v <= p.velocity_threshold and certain:
                    go(Mode.LANDING_P1, Reason.CAUGHT_UP)
            else:
                follow_target(p.descending_p1)
                miss = _STATE.get(x, "predicted_miss")
                if long_uncertain or (height <= p.landing_p2_offset
                                      and not miss <= p.miss_limit):
                    go(Mode.FOLLOW, Reason.PREDICTED_MISS)   # abort before Phase 2 commits
                elif height <= p.landing_p2_offset:
                    go(Mode.LANDING_P2, Reason.BELOW_P2_OFFSET)
        elif mode == Mode.LANDING_P2:
            # no timeout: lost close to the target, L Sec. 6.4; only a miss seen by the
            # rangefinder climbs back to Follow's height
            touchdown = self._touchdown(height, self._fresh_range(context, now))
            if touchdown == Reason.MISSED_PLATFORM:
                go(Mode.FOLLOW, touchdown)
                follow_target(0.0)
                climb_clear()
            else:
                follow_target(p.descending_p2)
                if touchdown == Reason.BELOW_LANDED_OFFSET:
                    go(Mode.LANDED, touchdown)
        discrete_state.set_value(self._xd, x)
