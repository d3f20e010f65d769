"""The target tracker (the L Sec. 6.3 reference generator as a tracker, issue 11) alone on its own
context: the L Fig. 8 lag behind a constant-velocity target, the start from last_reference and
the catch-up, the landing descents, holding on an invalid target estimate, estimator frame
switches, bad goals and parameters."""
import dataclasses as dc

import numpy as np
import pytest

from alight.diagrams.onboard.control_manager import load_control_manager_config
from alight.systems.boundary import REFERENCE, STATE_ESTIMATE, TARGET_ESTIMATE, TRACKER_STATUS
from alight.systems.mission.reference_generator import low_pass_gain
from alight.systems.params import ConfigError, load_params
from alight.systems.rotations import heading_quaternion
from alight.systems.tracking.target_tracker import (TargetGoal, TargetReason,
                                                    TargetTrackerParams,
                                                    load_target_tracker_params,
                                                    make_target_tracker)
from test_landoff_speed_trackers import PERIOD, Bench, estimate

PARAMS = load_target_tracker_params()
HEIGHT = 5.2      # m, the waypoint's (L Table 2 take-off height)
V_T = np.array([2.0, 1.0, 0.0])   # m/s, the target's constant velocity


def target(p, v=(0.0, 0.0, 0.0), valid=1.0, frame_counter=0.0):
    return TARGET_ESTIMATE.pack(
        stamp=0.0, p_WT=p, q_WT=[1.0, 0.0, 0.0, 0.0], v_WT=v, var_p=0.01, var_rot=0.01,
        var_v=0.01, last_measurement=0.0, valid=valid, keypoints=20, frame_counter=frame_counter)


def rest(p, stamp=0.0):
    return REFERENCE.pack(stamp=stamp, p=p, v=0.0, a=0.0, j=0.0, heading=0.0, heading_rate=0.0)


def bench(goal, p_T, v_T=(0.0, 0.0, 0.0), start=(0.0, 0.0, HEIGHT), params=PARAMS):
    """The tracker hovering at `start` (its last reference and the estimate), the target at
    `p_T` moving at `v_T`."""
    b = Bench(make_target_tracker(params), goal, p=start, last=rest(start))
    b.set("target_estimate", target(p_T, v_T))
    return b


def moving_target(p0, v):
    """`each` of Bench.run: the target estimate at the next tick's time, at constant `v`."""
    def each(b, _):
        b.set("target_estimate", target(np.add(p0, v * b.ticks * PERIOD), v))
    return each


def reason(b) -> TargetReason:
    return TargetReason(int(TRACKER_STATUS.get(
        b.dut.GetOutputPort("tracker_status").Eval(b.context), "reason")))


def test_follows_a_constant_velocity_target_with_the_l_6_3_lag():
    """L Fig. 8: the target predicted by t_prediction, then the first-order low pass
    y_k = y_k-1 + a (u_k - y_k-1): a ramp u_k lags by v T (1 - a) / a, so the reference leads
    the target by v (t_pred - T (1 - a) / a) at the reference's stamp, one period after the
    tick (the target of the tick itself trailed a 5 m/s car by 5 cm)."""
    p0 = np.array([3.0, -2.0, 1.0])
    b = bench(TargetGoal.follow(), p0, V_T)
    rows = b.run(6.0, each=moving_target(p0, V_T))
    t_last = (len(rows) - 1) * PERIOD                       # the tick of the last reference
    a = low_pass_gain(PARAMS.cutoff_position, PERIOD)
    lead = V_T * (PARAMS.t_prediction - PERIOD * (1 - a) / a)   # 0.198 m at 2 m/s
    p_ref = REFERENCE.get(rows[-1], "p")
    p_stamp = p0 + V_T * (t_last + PERIOD)                  # the target at the stamp
    np.testing.assert_allclose(p_ref[:2], (p_stamp + lead)[:2], atol=1e-3)
    np.testing.assert_allclose(REFERENCE.get(rows[-1], "v")[:2], V_T[:2], atol=1e-3)
    assert p_ref[2] == pytest.approx(HEIGHT)                 # Follow holds the height
    assert REFERENCE.get(rows[-1], "stamp") == pytest.approx(t_last + PERIOD)
    assert reason(b) == TargetReason.OK


def test_starts_from_last_reference_and_catches_up_within_its_speed_and_acceleration():
    """Activation (M Sec. 7.2): the first reference is the last one moved by at most one
    catch-up step, at the last one's velocity (a hover: at rest, not the target's velocity); the
    reference then speeds up to the target with at most catch_up_acceleration, output as its
    acceleration, and the gap closes at most at catch_up_speed relative to the target."""
    start = np.array([0.0, 0.0, HEIGHT])
    p0 = np.array([4.0, 3.0, 1.0])             # 5 m ahead, as when first detected (4.5 m)
    b = bench(TargetGoal.follow(), p0, V_T, start)
    rows = b.run(6.0, each=moving_target(p0, V_T))
    p = rows[:, REFERENCE.slice("p")]
    assert np.linalg.norm(p[0] - start) <= PARAMS.catch_up_speed * PERIOD + 1e-9
    t = np.arange(len(rows)) * PERIOD
    gap = np.linalg.norm((p0 + np.outer(t, V_T) - p)[:, :2], axis=1)
    closing = -np.diff(gap) / PERIOD
    assert closing.max() <= PARAMS.catch_up_speed + 0.05
    assert gap[int(1.0 / PERIOD)] > 2.5                       # no step: still far after 1 s
    assert gap[-1] < 0.25                                     # caught up: only the L lead left
    v = rows[:, REFERENCE.slice("v")]
    np.testing.assert_allclose(np.diff(p, axis=0)[10:], v[11:] * PERIOD, atol=2e-3)  # chi
    assert np.linalg.norm(v[0]) <= PARAMS.catch_up_acceleration * PERIOD + 1e-9  # no step
    a = rows[:, REFERENCE.slice("a")]
    np.testing.assert_allclose(np.diff(v, axis=0), a[1:] * PERIOD, atol=1e-12)
    assert np.linalg.norm(a, axis=1).max() <= PARAMS.catch_up_acceleration + 1e-9
    assert np.linalg.norm(a[1:int(0.5 / PERIOD)], axis=1).min() > 0.9 * \
        PARAMS.catch_up_acceleration                          # speeding up to the target
    np.testing.assert_allclose(v[-1, :2], V_T[:2], atol=0.02)


def test_landing_descents_stop_below_the_target_and_the_height_goal_is_held():
    """Landing phases (L Sec. 6.4): down at the rate, reached from the hover with at most
    vertical_acceleration (output as the reference's), the vertical velocity the target's less
    it, never more than press_depth below the target; a height goal is reached and held."""
    p_T = np.array([0.0, 0.0, 1.0])
    b = bench(TargetGoal.descend(1.3), p_T)
    rows = b.run(1.0)
    z, v_z = rows[:, REFERENCE.slice("p")][:, 2], rows[:, REFERENCE.slice("v")][:, 2]
    a_z = rows[:, REFERENCE.slice("a")][:, 2]
    ramp = 1.3 / PARAMS.vertical_acceleration                     # 0.65 s from the hover
    assert np.abs(np.diff(v_z)).max() <= PARAMS.vertical_acceleration * PERIOD + 1e-9
    np.testing.assert_allclose(np.diff(v_z), a_z[1:] * PERIOD, atol=1e-12)
    np.testing.assert_allclose(np.diff(z), v_z[1:] * PERIOD, atol=1e-12)
    np.testing.assert_allclose(np.diff(z)[int(ramp / PERIOD) + 1:], -1.3 * PERIOD, atol=1e-9)
    assert REFERENCE.get(rows[-1], "v")[2] == pytest.approx(-1.3)
    assert reason(b) == TargetReason.DESCENDING
    rows = b.run(4.0)
    assert REFERENCE.get(rows[-1], "p")[2] == pytest.approx(p_T[2] - PARAMS.press_depth)
    b.set("goal", TargetGoal(descent_rate=1.0, height=2.0))       # back up to 2 m above it
    rows = b.run(4.0)
    z = rows[:, REFERENCE.slice("p")][:, 2]
    assert np.diff(z).max() <= 1.0 * PERIOD + 1e-9
    assert z.max() <= p_T[2] + 2.0 + 1e-9     # braked onto it, not over
    assert z[-1] == pytest.approx(p_T[2] + 2.0)
    assert REFERENCE.get(rows[-1], "v")[2] == pytest.approx(0.0)
    assert reason(b) == TargetReason.OK


def test_holds_on_an_invalid_target_estimate_and_resumes_without_a_jump():
    p_T = np.array([5.0, 0.0, 1.0])
    b = bench(TargetGoal.descend(1.3), p_T)
    b.run(0.5)                                           # catching up, descending
    b.set("target_estimate", target(p_T, valid=0.0))
    rows = b.run(1.0)
    assert reason(b) == TargetReason.TARGET_INVALID
    assert TRACKER_STATUS.get(b.dut.GetOutputPort("tracker_status").Eval(b.context),
                              "valid") == 1.0          # a usable reference: holding
    p = rows[:, REFERENCE.slice("p")]
    np.testing.assert_allclose(p, np.tile(p[0], (len(p), 1)), atol=1e-12)
    np.testing.assert_allclose(rows[:, REFERENCE.slice("v")], 0.0)
    b.set("target_estimate", target(p_T + [0.0, 3.0, 0.0]))   # back, elsewhere
    again = b.run(0.1)
    assert np.linalg.norm(REFERENCE.get(again[0], "p")[:2] - p[-1, :2]) <= \
        PARAMS.catch_up_speed * PERIOD + 1e-9
    assert reason(b) == TargetReason.DESCENDING
    for bad in (target([np.nan, 0.0, 0.0]), target(p_T, v=[0.0, np.inf, 0.0])):
        b.set("target_estimate", bad)
        assert np.all(np.isfinite(b.run(0.05)))
        assert reason(b) == TargetReason.TARGET_INVALID


def test_estimator_frame_switch_reexpresses_the_reference_and_a_late_target_estimate():
    """M Sec. 3.5: at a switch (X_OldNew: 4 m, 30 deg) the reference is the same point in the
    new frame, also while the target estimate is still in the old one; a target estimate in an
    unknown frame is not used."""
    p_T = np.array([2.0, 1.0, 1.0])
    b = bench(TargetGoal.follow(), p_T)
    old = b.run(6.0)[-1]                               # caught up (to 2e-5 m)
    yaw, p_OldNew = np.radians(30.0), np.array([4.0, -1.0, 0.5])
    q = heading_quaternion(yaw)
    b.set("state_estimate", estimate([0.0, 0.0, HEIGHT], frame_counter=1.0, p_OldNew=p_OldNew,
                                     q_OldNew=q))
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0],
                  [0.0, 0.0, 1.0]])
    expected = R.T @ (REFERENCE.get(old, "p") - p_OldNew)
    rows = b.run(0.5)                                   # target estimate still in frame 0
    assert reason(b) == TargetReason.OK
    np.testing.assert_allclose(rows[:, REFERENCE.slice("p")], np.tile(expected, (50, 1)),
                               atol=1e-4)
    b.set("target_estimate", target(R.T @ (p_T - p_OldNew), frame_counter=1.0))
    np.testing.assert_allclose(REFERENCE.get(b.run(0.5)[-1], "p"), expected, atol=1e-4)
    b.set("target_estimate", target(p_T, frame_counter=7.0))
    b.run(0.05)
    assert reason(b) == TargetReason.TARGET_INVALID


def test_bad_goals_and_parameters_are_refused(tmp_path):
    with pytest.raises(ValueError, match="descent_rate"):
        TargetGoal(descent_rate=-1.0)
    with pytest.raises(ValueError, match="height"):
        TargetGoal(height=2.0)                               # no rate to get there
    with pytest.raises(ValueError, match="offset"):
        TargetGoal(offset=(np.nan, 0.0))
    b = bench(TargetGoal(descent_rate=PARAMS.max_descent_rate + 1.0), [0.0, 0.0, 1.0])
    b.run(0.1)
    assert reason(b) == TargetReason.BAD_GOAL
    assert REFERENCE.get(b.reference(), "p")[2] == pytest.approx(HEIGHT)   # held
    b.set("goal", "land")
    with pytest.raises(TypeError, match="TargetGoal"):
        b.run(0.01)
    bad = tmp_path / "bad.yaml"
    bad.write_text("t_prediction: -0.1\n")
    with pytest.raises(ConfigError, match="t_prediction"):
        load_params(TargetTrackerParams, bad)
    config = load_control_manager_config()
    assert {e.name: e.goal_kind for e in config.trackers}["target"] == "target"


def test_offset_goal_follows_beside_the_target_without_a_jump_at_the_change():
    p_T = np.array([1.0, 1.0, 1.0])
    b = bench(TargetGoal.follow(), p_T, start=(1.0, 1.0, HEIGHT))
    before = b.run(1.0)[-1]
    b.set("goal", dc.replace(TargetGoal.follow(), offset=(0.0, 1.5)))
    rows = b.run(4.0)
    assert np.linalg.norm(REFERENCE.get(rows[0], "p") - REFERENCE.get(before, "p")) <= \
        PARAMS.catch_up_speed * PERIOD + 1e-9
    np.testing.assert_allclose(REFERENCE.get(rows[-1], "p")[:2], p_T[:2] + [0.0, 1.5],
                               atol=1e-3)


@pytest.mark.parametrize("goal, lead", [(TargetGoal.descend(1.8), True),
                                        (TargetGoal.follow(), False)])
def test_a_descent_onto_the_platform_leads_the_target_by_the_level_touchdown_s_drift(goal, lead):
    """Rolled -10 deg (its thrust holds g tan 10 deg = 1.73 m/s^2 along +y, as against the air
    over a moving car) 0.5 m above the platform, under `level_lead_height`: descending onto it,
    the reference settles a_held t^2 / 2 = 21.6 cm ahead (t = `level_lead_time` 0.5 s); following,
    on it."""
    p_T = np.array([0.0, 0.0, 1.0])
    b = bench(goal, p_T, start=(0.0, 0.0, 1.5))
    roll = np.radians(-10.0)
    b.set("state_estimate", STATE_ESTIMATE.vector(
        p_EB=[0.0, 0.0, 1.5], q_EB=[np.cos(roll / 2), np.sin(roll / 2), 0.0, 0.0]))
    rows = b.run(4.0)
    expected = 0.5 * 9.81 * np.tan(-roll) * PARAMS.level_lead_time ** 2 if lead else 0.0
    np.testing.assert_allclose(REFERENCE.get(rows[-1], "p")[:2], [0.0, expected], atol=2e-3)


def test_caught_up_the_reference_keeps_to_the_target_estimate_through_its_velocity_jumps():
    """Close to the platform the target EKF's velocity jumps by up to 1 m/s while its position
    stays on the car (a 5 m/s landing campaign on the managed stack). Caught up, the reference is
    the filtered target estimate (L Fig. 8) itself: its position within 2 cm of the estimate's,
    its acceleration (the catch-up's, which the linear MPC moves the reference on with over its
    horizon) zero. Driven by the catch-up's law, such jumps had rung it at +-2.5 m/s^2 and put
    it up to 1 m ahead of the estimate."""
    v = np.array([5.0, 0.0, 0.0])
    p0 = np.array([0.0, 0.0, 1.0])
    b = bench(TargetGoal.follow(), p0, v, start=(0.0, 0.0, HEIGHT))
    b.run(8.0, each=moving_target(p0, v))                  # caught up with the car
    rng = np.random.default_rng(0)
    jumps = rng.choice([-1.0, 1.0], size=40) * rng.uniform(0.5, 1.0, 40)

    def jumping(b, _):
        """the estimate on the car, its velocity off by a jump held for 0.1 s"""
        t = b.ticks * PERIOD
        b.set("target_estimate", target(p0 + v * t, v + [jumps[int(t / 0.1) % 40], 0.0, 0.0]))
    start = b.ticks
    rows = b.run(4.0, each=jumping)
    t = (start + np.arange(len(rows)) + 1) * PERIOD         # the references' stamps
    along = rows[:, REFERENCE.slice("p")][:, 0] - (p0[0] + v[0] * t)
    assert np.abs(along).max() < 0.02
    assert np.abs(rows[:, REFERENCE.slice("a")]).max() < 0.01


def test_a_descent_requested_during_the_catch_up_waits_until_the_reference_has_caught_up():
    """Landing Phase 1 can start while the reference still chases the car (the mission's 0.8 m
    and 0.8 m/s thresholds): the descent holds the height until the reference has caught up,
    then goes down at its rate."""
    p0 = np.array([4.0, 3.0, 1.0])
    b = bench(TargetGoal.descend(1.8), p0, V_T, start=(0.0, 0.0, HEIGHT))
    rows = b.run(8.0, each=moving_target(p0, V_T))
    z = rows[:, REFERENCE.slice("p")][:, 2]
    t = (np.arange(len(rows)) + 1) * PERIOD                  # the references' stamps
    gap = np.linalg.norm((p0 + np.outer(t, V_T) - rows[:, REFERENCE.slice("p")])[:, :2], axis=1)
    first = int(np.argmax(z < HEIGHT - 1e-9))                # the first tick going down
    assert first > int(2.0 / PERIOD)                         # a 5 m gap at rest takes > 2 s
    assert gap[first] < 0.25 and np.all(gap[:first] > 0.05)  # caught up (within the L lag)
    assert z[-1] == pytest.approx(p0[2] - PARAMS.press_depth)    # then down onto the target
