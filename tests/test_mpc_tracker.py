"""The MPC tracker, M Sec. 4.1: constraint groups respected, steps settle, trajectories followed."""
import numpy as np
import pytest
from pydrake.systems.analysis import Simulator

from alight.systems.boundary import REFERENCE, STATE_ESTIMATE
from alight.systems.params import ConfigError
from alight.systems.tracking.constraints import (derivative_peaks, limits_table,
                                                 load_constraint_group)
from alight.systems.tracking.goal import TrackerGoal
from alight.systems.tracking.mpc_tracker import (MpcTrackerParams, load_mpc_tracker_params,
                                                 make_mpc_tracker)

PERIOD = 0.01
TOLERANCE = 1.02     # never over the group by more than 2 %


def run(goal, seconds, group="medium", p_start=(0.0, 0.0, 2.0)):
    """The tracker alone, started at rest at the estimate; the references, one per tick."""
    dut = make_mpc_tracker()
    context = dut.CreateDefaultContext()
    dut.GetInputPort("state_estimate").FixValue(context, STATE_ESTIMATE.pack(
        stamp=0.0, p_EB=p_start, v_EB=0.0, a_EB=0.0, q_EB=[1, 0, 0, 0], heading=0.0,
        heading_rate=0.0, var_pv=0.0, var_heading=0.0, frame_id=0, frame_counter=0,
        p_OldNew=0.0, q_OldNew=[1, 0, 0, 0], valid=1.0))
    dut.GetInputPort("active").FixValue(context, [1.0])
    dut.GetInputPort("last_reference").FixValue(context, np.full(REFERENCE.size, np.nan))
    dut.GetInputPort("constraint_group").FixValue(context, [dut.group_names.index(group)])
    dut.GetInputPort("goal").FixValue(context, goal)
    simulator = Simulator(dut, context)
    rows = []
    for i in range(int(round(seconds / PERIOD))):
        simulator.AdvanceTo((i + 1) * PERIOD)
        rows.append(dut.GetOutputPort("reference").Eval(context))
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
    settled = (np.flatnonzero(error > 0.05).max() + 1) * PERIOD
    assert settled < 12.0 if group == "slow" else settled < 6.0
    # no ringing: once within 0.05 m it stays within, and it never passes the goal
    assert np.all(error[int(settled / PERIOD):] <= 0.05)
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
    references = run(TrackerGoal(samples, 0.0, 0.05), 16.0, p_start=(3.0, 0.0, 2.0))
    assert peaks_over_limits(references, "medium").max() <= TOLERANCE
    times = PERIOD * np.arange(1, len(references) + 1)    # references are stamped a tick ahead
    wanted = TrackerGoal(samples, 0.0, 0.05).sample(times + PERIOD)
    error = np.linalg.norm(references[:, REFERENCE.slice("p")] - wanted[:, :3], axis=1)
    # KNOWN: a catch-up transient of up to ~1.1 m over the first 8 s (see docs/controllers.md)
    assert error[times > 9.0].max() < 0.06, error[times > 9.0].max()


def test_a_bad_goal_or_grid_is_refused():
    with pytest.raises(TypeError, match="TrackerGoal"):
        run(np.array([1.0, 2.0, 3.0, 0.0]), 0.02)
    params = load_mpc_tracker_params()
    params.axis.step = 0.105
    with pytest.raises(ConfigError, match="whole number"):
        make_mpc_tracker(params)
    assert isinstance(params, MpcTrackerParams)
