"""The moving target (issue 5): the car with the landing platform in the vehicle's plant, its motion
profiles (straight, MBZIRC figure eight, field test) and its generated textures."""
import dataclasses as dc

import cv2
import numpy as np
import pytest
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.geometry import Role
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import RandomSource, TrajectorySource, VectorLogSink

from alight.diagrams.scenario import load_scenario, placed_target
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.models import MODELS_DIR
from alight.models.textures import generated_files
from alight.systems.boundary import FC_COMMAND, GROUND_TRUTH
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.target.motion import (NOISE_SIZE, FieldTestParams, TargetMotion,
                                          path_evaluator, straight_path)
from alight.systems.target.vehicle import load_target_params


@pytest.fixture(scope="module")
def straight_run(vehicle_config):
    """The vehicle at rest (disarmed) while the target drives past at 5 m/s; 3 s."""
    target = dc.replace(load_target_params(), profile="straight", initial_position=[2.0, -10.0],
                        initial_heading=90.0)
    config = dc.replace(vehicle_config, target=target,
                        down_camera=DownCameraParams(source="geometric"))
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config))
    log = builder.AddSystem(VectorLogSink(GROUND_TRUTH.size, 0.01))
    builder.Connect(vehicle.GetOutputPort("ground_truth"), log.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(3))
    command = FC_COMMAND.pack(stamp=0.0, mode=1, q_WD=[1, 0, 0, 0], w_D=0.0, thrust=0.0, arm=0)
    vehicle.GetInputPort("fc_command").FixValue(vehicle.GetMyMutableContextFromRoot(context),
                                                command)
    simulator.AdvanceTo(3.0)
    return vehicle, log.FindLog(context), context


def test_target_follows_the_straight_profile_in_the_vehicle_plant(straight_run):
    _, log, _ = straight_run
    t, truth = log.sample_times(), log.data().T
    assert np.all(truth[:, GROUND_TRUTH.slice("target_present")] == 1.0)
    p_WT, v_WT = truth[:, GROUND_TRUTH.slice("p_WT")], truth[:, GROUND_TRUTH.slice("v_WT")]
    cruising = t > 2.0  # after the 1 s ramp and the joint controllers' settling
    # Heading 90 deg: along +y at 5 m/s, on its line x = 2 m, platform top 1 m above the ground.
    np.testing.assert_allclose(v_WT[cruising], np.tile([0.0, 5.0, 0.0], (cruising.sum(), 1)),
                               atol=0.05)
    np.testing.assert_allclose(p_WT[:, 0], 2.0, atol=0.01)
    np.testing.assert_allclose(p_WT[:, 2], 1.0, atol=0.01)
    # Distance covered: ramp (2.5 m over 1 s) then 5 m/s; the joints lag the profile slightly.
    assert p_WT[-1, 1] - p_WT[0, 1] == pytest.approx(2.5 + 5.0 * 2.0, abs=0.3)
    q_WT = truth[:, GROUND_TRUTH.slice("q_WT")]
    heading = np.degrees(2 * np.arctan2(q_WT[:, 3], q_WT[:, 0]))
    np.testing.assert_allclose(heading, 90.0, atol=0.5)
    # The hexacopter, disarmed, stays on the ground at the origin.
    assert np.abs(truth[:, GROUND_TRUTH.slice("p_WB")][:, :2]).max() < 0.01


def test_platform_has_contact_geometry_in_the_same_plant(straight_run):
    vehicle, _, _ = straight_run
    plant = vehicle.GetSubsystemByName("plant")
    platform = plant.GetBodyByName("platform")
    inspector = vehicle.GetSubsystemByName("scene_graph").model_inspector()
    boxes = [inspector.GetShape(g) for g in plant.GetCollisionGeometriesForBody(platform)]
    sizes = sorted(tuple(np.round(b.size(), 3)) for b in boxes)
    assert (1.5, 1.5, 0.04) in sizes  # the 1.5 m x 1.5 m platform plate
    assert inspector.NumGeometriesWithRole(Role.kProximity) >= 3  # ground, legs, platform...


def test_geometric_down_camera_publishes_20_hz_frames_with_latency_and_clock_offset(
        straight_run):
    vehicle, _, context = straight_run
    params = DownCameraParams()
    frame = vehicle.GetOutputPort("down_image").Eval(vehicle.GetMyContextFromRoot(context))
    # At t = 3 s the last frame released was exposed at phase + k period <= 3 - latency; its
    # stamp carries the camera's clock offset (no hardware sync).
    k = np.floor((3.0 - params.latency - params.phase) / params.period + 1e-9)
    assert frame.stamp == pytest.approx(params.phase + k * params.period + params.stamp_offset)
    assert frame.image is None and frame.keypoints is not None and frame.valid
    assert frame.calibration["width"] == 1280 and frame.calibration["height"] == 1024


def _motion_run(profile: str, duration: float, seed: int = 0, period: float = 0.05,
                field_test: FieldTestParams = FieldTestParams()):
    target = load_target_params()
    builder = DiagramBuilder()
    dut = builder.AddSystem(TargetMotion(profile, [0.0, 0.0], 0.0, target.straight,
                                         target.figure_eight, field_test))
    if profile == "field_test":
        noise = builder.AddSystem(RandomSource(RandomDistribution.kGaussian, NOISE_SIZE,
                                               field_test.period))
        builder.Connect(noise.get_output_port(), dut.GetInputPort("noise"))
    log = builder.AddSystem(VectorLogSink(6, period))
    builder.Connect(dut.GetOutputPort("desired_state"), log.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(seed))
    simulator.AdvanceTo(duration)
    found = log.FindLog(simulator.get_context())
    return found.sample_times(), found.data().T


@pytest.mark.parametrize("profile", ["straight", "field_test"])
def test_drake_evaluated_path_is_the_python_profile(profile):
    """What the plant reads at every step (the straight PiecewisePolynomial, the field test's
    per-period polynomial evaluated by Drake) is TargetMotion's desired_state, at every 1 ms."""
    target = load_target_params()
    field_test = FieldTestParams(pull_times=[1.5], ramp_time=1.0)
    builder = DiagramBuilder()
    dut = builder.AddSystem(TargetMotion(profile, [3.0, -4.0], 30.0, target.straight,
                                         target.figure_eight, field_test))
    if profile == "field_test":
        noise = builder.AddSystem(RandomSource(RandomDistribution.kGaussian, NOISE_SIZE,
                                               field_test.period))
        builder.Connect(noise.get_output_port(), dut.GetInputPort("noise"))
        evaluator = builder.AddSystem(path_evaluator())
        builder.Connect(dut.GetOutputPort("path_coefficients"), evaluator.get_input_port())
        fast = evaluator.get_output_port()
    else:
        fast = builder.AddSystem(TrajectorySource(straight_path(
            [3.0, -4.0], 30.0, target.straight))).get_output_port()
    logs = [builder.AddSystem(VectorLogSink(6, 0.001)) for _ in range(2)]
    builder.Connect(dut.GetOutputPort("desired_state"), logs[0].get_input_port())
    builder.Connect(fast, logs[1].get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(4))
    simulator.AdvanceTo(3.0)
    python, drake = (log.FindLog(simulator.get_context()).data().T for log in logs)
    assert len(python) == 3001
    np.testing.assert_allclose(drake, python, rtol=0, atol=1e-9)
    assert np.ptp(python[:, 1]) > 1.0   # it moved


def test_figure_eight_is_the_mbzirc_track_at_15_then_5_km_h():
    t, x = _motion_run("figure_eight", 500.0, period=0.5)
    speed = np.hypot(x[:, 3], x[:, 4])
    np.testing.assert_allclose(speed[(t > 3) & (t < 480)], 15 / 3.6, rtol=1e-3)
    np.testing.assert_allclose(speed[t > 483], 5 / 3.6, rtol=1e-3)
    # The lemniscate with half-width 30 m: 60 m long, about 21 m wide, crossing itself at p0.
    assert np.ptp(x[:, 0]) == pytest.approx(60.0, abs=0.2)
    assert np.ptp(x[:, 1]) == pytest.approx(21.2, abs=0.3)
    # The velocity points along the track: d p / d t matches v (central differences over 1 s
    # chords: up to 4 % short on the 10 m radius ends of the track).
    dp = np.gradient(x[:, :2], t, axis=0)
    np.testing.assert_allclose(dp[10:-10], x[10:-10, 3:5], atol=0.2)


def test_field_test_profile_wanders_at_the_mean_speed_with_sharp_pulls():
    params = FieldTestParams(mean_speed=3.0, pull_rate=0.0, pull_times=[20.0])
    t, x = _motion_run("field_test", 60.0, seed=1, field_test=params)
    speed = np.hypot(x[:, 3], x[:, 4])
    assert speed[t > 5].mean() == pytest.approx(3.0, abs=0.6)
    assert speed.max() <= params.max_speed + 1e-9
    assert 0.2 < speed[t > 5].std() < 1.2  # random speed changes (OU, 0.6 m/s stationary)
    # The scheduled pull: the turn rate jumps to about 90 deg/s for 0.8 s.
    rate = np.degrees(x[:, 5])
    pulling = (t > 20.1) & (t < 20.7)
    assert np.abs(rate[pulling]).min() > 60.0
    assert np.abs(rate[(t > 5) & (t < 19.5)]).max() < 45.0
    # Seeded: the same seed gives the same path, another seed another one.
    _, same = _motion_run("field_test", 10.0, seed=1, field_test=params)
    _, other = _motion_run("field_test", 10.0, seed=2, field_test=params)
    n = len(same)
    np.testing.assert_array_equal(same, x[:n])
    assert np.abs(other[-1, :2] - x[n - 1, :2]).max() > 0.1


@pytest.mark.parametrize("speed", [3.0, 8.0, 10.0])
def test_a_scenarios_field_test_car_drives_at_the_requested_mean_speed(speed):
    """`target_motion.speed` is the mean the car drives at: the car file's 8 m/s clip of a
    pulled target is raised where it would cut the requested spread (at 8 m/s the campaign's
    car averaged 7.78 m/s, at 10 m/s 7.97 before)."""
    scenario = load_scenario("field", overrides=[f"target_motion.speed: {speed}"])
    params = placed_target(scenario).field_test
    t, x = _motion_run("field_test", 40.0, seed=3,
                       field_test=dc.replace(params, pull_rate=0.0, turn_rate_std=0.0))
    driven = np.hypot(x[:, 3], x[:, 4])[t > 5]
    assert driven.mean() == pytest.approx(speed, abs=0.3)
    assert params.max_speed == max(8.0, speed + 4 * scenario.target_motion.speed_std)


def test_committed_textures_and_meshes_match_their_generator():
    for name, content in generated_files().items():
        path = MODELS_DIR / name
        if name.endswith(".png"):
            committed = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            generated = cv2.imdecode(np.frombuffer(content, np.uint8), cv2.IMREAD_UNCHANGED)
            np.testing.assert_array_equal(committed, generated, err_msg=name)
        else:
            assert path.read_bytes() == content, name
