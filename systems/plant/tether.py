"""A tether from a ground anchor to a point of the body: a rope that only pulls, as a spring-damper
when taut. It holds the vehicle down like ground foliage would (the landoff tracker's admittance
case, M Sec. 4.2). Off by default (`TetherParams.enabled`)."""
import dataclasses as dc

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.multibody.math import SpatialForce
from pydrake.multibody.plant import ExternallyAppliedSpatialForce
from pydrake.systems.framework import LeafSystem

from alight.systems.params import bounded
from alight.systems.rotations import cross, rotation_matrix


@dc.dataclass
class TetherParams:
    enabled: bool = False
    anchor: list[float] = bounded([0.0, 0.0, 0.0], -1e4, 1e4, "m")       # p_WA, in W
    attachment: list[float] = bounded([0.0, 0.0, 0.0], -2.0, 2.0, "m")    # p_BQ, in B
    length: float = bounded(0.5, 0.0, 1e3, "m")                           # slack length
    stiffness: float = bounded(2000.0, 1.0, 1e6, "N/m")
    damping: float = bounded(50.0, 0.0, 1e5, "N/(m/s)")


def tether_tension(p_WQ: np.ndarray, v_WQ: np.ndarray, params: TetherParams) -> np.ndarray:
    """The force [N, in W] of the rope on the body at Q: toward the anchor when taut, never a
    push."""
    d = np.asarray(params.anchor, float) - p_WQ
    distance = np.linalg.norm(d)
    if distance <= params.length or distance == 0.0:
        return np.zeros(3)
    u = d / distance
    tension = params.stiffness * (distance - params.length) - params.damping * (v_WQ @ u)
    return max(tension, 0.0) * u


class Tether(LeafSystem):
    """Input  `body_state`     (13) the body's free-joint state [q_WB (w,x,y,z), p_WB, w_WB, v_WB]
    Output `spatial_forces` list[ExternallyAppliedSpatialForce] at the attachment point
    Output `tension`        (1) [N]
    """

    def __init__(self, body_index, params: TetherParams):
        super().__init__()
        self._body_index, self._params = body_index, params
        self._p_BQ = np.asarray(params.attachment, float)
        self._state = self.DeclareVectorInputPort("body_state", 13)
        self.DeclareAbstractOutputPort(
            "spatial_forces", lambda: AbstractValue.Make([ExternallyAppliedSpatialForce()]),
            self._calc_forces, prerequisites_of_calc={self.all_input_ports_ticket()})
        self.DeclareVectorOutputPort("tension", 1, lambda context, output: output.SetFromVector(
            [np.linalg.norm(self._force_W(context))]), {self.all_input_ports_ticket()})

    def _force_W(self, context) -> np.ndarray:
        x = self._state.Eval(context)
        R_WB = rotation_matrix(x[0:4])
        p_BQ_W = R_WB @ self._p_BQ
        return tether_tension(x[4:7] + p_BQ_W, x[10:13] + cross(x[7:10], p_BQ_W), self._params)

    def _calc_forces(self, context, output):
        force = ExternallyAppliedSpatialForce()
        force.body_index = self._body_index
        force.p_BoBq_B = self._p_BQ
        force.F_Bq_W = SpatialForce(np.zeros(3), self._force_W(context))
        output.set_value([force])
