"""The feedforward failsafe controller, M Sec. 5.10: a landing that needs no position feedback.

On activation it takes the last estimated mass m_e and the heading of the last command. m_e is the
apparent mass M(34) of the issued thrust on its tilt (the vertical force the flying controller
produces, m_e g in hover), low-passed over `mass_filter_time` while the failsafe waits inactive:
one command's thrust alone is a few per cent off hover whenever the vehicle is accelerating, as
much as the descent's margin (measured on the landing stack: the MPC's command 3 % over hover
thrust at the hand-over gave a mass 5 % over, and the "descent" climbed for 10 s).

It then commands, through the flight controller's own attitude loop (attitude+thrust mode, as
the paper relies on the Pixhawk's), a level attitude at that heading and the hover thrust M(33)
of that mass, decreasing at `thrust_decrease_rate` (fraction of the hover force per second) down
to `descent_fraction` of it: a moderate, drag-limited descent that stops the vehicle from
accelerating in any direction.

Braking (not in the paper): a vehicle that loses its estimate at speed would otherwise coast on
during the whole descent (an estimate lost at 5.7 m/s touched the ground moving sideways, 228 N
on a leg). While inactive the failsafe low-passes the horizontal velocity of the usable estimates
(`velocity_filter_time`) in the estimate's heading frame; on activation, when that velocity is
recent (within `brake_window`) and faster than `brake_min_speed`, it first tilts against it at
`brake_acceleration` for |v| / `brake_acceleration` (at most `max_brake_time`), thrust raised by
1 / cos(tilt) so the descent is unchanged, then levels. The heading frames of the estimate and of
the last command are taken to coincide (both the vehicle's heading).

Touchdown, then disarm: when the state estimate is usable (valid, and its vertical speed's
standard deviation within `max_speed_std`: a speed noisier than that cannot tell a touchdown),
the vehicle is on the ground once it has been seen descending and its vertical speed (low-passed
over `speed_filter_time`) then stays below `touchdown_speed` for `touchdown_time`, however long
the descent takes. Seen descending: faster than `descent_speed`, or `descent_height` below where
the estimate last saw it before the hand-over (same estimator frame): an estimate lost during
the descent and back on the ground saw no speed, but the vehicle is lower. Only while there is
no usable estimate does a timer stand in for it: the vehicle is taken to be down once
`max_descent_time` has passed without one (since the activation or the last usable estimate).
It then commands zero thrust and arm = 0.
"""
import dataclasses as dc
import math

import numpy as np
from pydrake.math import RotationMatrix

from alight.systems.boundary import FC_COMMAND, STATE_ESTIMATE, VectorLayout, estimate_is_valid
from alight.systems.control.controller import (Controller, ControllerReason, command_is_usable,
                                               level_command, status_vector)
from alight.systems.control.force_controller import VehicleModel
from alight.systems.control.linear_model import rotate_to_navigation, to_navigation
from alight.systems.control.so3 import desired_orientation
from alight.systems.control.touchdown import apparent_mass
from alight.systems.params import bounded
from alight.systems.rotations import heading, rotation_matrix
from alight.systems.thrust_curve import GRAVITY


@dc.dataclass
class FailsafeParams:
    thrust_decrease_rate: float = bounded(0.02, 0.0, 1.0, "1/s")  # of the hover force
    descent_fraction: float = bounded(0.95, 0.5, 1.0)            # floor, of the hover force
    mass_range: list[float] = bounded([0.7, 1.5], 0.1, 10.0)     # of the nominal mass
    descent_speed: float = bounded(0.3, 0.01, 10.0, "m/s")
    touchdown_speed: float = bounded(0.1, 0.01, 10.0, "m/s")
    touchdown_time: float = bounded(0.5, 0.0, 30.0, "s")
    speed_filter_time: float = bounded(0.2, 0.0, 10.0, "s")  # low-pass on the estimated v_z
    max_descent_time: float = bounded(60.0, 1.0, 3600.0, "s")  # without a usable estimate
    mass_filter_time: float = bounded(2.0, 0.0, 60.0, "s")     # m_e: M(34) low-passed (0: last)
    max_speed_std: float = bounded(0.5, 0.01, 100.0, "m/s")  # usable estimate's v_z std
    descent_height: float = bounded(0.5, 0.05, 100.0, "m")   # below the hand-over: descended
    brake_acceleration: float = bounded(2.0, 0.0, 5.0, "m/s^2")  # 0: no braking
    brake_min_speed: float = bounded(1.0, 0.0, 30.0, "m/s")      # slower: no braking
    max_brake_time: float = bounded(4.0, 0.0, 30.0, "s")
    brake_window: float = bounded(0.5, 0.0, 10.0, "s")           # the velocity seen this recently
    velocity_filter_time: float = bounded(0.3, 0.0, 10.0, "s")   # low-pass on the seen velocity


_STATE = VectorLayout("failsafe_state", [
    ("start", 1), ("hover_force", 1), ("heading", 1), ("mass", 1),
    ("descended", 1), ("quiet_time", 1), ("touched_down", 1), ("v_z", 1),
    ("estimate_time", 1),    # the last tick with a usable estimate (the activation before one)
    ("brake", 2), ("brake_until", 1)])   # braking acceleration in the heading frame, until when
# the fields of the inputs read at every tick
_ARM, _THRUST = FC_COMMAND.slice("arm").start, FC_COMMAND.slice("thrust").start
_Z_EB, _V_EB = STATE_ESTIMATE.slice("p_EB").start + 2, STATE_ESTIMATE.slice("v_EB")
_HEADING = STATE_ESTIMATE.slice("heading").start
_FRAME_COUNTER = STATE_ESTIMATE.slice("frame_counter").start
_VAR_V_Z = STATE_ESTIMATE.slice("var_pv").start + 5    # var_pv: p (3) then v (3)


class FailsafeController(Controller):
    """Inputs  as `Controller`: `state_estimate` (only its vertical speed, when valid);
            `reference` (unused: the failsafe needs none); `active`; `last_command`
    Outputs `fc_command` FC_COMMAND (attitude+thrust, level); `controller_status`;
            `desired_acceleration` (3) the vertical acceleration the thrust gives at m_e [m/s^2]
    """

    def __init__(self, vehicle: VehicleModel, params: FailsafeParams, period: float = 0.01):
        super().__init__(period, level_command(0.0, 0.0, 0.0, 0.0))
        self._vehicle, self._p = vehicle, params
        self._curve = vehicle.curve
        self._acceleration = self.DeclareDiscreteState(3)
        self._state = self.DeclareDiscreteState(np.zeros(_STATE.size))
        # m_e: the issued commands' M(34) low-passed while inactive (NaN before a flying one).
        self._mass_seen = self.DeclareDiscreteState([np.nan])
        # [z, frame counter] of the last usable estimate before the hand-over (NaN: none).
        self._height_seen = self.DeclareDiscreteState([np.nan, np.nan])
        # [v_x, v_y] of the usable estimates in their heading frame, low-passed, and when seen.
        self._velocity_seen = self.DeclareDiscreteState([0.0, 0.0, np.nan])
        # (pydrake converts a DiscreteStateIndex per call: the per-tick accesses take ints)
        self._mass_seen_group, self._height_seen_group, self._velocity_seen_group = map(
            int, (self._mass_seen, self._height_seen, self._velocity_seen))
        self._mass_bounds = tuple((np.asarray(params.mass_range) * vehicle.mass).tolist())
        self._max_speed_var = params.max_speed_std ** 2
        self.DeclareStateOutputPort("desired_acceleration", self._acceleration)

    def flying_mass(self, command: np.ndarray) -> float:
        """The mass a flying command holds up, M(34) on its tilt, within `mass_range`; NaN for a
        command that is not usable, not armed or without thrust."""
        if not command_is_usable(command) or command[_ARM] < 0.5 or command[_THRUST] <= 0.0:
            return float("nan")
        lo, hi = self._mass_bounds
        return min(max(apparent_mass(command, self._vehicle), lo), hi)   # (np.clip's order)

    def last_mass(self, context, last_command: np.ndarray) -> float:
        """m_e: the low-passed mass of the issued commands, else the last command's, else the
        nominal mass."""
        for mass in (context.get_discrete_state(self._mass_seen).get_value()[0],
                     self.flying_mass(last_command)):
            if np.isfinite(mass):
                return float(mass)
        return self._vehicle.mass

    def usable(self, estimate) -> bool:
        """A valid estimate (not None) whose vertical speed can tell a touchdown."""
        return estimate is not None and estimate[_VAR_V_Z] <= self._max_speed_var

    def _update_inactive(self, context, discrete_state) -> None:
        """Status INACTIVE; the issued command's mass into m_e; the height last seen."""
        # (on the elements as floats: this runs at every tick of the flight)
        super()._update_inactive(context, discrete_state)
        estimate = self._estimate.Eval(context)
        if estimate_is_valid(estimate) and self.usable(estimate):
            discrete_state.set_value(self._height_seen_group, np.array(
                [estimate[_Z_EB], estimate[_FRAME_COUNTER]]))
            self._see_velocity(context, discrete_state, estimate)
        mass = self.flying_mass(self._last.Eval(context))
        if math.isnan(mass):
            return
        seen = context.get_discrete_state().get_value(self._mass_seen_group).tolist()[0]
        alpha = min(1.0, self._period / self._p.mass_filter_time) \
            if self._p.mass_filter_time > 0 else 1.0
        discrete_state.set_value(self._mass_seen_group, np.array([
            mass if math.isnan(seen) else seen + alpha * (mass - seen)]))

    def _see_velocity(self, context, discrete_state, estimate) -> None:
        eta = estimate[_HEADING]
        v_x, v_y, _ = to_navigation(estimate[_V_EB].tolist(), float(np.cos(eta)),
                                    float(np.sin(eta)))   # (rotate_to_navigation's operations)
        now = context.get_time()
        seen_x, seen_y, seen_t = \
            context.get_discrete_state().get_value(self._velocity_seen_group).tolist()
        recent = math.isfinite(seen_t) and now - seen_t <= 2 * self._period
        alpha = min(1.0, self._period / self._p.velocity_filter_time) \
            if self._p.velocity_filter_time > 0 and recent else 1.0
        discrete_state.set_value(self._velocity_seen_group, np.array(
            [seen_x + alpha * (v_x - seen_x), seen_y + alpha * (v_y - seen_y), now]))

    def _braking(self, context) -> tuple[np.ndarray, float]:
        """The braking acceleration in the heading frame and its duration (zero: none)."""
        p = self._p
        v_x, v_y, seen = context.get_discrete_state(self._velocity_seen).get_value()
        speed = float(np.hypot(v_x, v_y))
        if p.brake_acceleration <= 0 or not np.isfinite(seen) or speed < p.brake_min_speed \
                or context.get_time() - seen > p.brake_window:
            return np.zeros(2), 0.0
        return -np.array([v_x, v_y]) / speed * p.brake_acceleration, \
            min(speed / p.brake_acceleration, p.max_brake_time)

    def _activate(self, context, discrete_state, last, estimate) -> None:
        """m_e and the heading of the last command; on the ground when it was not flying."""
        mass = self.last_mass(context, last)
        flying = command_is_usable(last) and FC_COMMAND.get(last, "arm") > 0.5 \
            and FC_COMMAND.get(last, "thrust") > 0.0
        eta = heading(rotation_matrix(FC_COMMAND.get(last, "q_WD"))) \
            if command_is_usable(last) else 0.0
        brake, duration = self._braking(context) if flying else (np.zeros(2), 0.0)
        discrete_state.set_value(self._state, _STATE.pack(
            start=context.get_time(), hover_force=mass * GRAVITY, heading=eta, mass=mass,
            descended=0.0, quiet_time=0.0, touched_down=0.0 if flying else 1.0, v_z=0.0,
            estimate_time=context.get_time(), brake=brake,
            brake_until=context.get_time() + duration))

    def _update_active(self, context, discrete_state, estimate) -> None:
        now = context.get_time()
        S = _STATE
        x = discrete_state.get_value(self._state).copy()   # as `_activate` may have left it
        if x[S.slice("touched_down")][0] < 0.5:
            self._detect_touchdown(x, estimate if self.usable(estimate) else None, now,
                                   context.get_discrete_state(self._height_seen).get_value())
        touched_down = x[S.slice("touched_down")][0] > 0.5
        if touched_down:
            force, arm = 0.0, 0.0
        else:
            fraction = max(self._p.descent_fraction, 1.0 - self._p.thrust_decrease_rate
                           * (now - x[S.slice("start")][0]))
            force, arm = fraction * x[S.slice("hover_force")][0], 1.0
        mass, eta = x[S.slice("mass")][0], x[S.slice("heading")][0]
        command = level_command(now, eta, 0.0, arm)
        acceleration = np.array([0.0, 0.0, force / mass - GRAVITY])
        if arm and now < x[S.slice("brake_until")][0]:
            # the descent's vertical force, tilted against the speed (heading frame -> W)
            f_d = mass * rotate_to_navigation(np.append(x[S.slice("brake")], 0.0), -eta)
            f_d[2] = force
            command[FC_COMMAND.slice("q_WD")] = RotationMatrix(
                desired_orientation(f_d, eta)).ToQuaternion().wxyz()
            acceleration[:2] = f_d[:2] / mass
            force = float(np.linalg.norm(f_d))
        command[FC_COMMAND.slice("thrust")] = float(np.clip(self._curve.thrust(force), 0.0, 1.0)) \
            if arm else 0.0
        discrete_state.set_value(self._command, command)
        discrete_state.set_value(self._acceleration, acceleration)
        discrete_state.set_value(self._state, x)
        discrete_state.set_value(self._status, status_vector(
            ControllerReason.TOUCHDOWN if touched_down else ControllerReason.OK))

    def _detect_touchdown(self, x: np.ndarray, estimate, now: float, seen: np.ndarray) -> None:
        """`estimate`: None when it is not usable; `seen`: [z, frame counter] before the
        hand-over."""
        S = _STATE
        if estimate is None:
            if now - x[S.slice("estimate_time")][0] > self._p.max_descent_time:
                x[S.slice("touched_down")] = 1.0
            return
        x[S.slice("estimate_time")] = now
        alpha = min(1.0, self._period / max(self._p.speed_filter_time, 1e-9))
        v_z = x[S.slice("v_z")][0] + alpha * (STATE_ESTIMATE.get(estimate, "v_EB")[2]
                                              - x[S.slice("v_z")][0])
        x[S.slice("v_z")] = v_z
        lower = STATE_ESTIMATE.get(estimate, "frame_counter") == seen[1] \
            and STATE_ESTIMATE.get(estimate, "p_EB")[2] < seen[0] - self._p.descent_height
        if v_z < -self._p.descent_speed or lower:
            x[S.slice("descended")] = 1.0
        quiet = x[S.slice("descended")][0] > 0.5 and abs(v_z) < self._p.touchdown_speed
        x[S.slice("quiet_time")] = x[S.slice("quiet_time")][0] + self._period if quiet else 0.0
        if x[S.slice("quiet_time")][0] >= self._p.touchdown_time:
            x[S.slice("touched_down")] = 1.0
