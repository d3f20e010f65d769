"""Analytic full-state references chi (M(16)) for the M Sec. 8 experiments: take-off, position
steps of increasing size (M Sec. 8.1), the circle (M Sec. 8.2) with the heading to its centre or
constant, and hover.

Every motion is a septic smoothstep s(tau) = 35 tau^4 - 84 tau^5 + 70 tau^6 - 20 tau^7 (zero
velocity, acceleration and jerk at both ends), so position, velocity, acceleration and jerk are
continuous and known in closed form. A transition of length D gets the shortest duration that
keeps its peak speed, acceleration and jerk within the given limits. The circle's angular speed
ramps up and down with the same smoothstep. Stands in for the feedforward trackers (M Sec. 4)
until they exist; `AnalyticReference` samples a `Trajectory` as a REFERENCE port.
"""
import dataclasses as dc

import numpy as np
from numpy.polynomial import Polynomial
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import REFERENCE

SMOOTHSTEP = Polynomial([0, 0, 0, 0, 35, -84, 70, -20])
_DERIVATIVES = [SMOOTHSTEP.deriv(k) for k in range(4)]
_INTEGRAL = SMOOTHSTEP.integ()
_TAU = np.linspace(0.0, 1.0, 2001)
# Peak |d^k s / d tau^k| for k = 1, 2, 3.
PEAKS = [float(np.max(np.abs(_DERIVATIVES[k](_TAU)))) for k in (1, 2, 3)]


@dc.dataclass(frozen=True)
class Sample:
    """One point of chi: p, v, a, j (3 each, in E) and heading, heading rate."""
    p: np.ndarray
    v: np.ndarray
    a: np.ndarray
    j: np.ndarray
    heading: float = 0.0
    heading_rate: float = 0.0


def smoothstep(t: float, duration: float) -> np.ndarray:
    """[s, s', s'', s'''] with respect to t for a smoothstep of `duration` (clamped outside)."""
    if t <= 0.0:
        return np.zeros(4)
    if t >= duration:
        return np.array([1.0, 0.0, 0.0, 0.0])
    tau = t / duration
    return np.array([_DERIVATIVES[k](tau) / duration ** k for k in range(4)])


def transition_time(distance: float, max_speed: float, max_acceleration: float,
                    max_jerk: float) -> float:
    """Shortest smoothstep duration over `distance` within the speed/acceleration/jerk limits."""
    d = abs(distance)
    if d == 0.0:
        return 0.0
    return max(PEAKS[0] * d / max_speed, np.sqrt(PEAKS[1] * d / max_acceleration),
               np.cbrt(PEAKS[2] * d / max_jerk))


class Piece:
    duration: float

    def sample(self, t: float) -> Sample:
        raise NotImplementedError


@dc.dataclass
class Transition(Piece):
    """From p0, eta0 to p1, eta1 along a smoothstep of `duration` (hold when duration is 0)."""
    p0: np.ndarray
    p1: np.ndarray
    eta0: float
    eta1: float
    duration: float

    def sample(self, t):
        s = smoothstep(t, self.duration) if self.duration > 0 else np.array([1.0, 0, 0, 0])
        delta = np.asarray(self.p1) - np.asarray(self.p0)
        return Sample(self.p0 + s[0] * delta, s[1] * delta, s[2] * delta, s[3] * delta,
                      self.eta0 + s[0] * (self.eta1 - self.eta0), s[1] * (self.eta1 - self.eta0))


@dc.dataclass
class Circle(Piece):
    """A horizontal circle entered at angle 0 (the point centre + [radius, 0, 0]), counter-
    clockwise: the angular speed ramps up over `ramp` seconds to speed/radius, holds for `laps`
    full turns, ramps down. Heading to the centre (theta + pi) or `constant_heading`."""
    centre: np.ndarray
    radius: float
    speed: float
    ramp: float
    laps: float
    heading_to_centre: bool
    constant_heading: float = 0.0

    def __post_init__(self):
        self.omega = self.speed / self.radius
        self.cruise = 2 * np.pi * self.laps / self.omega
        self.duration = 2 * self.ramp + self.cruise
        self.ramp_angle = self.omega * self.ramp * float(_INTEGRAL(1.0))

    def angle(self, t: float) -> np.ndarray:
        """[theta, theta', theta'', theta''']."""
        w, T = self.omega, self.ramp
        if t < T:
            s = smoothstep(t, T)
            return np.array([w * T * float(_INTEGRAL(t / T)), w * s[0], w * s[1], w * s[2]])
        if t < T + self.cruise:
            return np.array([self.ramp_angle + w * (t - T), w, 0.0, 0.0])
        u = min(t - T - self.cruise, T)
        s = smoothstep(u, T)
        theta = self.ramp_angle + w * self.cruise + w * u - w * T * float(_INTEGRAL(u / T))
        return np.array([theta, w * (1 - s[0]), -w * s[1], -w * s[2]])

    def sample(self, t):
        th, th1, th2, th3 = self.angle(t)
        c, s = np.cos(th), np.sin(th)
        radial, tangent = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
        r = self.radius
        p = self.centre + r * radial
        v = r * th1 * tangent
        a = r * (th2 * tangent - th1 ** 2 * radial)
        j = r * ((th3 - th1 ** 3) * tangent - 3 * th1 * th2 * radial)
        if self.heading_to_centre:
            return Sample(p, v, a, j, float(np.angle(np.exp(1j * (th + np.pi)))), th1)
        return Sample(p, v, a, j, self.constant_heading, 0.0)


class Trajectory:
    """Pieces one after the other; holds the last point after the end."""

    def __init__(self, pieces: list[Piece], marks: dict[str, float] | None = None):
        self.pieces = pieces
        self.starts = np.concatenate([[0.0], np.cumsum([p.duration for p in pieces])])
        self.duration = float(self.starts[-1])
        self.marks = dict(marks or {})  # named times (e.g. "experiment", "cruise")

    def sample(self, t: float) -> Sample:
        i = int(np.clip(np.searchsorted(self.starts, t, side="right") - 1, 0,
                        len(self.pieces) - 1))
        return self.pieces[i].sample(min(t - self.starts[i], self.pieces[i].duration)
                                     if i == len(self.pieces) - 1 else t - self.starts[i])

    def end(self) -> Sample:
        return self.sample(self.duration)


def takeoff(p_ground: np.ndarray, altitude: float, eta0: float, eta1: float, spool: float,
            limits: tuple[float, float, float]) -> list[Piece]:
    """Hold on the ground for `spool` s (the controller's thrust ramp), climb `altitude` metres."""
    p_ground = np.asarray(p_ground, dtype=float)
    p_top = p_ground + [0.0, 0.0, altitude]
    return [Transition(p_ground, p_ground, eta0, eta0, spool),
            Transition(p_ground, p_top, eta0, eta1, transition_time(altitude, *limits))]


def hold(p: np.ndarray, eta: float, duration: float) -> Piece:
    return Transition(np.asarray(p, float), np.asarray(p, float), eta, eta, duration)


def steps(p_start: np.ndarray, eta: float, offsets: np.ndarray, hold_time: float,
          limits: tuple[float, float, float]) -> list[Piece]:
    """Smoothstep moves through `p_start + offset` for each offset, holding after each."""
    pieces, p = [], np.asarray(p_start, float)
    for offset in np.atleast_2d(offsets):
        target = np.asarray(p_start, float) + offset
        pieces.append(Transition(p, target, eta, eta,
                                 transition_time(np.linalg.norm(target - p), *limits)))
        pieces.append(hold(target, eta, hold_time))
        p = target
    return pieces


class AnalyticReference(LeafSystem):
    """Output `reference` REFERENCE: the trajectory sampled every `period` (state output)."""

    def __init__(self, trajectory: Trajectory, period: float = 0.01):
        super().__init__()
        self._trajectory = trajectory
        self._chi = self.DeclareDiscreteState(self.chi(0.0))
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareStateOutputPort("reference", self._chi)

    def chi(self, t: float) -> np.ndarray:
        s = self._trajectory.sample(t)
        return REFERENCE.pack(stamp=t, p=s.p, v=s.v, a=s.a, j=s.j, heading=s.heading,
                              heading_rate=s.heading_rate)

    def _update(self, context, discrete_state):
        discrete_state.set_value(self._chi, self.chi(context.get_time()))
