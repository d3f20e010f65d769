"""The flight controller's own state estimate (what PX4's EKF2 hands its controllers).

Attitude: the true orientation perturbed by a slowly varying error (Ornstein-Uhlenbeck, a few
tenths of a degree, as a tuned EKF2 on a level-calibrated Pixhawk); body rates: true rates plus
white noise (filtered gyro); vertical velocity: truth plus noise (baro/accelerometer fusion),
used only by the flight controller's failsafe descent and land detector.
"""
import dataclasses as dc
import math

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_ATTITUDE
from alight.systems.params import bounded
from alight.systems.rotations import (product_floats, quaternion_from_rotation_vector,
                                      rotation_matrix)


@dc.dataclass
class FcEstimateParams:
    period: float = bounded(0.004, 0.001, 0.1, "s")  # 250 Hz
    attitude_error_std: float = bounded(0.3, 0.0, 10.0, "deg")
    attitude_error_time: float = bounded(5.0, 0.01, 1000.0, "s")  # correlation time
    rate_noise_std: float = bounded(0.005, 0.0, 1.0, "rad/s")
    vertical_velocity_noise_std: float = bounded(0.05, 0.0, 2.0, "m/s")


class FcEstimate(LeafSystem):
    """Input  `body_state`        (13) true free-body state [q_WB, p_WB, w_WB (W), v_WB (W)]
    Input  `noise`             (7) unit white Gaussian noise, resampled every `period`
    Output `fc_attitude`       (8) FC_ATTITUDE: stamp, q_WB estimate, body rates (B)
    Output `vertical_velocity` (1) estimated v_WB z [m/s]
    """

    def __init__(self, params: FcEstimateParams):
        super().__init__()
        decay = np.exp(-params.period / params.attitude_error_time)
        self._decay = float(decay)  # Python floats: the per-call arithmetic is on floats
        self._attitude_drive = float(np.radians(params.attitude_error_std)
                                     * np.sqrt(1.0 - decay**2))
        self._rate_std = params.rate_noise_std
        self._vz_std = params.vertical_velocity_noise_std
        self._state = self.DeclareVectorInputPort("body_state", 13)
        self._noise = self.DeclareVectorInputPort("noise", 7)
        # State: the rotation-vector attitude error (3) and the two outputs, each its own group
        # so that the outputs are state output ports (no Python call when read).
        error = self.DeclareDiscreteState(3)
        initial = np.zeros(FC_ATTITUDE.size)
        initial[FC_ATTITUDE.slice("q_WB").start] = 1.0
        fc_attitude = self.DeclareDiscreteState(initial)
        vz = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self.DeclareStateOutputPort("fc_attitude", fc_attitude)
        self.DeclareStateOutputPort("vertical_velocity", vz)
        # Groups accessed by int index: pydrake converts a DiscreteStateIndex on every call.
        self._error, self._fc_attitude, self._vz = int(error), int(fc_attitude), int(vz)

    def _update(self, context, discrete_state):
        # On Python floats where NumPy's per-call overhead dominates (3- and 4-vectors); the
        # rotation keeps NumPy's matrix product (BLAS rounds differently from plain floats).
        # `discrete_state` holds the current state on entry (Drake copies it in); updated in place,
        # each group with one write.
        x = self._state.Eval(context)
        noise = self._noise.Eval(context).tolist()
        error_state = discrete_state.get_mutable_value(self._error)
        error = [self._decay * e + self._attitude_drive * n
                 for e, n in zip(error_state.tolist(), noise[:3])]
        error_state[:] = error
        q = x[:4]
        norm = math.sqrt(q.dot(q))  # np.linalg.norm(q)
        q_WB = [e / norm for e in q.tolist()]
        w_B = (rotation_matrix(q_WB).T @ x[7:10]).tolist()
        discrete_state.get_mutable_value(self._fc_attitude)[:] = [
            context.get_time(),
            *product_floats(*q_WB, *quaternion_from_rotation_vector(error).tolist()),
            *[w + self._rate_std * n for w, n in zip(w_B, noise[3:6])]]
        discrete_state.get_mutable_value(self._vz)[0] = x[12] + self._vz_std * noise[6]


# _update writes FC_ATTITUDE in its field order.
assert [name for name, _ in FC_ATTITUDE.fields] == ["stamp", "q_WB", "w_B"]
