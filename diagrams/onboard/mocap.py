"""Adds the `mocap` odometry source (sensor model + latency) to a simulation diagram."""
from pydrake.common import RandomDistribution
from pydrake.systems.primitives import DiscreteTimeDelay, RandomSource

from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.sensors.mocap import Mocap, MocapParams


def add_mocap(builder, ground_truth_port, params: MocapParams, name: str = "mocap"):
    """Returns the output port of the delayed mocap STATE_ESTIMATE. A consumer sampling it sees
    measurements `latency` + one period (the sample-and-hold) old."""
    mocap = builder.AddNamedSystem(name, Mocap(params))
    noise = builder.AddNamedSystem(f"{name}_noise", RandomSource(
        RandomDistribution.kGaussian, 6, params.period))
    builder.Connect(noise.get_output_port(), mocap.GetInputPort("noise"))
    builder.Connect(ground_truth_port, mocap.GetInputPort("ground_truth"))
    steps = round(params.latency / params.period) - 1  # the Mocap's own state holds one period
    if steps <= 0:
        return mocap.GetOutputPort("state_estimate")
    delay = builder.AddNamedSystem(f"{name}_latency", DiscreteTimeDelay(
        params.period, steps, STATE_ESTIMATE.size))
    builder.Connect(mocap.GetOutputPort("state_estimate"), delay.get_input_port())
    return delay.get_output_port()
