"""Applies the mission's arm request to a controller's command (disarmed: zero thrust, arm 0)."""
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_COMMAND

_ARM, _THRUST = FC_COMMAND.slice("arm").start, FC_COMMAND.slice("thrust").start


class ArmGate(LeafSystem):
    """Input  `fc_command` FC_COMMAND from the controller
    Input  `arm`        (2) the mission's arm request and thrust enable (0: thrust held at zero,
                        as the flight controller arms only at low thrust)
    Output `fc_command` FC_COMMAND with the arm request applied
    With `command_disarms`, a command that disarms itself (arm 0: the failsafe controller once
    on the ground, M Sec. 5.10) stays disarmed with zero thrust whatever the request; otherwise the
    request alone sets the arm flag.
    """

    def __init__(self, command_disarms: bool = False):
        super().__init__()
        self._command_disarms = command_disarms
        self._command = self.DeclareVectorInputPort("fc_command", FC_COMMAND.size)
        self._arm = self.DeclareVectorInputPort("arm", 2)
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, self._calc,
                                     {self.all_input_ports_ticket()})

    def _calc(self, context, output):
        command = self._command.Eval(context).copy()
        arm, thrust_enable = self._arm.Eval(context).tolist()
        if self._command_disarms and command[_ARM] < 0.5:
            arm = 0.0
        command[_ARM] = float(arm > 0.5)
        if arm < 0.5 or thrust_enable < 0.5:
            command[_THRUST] = 0.0
        output.SetFromVector(command)
