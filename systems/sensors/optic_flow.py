"""An optic-flow-like velocity source (M Sec. 3.1.2), simulation side: the horizontal velocity
in the heading frame H (x along the heading vector M(5), z up) plus white noise, and no
measurement (valid = 0) in the `outages` windows or below `min_height` (no texture in focus).
"""
import dataclasses as dc

import numpy as np

from alight.systems.boundary import GROUND_TRUTH
from alight.systems.estimation.measurements import VELOCITY_FIX
from alight.systems.params import bounded
from alight.systems.rotations import heading, rotation_matrix
from alight.systems.sensors.sampled import SampledSensor, check_windows, in_windows


@dc.dataclass
class OpticFlowParams:
    period: float = bounded(0.02, 0.001, 10.0, "s")             # 50 Hz
    latency: float = bounded(0.04, 0.0, 5.0, "s")
    noise_std: float = bounded(0.05, 0.0, 10.0, "m/s")
    min_height: float = bounded(0.0, 0.0, 100.0, "m")
    outages: list[list[float]] = dc.field(default_factory=list)

    def __post_init__(self):
        check_windows(self.outages, "outages")


class OpticFlow(SampledSensor):
    """Output `measurement` VELOCITY_FIX (v_H: velocity in H [m/s])."""

    def __init__(self, params: OpticFlowParams):
        super().__init__(VELOCITY_FIX, params.period, noise_size=2)
        self._p = params

    def measure(self, t, truth, noise, memory):
        valid = not in_windows(t, self._p.outages) and \
            GROUND_TRUTH.get(truth, "p_WB")[2] >= self._p.min_height
        eta = heading(rotation_matrix(GROUND_TRUTH.get(truth, "q_WB")))
        c, s = np.cos(eta), np.sin(eta)
        v_W = GROUND_TRUTH.get(truth, "v_WB")
        v_H = np.array([c * v_W[0] + s * v_W[1], -s * v_W[0] + c * v_W[1]])
        std = max(self._p.noise_std, 1e-3)
        return VELOCITY_FIX.pack(stamp=t, v_H=v_H + self._p.noise_std * noise,
                                 var_v=[std ** 2] * 2, valid=float(valid))
