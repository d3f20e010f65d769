"""A downward rangefinder (M Sec. 3.1.2), simulation side: the distance along -b3 from the body
to the first surface of the scene (scene_ray.py: the ground plane z = 0, over the ground
range = z / cos(tilt), and the target vehicle's platform and body boxes from `target_model`'s SDF),
plus white noise; no measurement beyond `max_range`, above `max_tilt` or in the `outages` windows.
"""
import dataclasses as dc

import numpy as np

from alight.systems.boundary import GROUND_TRUTH, RANGE
from alight.systems.params import bounded
from alight.systems.rotations import rotation_matrix
from alight.systems.sensors.sampled import SampledSensor, check_windows, in_windows
from alight.systems.sensors.scene_ray import ray_hit, target_boxes

DOWN_B = np.array([0.0, 0.0, -1.0])


@dc.dataclass
class RangefinderParams:
    period: float = bounded(0.02, 0.001, 10.0, "s")            # 50 Hz (Garmin LIDAR-Lite class)
    latency: float = bounded(0.02, 0.0, 5.0, "s")
    noise_std: float = bounded(0.02, 0.0, 10.0, "m")
    max_range: float = bounded(40.0, 0.1, 1000.0, "m")
    max_tilt: float = bounded(45.0, 1.0, 89.0, "deg")
    outages: list[list[float]] = dc.field(default_factory=list)
    target_model: str = "target_vehicle.sdf"   # the moving target it can hit ("": ground only)

    def __post_init__(self):
        check_windows(self.outages, "outages")


class Rangefinder(SampledSensor):
    """Output `measurement` RANGE [m]."""

    def __init__(self, params: RangefinderParams):
        super().__init__(RANGE, params.period, noise_size=1)
        self._p = params
        self._boxes = target_boxes(params.target_model) if params.target_model else ()
        self._min_cos_tilt = np.cos(np.radians(params.max_tilt))

    def measure(self, t, truth, noise, memory):
        R_WB = rotation_matrix(GROUND_TRUTH.get(truth, "q_WB"))
        valid = R_WB[2, 2] > self._min_cos_tilt and not in_windows(t, self._p.outages)
        surface, _ = ray_hit(truth, DOWN_B, self._boxes, R_WB)
        distance = min(surface, 2 * self._p.max_range) + self._p.noise_std * noise[0]
        valid = valid and distance <= self._p.max_range
        return RANGE.pack(stamp=t, range=distance, var=max(self._p.noise_std, 1e-3) ** 2,
                          valid=float(valid))
