"""A consumer MEMS IMU: accelerometer and gyroscope with white noise and bias random walk.

Per axis and sample (period dt): y = truth + b + n_d w1, b <- b + n_b sqrt(dt) w2, with the noise
densities of the YAML file turned into per-sample standard deviations (n_d = density / sqrt(dt)).
The truth comes from Drake's `Accelerometer` and `Gyroscope`; the noise from a `RandomSource`.
"""
import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import ImuSamples
from alight.systems.params import bounded


@dc.dataclass
class ImuParams:
    """Defaults: an MPU-9250/ICM-20602-class IMU (Kalibr-style densities), noise inflated for
    the vibration of a multirotor."""
    period: float = bounded(0.004, 0.0005, 0.1, "s")                        # 250 Hz
    accel_noise_density: float = bounded(0.02, 0.0, 1.0, "m/s^2/sqrt(Hz)")
    accel_bias_random_walk: float = bounded(1e-3, 0.0, 1.0, "m/s^3/sqrt(Hz)")
    gyro_noise_density: float = bounded(1.7e-3, 0.0, 1.0, "rad/s/sqrt(Hz)")
    gyro_bias_random_walk: float = bounded(2e-5, 0.0, 1.0, "rad/s^2/sqrt(Hz)")
    accel_bias: list[float] = bounded([0.05, -0.04, 0.03], -2.0, 2.0, "m/s^2")   # initial
    gyro_bias: list[float] = bounded([0.004, -0.003, 0.002], -0.5, 0.5, "rad/s")  # initial
    buffer_length: int = bounded(125, 2, 100000)  # samples kept on the port (0.5 s at 250 Hz)


class Imu(LeafSystem):
    """Input  `specific_force`   (3) true specific force in B [m/s^2]
    Input  `angular_velocity` (3) true angular velocity of B in B [rad/s]
    Input  `noise`            (12) unit white Gaussian noise, resampled every `period`
    Output `imu`              ImuSamples, the last `buffer_length` samples
    Output `bias`             (6) true accelerometer and gyroscope biases (for tests and logs)
    """

    def __init__(self, params: ImuParams):
        super().__init__()
        self._period = params.period
        self._capacity = params.buffer_length
        # Python floats: the per-sample arithmetic is on floats (NumPy's per-call overhead
        # dominates on 6-vectors), the same IEEE operations per element.
        self._white = (np.repeat([params.accel_noise_density, params.gyro_noise_density], 3)
                       / np.sqrt(params.period)).tolist()
        self._walk = (np.repeat([params.accel_bias_random_walk, params.gyro_bias_random_walk], 3)
                      * np.sqrt(params.period)).tolist()
        self._specific_force = self.DeclareVectorInputPort("specific_force", 3)
        self._angular_velocity = self.DeclareVectorInputPort("angular_velocity", 3)
        self._noise = self.DeclareVectorInputPort("noise", 12)
        bias = self.DeclareDiscreteState(np.concatenate([params.accel_bias, params.gyro_bias]))
        samples = self.DeclareAbstractState(AbstractValue.Make(ImuSamples.empty()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("imu", samples)
        self.DeclareStateOutputPort("bias", bias)
        # State accessed by int index: pydrake converts a state index object on every call.
        self._bias, self._samples = int(bias), int(samples)

    def _update(self, context, state):
        # `state` holds the current state on entry (Drake copies it in): the bias updated in place.
        bias = state.get_mutable_discrete_state(self._bias).get_mutable_value()
        b = bias.tolist()
        noise = self._noise.Eval(context).tolist()
        truth = self._specific_force.Eval(context).tolist() \
            + self._angular_velocity.Eval(context).tolist()
        measured = [y + b_ + w * n for y, b_, w, n in zip(truth, b, self._white, noise)]
        samples = context.get_abstract_state(self._samples).get_value()
        seq = int(samples.seq[-1]) + 1 if len(samples) else 0
        state.get_mutable_abstract_state(self._samples).set_value(samples.appended(
            seq, context.get_time(), measured[:3], measured[3:], self._capacity))
        bias[:] = [b_ + w * n for b_, w, n in zip(b, self._walk, noise[6:])]
