"""Motion profiles of the target vehicle (issue 5; L Sec. 1 and Sec. 7), as the desired state of
its planar joints [x, y, heading, vx, vy, heading rate]:

- `straight`: constant velocity along the initial heading after a start ramp (for tests);
- `figure_eight`: the MBZIRC 2017 track, a lemniscate of Bernoulli driven at 15 km/h for the first
  8 minutes, then 5 km/h (the challenge rules, L Sec. 1), heading along the track;
- `field_test`: pulled by a rope along a mostly straight, wandering path (L Sec. 7: average speeds
  1.3-5.7 m/s): Ornstein-Uhlenbeck speed and turn rate, plus occasional sharp pulls to one side
  (random, at `pull_rate` per minute, and at fixed `pull_times`) like the paper's failed
  experiment 12. The puller keeps to a lane, the line through the start along the initial heading:
  between pulls the heading is steered toward a point `lane_lookahead` ahead on that line
  (lookahead 0: free wander). Driven by a seeded `RandomSource`.

The plant reads the desired state at every step, so it is evaluated in Drake's C++, not by a
Python output call: the straight profile is a `PiecewisePolynomial` (`straight_path`, exact) in a
`TrajectorySource`; the field test's update writes, every period, the polynomial in time of the
coming period (`path_coefficients`, exact: the path is linear, quadratic during the start ramp,
between updates), which `path_evaluator` (a `TrajectoryAffineSystem`) evaluates at every step.
The figure eight (a tabulated track) keeps the Python output `desired_state`, which every profile
still has.
"""
import dataclasses as dc

import numpy as np
from pydrake.polynomial import Polynomial
from pydrake.systems.framework import BasicVector, LeafSystem
from pydrake.systems.primitives import TrajectoryAffineSystem
from pydrake.trajectories import PiecewisePolynomial
from scipy.special import ndtri

from alight.systems.params import bounded

NOISE_SIZE = 4  # field test: speed, turn rate, pull event, pull side
STATE_SIZE = 6  # desired state [x, y, heading, vx, vy, heading rate]
HORIZON = 1e7   # s, end of the closed-form paths (a PiecewisePolynomial holds its end value)


@dc.dataclass
class StraightParams:
    speed: float = bounded(5.0, 0.0, 30.0, "m/s")
    ramp_time: float = bounded(1.0, 0.0, 60.0, "s")


@dc.dataclass
class FigureEightParams:
    half_width: float = bounded(30.0, 3.0, 1000.0, "m")
    speed: float = bounded(15 / 3.6, 0.0, 30.0, "m/s")
    slow_speed: float = bounded(5 / 3.6, 0.0, 30.0, "m/s")
    slow_after: float = bounded(480.0, 0.0, 1e5, "s")
    ramp_time: float = bounded(2.0, 0.0, 60.0, "s")


@dc.dataclass
class FieldTestParams:
    mean_speed: float = bounded(3.0, 0.0, 30.0, "m/s")
    speed_std: float = bounded(0.6, 0.0, 10.0, "m/s")
    speed_time: float = bounded(3.0, 0.05, 600.0, "s")
    min_speed: float = bounded(0.3, 0.0, 30.0, "m/s")
    max_speed: float = bounded(8.0, 0.0, 30.0, "m/s")
    turn_rate_std: float = bounded(8.0, 0.0, 180.0, "deg/s")
    turn_time: float = bounded(2.0, 0.05, 600.0, "s")
    pull_rate: float = bounded(1.0, 0.0, 60.0, "1/min")
    pull_times: list[float] = dc.field(default_factory=list)  # s
    pull_duration: float = bounded(0.8, 0.0, 10.0, "s")
    pull_turn_rate: float = bounded(90.0, 0.0, 720.0, "deg/s")
    lane_lookahead: float = bounded(10.0, 0.0, 1000.0, "m")   # 0: no lane keeping
    lane_time: float = bounded(1.5, 0.05, 600.0, "s")          # heading steering time constant
    period: float = bounded(0.01, 0.001, 1.0, "s")
    ramp_time: float = bounded(1.0, 0.0, 60.0, "s")


class SpeedSchedule:
    """Piecewise-linear speed v(t) through knots (t_i, v_i), constant after the last knot, and its
    exact integral s(t)."""

    def __init__(self, times, speeds):
        self.t = np.asarray(times, float)
        self.v = np.asarray(speeds, float)
        steps = np.diff(self.t) * (self.v[1:] + self.v[:-1]) / 2
        self.s = np.concatenate([[0.0], np.cumsum(steps)])

    def speed(self, t: float) -> float:
        return float(np.interp(t, self.t, self.v))

    def distance(self, t: float) -> float:
        i = int(np.clip(np.searchsorted(self.t, t, side="right") - 1, 0, len(self.t) - 1))
        tau = t - self.t[i]
        if i == len(self.t) - 1:
            return float(self.s[i] + self.v[i] * tau)
        slope = (self.v[i + 1] - self.v[i]) / (self.t[i + 1] - self.t[i])
        return float(self.s[i] + self.v[i] * tau + slope * tau ** 2 / 2)


class Lemniscate:
    """The lemniscate of Bernoulli with half-width a, tabulated by arc length from its crossing
    point: position, tangent heading (continuous over laps: a figure eight turns by zero per lap)
    and curvature."""

    def __init__(self, a: float, samples: int = 8192):
        theta = np.pi / 2 + np.linspace(0, 2 * np.pi, samples + 1)
        d = 1 + np.sin(theta) ** 2
        xy = np.stack([a * np.cos(theta) / d, a * np.sin(theta) * np.cos(theta) / d], axis=1)
        seg = np.linalg.norm(np.diff(xy, axis=0), axis=1)
        self.s = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = self.s[-1]
        self.xy = xy
        tangent = np.gradient(xy, self.s, axis=0)
        self.heading = np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))
        self.curvature = np.gradient(self.heading, self.s)

    def at(self, s: float):
        s = s % self.length
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        return x, y, np.interp(s, self.s, self.heading), np.interp(s, self.s, self.curvature)


class TargetMotion(LeafSystem):
    """The desired planar state of the target's joints.

    Input  `noise`          (4) unit white Gaussian noise, resampled every field-test period
                            (only with the `field_test` profile)
    Output `desired_state`  (6) [x, y, heading, vx, vy, heading rate] [m, rad, m/s, rad/s] of the
                            platform centre in W, for the plant's desired-state input
    Output `path_coefficients` (18) [a, b, c] (6 each), only with `field_test`: until the next
                            update desired_state(t) = a + b t + c t^2 (for `path_evaluator`)
    """

    def __init__(self, profile: str, initial_position, initial_heading_deg: float,
                 straight: StraightParams = StraightParams(),
                 figure_eight: FigureEightParams = FigureEightParams(),
                 field_test: FieldTestParams = FieldTestParams()):
        super().__init__()
        self._profile = profile
        self._p0 = np.asarray(initial_position, float)
        self._psi0 = np.radians(initial_heading_deg)
        if profile == "straight":
            self._schedule = SpeedSchedule([0.0, max(straight.ramp_time, 1e-9)],
                                           [0.0, straight.speed])
        elif profile == "figure_eight":
            p = figure_eight
            ramp = max(p.ramp_time, 1e-9)
            slow = max(p.slow_after, ramp)
            self._schedule = SpeedSchedule([0.0, ramp, slow, slow + ramp],
                                           [0.0, p.speed, p.speed, p.slow_speed])
            self._track = Lemniscate(p.half_width)
        elif profile == "field_test":
            self._field = field_test
            # A random pull starts when the unit noise exceeds this (probability rate * period:
            # the standard normal's inverse survival function, -ndtri; scipy.stats is slow to
            # import, half a second of every command's start).
            self._pull_threshold = -float(ndtri(field_test.pull_rate / 60 * field_test.period))
            self._noise = self.DeclareVectorInputPort("noise", NOISE_SIZE)
            # state: x, y, heading, speed, turn rate, pull time left, pull side, time of update
            initial = np.array([*self._p0, self._psi0, field_test.mean_speed, 0.0, 0.0, 1.0, 0.0])
            # The per-update arithmetic runs on Python floats, its constant factors computed
            # once (the same operations and values: np.cos, np.radians... on the same numbers).
            self._lane_axis = (float(np.cos(self._psi0)), float(np.sin(self._psi0)))
            self._pull_turn_rate = float(np.radians(field_test.pull_turn_rate))
            dt = field_test.period
            self._speed_drive = field_test.speed_std \
                * float(np.sqrt(2 * dt / field_test.speed_time))
            self._rate_drive = float(np.radians(field_test.turn_rate_std)) \
                * float(np.sqrt(2 * dt / field_test.turn_time))
            self._state = self.DeclareDiscreteState(initial)
            self._state_group = int(self._state)   # (pydrake converts the index per call)
            self._coefficients = self.DeclareDiscreteState(self._field_coefficients(initial))
            self.DeclarePeriodicDiscreteUpdateEvent(field_test.period, 0.0, self._field_update)
            self.DeclareStateOutputPort("path_coefficients", self._coefficients)
        else:
            raise ValueError(f"unknown target motion profile {profile!r}")
        self.DeclareVectorOutputPort("desired_state", 6, self._calc)

    # --- closed-form profiles -----------------------------------------------------------------
    def _calc(self, context, output: BasicVector):
        t = context.get_time()
        if self._profile == "field_test":
            output.SetFromVector(self._field_output(self._field_state(context), t))
            return
        v = self._schedule.speed(t)
        s = self._schedule.distance(t)
        if self._profile == "straight":
            x, y, psi, kappa = s, 0.0, 0.0, 0.0
        else:
            x, y, psi, kappa = self._track.at(s)
        c, sn = np.cos(self._psi0), np.sin(self._psi0)
        p = self._p0 + np.array([c * x - sn * y, sn * x + c * y])
        heading = self._psi0 + psi
        output.SetFromVector([p[0], p[1], heading, v * np.cos(heading), v * np.sin(heading),
                              v * kappa])

    # --- the random field-test path -----------------------------------------------------------
    def _field_state(self, context) -> list[float]:
        """x, y, heading, speed, turn rate, pull time left, pull side, time of update."""
        return context.get_discrete_state().get_value(self._state_group).tolist()

    def _field_output(self, state: list[float], t) -> list[float]:
        """The desired state at t from the field state (`_field_state`) of the last update."""
        x, y, psi, speed, _, _, _, t_k = state
        v = speed * _ramp(t, self._field.ramp_time)
        omega = self._omega(state)
        dt = t - t_k
        cos_psi, sin_psi = float(np.cos(psi)), float(np.sin(psi))
        return [x + v * cos_psi * dt, y + v * sin_psi * dt, psi + omega * dt, v * cos_psi,
                v * sin_psi, omega]

    def _omega(self, state) -> float:
        """Turn rate until the next update: the wander plus the pull or the lane keeping."""
        x, y, psi, _, rate, pull_left, side, _ = state
        steer = side * self._pull_turn_rate if pull_left > 0 else self._lane_rate(x, y, psi)
        return rate + steer

    def _field_coefficients(self, state) -> np.ndarray:
        """[a, b, c] with `_field_output`(t) = a + b t + c t^2 from the update at t_k until the
        next: the ramp's speed (t / ramp_time) makes it quadratic while t_k is in the ramp."""
        x, y, psi, speed, _, _, _, t_k = (float(e) for e in state)
        omega = self._omega(state)
        cos_psi, sin_psi = float(np.cos(psi)), float(np.sin(psi))
        heading = [psi - omega * t_k, omega, 0.0]     # a, b, c of the heading
        ramp = self._field.ramp_time
        if ramp > 0 and t_k < ramp - 1e-9:       # v(t) = speed t / ramp
            slope_x, slope_y = speed / ramp * cos_psi, speed / ramp * sin_psi
            # p + slope t (t - t_k), velocity slope t
            a = [x, y, heading[0], 0.0, 0.0, omega]
            b = [-slope_x * t_k, -slope_y * t_k, heading[1], slope_x, slope_y, 0.0]
            c = [slope_x, slope_y, heading[2], 0.0, 0.0, 0.0]
        else:                                    # v(t) = speed
            v_x, v_y = speed * cos_psi, speed * sin_psi
            # p + velocity (t - t_k), velocity constant
            a = [x - v_x * t_k, y - v_y * t_k, heading[0], v_x, v_y, omega]
            b = [v_x, v_y, heading[1], 0.0, 0.0, 0.0]
            c = [0.0] * STATE_SIZE
        return np.array(a + b + c)

    def _lane_rate(self, x, y, psi) -> float:
        """Turn rate steering the heading toward the lane point `lane_lookahead` ahead."""
        f = self._field
        if f.lane_lookahead <= 0:
            return 0.0
        c, s = self._lane_axis
        dx, dy = x - self._p0[0], y - self._p0[1]
        cross = -s * dx + c * dy
        desired = self._psi0 - np.arctan2(cross, f.lane_lookahead)
        error = np.arctan2(np.sin(desired - psi), np.cos(desired - psi))
        return float(error / f.lane_time)

    def _field_update(self, context, discrete_state):
        f = self._field
        t = context.get_time()
        state = self._field_state(context)
        x, y, psi, _, _, _ = self._field_output(state, t)
        _, _, _, speed, rate, pull_left, side, _ = state
        n = self._noise.Eval(context).tolist()
        dt = f.period
        speed += (f.mean_speed - speed) * dt / f.speed_time + self._speed_drive * n[0]
        speed = min(max(speed, f.min_speed), f.max_speed)   # (np.clip's order)
        rate += -rate * dt / f.turn_time + self._rate_drive * n[1]
        pull_left -= dt
        scheduled = any(t <= tp < t + dt for tp in f.pull_times)
        random_pull = f.pull_rate > 0 and n[2] > self._pull_threshold
        if pull_left <= 0 and (scheduled or random_pull):
            pull_left, side = f.pull_duration, 1.0 if n[3] >= 0 else -1.0
        # Integrate over the coming period with the current speed and rate (see _field_output).
        state = [x, y, psi, speed, rate, pull_left, side, t]
        discrete_state.set_value(self._state_group, np.array(state))
        discrete_state.set_value(self._coefficients, self._field_coefficients(state))


def _ramp(t: float, ramp_time: float) -> float:
    return 1.0 if ramp_time <= 0 else min(max(t / ramp_time, 0.0), 1.0)   # (np.clip's order)


def path_evaluator() -> TrajectoryAffineSystem:
    """Drake's C++ evaluation of `path_coefficients`: input [a, b, c] (18), output
    a + b t + c t^2 (6), the desired state at the context's time (no state, no Python)."""
    n = STATE_SIZE
    t = Polynomial(np.array([0.0, 1.0]))
    D = np.full((n, 3 * n), Polynomial(0.0), dtype=object)
    for i in range(n):
        D[i, i], D[i, n + i], D[i, 2 * n + i] = Polynomial(1.0), t, t * t
    empty = lambda rows, cols: PiecewisePolynomial(np.zeros((rows, cols)))  # noqa: E731
    return TrajectoryAffineSystem(empty(0, 0), empty(0, 3 * n), empty(0, 1), empty(n, 0),
                                  PiecewisePolynomial([D], [0.0, HORIZON]), empty(n, 1))


def straight_path(initial_position, initial_heading_deg: float,
                  params: StraightParams) -> PiecewisePolynomial:
    """The `straight` profile's desired state as an exact piecewise polynomial in time: the
    quadratic start ramp, then constant velocity along the initial heading (until HORIZON)."""
    psi = np.radians(initial_heading_deg)
    u = np.array([np.cos(psi), np.sin(psi)])
    p0 = np.asarray(initial_position, float)
    ramp = max(params.ramp_time, 1e-9)
    accel = params.speed / ramp
    end_of_ramp = p0 + 0.5 * accel * ramp ** 2 * u

    def segment(p, v, a):  # rows: [x, y, heading, vx, vy, heading rate], in local time
        rows = [Polynomial(np.array([p[i], v[i], 0.5 * a[i]])) for i in range(2)]
        rows += [Polynomial(psi)] + [Polynomial(np.array([v[i], a[i]])) for i in range(2)]
        return np.array(rows + [Polynomial(0.0)], dtype=object).reshape(STATE_SIZE, 1)
    return PiecewisePolynomial([segment(p0, np.zeros(2), accel * u),
                                segment(end_of_ramp, params.speed * u, np.zeros(2))],
                               [0.0, ramp, HORIZON])
