"""A sampled sensor model on the simulation side (M Sec. 3.1.2 sources): reads `ground_truth`
and unit Gaussian noise every `period` and holds its message in discrete state; latency is a
Drake `DiscreteTimeDelay`. Subclasses give `measure`; `add_sampled_sensor` adds one with its
noise and latency to a diagram (the vehicle's rangefinder, the estimator bank's sources).
"""
import numpy as np
from pydrake.common import RandomDistribution
from pydrake.systems.framework import LeafSystem
from pydrake.systems.primitives import DiscreteTimeDelay, RandomSource

from alight.systems.boundary import GROUND_TRUTH, VectorLayout
from alight.systems.params import ConfigError


class SampledSensor(LeafSystem):
    """Input  `ground_truth` GROUND_TRUTH (simulation side only)
    Input  `noise`        (noise_size) unit white Gaussian noise, resampled every `period`
    Output `measurement`  `layout`, stamped with the sampling time, before latency
    """

    def __init__(self, layout: VectorLayout, period: float, noise_size: int,
                 memory=(0.0,)):
        super().__init__()
        self.layout, self.period, self.noise_size = layout, period, noise_size
        self._truth = self.DeclareVectorInputPort("ground_truth", GROUND_TRUTH.size)
        self._noise = self.DeclareVectorInputPort("noise", noise_size)
        self._message = self.DeclareDiscreteState(layout.size)  # valid = 0 until the first
        self._memory = self.DeclareDiscreteState(np.asarray(memory, float))  # e.g. a bias
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("measurement", self._message)

    def _update(self, context, discrete_state):
        memory = context.get_discrete_state(self._memory).get_value().copy()
        message = self.measure(context.get_time(), self._truth.Eval(context),
                               self._noise.Eval(context), memory)
        discrete_state.set_value(self._message, message)
        discrete_state.set_value(self._memory, memory)

    def measure(self, t: float, truth: np.ndarray, noise: np.ndarray,
                memory: np.ndarray) -> np.ndarray:
        raise NotImplementedError


def in_windows(t: float, windows: list[list[float]]) -> bool:
    """True while t lies in one of the [start, end) windows."""
    return any(start <= t < end for start, end in windows)


def check_windows(windows: list[list[float]], key: str) -> None:
    for window in windows:
        if len(window) != 2 or not window[0] < window[1]:
            raise ConfigError(f"key '{key}' = {windows!r}: each window is [start, end] with "
                              f"start < end [s]")


def add_sampled_sensor(builder, name: str, sensor, latency: float, ground_truth_port):
    """A `SampledSensor` with its noise source and latency; returns the delayed output port.
    A consumer sampling it sees messages `latency` (rounded to periods, at least one) old."""
    builder.AddNamedSystem(name, sensor)
    noise = builder.AddNamedSystem(f"{name}_noise", RandomSource(
        RandomDistribution.kGaussian, sensor.noise_size, sensor.period))
    builder.Connect(noise.get_output_port(), sensor.GetInputPort("noise"))
    builder.Connect(ground_truth_port, sensor.GetInputPort("ground_truth"))
    steps = round(latency / sensor.period) - 1  # the sensor's own state holds one period
    if steps <= 0:
        return sensor.GetOutputPort("measurement")
    delay = builder.AddNamedSystem(f"{name}_latency", DiscreteTimeDelay(
        sensor.period, steps, sensor.layout.size))
    builder.Connect(sensor.GetOutputPort("measurement"), delay.get_input_port())
    return delay.get_output_port()
