"""A stand-in for the unbiased desired acceleration M(53) where the active controller is the
landing paper's linear MPC (attitude + thrust commands, no disturbance estimate of its own):
a_d = f(T) / m R_WD e3 - g e3, with f(T) the thrust curve M(32) of the controller's model and
R_WD the commanded orientation, in the flight controller's attitude frame. Zero while the flight
controller reports the vehicle landed or disarmed, or while the commanded thrust holds less than
`ground_fraction` of the weight (idle before take-off: the ground carries the rest; the MPC's
own lower thrust bound is about 0.39 of the weight): without this the filters would predict a
free fall on the ground. The flight-stack
controllers output M(53) itself (`desired_acceleration`) and feed the bank directly.
"""
import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_COMMAND, FC_STATUS
from alight.systems.rotations import rotation_matrix
from alight.systems.thrust_curve import GRAVITY, ThrustCurve


class CommandAcceleration(LeafSystem):
    """Input  `fc_command`           FC_COMMAND (attitude + thrust)
    Input  `fc_status`            FC_STATUS (armed, landed)
    Output `desired_acceleration` (3) [m/s^2], zero while disarmed or for an unusable command
    """

    def __init__(self, mass: float, curve: ThrustCurve, ground_fraction: float = 0.25):
        super().__init__()
        self._mass, self._curve, self._ground_fraction = mass, curve, ground_fraction
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self._status = self.DeclareVectorInputPort("fc_status", FC_STATUS.size)
        self.DeclareVectorOutputPort("desired_acceleration", 3, self._calc)

    def _calc(self, context, output):
        command = self._command.Eval(context)
        status = self._status.Eval(context)
        q = FC_COMMAND.get(command, "q_WD")
        if FC_COMMAND.get(command, "arm") < 0.5 or not np.all(np.isfinite(command)) \
                or np.linalg.norm(q) < 0.5 or FC_STATUS.get(status, "armed") < 0.5 \
                or FC_STATUS.get(status, "landed") > 0.5:
            output.SetFromVector(np.zeros(3))
            return
        force = float(self._curve.force(FC_COMMAND.get(command, "thrust")))
        if force < self._ground_fraction * self._mass * GRAVITY:
            output.SetFromVector(np.zeros(3))
            return
        output.SetFromVector(force / self._mass * rotation_matrix(q)[:, 2]
                             - np.array([0.0, 0.0, GRAVITY]))
