"""Estimator faults (M Sec. 8.3-8.4, Fig. 12-13) and the failsafe (M Sec. 5.10) on the simulated F550:
noisy estimates, a 5 m estimator jump, and a feedforward landing from 10 m."""
import numpy as np
import pytest

from alight.diagrams.analysis.track import score
from alight.diagrams.running.track import TrackExperiment, fly_track

pytestmark = pytest.mark.mission

NOISE = 1.0        # m and m/s, sigma of M Fig. 12
TILT_BOUND = 20.0  # deg: the MPC stays under it with sigma = 1 m, the SE(3) controller does not


def hover(controller, **faults):
    return TrackExperiment(trajectory="hover", controller=controller, altitude=1.5, settle=0.0,
                           hover_time=4.0, jump_delay=0.5, **faults)


@pytest.fixture(scope="module")
def noisy(vehicle_config, tmp_path_factory):
    root = tmp_path_factory.mktemp("noise")
    return {c: fly_track(vehicle_config, hover(c, estimator_noise=NOISE), seed=3, plots=False,
                         run_dir=root / c) for c in ("mpc", "se3")}


def test_mpc_keeps_tilt_bounded_under_1_m_estimator_noise(noisy):
    mpc, se3 = score(noisy["mpc"]), score(noisy["se3"])
    assert mpc.max_tilt < TILT_BOUND, mpc
    assert se3.max_tilt > TILT_BOUND, se3           # M Fig. 12: SE(3) produces excessive tilts
    assert mpc.max_position_error < 1.5, mpc         # and the MPC still holds its position


@pytest.fixture(scope="module")
def jump(vehicle_config, tmp_path_factory):
    experiment = hover("mpc", estimator_jump=5.0)
    return fly_track(vehicle_config, experiment, seed=4, plots=False,
                     run_dir=tmp_path_factory.mktemp("jump") / "mpc")


def test_mpc_reacts_to_a_5_m_estimator_jump_within_its_constraints(jump):
    """M Fig. 13: the vehicle moves 5 m (the estimate says it is 5 m off) at most 2 m/s and
    2 m/s^2 (true speed and acceleration)."""
    start = jump.metadata["marks"]["start"]
    after = score(jump, start, jump["ground_truth"]["time"].iloc[-1])
    assert after.max_speed < 2.0, after
    assert after.max_acceleration < 2.0, after
    p = jump.field("ground_truth", "p_WB").to_numpy()
    assert p[-1, 0] - p[0, 0] < -1.5  # it is moving back by the jump (toward -x), not frozen
    status = jump["status_0_mpc"]
    assert (status["valid"][status["time"] > 3.0] > 0.5).all()


@pytest.fixture(scope="module")
def failsafe(vehicle_config, tmp_path_factory):
    experiment = TrackExperiment(trajectory="hover", controller="se3", altitude=10.0,
                                 settle=0.0, hover_time=0.0, climb_limits=[3.0, 2.0, 4.0])
    from alight.diagrams.running.track import make_trajectory, resting_position
    from alight.diagrams.world.sim_vehicle import make_sim_vehicle
    at = make_trajectory(experiment, resting_position(make_sim_vehicle(vehicle_config)))
    experiment.failsafe_at = at.duration + 0.5
    return fly_track(vehicle_config, experiment, seed=5, plots=False, duration=at.duration + 14.0,
                     run_dir=tmp_path_factory.mktemp("failsafe") / "run")


def test_failsafe_lands_from_10_m_slower_than_3_m_s_and_disarms(failsafe):
    truth, status = failsafe["ground_truth"], failsafe["fc_status"]
    switch = failsafe.metadata["controller_starts"][1]
    p = failsafe.field("ground_truth", "p_WB").to_numpy()
    v_z = failsafe.field("ground_truth", "v_WB").to_numpy()[:, 2]
    after = (truth["time"] >= switch).to_numpy()
    assert p[after][0, 2] > 9.5                       # it started from 10 m
    assert v_z[after].min() > -3.0                    # never faster than 3 m/s down
    assert p[-1, 2] < 0.3                             # on the ground
    assert status["armed"].iloc[-1] == 0              # disarmed
    assert failsafe["status_1_failsafe"]["reason"].iloc[-1] == 7  # TOUCHDOWN
