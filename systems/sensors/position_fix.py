"""A GNSS-like or RTK-like absolute position source (M Sec. 3.1.2, 3.5), simulation side.

p = p_WB + bias + jump + noise: white noise of `noise_std` per axis, a bias that starts at
`bias` and drifts as a random walk of `random_walk_std` (the slow GNSS error), an optional step
`jump` from `jump_time` on (a relocalization), and no fix (valid = 0) inside the `outages`
windows (a dropout; an RTK base switched off and on). The message reports the white-noise variance.
"""
import dataclasses as dc

import numpy as np

from alight.systems.boundary import GROUND_TRUTH
from alight.systems.estimation.measurements import POSITION_FIX
from alight.systems.params import bounded
from alight.systems.sensors.sampled import SampledSensor, check_windows, in_windows


@dc.dataclass
class PositionFixParams:
    period: float = bounded(0.2, 0.001, 10.0, "s")              # 5 Hz GNSS receiver
    latency: float = bounded(0.1, 0.0, 5.0, "s")                # rounded to whole periods
    noise_std: list[float] = bounded([1.0, 1.0, 1.5], 0.0, 100.0, "m")
    bias: list[float] = bounded([0.0, 0.0, 0.0], -1e4, 1e4, "m")
    random_walk_std: float = bounded(0.02, 0.0, 10.0, "m/sqrt(s)")
    jump: list[float] = bounded([0.0, 0.0, 0.0], -1e4, 1e4, "m")
    jump_time: float = bounded(1e9, 0.0, 1e9, "s")
    outages: list[list[float]] = dc.field(default_factory=list)  # [[start, end], ...] [s]

    def __post_init__(self):
        check_windows(self.outages, "outages")


class PositionFix(SampledSensor):
    """Output `measurement` POSITION_FIX in W (shifted by the bias and the jump)."""

    def __init__(self, params: PositionFixParams):
        super().__init__(POSITION_FIX, params.period, noise_size=6, memory=params.bias)
        self._p = params

    def measure(self, t, truth, noise, memory):
        memory += self._p.random_walk_std * np.sqrt(self.period) * noise[3:]
        if in_windows(t, self._p.outages):
            return POSITION_FIX.pack(stamp=t, p=np.zeros(3), var_p=np.ones(3), valid=0.0)
        std = np.asarray(self._p.noise_std)
        p = GROUND_TRUTH.get(truth, "p_WB") + memory + std * noise[:3]
        if t >= self._p.jump_time:
            p = p + np.asarray(self._p.jump)
        return POSITION_FIX.pack(stamp=t, p=p, var_p=np.maximum(std, 1e-3) ** 2, valid=1.0)
