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
"""
import dataclasses as dc

import numpy as np
from pydrake.systems.framework import BasicVector, LeafSystem
from scipy.stats import norm

from alight.systems.params import bounded

NOISE_SIZE = 4  # field test: speed, turn rate, pull event, pull side


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
            self._noise = self.DeclareVectorInputPort("noise", NOISE_SIZE)
            # state: x, y, heading, speed, turn rate, pull time left, pull side, time of update
            self._state = self.DeclareDiscreteState(np.array(
                [*self._p0, self._psi0, field_test.mean_speed, 0.0, 0.0, 1.0, 0.0]))
            self.DeclarePeriodicDiscreteUpdateEvent(field_test.period, 0.0, self._field_update)
        else:
            raise ValueError(f"unknown target motion profile {profile!r}")
        self.DeclareVectorOutputPort("desired_state", 6, self._calc)

    # --- closed-form profiles -----------------------------------------------------------------
    def _calc(self, context, output: BasicVector):
        t = context.get_time()
        if self._profile == "field_test":
            output.SetFromVector(self._field_output(context, t))
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
    def _field_output(self, context, t):
        x, y, psi, speed, rate, pull_left, side, t_k = context.get_discrete_state(
            self._state).get_value()
        f = self._field
        v = speed * _ramp(t, f.ramp_time)
        pulled = pull_left > 0
        steer = side * np.radians(f.pull_turn_rate) if pulled else self._lane_rate(x, y, psi)
        omega = rate + steer
        dt = t - t_k
        return np.array([x + v * np.cos(psi) * dt, y + v * np.sin(psi) * dt, psi + omega * dt,
                         v * np.cos(psi), v * np.sin(psi), omega])

    def _lane_rate(self, x, y, psi) -> float:
        """Turn rate steering the heading toward the lane point `lane_lookahead` ahead."""
        f = self._field
        if f.lane_lookahead <= 0:
            return 0.0
        c, s = np.cos(self._psi0), np.sin(self._psi0)
        dx, dy = x - self._p0[0], y - self._p0[1]
        cross = -s * dx + c * dy
        desired = self._psi0 - np.arctan2(cross, f.lane_lookahead)
        error = np.arctan2(np.sin(desired - psi), np.cos(desired - psi))
        return float(error / f.lane_time)

    def _field_update(self, context, discrete_state):
        f = self._field
        t = context.get_time()
        x, y, psi, vx, vy, omega = self._field_output(context, t)
        _, _, _, speed, rate, pull_left, side, _ = context.get_discrete_state(
            self._state).get_value()
        n = self._noise.Eval(context)
        dt = f.period
        speed += (f.mean_speed - speed) * dt / f.speed_time \
            + f.speed_std * np.sqrt(2 * dt / f.speed_time) * n[0]
        speed = float(np.clip(speed, f.min_speed, f.max_speed))
        rate += -rate * dt / f.turn_time \
            + np.radians(f.turn_rate_std) * np.sqrt(2 * dt / f.turn_time) * n[1]
        pull_left -= dt
        scheduled = any(t <= tp < t + dt for tp in f.pull_times)
        random_pull = f.pull_rate > 0 and n[2] > norm.isf(f.pull_rate / 60 * dt)
        if pull_left <= 0 and (scheduled or random_pull):
            pull_left, side = f.pull_duration, 1.0 if n[3] >= 0 else -1.0
        # Integrate over the coming period with the current speed and rate (see _field_output).
        discrete_state.set_value(self._state, [x, y, psi, speed, rate, pull_left, side, t])


def _ramp(t: float, ramp_time: float) -> float:
    return 1.0 if ramp_time <= 0 else float(np.clip(t / ramp_time, 0.0, 1.0))
