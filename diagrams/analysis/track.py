"""Scores a track run (`alight track`, M Sec. 8) against its reference and the simulation's ground
truth."""
import dataclasses as dc

import numpy as np

from alight.diagrams.running.run_log import RunLog
from alight.systems.rotations import tilt_deg


@dc.dataclass
class TrackScore:
    """Ground-truth figures of a track run over [start, end] (the scored window)."""
    mean_position_error: float   # m, |p_WB - p_d| (true position vs the reference)
    max_position_error: float    # m
    max_tilt: float              # deg, angle of b3 from e3
    max_speed: float             # m/s
    max_acceleration: float      # m/s^2 (finite differences of the true velocity, 0.1 s)
    mean_heading_error: float    # deg
    window: tuple[float, float]  # s

    def lines(self) -> list[str]:
        return [f"scored window         {self.window[0]:.1f} s - {self.window[1]:.1f} s",
                f"position error        mean {self.mean_position_error:.3f} m, "
                f"max {self.max_position_error:.3f} m",
                f"heading error         mean {self.mean_heading_error:.2f} deg",
                f"max tilt              {self.max_tilt:.1f} deg",
                f"max speed / accel.    {self.max_speed:.2f} m/s / {self.max_acceleration:.2f} "
                "m/s^2"]


def score(run: RunLog, start: float | None = None, end: float | None = None) -> TrackScore:
    """Scores `run` against its reference and ground truth, by default over its marks."""
    marks = run.metadata["marks"]
    start = marks["start"] if start is None else start
    end = marks["end"] if end is None else end
    truth, reference = run["ground_truth"], run["reference"]
    time = truth["time"].to_numpy()
    inside = (time >= start) & (time <= end)
    p = run.field("ground_truth", "p_WB").to_numpy()[inside]
    # The reference is logged on the same 10 ms grid; interpolate to be safe.
    p_d = np.column_stack([np.interp(time[inside], reference["time"], reference[f"p_{i}"])
                           for i in range(3)])
    heading_d = np.interp(time[inside], reference["time"], np.unwrap(reference["heading"]))
    q = run.field("ground_truth", "q_WB").to_numpy()[inside]
    tilt = tilt_deg(q)
    eta = np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]),
                     1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2))
    heading_error = np.degrees(np.abs(np.angle(np.exp(1j * (eta - heading_d)))))
    v = run.field("ground_truth", "v_WB").to_numpy()
    stride = max(1, int(round(0.1 / np.median(np.diff(time)))))
    a = np.linalg.norm(v[stride:] - v[:-stride], axis=1) / (time[stride:] - time[:-stride])
    a_inside = inside[stride:] & inside[:-stride]
    error = np.linalg.norm(p - p_d, axis=1)
    return TrackScore(float(error.mean()), float(error.max()), float(tilt.max()),
                      float(np.linalg.norm(v[inside], axis=1).max()),
                      float(a[a_inside].max()) if a_inside.any() else 0.0,
                      float(heading_error.mean()), (float(start), float(end)))
