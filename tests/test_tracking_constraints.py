"""Constraint groups (M Sec. 7.5) and tracker goals (M Sec. 4): loading, refusals, sampling."""
import numpy as np
import pytest

from alight.systems.params import ConfigError
from alight.systems.tracking.constraints import (derivative_peaks, limits_table,
                                                 load_constraint_group, load_constraint_groups)
from alight.systems.tracking.goal import TrackerGoal


def test_the_shipped_groups_load_and_the_fast_group_is_the_papers():
    groups = load_constraint_groups()
    assert {"slow", "medium", "fast"} <= set(groups.groups) and groups.default == "medium"
    fast = load_constraint_group("fast")   # M Sec. 8.1: 9 m/s, 12 m/s^2, 50 m/s^3, 50 m/s^4
    np.testing.assert_allclose(fast.horizontal.as_array(), [9.0, 12.0, 50.0, 50.0])
    with pytest.raises(ConfigError, match="unknown constraint group 'warp'"):
        load_constraint_group("warp")


def test_a_bad_limit_names_the_file_the_key_and_the_range(tmp_path):
    bad = tmp_path / "constraints.yaml"
    bad.write_text("default: slow\ngroups:\n  slow:\n    horizontal: {speed: -1.0}\n")
    with pytest.raises(ConfigError, match=r"constraints.yaml.*groups.slow.horizontal.speed"):
        load_constraint_groups(str(bad))
    bad.write_text("default: fast\ngroups:\n  slow: {}\n")
    with pytest.raises(ConfigError, match="key 'default' = 'fast'"):
        load_constraint_groups(str(bad))


def test_peaks_compare_horizontal_norms_ascent_descent_and_heading():
    d = np.array([[3.0, 4.0, 1.0, -0.5], [0.0, 0.0, -2.0, 0.2]])
    peaks = derivative_peaks([d, 2 * d, 3 * d, 4 * d])
    np.testing.assert_allclose(peaks[:, 0], [5.0, 1.0, 2.0, 0.5])
    np.testing.assert_allclose(peaks[:, 3], [20.0, 4.0, 8.0, 2.0])
    assert limits_table(load_constraint_group("slow")).shape == (4, 4)


def test_a_goal_interpolates_holds_its_ends_and_takes_the_short_way_round():
    goal = TrackerGoal(np.array([[0, 0, 1, np.pi - 0.1], [1, 2, 1, -np.pi + 0.1]]), 10.0, 0.5)
    rows = goal.sample(np.array([9.0, 10.25, 11.0]))
    np.testing.assert_allclose(rows[0], [0, 0, 1, np.pi - 0.1])
    np.testing.assert_allclose(rows[1], [0.5, 1.0, 1.0, np.pi])     # across +-pi, not through 0
    np.testing.assert_allclose(rows[2, :3], [1, 2, 1])
    np.testing.assert_allclose(TrackerGoal.point([1, 2, 3], 0.5).sample([0.0, 99.0]),
                               [[1, 2, 3, 0.5]] * 2)
    with pytest.raises(ValueError, match="finite"):
        TrackerGoal.point([np.nan, 0, 0])
    with pytest.raises(ValueError, match=r"\[x, y, z, heading\]"):
        TrackerGoal(np.zeros((3, 3)))
