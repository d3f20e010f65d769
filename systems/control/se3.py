"""The SE(3) state-feedback controller, M(38) (M Sec. 5.6): the agile controller.

    f_d = -m_e k_p o e_p - m_e k_v o e_v + m_e r''_d + m_e g e3 - (d_w + d_b) o [1, 1, 0]

i.e. the feedback acceleration a_fb = -k_p o e_p - k_v o e_v of `ForceController`, with gains from
a named group (soft / medium / tight, M Sec. 7.5) that also carries the disturbance-integrator gains.
The group is switchable in flight through the optional `gain_group` input (the gain manager of
M Sec. 7.5, alight.systems.managers.constraint_manager): read every tick, it changes k_p, k_v and
the integrator gains only; the integrators hold forces [N], so the disturbance estimate carries
over unchanged and the command does not jump.
"""
import dataclasses as dc

import numpy as np

from alight.systems.control.disturbance import DisturbanceGains, DisturbanceLimits
from alight.systems.control.controller import ControllerReason
from alight.systems.control.force_controller import ForceController, VehicleModel
from alight.systems.control.so3 import So3Params
from alight.systems.params import bounded, choice


@dc.dataclass
class Se3Gains:
    k_p: list[float] = bounded([6.0, 6.0, 10.0], 0.0, 1000.0, "1/s^2")  # x, y, z
    k_v: list[float] = bounded([4.0, 4.0, 6.0], 0.0, 1000.0, "1/s")
    disturbance: DisturbanceGains = dc.field(default_factory=DisturbanceGains)


@dc.dataclass
class Se3GainGroups:
    soft: Se3Gains = dc.field(default_factory=Se3Gains)
    medium: Se3Gains = dc.field(default_factory=Se3Gains)
    tight: Se3Gains = dc.field(default_factory=Se3Gains)


@dc.dataclass
class Se3Params:
    gains: str = choice("medium", "soft", "tight")  # the active group
    groups: Se3GainGroups = dc.field(default_factory=Se3GainGroups)

    @property
    def active(self) -> Se3Gains:
        return getattr(self.groups, self.gains)


def gain_group_names() -> list[str]:
    """The gain groups in the order the `gain_group` input indexes them: soft, medium, tight."""
    return [f.name for f in dc.fields(Se3GainGroups)]


class Se3Controller(ForceController):
    """M(38). Ports as `ForceController`, plus the optional input `gain_group` (1: an index into
    `gain_group_names()`; unconnected, non-finite or out of range: the YAML's `gains`)."""

    def __init__(self, vehicle: VehicleModel, so3: So3Params, params: Se3Params,
                 limits: DisturbanceLimits, period: float = 0.01, max_prediction: float = 0.1,
                 acceleration_gain: float = 0.0):
        super().__init__(vehicle, so3, params.active.disturbance, limits, period,
                         max_prediction=max_prediction,
                         acceleration_gain=acceleration_gain)
        self._groups = [getattr(params.groups, name) for name in gain_group_names()]
        self._gains_k = [(np.asarray(g.k_p, dtype=float), np.asarray(g.k_v, dtype=float))
                         for g in self._groups]
        self._default = gain_group_names().index(params.gains)
        self._gain_group = self.DeclareVectorInputPort("gain_group", 1)

    def _group_index(self, context) -> int:
        """This tick's group: the `gain_group` input when it names one, else the YAML's."""
        if not self._gain_group.HasValue(context):
            return self._default
        index = self._gain_group.Eval(context)[0]
        valid = np.isfinite(index) and index == int(index) and 0 <= index < len(self._groups)
        return int(index) if valid else self._default

    def _disturbance_gains(self, context) -> DisturbanceGains:
        return self._groups[self._group_index(context)].disturbance

    def _feedback_acceleration(self, context, discrete_state, e_p, e_v, reference):
        k_p, k_v = self._gains_k[self._group_index(context)]
        return -k_p * e_p - k_v * e_v, ControllerReason.OK, 0.0
