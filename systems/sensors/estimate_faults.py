"""A sensor-side fault injector between an odometry source and its consumers (simulation only):
estimator noise (M Sec. 8.3, Fig. 12) and an estimator position jump (M Sec. 8.4, Fig. 13).

From `noise_start` on, white Gaussian noise of standard deviation `noise_std` is added to the
position [m] and to the velocity [m/s] of the STATE_ESTIMATE (and its variances grow to match);
from `jump_time` on, the position is offset by `jump` [m] (a relocalization: the velocity is
unchanged); with `loss`, from `loss_time` on for `loss_duration`, the estimate is lost
(valid = 0). The noise comes
from a Drake `RandomSource`, so runs are reproducible from the seed.
Not onboard code: it models a bad localization system.
"""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.params import bounded


@dc.dataclass
class EstimateFaultParams:
    noise_std: float = bounded(0.0, 0.0, 100.0, "m, m/s")
    noise_start: float = bounded(0.0, 0.0, 1e6, "s")
    jump: list[float] = bounded([0.0, 0.0, 0.0], -1e4, 1e4, "m")
    jump_time: float = bounded(0.0, 0.0, 1e6, "s")
    loss: bool = False                                   # the estimate is lost (valid = 0) ...
    loss_time: float = bounded(0.0, 0.0, 1e6, "s")       # ... from this time on ...
    loss_duration: float = bounded(1e6, 0.0, 1e6, "s")   # ... for this long (default: for good)

    @property
    def active(self) -> bool:
        return self.noise_std > 0.0 or bool(np.any(np.asarray(self.jump) != 0.0)) or self.loss


class EstimateFaults(LeafSystem):
    """Input  `state_estimate` STATE_ESTIMATE from the odometry source
    Input  `noise`          (6) unit white Gaussian noise (position, velocity)
    Output `state_estimate` STATE_ESTIMATE with the faults applied
    """

    def __init__(self, params: EstimateFaultParams):
        super().__init__()
        self._p = params
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._noise = self.DeclareVectorInputPort("noise", 6)
        self.DeclareVectorOutputPort("state_estimate", STATE_ESTIMATE.size, self._calc)

    def _calc(self, context, output):
        estimate = self._estimate.Eval(context).copy()
        t = context.get_time()
        L = STATE_ESTIMATE
        if self._p.noise_std > 0.0 and t >= self._p.noise_start:
            noise = self._p.noise_std * self._noise.Eval(context)
            estimate[L.slice("p_EB")] += noise[:3]
            estimate[L.slice("v_EB")] += noise[3:]
            estimate[L.slice("var_pv")] += self._p.noise_std ** 2
        if t >= self._p.jump_time:
            estimate[L.slice("p_EB")] += np.asarray(self._p.jump)
        if self._p.loss and 0.0 <= t - self._p.loss_time < self._p.loss_duration:
            estimate[L.slice("valid")] = 0.0
        output.SetFromVector(estimate)
