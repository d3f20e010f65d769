"""An optic-flow-like velocity source (M Sec. 3.1.2), simulation side: the horizontal velocity
relative to the surface under the body (scene_ray.py: the ground, or the moving target's platform
and body from `target_model`'s SDF, whose velocity v_WT the flow then subtracts) in the heading
frame H (x along the heading vector M(5), z up) plus white noise, and no measurement (valid = 0)
in the `outages` windows or closer than `min_height` to that surface (no texture in focus).
"""
import dataclasses as dc

import numpy as np

from alight.systems.boundary import GROUND_TRUTH
from alight.systems.estimation.measurements import VELOCITY_FIX
from alight.systems.params import bounded
from alight.systems.rotations import heading, rotation_matrix
from alight.systems.sensors.sampled import SampledSensor, check_windows, in_windows
from alight.systems.sensors.scene_ray import ray_hit, target_boxes

DOWN_B = np.array([0.0, 0.0, -1.0])


@dc.dataclass
class OpticFlowParams:
    period: float = bounded(0.02, 0.001, 10.0, "s")             # 50 Hz
    latency: float = bounded(0.04, 0.0, 5.0, "s")
    noise_std: float = bounded(0.05, 0.0, 10.0, "m/s")
    min_height: float = bounded(0.0, 0.0, 100.0, "m")
    outages: list[list[float]] = dc.field(default_factory=list)
    target_model: str = "target_vehicle.sdf"   # the moving target it can see ("": ground only)

    def __post_init__(self):
        check_windows(self.outages, "outages")


class OpticFlow(SampledSensor):
    """Output `measurement` VELOCITY_FIX (v_H: velocity in H [m/s])."""

    def __init__(self, params: OpticFlowParams):
        super().__init__(VELOCITY_FIX, params.period, noise_size=2)
        self._p = params
        self._boxes = target_boxes(params.target_model) if params.target_model else ()

    def measure(self, t, truth, noise, memory):
        R_WB = rotation_matrix(GROUND_TRUTH.get(truth, "q_WB"))
        distance, on_target = ray_hit(truth, DOWN_B, self._boxes)
        valid = not in_windows(t, self._p.outages) and distance * R_WB[2, 2] >= self._p.min_height
        eta = heading(R_WB)
        c, s = np.cos(eta), np.sin(eta)
        v_W = GROUND_TRUTH.get(truth, "v_WB") - \
            (GROUND_TRUTH.get(truth, "v_WT") if on_target else 0.0)
        v_H = np.array([c * v_W[0] + s * v_W[1], -s * v_W[0] + c * v_W[1]])
        std = max(self._p.noise_std, 1e-3)
        return VELOCITY_FIX.pack(stamp=t, v_H=v_H + self._p.noise_std * noise,
                                 var_v=[std ** 2] * 2, valid=float(valid))
