"""A scripted pilot: flies a timed attitude/thrust profile through the attitude+thrust mode.

Each segment holds roll, pitch, heading and a vertical acceleration for its duration; the thrust is
the thrust curve M(32)-(33) applied to (m (g + a_z) + D(v_z)) / (cos(roll) cos(pitch)), where v_z is
the vertical speed the profile itself implies and D the vehicle's vertical drag: what a pilot who
knows the vehicle would give. No position feedback: this is the open-loop hover demo and an
excitation source for identification.
"""
import dataclasses as dc

import numpy as np
from pydrake.math import RollPitchYaw
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_COMMAND, CommandMode
from alight.systems.params import bounded, choice
from alight.systems.thrust_curve import GRAVITY, ThrustCurve


@dc.dataclass
class ProfileSegment:
    """One segment. In `attitude` mode roll/pitch/heading are held; in `rates` mode the body rates
    are commanded instead (the attitude fields are ignored)."""
    duration: float = bounded(1.0, 0.0, 3600.0, "s")
    arm: bool = True
    mode: str = choice("attitude", "rates")
    body_rates: list[float] = bounded([0.0, 0.0, 0.0], -300.0, 300.0, "deg/s")
    roll: float = bounded(0.0, -60.0, 60.0, "deg")
    pitch: float = bounded(0.0, -60.0, 60.0, "deg")
    heading: float = bounded(0.0, -360.0, 360.0, "deg")
    vertical_acceleration: float = bounded(0.0, -GRAVITY, 20.0, "m/s^2")  # -g: zero thrust


@dc.dataclass
class PilotProfile:
    period: float = bounded(0.02, 0.001, 1.0, "s")  # command rate (50 Hz)
    segments: list[ProfileSegment] = dc.field(default_factory=list)
    stop_at: float | None = None   # s: the output freezes from then on (a fault: see ScriptedPilot)

    @property
    def duration(self) -> float:
        return sum(s.duration for s in self.segments)


@dc.dataclass(frozen=True)
class PilotModel:
    """What the pilot knows about the vehicle."""
    mass: float                   # kg
    curve: ThrustCurve            # M(32)-(34)
    drag_linear: float = 0.0      # vertical drag, N/(m/s)
    drag_quadratic: float = 0.0   # N/(m/s)^2


def _segment_at(profile: PilotProfile, t: float) -> tuple[ProfileSegment, float]:
    """The active segment at time t and the vertical speed the profile implies then."""
    start, v_z = 0.0, 0.0
    for segment in profile.segments:
        if t < start + segment.duration:
            break
        if segment.arm and segment.vertical_acceleration > -GRAVITY:
            v_z += segment.vertical_acceleration * segment.duration
        start += segment.duration
    else:
        return profile.segments[-1], v_z
    if segment.arm and segment.vertical_acceleration > -GRAVITY:
        v_z += segment.vertical_acceleration * (t - start)
    return segment, v_z


def profile_command(profile: PilotProfile, t: float, model: PilotModel) -> np.ndarray:
    """The FC_COMMAND of the profile at time t (the last segment holds after the end)."""
    segment, v_z = _segment_at(profile, t)
    rpy = RollPitchYaw(np.radians([segment.roll, segment.pitch, segment.heading]))
    tilt = np.cos(rpy.roll_angle()) * np.cos(rpy.pitch_angle())
    drag = model.drag_linear * v_z + model.drag_quadratic * abs(v_z) * v_z
    force = (model.mass * (GRAVITY + segment.vertical_acceleration) + drag) / tilt
    mode = CommandMode.RATES_THRUST if segment.mode == "rates" else CommandMode.ATTITUDE_THRUST
    return FC_COMMAND.pack(stamp=t, mode=mode, q_WD=rpy.ToQuaternion().wxyz(),
                           w_D=np.radians(segment.body_rates),
                           thrust=float(model.curve.thrust(force)) if segment.arm else 0.0,
                           arm=float(segment.arm))


class ScriptedPilot(LeafSystem):
    """Output `fc_command` FC_COMMAND, sampled every `profile.period` and stamped with its time.

    With `stop_at`, the output freezes from that time on (a companion computer that stops sending:
    the flight controller sees the stamp age)."""

    def __init__(self, profile: PilotProfile, model: PilotModel, stop_at: float | None = None):
        super().__init__()
        if not profile.segments:
            raise ValueError("the pilot profile has no segments")
        self._profile, self._model = profile, model
        stop_at = profile.stop_at if stop_at is None else stop_at
        self._stop_at = np.inf if stop_at is None else stop_at
        command = self.DeclareDiscreteState(FC_COMMAND.size)
        self.DeclarePeriodicDiscreteUpdateEvent(profile.period, 0.0, self._update)
        self.DeclareInitializationDiscreteUpdateEvent(self._update)
        self.DeclareStateOutputPort("fc_command", command)

    def _update(self, context, discrete_state):
        if context.get_time() >= self._stop_at:
            return
        discrete_state.set_value(profile_command(self._profile, context.get_time(), self._model))
