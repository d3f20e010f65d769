"""The mocap odometry source: noise, velocity and latency as configured."""
import numpy as np
import pytest
from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pydrake.systems.primitives import VectorLogSink

from alight.diagrams.onboard.mocap import add_mocap
from alight.systems.boundary import GROUND_TRUTH, STATE_ESTIMATE
from alight.systems.sensors.mocap import MocapParams

V = np.array([2.0, -1.0, 0.5])


class MovingTruth(LeafSystem):
    """Ground truth of a body moving at constant velocity V with heading 0.3 rad."""

    def __init__(self):
        super().__init__()
        self.DeclareVectorOutputPort("ground_truth", GROUND_TRUTH.size, self._calc)

    def _calc(self, context, output):
        t = context.get_time()
        output.SetFromVector(GROUND_TRUTH.pack(
            p_WB=V * t, q_WB=[np.cos(0.15), 0, 0, np.sin(0.15)], v_WB=V, w_WB_B=np.zeros(3),
            v_WA=np.zeros(3), motor_command=np.zeros(6), rotor_thrust=np.zeros(6)))


def test_mocap_tracks_pose_and_velocity_with_configured_latency():
    params = MocapParams(latency=0.05)
    builder = DiagramBuilder()
    truth = builder.AddSystem(MovingTruth())
    port = add_mocap(builder, truth.get_output_port(), params)
    sink = builder.AddSystem(VectorLogSink(STATE_ESTIMATE.size, params.period))
    builder.Connect(port, sink.get_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    diagram.SetRandomContext(simulator.get_mutable_context(), RandomGenerator(1))
    simulator.AdvanceTo(5.0)
    log = sink.FindLog(simulator.get_context())
    data, t = log.data(), log.sample_times()
    late = (t > 1.0) & (data[STATE_ESTIMATE.slice("valid")][0] > 0.5)
    p = data[STATE_ESTIMATE.slice("p_EB")][:, late]
    stamps = data[STATE_ESTIMATE.slice("stamp")][0, late]
    # The published sample is `latency` old: its stamp and its position say so.
    np.testing.assert_allclose(t[late] - stamps, 0.05 + params.period, atol=1e-6)
    position_error = p - np.outer(V, stamps)
    assert np.std(position_error) == pytest.approx(params.position_noise_std, rel=0.15)
    v = data[STATE_ESTIMATE.slice("v_EB")][:, late]
    np.testing.assert_allclose(v.mean(axis=1), V, atol=0.05)
    assert np.all(np.abs(data[STATE_ESTIMATE.slice("heading")][0, late] - 0.3) < 0.05)
