"""Body aerodynamic drag: per body axis, F = -(c1 v + c2 |v| v) on the air-relative velocity in B."""
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.systems.framework import LeafSystem

from alight.systems.rotations import rotation_matrix


def drag_force_B(v_BA_B: np.ndarray, linear, quadratic) -> np.ndarray:
    """Drag on the body [N, in B] for its velocity relative to the air [m/s, in B] (per axis on
    Python floats: at 3 elements several times faster than NumPy, the same IEEE operations)."""
    return np.array([-(c1 * v + c2 * abs(v) * v)
                     for v, c1, c2 in zip(np.asarray(v_BA_B).tolist(), linear, quadratic)])


class AerodynamicDrag(LeafSystem):
    """Input  `body_state`     (13) the body's free-joint state [q_WB (w,x,y,z), p_WB, w_WB, v_WB]
    Input  `wind`           (3) air velocity v_WA [m/s, in W]
    Output `spatial_forces` list[ExternallyAppliedSpatialForce] applied at the body origin

    With `period` > 0 the force is sampled every `period` (and at initialization) and held in
    between, a zero-order hold: the plant then reads a state output, with no Python call at its
    own step (the drag changes over seconds, its time constant mass / linear coefficient; a hold of
    a few ms changes it by less than a percent of itself). With `period` 0 it is computed from
    the inputs at every evaluation.
    """

    def __init__(self, body_index, linear, quadratic, period: float = 0.0):
        super().__init__()
        self._linear = [float(c) for c in linear]
        self._quadratic = [float(c) for c in quadratic]
        self._state = self.DeclareVectorInputPort("body_state", 13)
        self._wind = self.DeclareVectorInputPort("wind", 3)
        self._zero = np.zeros(3)
        # One force object, re-filled at each sample or evaluation (the state or output copies it).
        self._force = ExternallyAppliedSpatialForce()
        self._force.body_index = body_index
        self._force.p_BoBq_B = self._zero
        self._force.F_Bq_W = SpatialForce(self._zero, self._zero)
        if period > 0:
            held = self.DeclareAbstractState(AbstractValue.Make([self._force]))
            self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._sample)
            self.DeclareInitializationUnrestrictedUpdateEvent(self._sample)
            self.DeclareStateOutputPort("spatial_forces", held)
            self._held = int(held)  # (by int: pydrake converts an index object on every call)
            return
        self.DeclareAbstractOutputPort(
            "spatial_forces", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
            self._calc, prerequisites_of_calc={self.all_input_ports_ticket()})

    def _forces(self, context) -> list[ExternallyAppliedSpatialForce]:
        x = self._state.Eval(context)
        R_WB = rotation_matrix(x[0:4])
        v_BA_B = (x[10:13] - self._wind.Eval(context)) @ R_WB  # R_WB^T (v_WB - v_WA)
        self._force.F_Bq_W = SpatialForce(
            self._zero, R_WB @ drag_force_B(v_BA_B, self._linear, self._quadratic))
        return [self._force]

    def _calc(self, context, output):
        output.set_value(self._forces(context))

    def _sample(self, context, state):
        state.get_mutable_abstract_state(self._held).set_value(self._forces(context))
