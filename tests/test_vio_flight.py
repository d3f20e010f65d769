"""The VIO closing the MPC loop on the geometric RGB-D camera (issue 8): a short waypoint flight,
and the landing mission on the VIO."""

import numpy as np
import pytest

from alight.diagrams.running.flights import fly_waypoints
from alight.diagrams.running.runner import run
from alight.diagrams.scenario import load_scenario
from alight.diagrams.world.sim_vehicle import load_sim_vehicle_config
from alight.diagrams.onboard.vio import VioRun, load_rgbd_camera_params, load_vio_params
from alight.systems.vio.estimator import VioStatus
from conftest import assert_landed

pytestmark = pytest.mark.mission


def truth_at(run, t, field="p_WB"):
    truth = run["ground_truth"]
    values = run.field("ground_truth", field).to_numpy()
    return np.column_stack([np.interp(t, truth["time"], values[:, i])
                            for i in range(values.shape[1])])


@pytest.fixture(scope="module")
def vio_flight(tmp_path_factory):
    config = load_sim_vehicle_config()
    config.rgbd_camera = load_rgbd_camera_params()
    vio = VioRun(load_vio_params())
    run = fly_waypoints(config, np.array([[0.0, 0.0, 2.0], [3.0, 0.0, 2.0]]), seed=3,
                        run_dir=tmp_path_factory.mktemp("runs") / "vio_flight", odometry=vio,
                        max_duration=30.0)
    return run


def test_vio_flies_the_waypoints_with_bounded_position_error(vio_flight):
    run = vio_flight
    assert run.metadata["landed"]
    estimate = run["vio_estimate"]
    valid = estimate["valid"].to_numpy() > 0.5
    t = estimate["time"].to_numpy()
    # initialized from rest before the mission armed (it waits for a valid estimate)
    assert t[valid][0] < 1.5
    after = t >= t[valid][0]
    assert valid[after].all()
    error = np.linalg.norm(run.field("vio_estimate", "p_EB").to_numpy()[after]
                           - truth_at(run, t[after]), axis=1)
    rmse = np.sqrt(np.mean(error ** 2))
    assert rmse < 0.10, rmse          # measured 0.02-0.03 m
    assert error.max() < 0.25, error.max()
    odometry = run["vio_odometry"]
    assert set(odometry["status"][odometry["time"] > 2.0]) <= {VioStatus.TRACKING,
                                                               VioStatus.IMU_ONLY}


def test_the_estimate_less_its_corrections_moves_with_the_imu_alone(vio_flight):
    """`p_EO` sums the keyframes' corrections of the propagated position: p_EB jumps at
    keyframes, p_EB - p_EO moves only as its velocity says (the target estimator keeps the car
    where it was relative to the vehicle through the jumps)."""
    run = vio_flight
    estimate = run["vio_estimate"]
    valid = estimate["valid"].to_numpy() > 0.5
    t = estimate["time"].to_numpy()[valid]
    p = run.field("vio_estimate", "p_EB").to_numpy()[valid]
    v = run.field("vio_estimate", "v_EB").to_numpy()[valid]
    p_EO = run.field("vio_estimate", "p_EO").to_numpy()[valid]
    dt = np.diff(t)[:, None]
    moved = 0.5 * (v[1:] + v[:-1]) * dt   # what the velocity says, per 4 ms sample
    jumps = np.linalg.norm(np.diff(p, axis=0) - moved, axis=1)
    smooth = np.linalg.norm(np.diff(p - p_EO, axis=0) - moved, axis=1)
    corrected = np.linalg.norm(np.diff(p_EO, axis=0), axis=1) > 0
    assert corrected.sum() > 50        # measured 94 over the flight
    assert jumps.max() > 0.01          # measured 1.7 cm
    assert smooth.max() < 0.001        # measured 0.1 mm (the velocity's trapezoid)


@pytest.fixture(scope="module")
def blackout_flight(tmp_path_factory):
    """A 1 s camera blackout in the middle of the 3 m leg (the vehicle is moving)."""
    config = load_sim_vehicle_config()
    config.rgbd_camera = load_rgbd_camera_params()
    vio = VioRun(load_vio_params(), blackouts=[(BLACKOUT, BLACKOUT + 1.0)])
    return fly_waypoints(config, np.array([[0.0, 0.0, 2.0], [3.0, 0.0, 2.0]]), seed=4,
                         run_dir=tmp_path_factory.mktemp("runs") / "vio_blackout",
                         odometry=vio, max_duration=30.0)


BLACKOUT = 5.5  # s


def test_biases_converge_toward_the_simulated_ones(vio_flight):
    config = load_sim_vehicle_config()
    odometry = vio_flight["vio_odometry"]
    t = odometry["time"].to_numpy()
    airborne = t[truth_at(vio_flight, t)[:, 2] > 1.0]  # the touchdown shock is not the bias
    late = (t > airborne[-1] - 2.0) & (t <= airborne[-1])
    b_g = vio_flight.field("vio_odometry", "b_g").to_numpy()
    b_a = vio_flight.field("vio_odometry", "b_a").to_numpy()
    gyro_error = np.linalg.norm(b_g[late].mean(axis=0) - config.imu.gyro_bias)
    # the true gyro bias is 5.4 mrad/s (its random walk over the flight ~0.1 mrad/s); measured
    # error 1.2 mrad/s
    assert gyro_error < 2e-3, gyro_error
    # vertical accelerometer bias (observable against gravity): measured error 0.01-0.02 m/s^2
    accel_z_error = abs(b_a[late, 2].mean() - config.imu.accel_bias[2])
    assert accel_z_error < 0.03, accel_z_error


def test_a_one_second_blackout_is_bridged_then_tracking_recovers(blackout_flight):
    run = blackout_flight
    assert run.metadata["landed"]
    estimate = run["vio_estimate"]
    t = estimate["time"].to_numpy()
    valid = estimate["valid"].to_numpy() > 0.5
    var_p = run.field("vio_estimate", "var_pv").to_numpy()[:, :3].sum(axis=1)
    error = np.linalg.norm(run.field("vio_estimate", "p_EB").to_numpy() - truth_at(run, t), axis=1)
    during = (t >= BLACKOUT) & (t < BLACKOUT + 1.0)
    assert valid[during].all()  # bridged by the IMU, never reported lost
    before = np.searchsorted(t, BLACKOUT)
    end = np.searchsorted(t, BLACKOUT + 1.0) - 1
    assert var_p[end] > 4 * var_p[before], (var_p[before], var_p[end])  # covariance grows
    assert np.all(np.diff(var_p[before + 60:end]) >= -1e-12)
    assert error[during].max() < 0.3, error[during].max()
    odometry = run["vio_odometry"]
    status = odometry["status"].to_numpy()
    t_odo = odometry["time"].to_numpy()
    assert VioStatus.IMU_ONLY in status[(t_odo > BLACKOUT) & (t_odo < BLACKOUT + 1.1)]
    assert VioStatus.LOST not in status
    recovered = (t_odo > BLACKOUT + 1.5) & (t_odo < BLACKOUT + 3.0)
    assert np.all(status[recovered] == VioStatus.TRACKING)
    after = (t > BLACKOUT + 1.5) & valid
    assert var_p[after].max() < 0.5 * var_p[end]
    assert error[after].max() < 0.2, error[after].max()


def test_the_landing_mission_on_vio_lands_on_the_moving_car(tmp_path):
    """Issue 8 closed loop: the field scenario at 2 m/s with `estimator: vio` (the forward RGB-D
    camera and the VIO instead of mocap, its frame at the surveyed take-off point), judged by the
    physics like every landing."""
    scenario = load_scenario("field", overrides=["target_motion.speed: 2.0",
                                                 "onboard.estimator: vio"])
    run_log = run(scenario, run_dir=tmp_path / "land")
    assert_landed(run_log, scenario, 2.0)
    estimate = run_log["state_estimate"]
    valid = estimate[estimate["valid"] > 0.5]
    t = valid["time"].to_numpy()
    error = np.linalg.norm(valid[["p_EB_0", "p_EB_1", "p_EB_2"]].to_numpy()
                           - truth_at(run_log, t), axis=1)
    assert np.median(error) < 0.15           # the VIO flew it (measured 0.06 m mean)
    assert "vio_odometry" in run_log.streams
