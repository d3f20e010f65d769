"""IMU and flight-controller estimate models."""
import numpy as np
import pytest

from alight.diagrams.running.flights import fly_profile
from alight.systems.rotations import rotation_matrix
from conftest import profile


@pytest.fixture(scope="module")
def rest_run(vehicle_config, tmp_path_factory):
    """Twenty seconds disarmed on the ground."""
    return fly_profile(vehicle_config, profile("{duration: 20.0, arm: false}"), seed=5,
                       run_dir=tmp_path_factory.mktemp("runs") / "rest")


def test_imu_at_rest_reads_gravity_plus_bias_with_the_configured_noise(rest_run, vehicle_config):
    imu = rest_run["imu"]
    params = vehicle_config.imu
    accel = imu[["accel_x", "accel_y", "accel_z"]].to_numpy()
    gyro = imu[["gyro_x", "gyro_y", "gyro_z"]].to_numpy()
    n = len(imu)
    accel_std = params.accel_noise_density / np.sqrt(params.period)
    gyro_std = params.gyro_noise_density / np.sqrt(params.period)
    # Mean: specific force of a body at rest (+g along z_B) plus the initial bias (the random walk
    # over 20 s is far below the tolerance).
    np.testing.assert_allclose(accel.mean(axis=0), np.array([0, 0, 9.81]) + params.accel_bias,
                               atol=5 * accel_std / np.sqrt(n) + 0.01)
    np.testing.assert_allclose(gyro.mean(axis=0), params.gyro_bias,
                               atol=5 * gyro_std / np.sqrt(n) + 5e-4)
    np.testing.assert_allclose(accel.std(axis=0), accel_std, rtol=0.1)
    np.testing.assert_allclose(gyro.std(axis=0), gyro_std, rtol=0.1)


def test_every_imu_sample_is_logged_exactly_once_with_its_own_stamp(hover_run, vehicle_config):
    imu = hover_run["imu"]
    assert imu["seq"].iloc[0] == 0
    assert (np.diff(imu["seq"]) == 1).all()  # no sample lost or repeated
    np.testing.assert_allclose(np.diff(imu["time"]), vehicle_config.imu.period, atol=1e-9)
    duration = hover_run.metadata["duration"]
    assert len(imu) == pytest.approx(duration / vehicle_config.imu.period, abs=2)


def test_imu_port_buffer_lets_a_slow_consumer_take_each_sample_once(vehicle_config):
    from pydrake.systems.analysis import Simulator
    from alight.diagrams.world.sim_vehicle import make_sim_vehicle
    from alight.systems.boundary import FC_COMMAND
    vehicle = make_sim_vehicle(vehicle_config)
    context = vehicle.CreateDefaultContext()
    vehicle.GetInputPort("fc_command").FixValue(context, np.zeros(FC_COMMAND.size))
    simulator = Simulator(vehicle, context)
    last, seen = -1, []
    for t in np.arange(0.0, 1.0, 0.1):  # a 10 Hz consumer of the 250 Hz IMU
        simulator.AdvanceTo(t + 0.1)
        new = vehicle.GetOutputPort("imu").Eval(context).newer_than(last)
        seen += list(new.seq)
        last = int(new.seq[-1])
    # t = 0 ... 1 s - one period: every sample once
    assert seen == list(range(len(seen))) and len(seen) == round(1.0 / vehicle_config.imu.period)


def test_fc_attitude_estimate_is_close_to_the_truth_in_flight(hover_run):
    truth = hover_run["ground_truth"].set_index("time")
    estimate = hover_run["fc_attitude"].set_index("time")
    common = truth.index.intersection(estimate.index)
    errors = []
    for t in common[::10]:
        R_true = rotation_matrix(truth.loc[t, [f"q_WB_{i}" for i in range(4)]].to_numpy())
        R_est = rotation_matrix(estimate.loc[t, [f"q_WB_{i}" for i in range(4)]].to_numpy())
        cos = (np.trace(R_true.T @ R_est) - 1) / 2
        errors.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    assert np.max(errors) < 1.5  # 0.3 deg per axis error process, a few sigma over the flight
    assert np.mean(errors) > 0.05  # it is an estimate, not the truth


def test_same_seed_same_run_other_seed_other_noise(vehicle_config, tmp_path):
    short = profile("{duration: 0.5, arm: false}")
    a = fly_profile(vehicle_config, short, seed=11, run_dir=tmp_path / "a")["imu"]
    b = fly_profile(vehicle_config, short, seed=11, run_dir=tmp_path / "b")["imu"]
    c = fly_profile(vehicle_config, short, seed=12, run_dir=tmp_path / "c")["imu"]
    np.testing.assert_array_equal(a.to_numpy(), b.to_numpy())
    assert not np.allclose(a["accel_x"], c["accel_x"])


def test_imu_samples_appended_is_a_frozen_value_even_when_two_buffers_append_to_one():
    """`appended` writes into a store its buffers view: the arrays are those of appending to
    copies, read-only, and a buffer appended to twice (a cloned context) leaves both intact."""
    from alight.systems.boundary import ImuSamples
    rng = np.random.default_rng(0)
    capacity, samples, plain = 5, ImuSamples.empty(), []
    for seq in range(23):  # through several stores
        t, accel, gyro = seq * 0.004, rng.normal(size=3), rng.normal(size=3)
        samples = samples.appended(seq, t, accel, gyro, capacity)
        plain = (plain + [(seq, t, accel, gyro)])[-capacity:]
        assert np.array_equal(samples.seq, [p[0] for p in plain])
        assert samples.seq.dtype == np.int64
        assert np.array_equal(samples.t, [p[1] for p in plain])
        assert np.array_equal(samples.accel, [p[2] for p in plain])
        assert np.array_equal(samples.gyro, [p[3] for p in plain])
        assert not any(a.flags.writeable for a in (samples.seq, samples.t, samples.accel,
                                                   samples.gyro))
    first = samples.appended(23, 1.0, np.ones(3), np.ones(3), capacity)
    second = samples.appended(23, 2.0, np.full(3, 2.0), np.full(3, 2.0), capacity)
    assert list(first.t[-2:]) == [22 * 0.004, 1.0] and list(second.t[-2:]) == [22 * 0.004, 2.0]
    assert np.array_equal(first.accel[-1], np.ones(3)) and np.array_equal(samples.seq,
                                                                          np.arange(18, 23))
    assert list(samples.newer_than(20).seq) == [21, 22] and samples.newer_than(-1) is samples
    assert len(samples.newer_than(22)) == 0
