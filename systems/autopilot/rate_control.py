"""Body-rate PID controller: rate error -> torque demand, as PX4's rate controller.

alpha = Kp e + Ki integral(e) - Kd d(w)/dt (derivative on measurement), torque = J alpha + w x J w.
The integrator is clamped and reset while disarmed or landed, like PX4's.
"""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.autopilot.setpoint import SETPOINT
from alight.systems.boundary import FC_ATTITUDE
from alight.systems.params import bounded
from alight.systems.rotations import cross


@dc.dataclass
class RateControlParams:
    kp: list[float] = bounded([14.0, 14.0, 8.0], 0.0, 200.0, "1/s")
    ki: list[float] = bounded([10.0, 10.0, 5.0], 0.0, 500.0, "1/s^2")
    kd: list[float] = bounded([0.25, 0.25, 0.0], 0.0, 10.0, "")
    integrator_limit: list[float] = bounded([3.0, 3.0, 2.0], 0.0, 50.0, "rad/s^2")


class RateController(LeafSystem):
    """Input  `rate_setpoint` (3) [rad/s, in B]
    Input  `fc_attitude`   FC_ATTITUDE (its body rates are the measurement)
    Input  `setpoint`      SETPOINT (armed flag resets the integrator)
    Output `torque`        (3) torque demand [N m, in B]
    State: integral of the rate error (3), previous measured rate (3); updated every `period`.
    """

    def __init__(self, params: RateControlParams, inertia: np.ndarray, period: float):
        super().__init__()
        self._p = params
        self._J = np.asarray(inertia)
        self._period = period
        self._kp, self._kd = np.asarray(params.kp, float), np.asarray(params.kd, float)
        self._ki_dt = np.asarray(params.ki, float) * period
        self._limit = np.asarray(params.integrator_limit, float)
        self._rate_setpoint = self.DeclareVectorInputPort("rate_setpoint", 3)
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self._setpoint = self.DeclareVectorInputPort("setpoint", SETPOINT.size)
        self._xd = self.DeclareDiscreteState(6)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("torque", 3, self._calc)

    def _update(self, context, discrete_state):
        w = self._attitude.Eval(context)[_W_B]
        x = discrete_state.get_mutable_value(self._xd)
        if self._setpoint.Eval(context)[_ARMED] > 0.5:
            error = self._rate_setpoint.Eval(context) - w
            x[:3] = np.minimum(np.maximum(x[:3] + self._ki_dt * error, -self._limit),
                               self._limit)
        else:
            x[:3] = 0.0
        x[3:] = w

    def _calc(self, context, output):
        w = self._attitude.Eval(context)[_W_B]
        x = context.get_discrete_state(self._xd).get_value()
        alpha = self._kp * (self._rate_setpoint.Eval(context) - w) + x[:3] \
            - self._kd * (w - x[3:]) / self._period
        output.SetFromVector(self._J * alpha + cross(w, self._J * w))


_W_B = FC_ATTITUDE.slice("w_B")
_ARMED = SETPOINT.slice("armed").start
