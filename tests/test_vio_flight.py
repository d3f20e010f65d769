"""The VIO closing the MPC loop on the geometric RGB-D camera (issue 8): a short waypoint flight."""
import numpy as np
import pytest

from alight.diagrams.fly import fly_waypoints
from alight.diagrams.sim_vehicle import load_sim_vehicle_config
from alight.diagrams.vio import VioRun, load_rgbd_camera_params
from alight.systems.vio.estimator import VioStatus


def truth_at(run, t, field="p_WB"):
    truth = run["ground_truth"]
    values = run.field("ground_truth", field).to_numpy()
    return np.column_stack([np.interp(t, truth["time"], values[:, i])
                            for i in range(values.shape[1])])


@pytest.fixture(scope="module")
def vio_flight(tmp_path_factory):
    config = load_sim_vehicle_config()
    config.rgbd_camera = load_rgbd_camera_params()
    vio = VioRun()
    run = fly_waypoints(config, np.array([[0.0, 0.0, 2.0], [3.0, 0.0, 2.0]]), seed=3,
                        run_dir=tmp_path_factory.mktemp("runs") / "vio_flight", odometry=vio,
                        log=vio.log, max_duration=30.0)
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
