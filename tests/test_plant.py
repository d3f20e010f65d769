"""Physics of the simulated hexacopter: hover thrust, ground contact, drag, wind, motors."""
import copy

import numpy as np
import pytest
from pydrake.common import RandomDistribution, RandomGenerator
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import MultibodyPlant
from pydrake.multibody.tree import BodyIndex
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder
from pydrake.systems.primitives import RandomSource

from alight.diagrams.running.flights import fly_profile
from alight.systems.plant.drag import AerodynamicDrag
from alight.systems.plant.hexacopter import add_hexacopter, airframe, load_hexacopter_params
from alight.systems.plant.motors import EscThrustMap, first_order_motors
from alight.systems.plant.wind import Wind, WindParams
from alight.systems.thrust_curve import GRAVITY, ThrustCurve
from conftest import profile

PARAMS = load_hexacopter_params()


def _airframe():
    plant = MultibodyPlant(0.0)
    add_hexacopter(plant, PARAMS)
    plant.Finalize()
    return airframe(plant, PARAMS)


def test_model_is_an_f550_class_hexacopter():
    frame = _airframe()
    assert frame.num_rotors == 6
    assert frame.mass == pytest.approx(2.5)
    diagonal = 2 * np.linalg.norm(frame.p_BR[:, :2], axis=1)
    np.testing.assert_allclose(diagonal, 0.55, atol=0.005)  # motor to motor
    assert sorted(np.sign(frame.yaw_moment)) == [-1, -1, -1, 1, 1, 1]
    assert np.all(frame.yaw_moment[::2] == -frame.yaw_moment[1::2])  # alternating spin
    thrust_to_weight = 6 * frame.max_thrust / (frame.mass * GRAVITY)
    assert 1.8 < thrust_to_weight < 2.6


def test_hover_thrust_matches_weight(hover_run):
    truth = hover_run["ground_truth"]
    hover = (truth["time"] > 8.0) & (truth["time"] < 16.0)  # the hover segment of the profile
    thrust = hover_run.field("ground_truth", "rotor_thrust")[hover].sum(axis=1)
    weight = 2.5 * GRAVITY
    assert thrust.mean() == pytest.approx(weight, rel=0.02)
    # The normalized hover thrust M(33) the pilot commanded maps back to the weight (M(34)).
    command = hover_run["fc_command"]
    hover_command = command["thrust"][(command["time"] > 8.0) & (command["time"] < 16.0)]
    curve = _airframe().thrust_curve
    assert curve.apparent_mass(hover_command.mean()) == pytest.approx(2.5, rel=0.02)


def test_hover_demo_takes_off_hovers_and_lands(hover_run):
    truth = hover_run["ground_truth"]
    z = truth["p_WB_2"].to_numpy()
    t = truth["time"].to_numpy()
    assert 4.0 < z.max() - z[0] < 6.0
    assert np.std(z[(t > 8.0) & (t < 16.0)]) < 0.3
    assert abs(z[-1] - z[0]) < 0.01  # back on its legs
    status = hover_run["fc_status"]
    assert status["armed"].iloc[-1] == 0.0


def test_collective_curve_equals_sum_of_rotor_curves():
    frame = _airframe()
    esc = EscThrustMap(6, frame.rotor_curve)
    context = esc.CreateDefaultContext()
    esc.GetInputPort("armed").FixValue(context, [1.0])
    for command in (0.0, 0.3, 0.637, 1.0):
        esc.GetInputPort("motor_command").FixValue(context, np.full(6, command))
        total = esc.get_output_port().Eval(context).sum()
        assert total == pytest.approx(frame.thrust_curve.force(command), rel=1e-12)
    curve = frame.thrust_curve
    assert curve.thrust(curve.force(0.42)) == pytest.approx(0.42)


def test_esc_saturates_and_stops_on_bad_commands_or_disarm():
    frame = _airframe()
    esc = EscThrustMap(6, frame.rotor_curve)
    context = esc.CreateDefaultContext()
    esc.GetInputPort("armed").FixValue(context, [1.0])
    esc.GetInputPort("motor_command").FixValue(context, [1.5, -0.5, np.nan, np.inf, 0.5, 1.0])
    thrust = esc.get_output_port().Eval(context)
    assert thrust[0] == pytest.approx(frame.max_thrust) and thrust[5] == thrust[0]
    assert thrust[1] == pytest.approx(frame.min_thrust)  # idle
    assert thrust[2] == pytest.approx(frame.min_thrust) and thrust[3] == thrust[2]
    esc.GetInputPort("armed").FixValue(context, [0.0])
    assert np.all(esc.get_output_port().Eval(context) == 0.0)


def test_motor_reaches_63_percent_after_one_time_constant():
    dut = first_order_motors(PARAMS.time_constant, 6, 0.001)
    context = dut.CreateDefaultContext()
    dut.get_input_port().FixValue(context, np.full(6, 4.0))
    simulator = Simulator(dut, context)
    simulator.AdvanceTo(PARAMS.time_constant)
    np.testing.assert_allclose(dut.get_output_port().Eval(context), 4.0 * (1 - np.exp(-1)),
                               rtol=0.03)


def test_vehicle_at_rest_on_the_ground_neither_drifts_nor_sinks(vehicle_config, tmp_path):
    run = fly_profile(vehicle_config, profile("{duration: 5.0, arm: false}"), run_dir=tmp_path)
    p = run.field("ground_truth", "p_WB").to_numpy()
    assert np.linalg.norm(p[-1, :2] - p[0, :2]) < 1e-3
    assert abs(p[-1, 2] - 0.22) < 2e-3  # the legs' resting height, no sinking
    assert np.abs(run.field("ground_truth", "v_WB").to_numpy()[-100:]).max() < 1e-3


@pytest.mark.parametrize("heading", [0.0, 0.7])
def test_drag_force_for_air_relative_velocity(heading):
    dut = AerodynamicDrag(body_index=BodyIndex(1), linear=PARAMS.drag_linear,
                          quadratic=PARAMS.drag_quadratic)
    context = dut.CreateDefaultContext()
    q_WB = RollPitchYaw(0, 0, heading).ToQuaternion().wxyz()
    dut.GetInputPort("body_state").FixValue(context, np.concatenate(
        [q_WB, np.zeros(3), np.zeros(3), np.zeros(3)]))
    wind = 15 / 3.6  # the landing paper's field-test wind
    dut.GetInputPort("wind").FixValue(context, [wind, 0, 0])
    (force,) = dut.GetOutputPort("spatial_forces").Eval(context)
    f_W = force.F_Bq_W.translational()
    # The body sees air moving at +wind along x_W; in B that splits over x_B and y_B.
    v_B = RollPitchYaw(0, 0, heading).ToRotationMatrix().inverse().multiply([wind, 0, 0])
    expected_B = np.asarray(PARAMS.drag_linear) * v_B \
        + np.asarray(PARAMS.drag_quadratic) * np.abs(v_B) * v_B
    expected_W = RollPitchYaw(0, 0, heading).ToRotationMatrix().multiply(expected_B)
    np.testing.assert_allclose(f_W, expected_W, rtol=1e-9)
    assert f_W[0] > 0  # pushed downwind
    if heading == 0.0:
        assert f_W[0] == pytest.approx(0.25 * wind + 0.06 * wind**2)  # 2.08 N at 15 km/h


def test_sampled_drag_holds_the_force_of_its_last_sample():
    """With a period (the vehicle's 250 Hz), the drag is the same function of the body state
    and wind, sampled at initialization and every period, held in between."""
    dut = AerodynamicDrag(body_index=BodyIndex(1), linear=PARAMS.drag_linear,
                          quadratic=PARAMS.drag_quadratic, period=0.004)
    context = dut.CreateDefaultContext()
    state = dut.GetInputPort("body_state")
    state.FixValue(context, np.r_[1.0, 0, 0, 0, np.zeros(6), 2.0, 0, 0])
    dut.GetInputPort("wind").FixValue(context, np.zeros(3))
    simulator = Simulator(dut, context)
    simulator.Initialize()
    force = lambda: dut.GetOutputPort("spatial_forces").Eval(context)[0].F_Bq_W.translational()
    np.testing.assert_allclose(force(), [-(0.25 * 2.0 + 0.06 * 4.0), 0, 0])  # sampled at t = 0
    simulator.AdvanceTo(0.002)
    state.FixValue(context, np.r_[1.0, 0, 0, 0, np.zeros(6), 1.0, 0, 0])
    np.testing.assert_allclose(force(), [-0.74, 0, 0])                       # held
    simulator.AdvanceTo(0.0041)
    np.testing.assert_allclose(force(), [-(0.25 + 0.06), 0, 0])              # sampled at 4 ms


def test_hovering_vehicle_is_carried_at_the_mean_wind_speed(vehicle_config, tmp_path):
    config = copy.deepcopy(vehicle_config)
    config.wind = WindParams(mean_speed=15 / 3.6, direction=90.0)
    config.fc_estimate.attitude_error_std = 0.0  # isolate the drag from attitude-estimate drift
    run = fly_profile(config, profile("""
        {duration: 0.5, vertical_acceleration: -9.81}
        {duration: 1.0, vertical_acceleration: 1.5}
        {duration: 1.0, vertical_acceleration: -1.5}
        {duration: 12.0}
        """), run_dir=tmp_path)
    truth = run["ground_truth"]
    v = run.field("ground_truth", "v_WB").to_numpy()
    t = truth["time"].to_numpy()
    # Level attitude, no position control: drag accelerates the vehicle toward the air's speed,
    # m dv/dt = c1 (w - v) + c2 |w - v| (w - v), from lift-off (about 0.6 s).
    wind = 15 / 3.6
    expected, dt = 0.0, 0.001
    for _ in np.arange(0.6, 14.5, dt):
        relative = wind - expected
        expected += dt * (0.25 * relative + 0.06 * abs(relative) * relative) / 2.5
    at = np.argmin(np.abs(t - 14.5))
    assert v[at, 1] == pytest.approx(expected, rel=0.1)
    assert np.abs(v[t > 3.0, 0]).max() < 0.1  # nothing across the wind


def test_gusts_have_the_configured_mean_and_spread():
    params = WindParams(mean_speed=4.0, direction=30.0, gust_std=1.0, vertical_gust_std=0.3,
                        correlation_time=1.0, period=0.05)
    builder = DiagramBuilder()
    wind = builder.AddSystem(Wind(params))
    noise = builder.AddSystem(RandomSource(RandomDistribution.kGaussian, 3, params.period))
    builder.Connect(noise.get_output_port(), wind.GetInputPort("noise"))
    from pydrake.systems.primitives import VectorLogSink
    sink = builder.AddSystem(VectorLogSink(3, params.period))
    builder.Connect(wind.get_output_port(), sink.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(7))
    simulator.AdvanceTo(600.0)
    samples = sink.FindLog(simulator.get_context()).data()[:, 100:]
    mean = samples.mean(axis=1)
    np.testing.assert_allclose(mean[:2], 4.0 * np.array([np.cos(np.pi / 6), np.sin(np.pi / 6)]),
                               atol=0.25)  # 600 s / 1 s correlation: standard error ~0.06
    np.testing.assert_allclose(samples.std(axis=1), [1.0, 1.0, 0.3], rtol=0.15)
    lag = int(params.correlation_time / params.period)
    x = samples[0] - mean[0]
    correlation = np.corrcoef(x[:-lag], x[lag:])[0, 1]
    assert correlation == pytest.approx(np.exp(-1), abs=0.12)
