"""Electronic speed controllers: ESC command in [0, 1] -> steady-state rotor thrust [N].

The first-order motor response follows in the diagram (`first_order_motors`: a Drake discrete
`LinearSystem`, the exact zero-order-hold discretization of tau df/dt = f_cmd - f at the plant's
step); saturation happens here: commands are clipped to [0, 1], a non-finite
command stops the motor, and a disarmed vehicle's rotors do not turn.
"""
import math

import numpy as np
from pydrake.systems.framework import LeafSystem
from pydrake.systems.primitives import LinearSystem

from alight.systems.thrust_curve import ThrustCurve


class EscThrustMap(LeafSystem):
    """Input  `motor_command` (n) ESC commands in [0, 1]
    Input  `armed`         (1) 1 when the flight controller is armed
    Output `thrust_command` (n) steady-state thrust of each rotor [N]
    """

    def __init__(self, num_rotors: int, rotor_curve: ThrustCurve):
        super().__init__()
        self._curve = rotor_curve
        self._stopped = np.zeros(num_rotors)
        self._command = self.DeclareVectorInputPort("motor_command", num_rotors)
        self._armed = self.DeclareVectorInputPort("armed", 1)
        self.DeclareVectorOutputPort("thrust_command", num_rotors, self._calc,
                                     prerequisites_of_calc={self.all_input_ports_ticket()})

    def _calc(self, context, output):
        if self._armed.Eval(context)[0] > 0.5:
            # On Python floats: NumPy's per-call overhead dominates on a few rotors.
            command = [c if math.isfinite(c) else 0.0 for c in self._command.Eval(context).tolist()]
            output.SetFromVector(self._curve.force_floats(command))
        else:
            output.SetFromVector(self._stopped)


def first_order_motors(time_constant: float, num_rotors: int, period: float) -> LinearSystem:
    """Rotor thrusts following their commands with `time_constant`, sampled every `period`."""
    decay = np.exp(-period / time_constant)
    eye = np.eye(num_rotors)
    return LinearSystem(A=decay * eye, B=(1.0 - decay) * eye, C=eye, D=0.0 * eye,
                        time_period=period)
