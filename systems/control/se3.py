"""The SE(3) state-feedback controller, M(38) (M Sec. 5.6): the agile controller.

    f_d = -m_e k_p o e_p - m_e k_v o e_v + m_e r''_d + m_e g e3 - (d_w + d_b) o [1, 1, 0]

i.e. the feedback acceleration a_fb = -k_p o e_p - k_v o e_v of `ForceController`, with gains from
a named group (soft / medium / tight, M Sec. 7.5) that also carries the disturbance-integrator gains.
"""
import dataclasses as dc

import numpy as np

from alight.systems.control.disturbance import DisturbanceGains, DisturbanceLimits
from alight.systems.control.force_controller import ControllerReason, ForceController, VehicleModel
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


class Se3Controller(ForceController):
    """M(38). Ports as `ForceController`."""

    def __init__(self, vehicle: VehicleModel, so3: So3Params, params: Se3Params,
                 limits: DisturbanceLimits, period: float = 0.01, max_prediction: float = 0.1):
        gains = params.active
        super().__init__(vehicle, so3, gains.disturbance, limits, period,
                         max_prediction=max_prediction)
        self._k_p = np.asarray(gains.k_p, dtype=float)
        self._k_v = np.asarray(gains.k_v, dtype=float)

    def _feedback_acceleration(self, context, discrete_state, e_p, e_v, reference):
        return -self._k_p * e_p - self._k_v * e_v, ControllerReason.OK, 0.0
