"""A pilot-like excitation flight for identification (L Sec. 6.1): the paper flew manually because
a chirp would let the position run away; this pilot does what a pilot does, holding the position
loosely (a soft PD on the state estimate, like a pilot watching the vehicle) while stepping one axis,
or all at once, with random steps through the attitude+thrust interface.

Segments (from YAML) name the excited axes: `pitch`, `roll`, `thrust`, `all` or `none` (hover).
"""
import dataclasses as dc

import numpy as np
from pydrake.math import RollPitchYaw
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_COMMAND, STATE_ESTIMATE, CommandMode
from alight.systems.params import bounded, choice
from alight.systems.thrust_curve import GRAVITY, ThrustCurve


@dc.dataclass
class ExcitationSegment:
    duration: float = bounded(20.0, 0.0, 3600.0, "s")
    axes: str = choice("none", "pitch", "roll", "thrust", "all")


@dc.dataclass
class ExcitationParams:
    period: float = bounded(0.02, 0.005, 0.1, "s")
    seed: int = bounded(1, 0, 2**31)
    takeoff_height: float = bounded(4.0, 1.0, 50.0, "m")
    climb_speed: float = bounded(1.0, 0.1, 5.0, "m/s")
    takeoff_time: float = bounded(8.0, 0.0, 60.0, "s")   # before the first segment
    angle_amplitude: float = bounded(8.0, 0.0, 30.0, "deg")
    thrust_amplitude: float = bounded(1.5, 0.0, 5.0, "m/s^2")
    step_duration: list[float] = bounded([0.3, 1.5], 0.05, 10.0, "s")  # min, max
    hold_gains: list[float] = bounded([0.4, 1.0], 0.0, 10.0)  # horizontal kp [1/s^2], kd [1/s]
    altitude_gains: list[float] = bounded([1.5, 2.0], 0.0, 20.0)
    segments: list[ExcitationSegment] = dc.field(default_factory=lambda: [
        ExcitationSegment(25.0, "pitch"), ExcitationSegment(25.0, "roll"),
        ExcitationSegment(20.0, "thrust")])

    @property
    def duration(self) -> float:
        return self.takeoff_time + sum(s.duration for s in self.segments)


def random_steps(rng: np.random.Generator, duration: float, period: float, amplitude: float,
                 step_duration: tuple[float, float]) -> np.ndarray:
    """Piecewise-constant random levels in [-amplitude, amplitude], each held a random time."""
    n = int(np.ceil(duration / period)) + 1
    out = np.empty(n)
    k = 0
    while k < n:
        hold = max(1, int(rng.uniform(*step_duration) / period))
        out[k:k + hold] = rng.uniform(-amplitude, amplitude)
        k += hold
    return out


class ExcitationPilot(LeafSystem):
    """Input  `state_estimate` STATE_ESTIMATE
    Output `fc_command` FC_COMMAND (attitude+thrust), `excitation` (3: pitch, roll [rad], T [m/s^2])
    """

    def __init__(self, params: ExcitationParams, mass: float, curve: ThrustCurve):
        super().__init__()
        self._p, self._mass, self._curve = params, mass, curve
        rng = np.random.default_rng(params.seed)
        angle = np.radians(params.angle_amplitude)
        self._excitation = np.stack([
            random_steps(rng, params.duration, params.period, angle, params.step_duration),
            random_steps(rng, params.duration, params.period, angle, params.step_duration),
            random_steps(rng, params.duration, params.period, params.thrust_amplitude,
                         params.step_duration)], axis=1)
        self._mask = self._axis_mask()
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        # [fc_command (11), excitation (3), start position (3), started]
        self._xd = self.DeclareDiscreteState(np.zeros(FC_COMMAND.size + 7))
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, lambda c, o: o.SetFromVector(
            c.get_discrete_state(self._xd).get_value()[:FC_COMMAND.size]),
            prerequisites_of_calc={self.xd_ticket()})
        self.DeclareVectorOutputPort("excitation", 3, lambda c, o: o.SetFromVector(
            c.get_discrete_state(self._xd).get_value()[FC_COMMAND.size:FC_COMMAND.size + 3]),
            prerequisites_of_calc={self.xd_ticket()})

    def _axis_mask(self) -> np.ndarray:
        """Which axes are excited at each sample (pitch, roll, thrust)."""
        mask = np.zeros_like(self._excitation)
        axes = {"none": [], "pitch": [0], "roll": [1], "thrust": [2], "all": [0, 1, 2]}
        start = self._p.takeoff_time
        for segment in self._p.segments:
            rows = slice(int(start / self._p.period), int((start + segment.duration)
                                                          / self._p.period))
            mask[rows, axes[segment.axes]] = 1.0
            start += segment.duration
        return mask

    def _update(self, context, discrete_state):
        x = context.get_discrete_state(self._xd).get_value().copy()
        t = context.get_time()
        estimate = self._estimate.Eval(context)
        p = STATE_ESTIMATE.get(estimate, "p_EB")
        v = STATE_ESTIMATE.get(estimate, "v_EB")
        if x[-1] < 0.5:  # remember where we started
            x[-4:-1], x[-1] = p, 1.0
        start = x[-4:-1]
        k = min(int(round(t / self._p.period)), len(self._excitation) - 1)
        excitation = self._excitation[k] * self._mask[k]
        arming = t < 1.0
        height = min(self._p.takeoff_height, self._p.climb_speed * max(t - 1.0, 0.0))
        target = start + [0.0, 0.0, height]
        kp, kd = self._p.hold_gains
        a_xy = kp * (target[:2] - p[:2]) - kd * v[:2]
        kpz, kdz = self._p.altitude_gains
        a_z = kpz * (target[2] - p[2]) - kdz * v[2] + excitation[2]
        pitch = np.clip(a_xy[0] / GRAVITY, -0.3, 0.3) + excitation[0]   # heading 0: N = W
        roll = np.clip(-a_xy[1] / GRAVITY, -0.3, 0.3) + excitation[1]
        force = self._mass * (GRAVITY + a_z) / (np.cos(pitch) * np.cos(roll))
        thrust = 0.0 if arming else float(self._curve.thrust(force))
        x[:FC_COMMAND.size] = FC_COMMAND.pack(
            stamp=t, mode=CommandMode.ATTITUDE_THRUST,
            q_WD=RollPitchYaw(roll, pitch, 0.0).ToQuaternion().wxyz(), w_D=np.zeros(3),
            thrust=thrust, arm=1.0)
        x[FC_COMMAND.size:FC_COMMAND.size + 3] = [pitch, roll, a_z]
        discrete_state.set_value(self._xd, x)
