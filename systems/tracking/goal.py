"""The goal a tracker follows (M Sec. 4): a single point (r_d, eta_d) or a time-parametrized
trajectory {(r_d, eta_d)_1, ..., (r_d, eta_d)_k} sampled at any fixed period.

`TrackerGoal` is the value on a tracker's abstract `goal` input. A point is a trajectory of one
sample. Between samples the position is interpolated linearly, the heading along the shorter
arc; before the first sample the first is held, after the last the last.
"""
import dataclasses as dc

import numpy as np


@dc.dataclass(frozen=True)
class TrackerGoal:
    """samples: (k, 4) rows [x, y, z, heading] in the estimator frame E [m, rad];
    t_start: time of the first sample [s]; dt: sample period [s] (unused for one sample)."""
    samples: np.ndarray
    t_start: float = 0.0
    dt: float = 0.01

    def __post_init__(self):
        samples = np.atleast_2d(np.asarray(self.samples, dtype=float))
        if samples.ndim != 2 or samples.shape[1] != 4 or len(samples) == 0:
            raise ValueError(f"goal samples must be rows of [x, y, z, heading], got shape "
                             f"{np.shape(self.samples)}")
        if not np.all(np.isfinite(samples)):
            raise ValueError("goal samples must be finite")
        if not (np.isfinite(self.t_start) and self.dt > 0.0 and np.isfinite(self.dt)):
            raise ValueError(f"goal t_start must be finite and dt > 0, got {self.t_start}, "
                             f"{self.dt}")
        samples = samples.copy()
        samples[:, 3] = np.unwrap(samples[:, 3])
        object.__setattr__(self, "samples", samples)

    @staticmethod
    def point(p, heading: float = 0.0) -> "TrackerGoal":
        return TrackerGoal(np.append(np.asarray(p, float), heading)[None, :])

    @property
    def duration(self) -> float:
        return (len(self.samples) - 1) * self.dt

    def sample(self, times: np.ndarray) -> np.ndarray:
        """(len(times), 4) [x, y, z, heading] (heading unwrapped along the goal)."""
        s = (np.asarray(times, float) - self.t_start) / self.dt
        s = np.clip(s, 0.0, len(self.samples) - 1)
        i = np.minimum(np.floor(s).astype(int), len(self.samples) - 2) if len(self.samples) > 1 \
            else np.zeros(len(s), int)
        if len(self.samples) == 1:
            return np.repeat(self.samples, len(s), axis=0)
        w = (s - i)[:, None]
        return (1.0 - w) * self.samples[i] + w * self.samples[i + 1]
