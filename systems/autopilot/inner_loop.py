"""The flight controller's inner loop, as PX4 runs it every control period: attitude control
(attitude_control.py), the body-rate PID (rate_control.py) and the mixer (mixer.py), whose ESC
commands are held until the next period (the PWM outputs).

One LeafSystem with one update per period, its ESC commands a state output port: the plant reads
them at every step without a Python call. What a period computes is what the former chain of
systems (attitude controller, rate controller, mixer, zero-order hold) computed: the commands of
the tick at t_k come from the commander's setpoint and the attitude estimate as they were just
before t_k, and the rate PID's memory moves on from the same values.
"""
import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.autopilot.attitude_control import AttitudeControlParams, rate_setpoint
from alight.systems.autopilot.mixer import Mixer
from alight.systems.autopilot.rate_control import RateControlParams, RatePid
from alight.systems.autopilot.setpoint import SETPOINT
from alight.systems.boundary import FC_ATTITUDE
from alight.systems.plant.hexacopter import Airframe


class InnerLoop(LeafSystem):
    """Input  `setpoint`      SETPOINT (mode, q_WD, w_D, thrust, armed) from the commander
    Input  `fc_attitude`   FC_ATTITUDE estimate (its body rates are the rate loop's measurement)
    Output `motor_command` (n) ESC commands in [0, 1], held for `period` (zero while disarmed)
    State: the rate PID's memory (6) and the held commands (n), updated every `period`.
    """

    def __init__(self, attitude: AttitudeControlParams, rate: RateControlParams,
                 airframe: Airframe, period: float):
        super().__init__()
        self._attitude_params = attitude
        self._max_rate = np.asarray(attitude.max_rate, float).tolist()
        self._pid = RatePid(rate, airframe.inertia, period)
        self._mixer = Mixer(airframe)
        self._setpoint = self.DeclareVectorInputPort("setpoint", SETPOINT.size)
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        memory = self.DeclareDiscreteState(6)
        command = self.DeclareDiscreteState(airframe.num_rotors)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("motor_command", command)
        # Groups accessed by int index: pydrake converts a DiscreteStateIndex on every call.
        self._memory, self._command = int(memory), int(command)

    def _update(self, context, discrete_state):
        # `discrete_state` holds the current state on entry (Drake copies it in).
        setpoint = self._setpoint.Eval(context)
        attitude = self._attitude.Eval(context)
        w = attitude[_W_B].tolist()
        memory = discrete_state.get_mutable_value(self._memory)
        previous = memory.tolist()
        rates = rate_setpoint(setpoint, attitude, self._attitude_params, self._max_rate)
        torque = self._pid.torque(rates, w, previous)
        discrete_state.set_value(self._command, self._mixer.motor_commands(setpoint, torque))
        memory[:] = self._pid.updated(rates, w, setpoint[_ARMED] > 0.5, previous)


_W_B = FC_ATTITUDE.slice("w_B")
_ARMED = SETPOINT.slice("armed").start
