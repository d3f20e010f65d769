"""The speed tracker, M Sec. 4.3 and 7.4: a desired horizontal velocity (or acceleration), height
and heading, for swarming; at 100 Hz.

M Sec. 7.4: "we only constrain the first derivative of given references by a low-pass filter".
Each given reference x_d drives its chi state x through the first-order low-pass
x' = (x_d - x) / tau, its first derivative clipped to a limit:
- velocity goal: the horizontal velocity (tau `time_constant`; acceleration norm at most
  `max_acceleration`);
- acceleration goal: the horizontal acceleration (tau `time_constant`), the velocity then held
  under `max_speed` (the acceleration along it is dropped there);
- the height (tau `height_time_constant`; climb at most `ascent_speed`, descent `descent_speed`);
- the heading (tau `heading_time_constant`; rate at most `max_heading_rate`).
Goals over `max_speed` / `max_acceleration` are clipped (reason SATURATED). The position integrates
the velocity, and chi's derivatives are those of the filters at the new state, so chi is
consistent (constant jerk over a tick, like every tracker's).

The goal is in the estimator frame E. The goal being followed is re-expressed with chi when the
frame changes (M Sec. 3.5) until a new goal arrives. Without a goal the tracker stops and holds
the height and heading it started with.
"""
import dataclasses as dc

import numpy as np

from alight.models import model_path
from alight.systems.boundary import REFERENCE
from alight.systems.control.force_controller import advance_reference
from alight.systems.estimation.heading import wrap_angle
from alight.systems.params import bounded, load_params
from alight.systems.rotations import heading
from alight.systems.estimation.frames import reexpress_point
from alight.systems.tracking.chi_tracker import ChiMemory, ChiReason, ChiTracker


def _vector2(value, name: str):
    if value is None:
        return None
    vector = np.asarray(value, dtype=float)
    if vector.shape != (2,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"speed goal: {name} must be 2 finite numbers [x, y], got {value!r}")
    return (float(vector[0]), float(vector[1]))


@dc.dataclass(frozen=True)
class SpeedGoal:
    """Exactly one of `velocity` [m/s] or `acceleration` [m/s^2] (horizontal, in E); `height`
    [m, z in E]; `heading` [rad]. Raises ValueError when invalid."""
    height: float
    heading: float = 0.0
    velocity: tuple | None = None
    acceleration: tuple | None = None

    def __post_init__(self):
        if (self.velocity is None) == (self.acceleration is None):
            raise ValueError("speed goal: give exactly one of velocity or acceleration")
        object.__setattr__(self, "velocity", _vector2(self.velocity, "velocity"))
        object.__setattr__(self, "acceleration", _vector2(self.acceleration, "acceleration"))
        for name in ("height", "heading"):
            if not np.isfinite(getattr(self, name)):
                raise ValueError(f"speed goal: {name} {getattr(self, name)} must be finite")


@dc.dataclass
class SpeedTrackerParams:
    period: float = bounded(0.01, 0.001, 0.1, "s")                 # 100 Hz
    time_constant: float = bounded(0.5, 0.02, 10.0, "s")           # horizontal low-pass
    height_time_constant: float = bounded(1.0, 0.02, 10.0, "s")
    heading_time_constant: float = bounded(1.0, 0.02, 10.0, "s")
    max_speed: float = bounded(5.0, 0.1, 50.0, "m/s")              # horizontal norm
    max_acceleration: float = bounded(3.0, 0.1, 50.0, "m/s^2")     # horizontal norm
    ascent_speed: float = bounded(2.0, 0.05, 20.0, "m/s")
    descent_speed: float = bounded(1.0, 0.05, 20.0, "m/s")
    max_heading_rate: float = bounded(1.0, 0.05, 20.0, "rad/s")


@dc.dataclass
class SpeedMemory(ChiMemory):
    """The goal followed, in the current frame: horizontal velocity or acceleration (`mode`),
    height, heading."""
    mode: str = "velocity"
    horizontal: np.ndarray = dc.field(default_factory=lambda: np.zeros(2))
    height: float = 0.0
    heading: float = 0.0


def clip_norm(vector: np.ndarray, limit: float) -> np.ndarray:
    norm = np.linalg.norm(vector)
    return vector * (limit / norm) if norm > limit else vector


def low_pass_rate(error: float, tau: float, lo: float, hi: float) -> tuple[float, float]:
    """x' = (x_d - x) / tau clipped to [lo, hi], and d(x')/dx' . x' = x'' along the filter."""
    rate = error / tau
    if lo <= rate <= hi:
        return rate, -rate / tau
    return float(np.clip(rate, lo, hi)), 0.0


class SpeedTracker(ChiTracker):
    """Inputs  as `Tracker`, with `goal` a SpeedGoal (None: stop and hold)
    Outputs `reference` REFERENCE (chi of M(16) in E, stamped one period ahead);
            `tracker_status` TRACKER_STATUS (reason: ChiReason)
    """

    def __init__(self, params: SpeedTrackerParams):
        super().__init__(params.period, SpeedMemory(), SpeedGoal(height=0.0, velocity=(0.0, 0.0)))
        self.params = params

    def _begin(self, context, memory: SpeedMemory, goal, estimate) -> ChiReason:
        if goal is None:
            memory.mode, memory.horizontal = "velocity", np.zeros(2)
            memory.height = REFERENCE.get(memory.chi, "p")[2]
            memory.heading = REFERENCE.get(memory.chi, "heading")
            return ChiReason.OK
        memory.mode = "velocity" if goal.velocity is not None else "acceleration"
        memory.horizontal = np.array(goal.velocity if goal.velocity is not None
                                     else goal.acceleration)
        memory.height, memory.heading = goal.height, goal.heading
        return ChiReason.OK

    def _switch_frame(self, memory: SpeedMemory, R_OldNew, p_OldNew) -> None:
        super()._switch_frame(memory, R_OldNew, p_OldNew)
        p = REFERENCE.get(memory.chi, "p")   # now in the new frame
        R_NewOld = R_OldNew.T
        memory.height = reexpress_point([*(R_OldNew @ p + p_OldNew)[:2], memory.height],
                                        R_OldNew, p_OldNew)[2]
        memory.horizontal = (R_NewOld @ [*memory.horizontal, 0.0])[:2]
        memory.heading = memory.heading - heading(R_OldNew)

    def _step(self, context, memory: SpeedMemory, estimate) -> ChiReason:
        """The filters' derivatives at the current state (the goal may be new), one period
        along them, and their derivatives at the new state."""
        self._derivatives(memory, memory.chi)
        memory.chi = advance_reference(memory.chi, self.period)
        return ChiReason.SATURATED if self._derivatives(memory, memory.chi) else ChiReason.OK

    def _derivatives(self, memory: SpeedMemory, chi: np.ndarray) -> bool:
        """Sets chi's derivatives to the filters'; True when the goal was clipped."""
        saturated = self._horizontal(memory, chi)
        self._vertical(memory, chi)
        self._heading(memory, chi)
        return saturated

    def _horizontal(self, memory: SpeedMemory, chi: np.ndarray) -> bool:
        """Velocity mode: a = (v_d - v) / tau; acceleration mode: j = (a_d - a) / tau."""
        P, params, tau = REFERENCE, self.params, self.params.time_constant
        v, a = P.get(chi, "v")[:2], P.get(chi, "a")[:2]
        if memory.mode == "velocity":
            v_d = clip_norm(memory.horizontal, params.max_speed)
            a = (v_d - v) / tau
            j = -a / tau
            if np.linalg.norm(a) > params.max_acceleration:
                a, j = clip_norm(a, params.max_acceleration), np.zeros(2)
        else:
            a_d = clip_norm(memory.horizontal, params.max_acceleration)
            j = (a_d - a) / tau
            speed = np.linalg.norm(v)
            if speed >= params.max_speed:     # no acceleration (or jerk) outward
                v = v * (params.max_speed / speed)
                along = v / np.linalg.norm(v)
                a = a - max(0.0, a @ along) * along
                j = j - max(0.0, j @ along) * along
        for field, value in (("v", v), ("a", a), ("j", j)):
            chi[P.slice(field).start:P.slice(field).start + 2] = value
        return bool(np.linalg.norm(memory.horizontal) >
                    (params.max_speed if memory.mode == "velocity" else params.max_acceleration))

    def _vertical(self, memory: SpeedMemory, chi: np.ndarray) -> None:
        z = REFERENCE.get(chi, "p")[2]
        v, a = low_pass_rate(memory.height - z, self.params.height_time_constant,
                             -self.params.descent_speed, self.params.ascent_speed)
        chi[REFERENCE.slice("v").start + 2] = v
        chi[REFERENCE.slice("a").start + 2] = a
        chi[REFERENCE.slice("j").start + 2] = -a / self.params.height_time_constant

    def _heading(self, memory: SpeedMemory, chi: np.ndarray) -> None:
        eta = REFERENCE.get(chi, "heading")
        rate, _ = low_pass_rate(float(wrap_angle(memory.heading - eta)),
                                self.params.heading_time_constant,
                                -self.params.max_heading_rate, self.params.max_heading_rate)
        chi[REFERENCE.slice("heading_rate")] = rate


def load_speed_tracker_params(filename: str = "speed_tracker.yaml") -> SpeedTrackerParams:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    return load_params(SpeedTrackerParams, model_path(filename))


def make_speed_tracker(params: SpeedTrackerParams) -> SpeedTracker:
    return SpeedTracker(params)
