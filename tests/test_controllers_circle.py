"""The 5 m circle at 7 m/s (M Sec. 8.2, Fig. 9-10) with the SE(3) controller on the simulated F550:
two laps, scored on the last one against the ground truth."""
import pytest

from alight.diagrams.track import TrackExperiment, fly_track, score


def circle(heading):
    return TrackExperiment(trajectory="circle", controller="se3", radius=5.0, speed=7.0,
                           heading=heading, laps=2.0, altitude=1.5, settle=1.0, ramp=2.0)


@pytest.fixture(scope="module")
def circles(vehicle_config, tmp_path_factory):
    root = tmp_path_factory.mktemp("circle")
    return {h: fly_track(vehicle_config, circle(h), seed=2, plots=False, run_dir=root / h)
            for h in ("center", "constant")}


def test_circle_with_constant_heading_mean_error_under_half_a_metre(circles):
    result = score(circles["constant"])
    assert result.mean_position_error <= 0.5, result     # M Sec. 8.2: 0.5 m
    assert result.mean_heading_error < 5.0, result
    assert result.max_tilt < 60.0, result


def test_circle_with_heading_to_centre(circles):
    """The paper reports 0.1 m here. On this simulated F550 (thrust/weight 2.2, 45 deg of tilt on
    the circle, 30 ms of mocap latency) the SE(3) controller reaches about 0.2 m: the bound below
    is what it holds, not the paper's figure (see the README, "Flight-stack controllers")."""
    result = score(circles["center"])
    assert result.mean_position_error <= 0.3, result
    assert result.mean_heading_error < 5.0, result
    p = circles["center"].field("ground_truth", "v_WB").to_numpy()
    assert result.max_speed > 6.5   # it really flew the 7 m/s circle
