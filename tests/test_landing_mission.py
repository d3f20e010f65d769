"""The landing mission's state machine (L Sec. 6.4) and reference generation (L Sec. 6.3), driven by
scripted state and target estimates (no physics): transitions, thresholds, timeouts, disarm."""
import numpy as np
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import VectorLogSink

from alight.systems.boundary import RANGE, REFERENCE, STATE_ESTIMATE, TARGET_ESTIMATE
from alight.systems.mission.landing import (MISSION_STATUS, LandingMission, LandingMissionParams,
                                            Mode, Reason)
from alight.systems.mission.reference_generator import (filter_acceleration, filter_reference,
                                                       low_pass_gain)

PLATFORM_Z = 1.0


def HOVER(t):
    """A scripted vehicle: on the ground, then hovering at the waypoint whatever it is told."""
    return np.array([0.0, 0.0, 0.22 if t < 2.0 else 5.42]), np.zeros(3)


class Scripted(LeafSystem):
    """Estimates from functions of time: vehicle(t) -> p, v; target(t) -> p, v or None (unseen).
    The vehicle follows the mission's reference exactly (an ideal controller) when vehicle is None."""

    def __init__(self, target, vehicle=None):
        super().__init__()
        self._target, self._vehicle = target, vehicle
        self._reference = self.DeclareVectorInputPort("reference", REFERENCE.size)
        self.DeclareVectorOutputPort("state_estimate", STATE_ESTIMATE.size, self._estimate)
        self.DeclareVectorOutputPort("target_estimate", TARGET_ESTIMATE.size, self._target_estimate)
        self._last = None   # (time, p, v) of the last sighting

    def _estimate(self, context, output):
        t = context.get_time()
        if self._vehicle is not None:
            p, v = self._vehicle(t)
        else:
            reference = self._reference.Eval(context)
            p, v = REFERENCE.get(reference, "p"), REFERENCE.get(reference, "v")
            if t < 0.01:
                p = np.array([0.0, -6.0, 0.22])
        output.SetFromVector(STATE_ESTIMATE.vector(
            stamp=t, p_EB=p, v_EB=v, var_pv=np.full(6, 1e-4), var_heading=1e-4))

    def _target_estimate(self, context, output):
        """As the target EKF: unseen, the last seen motion predicted at constant velocity with
        its position variance grown as L(6)-(8) (q = 0.1 m/s/sqrt(Hz)); invalid before the
        first sighting."""
        t = context.get_time()
        seen = self._target(t)
        if seen is not None:
            self._last = (t, *seen)
        if self._last is None:
            p, v, last, dt = np.zeros(3), np.zeros(3), np.nan, 0.0
        else:
            last, p, v = self._last
            dt = t - last
            p = p + v * dt
        var_v = 1e-2 + 0.01 * dt
        output.SetFromVector(TARGET_ESTIMATE.pack(
            stamp=t, p_WT=p, q_WT=[1, 0, 0, 0], v_WT=v,
            var_p=np.full(3, 1e-3 + 1e-2 * dt ** 2 + 0.01 * dt ** 3 / 3.0),
            var_rot=np.full(3, 1e-3), var_v=np.full(3, var_v), last_measurement=last,
            valid=float(self._last is not None), keypoints=9.0 if seen is not None else 0.0,
            frame_counter=0.0))


class ScriptedRange(LeafSystem):
    """The downward rangefinder of the ideal vehicle (at the mission's reference): `reading(t, p)`
    -> (distance [m], valid, age [s]) with p the vehicle's position."""

    def __init__(self, reading):
        super().__init__()
        self._reading = reading
        self._reference = self.DeclareVectorInputPort("reference", REFERENCE.size)
        self.DeclareVectorOutputPort("range", RANGE.size, self._range)

    def _range(self, context, output):
        t = context.get_time()
        distance, valid, age = self._reading(t, REFERENCE.get(self._reference.Eval(context), "p"))
        output.SetFromVector(RANGE.pack(stamp=t - age, range=distance, var=4e-4,
                                        valid=float(valid)))


def fly(target, duration, vehicle=None, params=None, script=None, rangefinder=None):
    """The mission flown against `script` (default Scripted(target, vehicle)) for `duration` s,
    with the `rangefinder` reading of ScriptedRange if given (else `range` unconnected)."""
    params = params or LandingMissionParams()
    builder = DiagramBuilder()
    mission = builder.AddSystem(LandingMission(params))
    script = builder.AddSystem(script or Scripted(target, vehicle))
    builder.Connect(mission.GetOutputPort("reference"), script.GetInputPort("reference"))
    builder.Connect(script.GetOutputPort("state_estimate"), mission.GetInputPort("state_estimate"))
    builder.Connect(script.GetOutputPort("target_estimate"),
                    mission.GetInputPort("target_estimate"))
    if rangefinder is not None:
        ranged = builder.AddSystem(ScriptedRange(rangefinder))
        builder.Connect(mission.GetOutputPort("reference"), ranged.GetInputPort("reference"))
        builder.Connect(ranged.GetOutputPort("range"), mission.GetInputPort("range"))
    logs = {}
    for name, size in (("mission_status", MISSION_STATUS.size), ("reference", REFERENCE.size),
                       ("arm", 2)):
        logs[name] = builder.AddSystem(VectorLogSink(size, params.period))
        builder.Connect(mission.GetOutputPort(name), logs[name].get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    simulator.AdvanceTo(duration)
    context = simulator.get_context()
    return {name: (log.FindLog(context).sample_times(), log.FindLog(context).data().T)
            for name, log in logs.items()}


def transitions(logs):
    t, status = logs["mission_status"]
    count = status[:, MISSION_STATUS.slice("transitions")].ravel()
    changed = np.flatnonzero(np.diff(count)) + 1
    return [(float(t[i]), Mode(int(status[i, 0])), Reason(int(status[i, 1]))) for i in changed]


def moving_target(speed, appear=None, hide=()):
    """A platform moving along +y through the waypoint (0, 0) at `speed`, at y = 0 at t = 20 s;
    unseen before `appear` and within the `hide` windows."""
    def target(t):
        if (appear is not None and t < appear) or any(a <= t < b for a, b in hide):
            return None
        return np.array([0.0, speed * (t - 20.0), PLATFORM_Z]), np.array([0.0, speed, 0.0])
    return target


def test_ideal_vehicle_runs_every_mode_in_order_and_disarms():
    logs = fly(moving_target(2.0, appear=17.0), 40.0)
    modes = [m for _, m, _ in transitions(logs)]
    assert modes == [Mode.TAKING_OFF, Mode.WAYPOINT, Mode.FOLLOW, Mode.LANDING_P1,
                     Mode.LANDING_P2, Mode.LANDED]
    reasons = [r for _, _, r in transitions(logs)]
    assert reasons == [Reason.ESTIMATE_VALID, Reason.TAKEOFF_HEIGHT, Reason.DETECTION,
                       Reason.CAUGHT_UP, Reason.BELOW_P2_OFFSET, Reason.BELOW_LANDED_OFFSET]
    t, arm = logs["arm"]
    landed_at = transitions(logs)[-1][0]
    assert np.all(arm[t > landed_at + 0.1] == 0.0)          # Landed disarms
    assert np.all(arm[(t > 2.0) & (t < landed_at - 0.1), 0] == 1.0)
    # Take-off climbs at the take-off velocity (L Table 2: 0.5 m/s) to 5.2 m above the start.
    t_ref, reference = logs["reference"]
    z = reference[:, REFERENCE.slice("p")][:, 2]
    climbing = (t_ref > 3.0) & (t_ref < 10.0)
    assert np.diff(z[climbing]).mean() / 0.05 == pytest.approx(0.5, rel=0.05)
    assert z.max() == pytest.approx(0.22 + 5.2, abs=1e-6)


def lost_after() -> float:
    """Seconds unseen after which the scripted estimate's 3-sigma horizontal radius passes the
    default 1.5 m: 2 (1e-3 + 1e-2 dt^2 + 0.01 dt^3 / 3) = 0.5^2."""
    roots = np.roots([2 * 0.01 / 3, 2 * 1e-2, 0.0, 2 * 1e-3 - 0.25])
    return float(max(r.real for r in roots if abs(r.imag) < 1e-9))


def test_target_unseen_in_follow_is_lost_when_its_prediction_is_too_uncertain():
    """With `pursuit_time` 0 (the paper's return), the first tick at which 3 sigma_xy passes
    `lost_radius` sends the mission back to the waypoint."""
    # The vehicle (scripted) hovers at the waypoint: 3 m from the target, it stays in Follow.
    logs = fly(moving_target(1.0, appear=17.0, hide=[(18.02, 30.0)]), 25.0, vehicle=HOVER,
               params=LandingMissionParams(pursuit_time=0.0))
    events = transitions(logs)
    follow = [t for t, m, _ in events if m == Mode.FOLLOW][0]
    back = [(t, r) for t, m, r in events if m == Mode.WAYPOINT and t > follow]
    assert back and back[0][1] == Reason.TARGET_LOST
    seen = 18.0                                                  # the last tick it was seen
    # the next tick, logged one tick later
    assert seen + lost_after() <= back[0][0] <= seen + lost_after() + 0.1 + 1e-6
    assert all(m < Mode.LANDING_P1 for _, m, _ in events)


def test_a_lost_target_is_pursued_along_its_last_motion_then_searched_from_the_waypoint():
    """Lost (3 sigma_xy past lost_radius, about 2.5 s unseen here), Follow flies on along the
    target's last motion until `pursuit_time` (3 s) after the last detection, then returns to
    the waypoint; a car seen again during the pursuit is followed without a return."""
    assert lost_after() < LandingMissionParams().pursuit_time == 3.0
    logs = fly(moving_target(4.0, appear=17.0, hide=[(18.02, 40.0)]), 25.0, vehicle=HOVER)
    events = transitions(logs)
    back = [t for t, m, r in events if m == Mode.WAYPOINT and r == Reason.TARGET_LOST]
    seen = 18.0
    assert back and seen + 3.0 <= back[0] <= seen + 3.0 + 0.1 + 1e-6
    t, reference = logs["reference"]
    y = reference[:, REFERENCE.slice("p")][:, 1]
    v_y = reference[:, REFERENCE.slice("v")][:, 1]
    pursuing = (t > seen + lost_after() + 0.1) & (t < back[0])
    assert pursuing.sum() >= 5   # the ticks between the loss (2.5 s) and 3 s
    # on along the car's 4 m/s, ahead of where it was last seen (y = -8 m at 18 s)
    np.testing.assert_allclose(v_y[pursuing], 4.0, atol=0.05)
    assert np.all(np.diff(y[pursuing]) > 0.19) and np.all(y[pursuing] > -8.0 + 4.0 * 2.0)
    assert np.all(y[t > back[0] + 0.1] == 0.0)   # the waypoint
    # seen again 2.6 s after the loss: still Follow, no return to the waypoint
    again = transitions(fly(moving_target(4.0, appear=17.0, hide=[(18.02, 20.6)]), 25.0,
                            vehicle=HOVER))
    assert [m for _, m, _ in again] == [Mode.TAKING_OFF, Mode.WAYPOINT, Mode.FOLLOW]


class ReinitializedAt(Scripted):
    """As Scripted, but in [start, end) the target EKF reports what a re-initialization from a
    detection gives: the position seen, zero velocity with a 5 m/s std."""

    def __init__(self, target, start, end):
        super().__init__(target)
        self._window = (start, end)

    def _target_estimate(self, context, output):
        super()._target_estimate(context, output)
        if self._window[0] <= context.get_time() < self._window[1]:
            estimate = output.get_mutable_value()
            estimate[TARGET_ESTIMATE.slice("v_WT")] = 0.0
            estimate[TARGET_ESTIMATE.slice("var_v")] = 25.0


def test_a_re_initialized_target_velocity_does_not_stop_the_reference():
    """In Landing Phase 2 over a car at 6 m/s, the target EKF re-initializes for 0.1 s (zero
    velocity, 5 m/s std): the reference goes on at the filtered 6 m/s instead of dropping to
    zero (`max_velocity_std` 0.3 m/s), and the landing runs on as without it."""
    car = moving_target(6.0, appear=17.0)
    logs = fly(car, 25.0, script=ReinitializedAt(car, 18.8, 18.9))
    t, reference = logs["reference"]
    v_y = reference[:, REFERENCE.slice("v")][:, 1]
    window = (t >= 18.8) & (t < 19.0)
    assert window.sum() >= 4 and np.all(np.abs(v_y[window] - 6.0) < 0.05), v_y[window]
    assert [m for _, m, _ in transitions(logs)] == [m for _, m, _ in transitions(fly(car, 25.0))]
    assert transitions(logs)[-1][1] == Mode.LANDED
    # what it guards against: with the EKF's every velocity fed, the reference stops
    dropped = fly(car, 19.0, script=ReinitializedAt(car, 18.8, 18.9),
                  params=LandingMissionParams(max_velocity_std=100.0))["reference"]
    assert np.abs(dropped[1][(dropped[0] >= 18.85) & (dropped[0] < 18.9),
                             REFERENCE.slice("v")][:, 1]).max() < 1.0


def test_a_short_loss_in_phase_1_aborts_to_follow_not_to_the_waypoint_and_lands():
    """The ideal vehicle is in Landing Phase 1 at 17.1 s; unseen 17.3-19.0 s, the growing
    uncertainty aborts the descent (predicted miss over 0.6 m) to Follow, never to Waypoint."""
    events = transitions(fly(moving_target(2.0, appear=17.0, hide=[(17.3, 19.0)]), 40.0))
    assert [m for _, m, _ in events] == [Mode.TAKING_OFF, Mode.WAYPOINT, Mode.FOLLOW,
                                         Mode.LANDING_P1, Mode.FOLLOW, Mode.LANDING_P1,
                                         Mode.LANDING_P2, Mode.LANDED]
    abort = events[4]
    assert abort[2] == Reason.PREDICTED_MISS and 17.3 < abort[0] < 19.0


def test_detection_loss_in_landing_phase_2_does_not_cancel_the_landing():
    events = transitions(fly(moving_target(2.0, appear=17.0), 40.0))
    p2 = [t for t, m, _ in events if m == Mode.LANDING_P2][0]
    hidden = transitions(fly(moving_target(2.0, appear=17.0, hide=[(p2 + 0.1, 99.0)]), 40.0))
    assert [m for _, m, _ in hidden] == [m for _, m, _ in events]   # still Landed, no return
    assert hidden[-1][1] == Mode.LANDED


def test_a_target_diverging_vertically_does_not_move_the_height_reference():
    """Follow holds its height with a vertical reference velocity of 0 whatever the target EKF's
    vertical velocity says (a diverged EKF once said -4.6 m/s at a held height, and the MPC flew
    the vehicle into the ground); the descent's is the descent rate."""
    def sinking(t):
        seen = moving_target(2.0, appear=17.0)(t)
        return None if seen is None else (seen[0] + [0.0, 0.0, -4.6 * (t - 17.0)],
                                           seen[1] + [0.0, 0.0, -4.6])
    logs = fly(sinking, 21.0, vehicle=HOVER)
    t, reference = logs["reference"]
    following = t > [at for at, m, _ in transitions(logs) if m == Mode.FOLLOW][0] + 0.1
    assert following.sum() > 20
    np.testing.assert_array_equal(reference[following, REFERENCE.slice("v")][:, 2], 0.0)
    np.testing.assert_allclose(reference[following, REFERENCE.slice("p")][:, 2],
                               LandingMissionParams().waypoint[2])   # held
    events = transitions(fly(moving_target(2.0, appear=17.0), 40.0))
    p1, p2 = [at for at, m, _ in events if m in (Mode.LANDING_P1, Mode.LANDING_P2)]
    logs = fly(moving_target(2.0, appear=17.0), p2)
    t, reference = logs["reference"]
    descending = (t > p1 + 0.1) & (t < p2 - 0.1)
    np.testing.assert_allclose(reference[descending, REFERENCE.slice("v")][:, 2],
                               -LandingMissionParams().descending_p1)


def test_target_that_cannot_be_caught_never_triggers_a_landing_phase():
    # The vehicle (scripted) stays at the waypoint; the target crosses the view and leaves.
    in_view = lambda t: (moving_target(8.0)(t) if abs(8.0 * (t - 20.0)) < 4.0 else None)
    events = transitions(fly(in_view, 30.0, vehicle=HOVER))
    assert Mode.WAYPOINT in [m for _, m, _ in events]
    assert Mode.FOLLOW in [m for _, m, _ in events]
    assert all(m not in (Mode.LANDING_P1, Mode.LANDING_P2, Mode.LANDED) for _, m, _ in events)


def test_a_target_never_found_sends_the_vehicle_home_to_land_and_disarm():
    """No detection for `search_timeout` at the waypoint: back over the take-off point at the
    take-off height, down at the take-off velocity, Landed (disarmed) on the ground there."""
    params = LandingMissionParams(search_timeout=5.0)
    logs = fly(lambda t: None, 45.0, params=params)
    events = transitions(logs)
    assert [(m, r) for _, m, r in events] == [
        (Mode.TAKING_OFF, Reason.ESTIMATE_VALID), (Mode.WAYPOINT, Reason.TAKEOFF_HEIGHT),
        (Mode.RETURNING, Reason.SEARCH_TIMEOUT), (Mode.LANDING_HOME, Reason.OVER_HOME),
        (Mode.LANDED, Reason.ON_THE_GROUND)]
    times = {m: t for t, m, _ in events}
    assert times[Mode.RETURNING] - times[Mode.WAYPOINT] == pytest.approx(5.0, abs=0.051)
    t_ref, reference = logs["reference"]
    p_ref = reference[:, REFERENCE.slice("p")]
    home = np.array([0.0, -6.0, 0.22 + params.takeoff_height])   # the scripted start + 5.2 m
    returning = (t_ref > times[Mode.RETURNING] + 0.06) & (t_ref < times[Mode.LANDING_HOME])
    np.testing.assert_allclose(p_ref[returning], np.tile(home, (returning.sum(), 1)))
    descending = (t_ref > times[Mode.LANDING_HOME] + 0.5) & (t_ref < times[Mode.LANDED] - 2.0)
    assert np.all(p_ref[descending, :2] == home[:2])
    assert np.diff(p_ref[descending, 2]).mean() / params.period == pytest.approx(-0.5, rel=1e-6)
    t, arm = logs["arm"]
    assert np.all(arm[t > times[Mode.LANDED] + 0.06] == 0.0)
    assert np.all(arm[(t > 2.0) & (t < times[Mode.LANDED] - 0.06), 0] == 1.0)


def test_a_target_seen_while_returning_is_followed():
    """The vehicle (scripted) hovers 3 m from its take-off point, never back over it: a detection
    while Returning resumes Follow."""
    params = LandingMissionParams(search_timeout=5.0)
    away = lambda t: (np.array([0.0, 0.0, 0.22]) if t < 2.0 else np.array([3.0, 0.0, 5.42]),
                      np.zeros(3))
    quiet = transitions(fly(lambda t: None, 30.0, vehicle=away, params=params))
    assert [m for _, m, _ in quiet] == [Mode.TAKING_OFF, Mode.WAYPOINT, Mode.RETURNING]
    returning = quiet[-1][0]
    events = transitions(fly(moving_target(0.5, appear=returning + 1.0), 30.0, vehicle=away,
                             params=params))
    assert [(m, r) for _, m, r in events][2:] == [(Mode.RETURNING, Reason.SEARCH_TIMEOUT),
                                                 (Mode.FOLLOW, Reason.DETECTION)]
    assert events[3][0] == pytest.approx(returning + 1.0, abs=0.051)


def test_reference_generation_predicts_and_low_passes_the_target():
    p, v = filter_reference(np.zeros(3), np.zeros(3), np.array([1.0, 2.0, 1.0]),
                            np.array([0.0, 4.0, 0.0]), 0.1, 30.0, 30.0, 0.05)
    a = low_pass_gain(30.0, 0.05)
    np.testing.assert_allclose(p, a * np.array([1.0, 2.4, 1.0]))   # predicted 0.1 s ahead
    np.testing.assert_allclose(v, a * np.array([0.0, 4.0, 0.0]))
    assert low_pass_gain(1.0, 0.05) == pytest.approx(1 - np.exp(-2 * np.pi * 0.05))


def test_a_turning_target_s_acceleration_is_estimated_toward_the_centre_of_its_turn():
    """The MBZIRC car's tightest turn (10 m radius at 15 km/h: 1.74 m/s^2) sampled at the
    mission's 20 Hz with the target EKF's velocity noise: 3 s into the turn the filtered
    acceleration points to the centre within 12 degrees (the 0.5 Hz low pass lags 7.6) and has
    its size within 15 %; a velocity jump (a new track) is clipped; cutoff 0 is the paper's none."""
    rng = np.random.default_rng(0)
    radius, speed, period = 10.0, 15 / 3.6, 0.05
    rate = speed / radius
    a, v_before = np.zeros(3), np.array([speed, 0.0, 0.0])
    for k in range(1, 61):
        angle = rate * k * period
        v = speed * np.array([np.cos(angle), np.sin(angle), 0.0]) + rng.normal(0, 0.01, 3)
        a = filter_acceleration(a, v_before, v, 0.5, 3.0, period)
        v_before = v
    centre = np.array([-np.sin(angle), np.cos(angle)])
    assert np.degrees(np.arccos(a[:2] @ centre / np.linalg.norm(a[:2]))) < 12.0
    assert np.linalg.norm(a) == pytest.approx(speed * rate, rel=0.15)
    assert a[2] == 0.0
    jump = filter_acceleration(np.zeros(3), np.zeros(3), np.array([6.0, 0, 0]), 0.5, 3.0, period)
    assert np.linalg.norm(jump) == pytest.approx(3.0)
    np.testing.assert_array_equal(filter_acceleration(a, v_before, v + 1.0, 0.0, 3.0, period), 0.0)


def test_the_mission_s_reference_carries_a_turning_car_s_acceleration():
    """On the car circling at 15 km/h on 10 m (1.74 m/s^2 toward the centre), followed by the
    ideal vehicle and landed on 2.7 s after the detection: at the touchdown the reference's
    horizontal acceleration points to the centre within 12 degrees (measured 8) and has its size
    within 15 % (the 0.5 Hz low pass), and none vertically."""
    radius, speed = 10.0, 15 / 3.6
    rate = speed / radius
    angle = lambda t: rate * (t - 20.0)

    def circling(t):
        a = angle(t)
        return (np.array([radius * np.sin(a), radius * (1 - np.cos(a)), PLATFORM_Z]),
                speed * np.array([np.cos(a), np.sin(a), 0.0]))
    logs = fly(circling, 20.0)
    landed = [at for at, mode, _ in transitions(logs) if mode == Mode.LANDED][0]
    t, reference = logs["reference"]
    last = np.flatnonzero(t < landed)[-1]   # (the reference freezes once landed)
    acceleration = reference[last, REFERENCE.slice("a")]
    inward = np.array([-np.sin(angle(t[last])), np.cos(angle(t[last]))])
    assert np.degrees(np.arccos(acceleration[:2] @ inward / np.linalg.norm(acceleration[:2]))) \
        < 12.0
    assert np.linalg.norm(acceleration) == pytest.approx(speed * rate, rel=0.15)
    assert acceleration[2] == 0.0


class PeriodicReader(LeafSystem):
    """A controller's view of the reference: read at its own ticks (`period`, with the
    mission's) and moved along its velocity from its stamp to the tick, as the MPC does
    (LinearMpcParams.max_prediction); `rows` collects (tick, reference position now)."""

    def __init__(self, period: float):
        super().__init__()
        self._reference = self.DeclareVectorInputPort("reference", REFERENCE.size)
        self.rows = []
        self.DeclarePeriodicPublishEvent(period, 0.0, self._read)

    def _read(self, context):
        reference, t = self._reference.Eval(context), context.get_time()
        age = t - REFERENCE.get(reference, "stamp")
        self.rows.append((t, age, REFERENCE.get(reference, "p") + REFERENCE.get(reference, "v")
                          * age))


def test_a_controller_ticking_with_the_mission_sees_the_reference_on_the_moving_target():
    """Drake updates the mission and a controller of the same period together, so the
    controller reads the reference of the mission's previous tick: stamped with that tick, moved
    one period along its velocity it is on the 5 m/s target within 1 mm in Follow (the low pass
    at 30 Hz: a lag of v T (1 - a) / a = 0.02 mm; stamped with the reading time, 25 cm behind)."""
    params = LandingMissionParams(t_prediction=0.0)
    target = moving_target(5.0, appear=17.0)
    builder = DiagramBuilder()
    mission = builder.AddSystem(LandingMission(params))
    script = builder.AddSystem(Scripted(target, HOVER))
    reader = builder.AddSystem(PeriodicReader(params.period))
    builder.Connect(mission.GetOutputPort("reference"), script.GetInputPort("reference"))
    builder.Connect(mission.GetOutputPort("reference"), reader.GetInputPort("reference"))
    builder.Connect(script.GetOutputPort("state_estimate"), mission.GetInputPort("state_estimate"))
    builder.Connect(script.GetOutputPort("target_estimate"),
                    mission.GetInputPort("target_estimate"))
    Simulator(builder.Build()).AdvanceTo(19.0)
    following = [(t, age, p) for t, age, p in reader.rows if 17.5 <= t]
    assert following
    for t, age, p in following:
        assert age == pytest.approx(params.period, abs=1e-9)
        np.testing.assert_allclose(p[:2], target(t)[0][:2], atol=1e-3)


class TiltedScripted(Scripted):
    """Scripted (the ideal vehicle) rolled by `roll` [rad]: its thrust holds g tan(roll)
    sideways, as against the air over a moving car."""

    def __init__(self, target, roll: float):
        super().__init__(target)
        self._q = [np.cos(roll / 2), np.sin(roll / 2), 0.0, 0.0]

    def _estimate(self, context, output):
        super()._estimate(context, output)
        output.get_mutable_value()[STATE_ESTIMATE.slice("q_EB")] = self._q


def test_the_descending_reference_leads_the_target_by_the_level_touchdown_s_drift():
    """Rolled -10 deg (g tan 10 deg = 1.73 m/s^2 along the car's +y), the ideal vehicle's
    reference is on the 2 m/s car in Follow and, in Landing Phase 2 below `level_lead_height`,
    a_held t^2 / 2 = 21.6 cm ahead of it (t = `level_lead_time`, 0.5 s), half that halfway down
    the ramp from `landing_p2_offset`."""
    params = LandingMissionParams(t_prediction=0.0, level_lead_time=0.5)
    target = moving_target(2.0, appear=17.0)
    logs = fly(target, 40.0, params=params, script=TiltedScripted(target, np.radians(-10.0)))
    t, reference = logs["reference"]
    _, status = logs["mission_status"]
    mode = status[:, 0].astype(int)
    stamp = reference[:, REFERENCE.slice("stamp")].ravel()
    p_ref = reference[:, REFERENCE.slice("p")]
    ahead = p_ref[:, 1] - 2.0 * (stamp - 20.0)              # of the car at the stamp
    height = p_ref[:, 2] - PLATFORM_Z
    lead = 0.5 * 9.81 * np.tan(np.radians(10.0)) * 0.5 ** 2
    following = mode == Mode.FOLLOW
    assert following.any() and np.all(np.abs(ahead[following]) < 1e-3)
    low = (mode == Mode.LANDING_P2) & (height < params.level_lead_height - 0.1)
    assert low.any()
    np.testing.assert_allclose(ahead[low], lead, atol=2e-3)
    halfway = (params.landing_p2_offset + params.level_lead_height) / 2
    middle = np.argmin(np.abs(height - halfway) + 10.0 * (mode != Mode.LANDING_P2))
    assert ahead[middle] == pytest.approx(lead / 2, abs=0.02)


def test_nan_target_estimate_is_not_a_detection():
    nan_target = lambda t: (np.full(3, np.nan), np.zeros(3)) if t > 17.0 else None
    events = transitions(fly(nan_target, 22.0))
    assert all(m != Mode.FOLLOW for _, m, _ in events)
