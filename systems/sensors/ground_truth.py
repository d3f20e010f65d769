"""The simulation-only `ground_truth` output (DESIGN.md): never read by an onboard system."""
import math

from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import CONTACTS, GROUND_TRUTH
from alight.systems.rotations import rotation_matrix, unit_floats


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
        self._wind_port = self.DeclareVectorInputPort("wind", 3)
        self._command = self.DeclareVectorInputPort("motor_command", num_rotors)
        self._thrust = self.DeclareVectorInputPort("rotor_thrust", num_rotors)
        self._target = self.DeclareVectorInputPort("target_state", 13) if with_target else None
        self._contacts = self.DeclareVectorInputPort("contacts", CONTACTS.size)
        # A pure function of the inputs (not of the time): recomputed only when they change.
        self.DeclareVectorOutputPort("ground_truth", GROUND_TRUTH.size, self._calc,
                                     prerequisites_of_calc={self.all_input_ports_ticket()})
        # The layout's fields in order: the vehicle's state, the inputs copied, the target's, then
        # the CONTACTS fields (their order, at the end); written by one slice each run.
        assert [f for f, _ in GROUND_TRUTH.fields] == [
            "p_WB", "q_WB", "v_WB", "w_WB_B", "v_WA", "motor_command", "rotor_thrust", "p_WT",
            "q_WT", "v_WT", "target_present", *(f for f, _ in CONTACTS.fields)]
        at = {field: GROUND_TRUTH.slice(field) for field, _ in GROUND_TRUTH.fields}
        self._vehicle = slice(0, at["w_WB_B"].start)           # p_WB, q_WB, v_WB
        self._w = at["w_WB_B"]
        self._wind, self._motors, self._thrusts = (at[f] for f in (
            "v_WA", "motor_command", "rotor_thrust"))
        self._target_fields = slice(at["p_WT"].start, at["target_present"].stop)
        self._no_target = GROUND_TRUTH.vector()[self._target_fields]
        self._contact_fields = slice(at[CONTACTS.fields[0][0]].start, GROUND_TRUTH.size)

    def _calc(self, context, output):
        # Each run of fields written in place by one slice (no per-call packing or lookups); the
        # quaternions' q / |q| and R_WB^T w_WB on the elements as Python floats: the same sums in
        # the same order as NumPy's (its dot and matrix-vector product of 3 or 4 elements).
        y = output.get_mutable_value()
        x = self._state.Eval(context).tolist()
        q_WB = unit_floats(*x[:4]) or [math.nan] * 4   # (x[:4] / norm(x[:4]))
        R = rotation_matrix(q_WB).tolist()
        w0, w1, w2 = x[7:10]
        y[self._vehicle] = [*x[4:7], *q_WB, *x[10:13]]
        y[self._w] = [R[0][i] * w0 + R[1][i] * w1 + R[2][i] * w2 for i in range(3)]
        y[self._wind] = self._wind_port.Eval(context)
        y[self._motors] = self._command.Eval(context)
        y[self._thrusts] = self._thrust.Eval(context)
        if self._target is None:
            y[self._target_fields] = self._no_target
        else:
            x_T = self._target.Eval(context).tolist()
            y[self._target_fields] = [*x_T[4:7], *(unit_floats(*x_T[:4]) or [math.nan] * 4),
                                      *x_T[10:13], 1.0]
        y[self._contact_fields] = self._contacts.Eval(context)
