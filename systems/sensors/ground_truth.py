"""The simulation-only `ground_truth` output (DESIGN.md): never read by an onboard system."""
import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import CONTACTS, GROUND_TRUTH
from alight.systems.rotations import rotation_matrix


class GroundTruth(LeafSystem):
    """Input  `body_state`   (13) free-body state [q_WB, p_WB, w_WB (W), v_WB (W)]
    Input  `wind`         (3) air velocity v_WA [m/s, in W]
    Input  `motor_command` (n) ESC commands in [0, 1]
    Input  `rotor_thrust` (n) rotor thrusts [N]
    Input  `target_state` (13) [q_WT, p_WT, w_WT (W), v_WT (W)] of the target frame T; only with
                          `with_target` (otherwise target_present is 0)
    Input  `contacts`     CONTACTS layout, the vehicle's contacts (alight.systems.sensors.contacts)
    Output `ground_truth` GROUND_TRUTH layout
    """

    def __init__(self, num_rotors: int, with_target: bool = False):
        super().__init__()
        self._state = self.DeclareVectorInputPort("body_state", 13)
        self._wind = self.DeclareVectorInputPort("wind", 3)
        self._command = self.DeclareVectorInputPort("motor_command", num_rotors)
        self._thrust = self.DeclareVectorInputPort("rotor_thrust", num_rotors)
        self._target = self.DeclareVectorInputPort("target_state", 13) if with_target else None
        self._contacts = self.DeclareVectorInputPort("contacts", CONTACTS.size)
        self.DeclareVectorOutputPort("ground_truth", GROUND_TRUTH.size, self._calc)

    def _calc(self, context, output):
        x = self._state.Eval(context)
        q_WB = x[:4] / np.linalg.norm(x[:4])
        R_WB = rotation_matrix(q_WB)
        target = {}
        if self._target is not None:
            x_T = self._target.Eval(context)
            target = dict(p_WT=x_T[4:7], q_WT=x_T[:4] / np.linalg.norm(x_T[:4]),
                          v_WT=x_T[10:13], target_present=1.0)
        contacts = self._contacts.Eval(context)
        output.SetFromVector(GROUND_TRUTH.pack(
            p_WB=x[4:7], q_WB=q_WB, v_WB=x[10:13], w_WB_B=R_WB.T @ x[7:10],
            v_WA=self._wind.Eval(context), motor_command=self._command.Eval(context),
            rotor_thrust=self._thrust.Eval(context), **target,
            **{field: CONTACTS.get(contacts, field) for field, _ in CONTACTS.fields}))
