"""The estimator bank's input, the unbiased desired acceleration M(53) (M Sec. 3.1.1), in the
flight controller's attitude frame.

Where the active controller outputs M(53) itself (the force controllers' and the failsafe's
`desired_acceleration`, forwarded by the control manager, in the estimator frame E), that is the
input, turned about e3 from E to the attitude frame by the two headings (M(12)-(14)).

Otherwise (the landing paper's linear MPC: attitude + thrust commands, no disturbance estimate of
its own) a stand-in from the command: a_d = f(T) / m R_WD e3 - g e3, with f(T) the thrust curve
M(32) of the controller's model and R_WD the commanded orientation, zero while the commanded
thrust holds less than `ground_fraction` of the weight (idle before take-off: the ground carries
the rest; the MPC's own lower thrust bound is about 0.39 of the weight).

Either is zero while the flight controller reports the vehicle landed or disarmed: without this
the filters would predict a free fall on the ground. (The bank itself drops the downward part
while its rangefinder reads the vehicle on the ground: `bank.py`, ground contact.)
"""
import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_ATTITUDE, FC_COMMAND, FC_STATUS, STATE_ESTIMATE
from alight.systems.estimation.heading import rotation_z
from alight.systems.rotations import heading, rotation_matrix
from alight.systems.thrust_curve import GRAVITY, ThrustCurve


class CommandAcceleration(LeafSystem):
    """Input  `fc_command`              FC_COMMAND (attitude + thrust)
    Input  `fc_status`               FC_STATUS (armed, landed)
    Input  `controller_acceleration` (3, optional) the active controller's M(53) [m/s^2, in E],
                                      NaN when it has none (then the command stand-in)
    Input  `state_estimate`          STATE_ESTIMATE (optional; with the above: E's heading)
    Input  `fc_attitude`             FC_ATTITUDE (optional; with the above: the attitude heading)
    Output `desired_acceleration`    (3) [m/s^2, attitude frame], zero while disarmed or landed
                                      or for an unusable command
    """

    def __init__(self, mass: float, curve: ThrustCurve, ground_fraction: float = 0.25):
        super().__init__()
        self._mass, self._curve, self._ground_fraction = mass, curve, ground_fraction
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self._status = self.DeclareVectorInputPort("fc_status", FC_STATUS.size)
        self._controller = self.DeclareVectorInputPort("controller_acceleration", 3)
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self.DeclareVectorOutputPort("desired_acceleration", 3, self._calc)

    def _calc(self, context, output):
        status = self._status.Eval(context)
        if FC_STATUS.get(status, "armed") < 0.5 or FC_STATUS.get(status, "landed") > 0.5:
            output.SetFromVector(np.zeros(3))
            return
        a_o = self._controller_acceleration(context)
        output.SetFromVector(a_o if a_o is not None else self._stand_in(context))

    def _controller_acceleration(self, context) -> np.ndarray | None:
        """The controller's M(53) in the attitude frame; None where it has none or the frames'
        headings are not known."""
        if not (self._controller.HasValue(context) and self._estimate.HasValue(context)
                and self._attitude.HasValue(context)):
            return None
        a_E = self._controller.Eval(context)
        estimate = self._estimate.Eval(context)
        q_WB = FC_ATTITUDE.get(self._attitude.Eval(context), "q_WB")
        if not (np.all(np.isfinite(a_E)) and np.all(np.isfinite(estimate))
                and STATE_ESTIMATE.get(estimate, "valid") > 0.5 and np.all(np.isfinite(q_WB))
                and np.linalg.norm(q_WB) > 0.5):
            return None
        eta_o = heading(rotation_matrix(q_WB))
        return rotation_z(eta_o - STATE_ESTIMATE.get(estimate, "heading")) @ a_E

    def _stand_in(self, context) -> np.ndarray:
        command = self._command.Eval(context)
        q = FC_COMMAND.get(command, "q_WD")
        if FC_COMMAND.get(command, "arm") < 0.5 or not np.all(np.isfinite(command)) \
                or np.linalg.norm(q) < 0.5:
            return np.zeros(3)
        force = float(self._curve.force(FC_COMMAND.get(command, "thrust")))
        if force < self._ground_fraction * self._mass * GRAVITY:
            return np.zeros(3)
        return force / self._mass * rotation_matrix(q)[:, 2] - np.array([0.0, 0.0, GRAVITY])
