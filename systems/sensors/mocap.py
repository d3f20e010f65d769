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
from alight.systems.rotations import (product_floats, quaternion_from_rotation_vector,
                                      quaternion_heading)


# the fields read and written every tick
_P_WB, _Q_WB = GROUND_TRUTH.slice("p_WB"), GROUND_TRUTH.slice("q_WB")
_P_EB, _V_EB, _A_EB, _Q_EB, _VAR_PV = (STATE_ESTIMATE.slice(field) for field in (
    "p_EB", "v_EB", "a_EB", "q_EB", "var_pv"))
_HEADING, _VALID = (STATE_ESTIMATE.slice(field).start for field in ("heading", "valid"))
# the fields written at every tick, in the layout's order
_CHANGING = slice(STATE_ESTIMATE.slice("stamp").start, _VAR_PV.stop)
assert [f for f, _ in STATE_ESTIMATE.fields][:8] == [
    "stamp", "p_EB", "v_EB", "a_EB", "q_EB", "heading", "heading_rate", "var_pv"]


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
        self._xd_group = int(self._xd)   # (pydrake converts a DiscreteStateIndex per call)
        # the published fields that never change (the layout's defaults: q_OldNew, valid...)
        self._constant = STATE_ESTIMATE.pack(
            stamp=0.0, p_EB=0.0, v_EB=0.0, a_EB=0.0, heading=0.0, heading_rate=0.0, var_pv=0.0,
            var_heading=self._attitude_std ** 2, frame_id=0.0, frame_counter=0.0,
            p_OldNew=np.zeros(3), q_OldNew=[1, 0, 0, 0], valid=1.0)
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("state_estimate", self._xd)

    def _update(self, context, discrete_state):
        # On the elements as Python floats (this runs at every tick): the operations, element by
        # element, of the NumPy expressions they stand for.
        previous = context.get_discrete_state().get_value(self._xd_group).tolist()
        truth = self._truth.Eval(context)
        noise = self._noise.Eval(context).tolist()
        std = self._p.position_noise_std
        p = [p_i + std * n_i for p_i, n_i in zip(truth[_P_WB].tolist(), noise[:3])]
        q = product_floats(*truth[_Q_WB].tolist(), *quaternion_from_rotation_vector(
            [self._attitude_std * n_i for n_i in noise[3:]]).tolist())
        first = previous[_VALID] < 0.5
        dt = self._p.period
        alpha = 0.0 if first else self._p.velocity_filter
        if first:   # no velocity from one sample (the previous state is the zero initial one)
            v, a = [0.0] * 3, [0.0] * 3
        else:
            raw_v = [(p_i - u_i) / dt for p_i, u_i in zip(p, previous[_P_EB])]
            v_previous = previous[_V_EB]
            v = [alpha * u_i + (1 - alpha) * r_i for u_i, r_i in zip(v_previous, raw_v)]
            a = [(v_i - u_i) / dt for v_i, u_i in zip(v, v_previous)]
        eta = quaternion_heading(*q)
        eta_rate = 0.0 if first else np.angle(np.exp(1j * (eta - previous[_HEADING]))) / dt
        var_p = std ** 2
        var_v = 2 * var_p / dt ** 2 * (1 - alpha) / (1 + alpha)
        # the fields that change, stamp to var_pv, written by one slice (the others: `_constant`)
        x = self._constant.copy()
        x[_CHANGING] = [context.get_time(), *p, *v, *a, *q, eta, eta_rate, var_p, var_p, var_p,
                        var_v, var_v, var_v]
        discrete_state.set_value(self._xd_group, x)
