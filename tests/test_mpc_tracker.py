"""The MPC tracker, M Sec. 4.1: constraint groups respected, steps settle, trajectories followed."""
import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from alight.systems.boundary import REFERENCE, STATE_ESTIMATE, TRACKER_STATUS
from alight.systems.params import ConfigError
from alight.systems.tracking.constraints import (derivative_peaks, limits_table,
                                                 load_constraint_group)
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.mpc_tracker import (MpcTrackerParams, TrackerReason,
                                                 load_mpc_tracker_params, make_mpc_tracker)

PERIOD = 0.01
TOLERANCE = 1.02     # never over the group by more than 2 %


def run(goal, seconds, group="medium", p_start=(0.0, 0.0, 2.0), handed_over=None,
        reasons=None):
    """The tracker alone, started at rest at the estimate (or from the `handed_over` reference);
    the references, one per tick (and each tick's `tracker_status.reason` appended to
    `reasons` when given)."""
    dut = make_mpc_tracker(load_mpc_tracker_params())
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.vector(p_EB=p_start))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_reference").FixValue(
        context, np.full(REFERENCE.size, np.nan) if handed_over is None else handed_over)
    dut.GetInputPort("constraint_group").FixValue(context, [dut.group_names.index(group)])
    dut.GetInputPort("goal").FixValue(context, goal)
    simulator = Simulator(dut, context)
    rows = []
    for i in range(int(round(seconds / PERIOD))):
        simulator.AdvanceTo((i + 1) * PERIOD)
        rows.append(dut.GetOutputPort("reference").Eval(context))
        if reasons is not None:
            reasons.append(TRACKER_STATUS.get(
                dut.GetOutputPort("tracker_status").Eval(context), "reason"))
    return np.array(rows)


def peaks_over_limits(references, group):
    """Peaks of the reference's 1st..4th derivatives over the group's limits (4 x 4); the
    heading's higher derivatives by finite differences of its rate, the snap of the jerk's."""
    v, a, j = (references[:, REFERENCE.slice(f)] for f in ("v", "a", "j"))
    rate = references[:, REFERENCE.slice("heading_rate")].ravel()
    d = [np.diff(rate, n) / PERIOD ** n for n in (1, 2, 3)]
    snap = np.diff(j, axis=0) / PERIOD
    derivatives = [np.column_stack([v, rate]), np.column_stack([a[1:], d[0]]),
                   np.column_stack([j[2:], d[1]]), np.column_stack([snap[2:], d[2]])]
    return derivative_peaks(derivatives) / limits_table(load_constraint_group(group))


@pytest.mark.parametrize("group", ["medium", "slow"])
def test_a_step_never_exceeds_the_group_and_settles_without_ringing(group):
    goal = np.array([8.0, -6.0, 5.0])
    references = run(TrackerGoal.point(goal, 2.0), 14.0, group)
    assert np.all(np.isfinite(references))
    ratios = peaks_over_limits(references, group)
    assert ratios.max() <= TOLERANCE, ratios
    assert ratios[0, 0] > 0.95          # and it does use the horizontal speed it is given
    error = np.linalg.norm(references[:, REFERENCE.slice("p")] - goal, axis=1)
    within = error <= 0.05
    settled = np.argmax(within) * PERIOD
    assert settled < 12.0 if group == "slow" else settled < 6.0
    # no ringing: once within 0.05 m it stays within, and it never passes the goal
    assert np.all(within[np.argmax(within):])
    along = (references[:, REFERENCE.slice("p")] - [0, 0, 2]) @ (goal - [0, 0, 2]) \
        / np.linalg.norm(goal - [0, 0, 2]) ** 2
    assert along.max() < 1.0 + 0.01
    assert abs(references[-1, REFERENCE.slice("heading")][0] - 2.0) < 1e-3


def test_a_sampled_trajectory_is_followed_within_limits():
    """A 3 m circle at 1.5 m/s (0.75 m/s^2) sampled at 20 Hz, heading along the tangent."""
    t = np.arange(0.0, 20.0, 0.05)
    w = 1.5 / 3.0
    samples = np.column_stack([3 * np.cos(w * t), 3 * np.sin(w * t), np.full_like(t, 2.0),
                               w * t + np.pi / 2])
    reasons = []
    references = run(TrackerGoal(samples, 0.0, 0.05), 16.0, p_start=(3.0, 0.0, 2.0),
                     reasons=reasons)
    assert TrackerReason.SOLVER_FAILED not in reasons          # every QP solved, every tick
    assert peaks_over_limits(references, "medium").max() <= TOLERANCE
    times = PERIOD * np.arange(1, len(references) + 1)    # references are stamped a tick ahead
    wanted = TrackerGoal(samples, 0.0, 0.05).sample(times + PERIOD)
    error = np.linalg.norm(references[:, REFERENCE.slice("p")] - wanted[:, :3], axis=1)
    # The catch-up from rest on the moving goal (docs/controllers.md): the lag of reaching
    # 1.5 m/s from rest under medium's jerk and snap peaks at 0.93 m at 0.92 s (measured), then
    # closes without a stop by 3 s and stays on the circle; measured peaks per window in
    # comments. (Before the near steps' shares followed the last plan, the lag came back to
    # 0.5-0.8 m at 4-9 s, or not, by the machine's rounding: docs/controllers.md.)
    peak = int(np.argmax(error))
    assert error[peak] < 1.0 and times[peak] < 1.5, (error[peak], times[peak])
    assert np.all(np.diff(error[peak:np.searchsorted(times, 3.0)]) <= 0.0)
    for start, end, bound in ((3.0, 5.0, 0.03),    # 0.020 m
                              (5.0, 7.0, 0.03),    # 0.017 m
                              (7.0, 9.0, 0.03),    # 0.020 m
                              (9.0, 16.0, 0.03)):  # 0.020 m
        window = (times > start) & (times <= end)
        assert error[window].max() < bound, (start, error[window].max())


def fastest_return(v, a, j, jerk, snap, seconds=4.0, dt=1e-4):
    """What a start (v, a, j) along an axis forces whatever the plan: the jerk turned toward
    -jerk as fast as `snap` allows (from below when it starts under -jerk). Returns the peak
    speed, its time, and the lowest acceleration (the jerk lifted to 0 at `snap`)."""
    t = np.arange(dt, seconds, dt)
    jerks = np.maximum(j - snap * t, -jerk) if j >= -jerk else np.minimum(j + snap * t, -jerk)
    speeds = v + np.cumsum(a + np.cumsum(jerks) * dt) * dt
    k = np.argmax(speeds)
    lowest = a - j ** 2 / (2 * snap) if j < 0 else a
    return max(v, speeds[k]), t[k] if speeds[k] > v else 0.0, lowest


@pytest.mark.parametrize("v, a, j", [
    (1.3, 0.0, 0.0),        # just over slow's speed
    (2.91, -0.07, 2.61),    # medium's speed, its jerk still lifting the acceleration
    (2.945, 0.807, -6.5),   # medium's jerk, over slow's: slow's snap lifts it in 0.4 s
    (2.9, 2.5, 0.0),        # medium's acceleration, over slow's
])
def test_a_start_faster_than_the_group_returns_as_fast_as_the_group_allows(v, a, j):
    """Handed a reference over slow's limits (a group switched, another tracker's), the tracker
    gets back within them as fast as slow's jerk and snap allow (x axis: 1/sqrt(2) of them,
    `horizontal_factors`), and no faster: the speed rises no more than the start forces
    (`fastest_return`, +0.01 m/s), never rises again while over 1.05 m/s, is under it within
    t_peak + (v_peak - 1 m/s) / 1 m/s^2 + 2 sqrt(A / S) + h (shedding the excess at slow's
    acceleration, its ramp in and out at slow's snap, a grid step), and the braking is within
    slow's acceleration or what the start forces (2 %)."""
    slow = load_constraint_group("slow").horizontal
    jerk, snap = slow.jerk / np.sqrt(2), slow.snap / np.sqrt(2)
    handed_over = REFERENCE.pack(stamp=0.0, p=[0.0, 0.0, 2.0], v=[v, 0, 0], a=[a, 0, 0],
                                 j=[j, 0, 0], heading=0.0, heading_rate=0.0)
    references = run(TrackerGoal.point([40.0, 0.0, 2.0], 0.0), 6.0, "slow",
                     handed_over=handed_over)
    assert np.all(np.isfinite(references))
    speed = np.linalg.norm(references[:, REFERENCE.slice("v")][:, :2], axis=1)
    peak, peak_time, lowest = fastest_return(v, a, j, jerk, snap)
    assert speed.max() <= peak + 0.01
    over = np.flatnonzero(speed > 1.05 * slow.speed).max()
    assert np.all(np.diff(speed[np.argmax(speed):over + 2]) <= 1e-6)
    limit_time = peak_time + (peak - slow.speed) / slow.acceleration \
        + 2 * np.sqrt(slow.acceleration / snap) + 0.1
    assert (over + 1) * PERIOD <= limit_time
    acceleration = references[:, REFERENCE.slice("a")][:, 0]
    assert acceleration.min() >= 1.02 * min(-slow.acceleration, lowest)


def test_a_bad_goal_or_grid_is_refused():
    with pytest.raises(TypeError, match="TrackerGoal"):
        run(np.array([1.0, 2.0, 3.0, 0.0]), 0.02)
    params = load_mpc_tracker_params()
    params.axis.step = 0.105
    with pytest.raises(ConfigError, match="whole number"):
        make_mpc_tracker(params)
    assert isinstance(params, MpcTrackerParams)
