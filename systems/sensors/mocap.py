"""The `mocap` odometry source (DESIGN.md, M Sec. 3.2): true pose plus noise, with latency.

A sensor model on the simulation side: it reads the simulation's `ground_truth` (as a motion-capture
system observes the real vehicle) and publishes a STATE_ESTIMATE in the mocap frame (= W) at `period`.
Position and orientation get white noise, velocity is the noisy finite difference a mocap pipeline
would compute, acceleration the finite difference of that. Latency: `make_mocap` puts a Drake
`DiscreteTimeDelay` behind it. Never the default odometry when VIO is available.
"""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import GROUND_TRUTH, STATE_ESTIMATE
from alight.systems.params import bounded
from alight.systems.rotations import (quaternion_from_rotation_vector, quaternion_product,
                                      rotation_matrix, heading)


# the fields read every tick
_P_WB, _Q_WB = GROUND_TRUTH.slice("p_WB"), GROUND_TRUTH.slice("q_WB")
_P_EB, _V_EB = STATE_ESTIMATE.slice("p_EB"), STATE_ESTIMATE.slice("v_EB")
_HEADING, _VALID = STATE_ESTIMATE.slice("heading").start, STATE_ESTIMATE.slice("valid").start


@dc.dataclass
class MocapParams:
    period: float = bounded(0.01, 0.001, 1.0, "s")             # 100 Hz
    latency: float = bounded(0.02, 0.0, 1.0, "s")              # rounded to whole periods
    position_noise_std: float = bounded(0.001, 0.0, 1.0, "m")    # Vicon/OptiTrack class
    attitude_noise_std: float = bounded(0.3, 0.0, 10.0, "deg")
    velocity_filter: float = bounded(0.6, 0.0, 0.99)  # weight of the previous velocity (smoothing)


class Mocap(LeafSystem):
    """Input  `ground_truth`   GROUND_TRUTH (simulation side only)
    Input  `noise`          (6) unit white Gaussian noise, resampled every `period`
    Output `state_estimate` STATE_ESTIMATE in the mocap frame (frame id 0), before latency
    """

    def __init__(self, params: MocapParams):
        super().__init__()
        self._p = params
        self._attitude_std = np.radians(params.attitude_noise_std)   # [rad]
        self._truth = self.DeclareVectorInputPort("ground_truth", GROUND_TRUTH.size)
        self._noise = self.DeclareVectorInputPort("noise", 6)
        self._xd = self.DeclareDiscreteState(STATE_ESTIMATE.size)
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("state_estimate", self._xd)

    def _update(self, context, discrete_state):
        previous = context.get_discrete_state(self._xd).get_value()
        truth = self._truth.Eval(context)
        noise = self._noise.Eval(context)
        p = truth[_P_WB] + self._p.position_noise_std * noise[:3]
        q = quaternion_product(truth[_Q_WB], quaternion_from_rotation_vector(
            self._attitude_std * noise[3:]))
        first = previous[_VALID] < 0.5
        dt = self._p.period
        raw_v = np.zeros(3) if first else (p - previous[_P_EB]) / dt
        alpha = 0.0 if first else self._p.velocity_filter
        v = alpha * previous[_V_EB] + (1 - alpha) * raw_v
        a = np.zeros(3) if first else (v - previous[_V_EB]) / dt
        eta = heading(rotation_matrix(q))
        eta_rate = 0.0 if first else np.angle(np.exp(1j * (eta - previous[_HEADING]))) / dt
        var_p = self._p.position_noise_std ** 2
        var_v = 2 * var_p / dt ** 2 * (1 - alpha) / (1 + alpha)
        discrete_state.set_value(self._xd, STATE_ESTIMATE.pack(
            stamp=context.get_time(), p_EB=p, v_EB=v, a_EB=a, q_EB=q, heading=eta,
            heading_rate=eta_rate, var_pv=[var_p] * 3 + [var_v] * 3,
            var_heading=self._attitude_std ** 2, frame_id=0.0,
            frame_counter=0.0, p_OldNew=np.zeros(3), q_OldNew=[1, 0, 0, 0], valid=1.0))
