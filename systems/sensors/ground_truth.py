"""The simulation-only `ground_truth` output (DESIGN.md): never read by an onboard system."""
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import CONTACTS, GROUND_TRUTH
from alight.systems.rotations import norm, rotation_matrix


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
        # A pure function of the inputs (not of the time): recomputed only when they change.
        self.DeclareVectorOutputPort("ground_truth", GROUND_TRUTH.size, self._calc,
                                     prerequisites_of_calc={self.all_input_ports_ticket()})
        self._at = {field: GROUND_TRUTH.slice(field) for field, _ in GROUND_TRUTH.fields}
        # Two runs of fields written at once: the target's (p_WT to target_present, their
        # defaults without a target) and the CONTACTS fields (in their order, at the end).
        self._target_fields = slice(self._at["p_WT"].start, self._at["target_present"].stop)
        self._no_target = GROUND_TRUTH.vector()[self._target_fields]
        self._contact_fields = slice(self._at[CONTACTS.fields[0][0]].start, GROUND_TRUTH.size)
        assert GROUND_TRUTH.fields[-len(CONTACTS.fields):] == CONTACTS.fields

    def _calc(self, context, output):
        # Each field written in place by its slice (no per-call packing of keyword arguments).
        at, y = self._at, output.get_mutable_value()
        x = self._state.Eval(context)
        q_WB = x[:4] / norm(x[:4])
        y[at["p_WB"]] = x[4:7]
        y[at["q_WB"]] = q_WB
        y[at["v_WB"]] = x[10:13]
        y[at["w_WB_B"]] = rotation_matrix(q_WB).T @ x[7:10]
        y[at["v_WA"]] = self._wind.Eval(context)
        y[at["motor_command"]] = self._command.Eval(context)
        y[at["rotor_thrust"]] = self._thrust.Eval(context)
        if self._target is None:
            y[self._target_fields] = self._no_target
        else:
            x_T = self._target.Eval(context)
            y[at["p_WT"]] = x_T[4:7]
            y[at["q_WT"]] = x_T[:4] / norm(x_T[:4])
            y[at["v_WT"]] = x_T[10:13]
            y[at["target_present"]] = 1.0
        y[self._contact_fields] = self._contacts.Eval(context)
