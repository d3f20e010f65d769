"""The part the SE(3) controller M(38) and the MPC force-feedback controller M(39) share.

Both compute a desired force

    f_d = m_e (a_fb + r''_d + g e3) - (d_w + d_b) o [1, 1, 0]

from a feedback acceleration a_fb (the subclass: SE(3) state feedback or the MPC's c_d), the
reference acceleration, the estimated mass M(37) and the disturbances M(35); then SO(3) force
tracking M(17)-(31) turns f_d into body rates, and the thrust model M(32) turns f_d . b3 into the
normalized thrust T_d. They publish the unbiased desired acceleration M(53)

    a_d = (f(T_d) b3 + (d_w + d_b) o [1, 1, 0]) / m_e - g e3

(printed M(53) divides g by m_e too; this is the dimensionally consistent form).

The controller role (alight.systems.control.controller): only the active controller computes; on
activation it starts from `last_command` (M Sec. 7.2): its thrust is the start of a thrust ramp
(rate `thrust_ramp_rate`) toward the computed thrust, so the hand-over (or the take-off from the
ground, where the last command is zero thrust) has no thrust step; when the last command was
flying, its apparent mass M(34) on the current tilt seeds the mass estimate. With
`acceleration_gain` > 0 (beyond M, on odometry whose acceleration is measured: the VIO's IMU) the
external horizontal force m_e a - f(T) b3 is also measured every tick, low-passed and compensated
with the integrators' (`disturbance.measured_force`): drag and wind are learned within a fraction
of a second instead of through a position error. The disturbance
integrators start at zero, or, when the optional input `last_disturbance` is connected (the control
manager forwards the previous controller's `disturbance_estimate`) and finite, from the previous
controller's estimates; they are frozen while the ramp lasts, and while the optional input
`tracker_status` (the active tracker's) reports ADMITTANCE_HOLD (M Sec. 4.2: the vehicle is held
down; learning that pull as mass M(37) would wind the thrust up to its limit). When the
estimator frame changes (frame_counter), the integrators are re-expressed in the new frame
(M Sec. 3.5).

Reference latency: the reference chi is advanced from its `stamp` to the tick time (at most
`max_prediction`) along its own derivatives (v, a, j; heading by its rate). A tracker that
updates on the same tick as the controller hands over the chi of the previous tick (Drake's
discrete updates read the state before the tick); tracking that 10 ms old chi put the vehicle
0.07 m behind the reference on the 7 m/s circle (measured, README "Flight-stack controllers").

Estimate latency: the state estimate is predicted from its `stamp` to the tick time (at most
`max_prediction`) with the last desired acceleration M(53) and the last commanded body rates, as
an estimator's prediction step would. Without it, the 30 ms of the mocap source make the velocity
error on the 7 m/s circle point outward (the estimate's velocity is 30 ms old: the vehicle cut
0.23 m inside) and, with the heading to the centre, the stale orientation made the attitude loop
oscillate (tilt errors growing past 20 degrees within two laps).

A tick that cannot compute (invalid or non-finite estimate or reference, a failed solver, a
non-finite result) outputs a finite, level attitude+thrust hover command and reports valid = 0 on
`controller_status`, for the control manager to fall back.
"""
import dataclasses as dc

import numpy as np
from pydrake.math import RotationMatrix

from alight.systems.boundary import (ADMITTANCE_HOLD, FC_ATTITUDE, FC_COMMAND, REFERENCE,
                                     STATE_ESTIMATE, TRACKER_STATUS, CommandMode, VectorLayout)
from alight.systems.control import disturbance
from alight.systems.control.controller import (VALID_REASONS, Controller, ControllerReason,
                                               command_is_usable, level_command, status_vector)
from alight.systems.control.disturbance import (DISTURBANCE, DISTURBANCE_ESTIMATE,
                                                DisturbanceGains, DisturbanceLimits)
from alight.systems.control.so3 import (E3, So3Params, body_rate_command, desired_orientation,
                                        jerk_feedforward, limit_tilt)
from alight.systems.estimation.heading import with_heading, wrap_angle
from alight.systems.params import bounded
from alight.systems.rotations import (heading, quaternion_from_rotation_vector, quaternion_product,
                                      rotation_matrix)
from alight.systems.thrust_curve import GRAVITY, ThrustCurve


@dc.dataclass
class VehicleModel:
    """What the controllers know of the vehicle: the weighed mass and the thrust curve M(32)
    (`alight thrust-curve` fits a_t, b_t from hover flights)."""
    mass: float = bounded(2.5, 0.05, 200.0, "kg")
    a_t: float = bounded(0.1512, 1e-4, 10.0)
    b_t: float = bounded(-0.1111, -1.0, 1.0)

    @property
    def curve(self) -> ThrustCurve:
        return ThrustCurve(self.a_t, self.b_t)


def advance_reference(reference: np.ndarray, dt: float) -> np.ndarray:
    """REFERENCE chi advanced by `dt` [s] along its derivatives (constant jerk, constant heading
    rate), stamped `dt` later."""
    L = REFERENCE
    p, v, a, j = (L.get(reference, k) for k in ("p", "v", "a", "j"))
    return L.pack(stamp=L.get(reference, "stamp") + dt,
                  p=p + v * dt + a * dt ** 2 / 2 + j * dt ** 3 / 6, v=v + a * dt + j * dt ** 2 / 2,
                  a=a + j * dt, j=j, heading=float(wrap_angle(
                      L.get(reference, "heading") + L.get(reference, "heading_rate") * dt)),
                  heading_rate=L.get(reference, "heading_rate"))


_INTERNAL = VectorLayout("force_controller_state", [
    ("ramping", 1), ("ramp_thrust", 1), ("disturbance", DISTURBANCE.size), ("measured", 2)])


class ForceController(Controller):
    """Base of the SE(3) and MPC force-feedback controllers (M(38), M(39)); see the module
    docstring. Subclasses implement `_feedback_acceleration`.

    Inputs  as `Controller` (`state_estimate`, `reference`, `active`, `last_command`);
            `last_disturbance` DISTURBANCE_ESTIMATE (optional: the previous controller's);
            `fc_attitude` FC_ATTITUDE (optional: the flight controller's attitude, M footnote 18);
            `tracker_status` TRACKER_STATUS (optional: the active tracker's; ADMITTANCE_HOLD
            holds the integrators)
    Outputs `fc_command` FC_COMMAND (body rates + thrust); `controller_status` CONTROLLER_STATUS;
            `desired_acceleration` (3) the unbiased desired acceleration M(53) [m/s^2, in E];
            `disturbance_estimate` DISTURBANCE_ESTIMATE (d_w, d_b [N, in E], m_e [kg])
    All outputs are state, updated every `period` (100 Hz by default).
    """

    def __init__(self, vehicle: VehicleModel, so3: So3Params, gains: DisturbanceGains,
                 limits: DisturbanceLimits, period: float, extra_state=None,
                 max_prediction: float = 0.1, acceleration_gain: float = 0.0):
        super().__init__(period, level_command(0.0, 0.0, 0.0, 0.0))
        self._max_prediction = max_prediction
        self._acceleration_gain = acceleration_gain
        self._vehicle, self._so3, self._gains, self._limits = vehicle, so3, gains, limits
        self._curve = vehicle.curve
        self._fc_attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self._last_disturbance = self.DeclareVectorInputPort("last_disturbance",
                                                             DISTURBANCE_ESTIMATE.size)
        self._tracker_status = self.DeclareVectorInputPort("tracker_status", TRACKER_STATUS.size)
        self._acceleration = self.DeclareDiscreteState(3)
        self._estimates = self.DeclareDiscreteState(DISTURBANCE_ESTIMATE.pack(
            d_w=np.zeros(2), d_b=np.zeros(2), m_e=vehicle.mass))
        self._internal = self.DeclareDiscreteState(np.zeros(_INTERNAL.size))
        self._extra = None if extra_state is None else self.DeclareDiscreteState(extra_state)
        self.DeclareStateOutputPort("desired_acceleration", self._acceleration)
        self.DeclareStateOutputPort("disturbance_estimate", self._estimates)

    # --- subclass interface -------------------------------------------------------------------

    def _feedback_acceleration(self, context, discrete_state, e_p, e_v, reference
                               ) -> tuple[np.ndarray, ControllerReason, float]:
        """a_fb [m/s^2, in E], the reason (OK, SOLVER_FALLBACK, SOLVER_FAILED), solver status."""
        raise NotImplementedError

    def _disturbance_gains(self, context) -> DisturbanceGains:
        """The integrator gains of M(35)-(37) for this tick (the SE(3) gain group may switch)."""
        return self._gains

    # --- the role's hooks (alight.systems.control.controller) ----------------------------------

    def _update_active(self, context, discrete_state, estimate) -> None:
        x = discrete_state.get_value(self._internal).copy()   # as `_activate` may have left it
        reference = self._reference.Eval(context)
        if estimate is None:
            return self._hold(context, discrete_state, x, ControllerReason.BAD_ESTIMATE)
        if not np.all(np.isfinite(reference)):
            return self._hold(context, discrete_state, x, ControllerReason.BAD_REFERENCE)
        self._compute(context, discrete_state, x, estimate, reference)

    def _switch_frame(self, context, discrete_state, R_OldNew, p_OldNew) -> None:
        """The disturbance integrators, M(35)-(36), in the new frame."""
        x = discrete_state.get_value(self._internal).copy()
        x[_INTERNAL.slice("disturbance")] = disturbance.reexpress(
            x[_INTERNAL.slice("disturbance")], R_OldNew)
        x[_INTERNAL.slice("measured")] = (R_OldNew.T @ np.append(
            x[_INTERNAL.slice("measured")], 0.0))[:2]
        discrete_state.set_value(self._internal, x)

    def _activate(self, context, discrete_state, last, estimate) -> None:
        """The thrust ramp from the last command's thrust; the mass estimate from its apparent
        mass M(34); the integrators from `last_disturbance` when connected."""
        usable = command_is_usable(last)
        armed = usable and FC_COMMAND.get(last, "arm") > 0.5
        thrust = float(FC_COMMAND.get(last, "thrust")) if armed else 0.0
        state = np.zeros(DISTURBANCE.size)
        if armed and estimate is not None:
            tilt_cos = rotation_matrix(STATE_ESTIMATE.get(estimate, "q_EB"))[2, 2]
            apparent = float(self._curve.apparent_mass(thrust)) * tilt_cos  # M(34)
            if apparent > 0.5 * self._vehicle.mass:
                state[DISTURBANCE.slice("mass_difference")] = np.clip(
                    apparent - self._vehicle.mass, -self._limits.mass, self._limits.mass)
        if armed and estimate is not None and self._last_disturbance.HasValue(context):
            handed = disturbance.state_from_estimate(
                self._last_disturbance.Eval(context), self._vehicle.mass,
                STATE_ESTIMATE.get(estimate, "heading"), self._limits)
            state = state if handed is None else handed
        discrete_state.set_value(self._internal, _INTERNAL.pack(ramping=1.0, ramp_thrust=thrust,
                                                                disturbance=state,
                                                                measured=np.zeros(2)))

    def _compute(self, context, discrete_state, x, estimate, reference) -> None:
        now = context.get_time()
        reference = advance_reference(reference, float(np.clip(
            now - REFERENCE.get(reference, "stamp"), 0.0, self._max_prediction)))
        p, v, R = self._predict(context, estimate, now)
        eta = heading(R)
        e_p = p - REFERENCE.get(reference, "p")
        e_v = v - REFERENCE.get(reference, "v")
        ramping = x[_INTERNAL.slice("ramping")][0] > 0.5
        state = x[_INTERNAL.slice("disturbance")]
        learning = not (ramping or self._reference_held(context))
        if learning:
            state = disturbance.integrate(state, e_p, eta, self._period,
                                          self._disturbance_gains(context), self._limits)
        m_e = disturbance.estimated_mass(self._vehicle.mass, state)
        d_w, d_b = disturbance.forces(state, eta)
        d_m = self._measured_disturbance(context, x, estimate, m_e, R, learning)
        d_w = d_w + d_m   # the compensated force: integrators M(35) + the measured one
        a_fb, reason, solver_status = self._feedback_acceleration(
            context, discrete_state, e_p, e_v, reference)
        if reason not in VALID_REASONS:
            x[_INTERNAL.slice("disturbance")] = state
            return self._hold(context, discrete_state, x, reason, solver_status)
        f_d = m_e * (a_fb + REFERENCE.get(reference, "a") + GRAVITY * E3) - (d_w + d_b)  # M(38/39)
        f_d = limit_tilt(f_d, np.radians(self._so3.max_tilt), 0.2 * m_e * GRAVITY)
        R_d = desired_orientation(f_d, REFERENCE.get(reference, "heading"),
                                  self._so3.orientation == "heading_compliant")
        omega_j = jerk_feedforward(np.linalg.norm(f_d), m_e, R_d, REFERENCE.get(reference, "j"))
        omega_d = body_rate_command(R, R_d, self._so3, omega_j,
                                    REFERENCE.get(reference, "heading_rate"))
        lo, hi = self._so3.thrust_limits
        thrust = float(np.clip(self._curve.thrust(f_d @ R[:, 2]), lo, hi))  # M(32)
        if ramping:
            step = self._so3.thrust_ramp_rate * self._period
            ramp = x[_INTERNAL.slice("ramp_thrust")][0]
            if abs(thrust - ramp) <= step:
                x[_INTERNAL.slice("ramping")] = 0.0
            else:
                thrust = ramp + np.sign(thrust - ramp) * step
            x[_INTERNAL.slice("ramp_thrust")] = thrust
        a_d = (float(self._curve.force(thrust)) * R[:, 2] + d_w + d_b) / m_e - GRAVITY * E3
        command = FC_COMMAND.pack(stamp=now, mode=CommandMode.RATES_THRUST,
                                  q_WD=RotationMatrix(R_d).ToQuaternion().wxyz(), w_D=omega_d,
                                  thrust=thrust, arm=1.0)
        x[_INTERNAL.slice("disturbance")] = state
        if not (np.all(np.isfinite(command)) and np.all(np.isfinite(a_d))):
            return self._hold(context, discrete_state, x, ControllerReason.NOT_FINITE)
        discrete_state.set_value(self._command, command)
        discrete_state.set_value(self._acceleration, a_d)
        discrete_state.set_value(self._estimates, disturbance.estimate_vector(
            self._vehicle.mass, state, eta))
        discrete_state.set_value(self._internal, x)
        discrete_state.set_value(self._status, status_vector(reason, solver_status))

    def _measured_disturbance(self, context, x, estimate, m_e: float, R: np.ndarray,
                              learning: bool) -> np.ndarray:
        """The low-passed external force measured from the estimate's acceleration (gain
        `acceleration_gain` per tick; 0: off, M(35) alone), kept in `x`; frozen as the
        integrators are (thrust ramp, admittance hold), and while the estimate's acceleration or
        the last command is not finite. [N, in E, z zero]"""
        measured = x[_INTERNAL.slice("measured")]
        if self._acceleration_gain <= 0.0:
            return np.zeros(3)
        a_EB = STATE_ESTIMATE.get(estimate, "a_EB")
        thrust = float(FC_COMMAND.get(context.get_discrete_state(self._command).get_value(),
                                      "thrust"))
        if learning and np.all(np.isfinite(a_EB)) and np.isfinite(thrust):
            force = disturbance.measured_force(m_e, a_EB, float(self._curve.force(thrust)), R)
            measured = np.clip(measured + self._acceleration_gain * (force - measured),
                               -self._limits.world, self._limits.world)
            x[_INTERNAL.slice("measured")] = measured
        return np.append(measured, 0.0)

    def _reference_held(self, context) -> bool:
        """The active tracker holds the reference back by admittance (M Sec. 4.2)."""
        return self._tracker_status.HasValue(context) and TRACKER_STATUS.get(
            self._tracker_status.Eval(context), "reason") == ADMITTANCE_HOLD

    def _predict(self, context, estimate, now) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity and orientation R_EB of the estimate predicted from its stamp to
        `now` (at most `max_prediction`) with the last unbiased desired acceleration M(53) and the
        body rates of the last issued command (when it was a rates command)."""
        dt = float(np.clip(now - STATE_ESTIMATE.get(estimate, "stamp"), 0.0,
                           self._max_prediction))
        a = context.get_discrete_state(self._acceleration).get_value()
        v = STATE_ESTIMATE.get(estimate, "v_EB")
        q = STATE_ESTIMATE.get(estimate, "q_EB")
        last = self._last.Eval(context)
        if float(FC_COMMAND.get(last, "mode")) == CommandMode.RATES_THRUST \
                and command_is_usable(last):
            q = quaternion_product(q, quaternion_from_rotation_vector(
                FC_COMMAND.get(last, "w_D") * dt))
        R = rotation_matrix(q)
        if self._fc_attitude.HasValue(context):
            R = self._flight_controller_orientation(context, now, R)
        return STATE_ESTIMATE.get(estimate, "p_EB") + v * dt + 0.5 * a * dt * dt, v + a * dt, R

    def _flight_controller_orientation(self, context, now, R_estimate) -> np.ndarray:
        """R_EB at `now` from `fc_attitude` (M footnote 18: attitude from the flight controller)
        predicted by its own body rates, turned about e3 to the heading of the estimate's
        `R_estimate` (M(12)-(14)); `R_estimate` itself when the message is not usable."""
        attitude = self._fc_attitude.Eval(context)
        if not np.all(np.isfinite(attitude)) \
                or np.linalg.norm(FC_ATTITUDE.get(attitude, "q_WB")) < 0.5:
            return R_estimate
        dt = float(np.clip(now - FC_ATTITUDE.get(attitude, "stamp"), 0.0, self._max_prediction))
        q = quaternion_product(FC_ATTITUDE.get(attitude, "q_WB"), quaternion_from_rotation_vector(
            FC_ATTITUDE.get(attitude, "w_B") * dt))
        return with_heading(rotation_matrix(q), heading(R_estimate))

    def _hold(self, context, discrete_state, x, reason, solver_status=0.0) -> None:
        """A tick that cannot compute: level hover command (finite), valid = 0."""
        previous = context.get_discrete_state(self._command).get_value()
        eta = heading(rotation_matrix(FC_COMMAND.get(previous, "q_WD"))) \
            if np.all(np.isfinite(previous)) else 0.0
        m_e = disturbance.estimated_mass(self._vehicle.mass, x[_INTERNAL.slice("disturbance")])
        arm = 1.0 if FC_COMMAND.get(previous, "arm") > 0.5 else 0.0
        thrust = 0.0 if not arm else x[_INTERNAL.slice("ramp_thrust")][0] \
            if x[_INTERNAL.slice("ramping")][0] > 0.5 else float(self._curve.thrust(m_e * GRAVITY))
        discrete_state.set_value(self._command, level_command(context.get_time(), eta, thrust,
                                                              arm))
        discrete_state.set_value(self._acceleration, np.zeros(3))
        discrete_state.set_value(self._internal, x)
        discrete_state.set_value(self._status, status_vector(reason, solver_status))
