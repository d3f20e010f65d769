"""The MPC force-feedback controller, M(39)-(52) (M Sec. 5.7): the robust controller.

A linear MPC computes the feedback acceleration c_d of M(39),

    f_d = m_e r''_d + m_e c_d + m_e g e3 - (d_w + d_b) o [1, 1, 0],

on the 9-state model M(40)-(42) (three decoupled axes of M(10) with p = 0, dt = 0.05 s: the input
is the acceleration), minimizing M(46) with Q and S of M(52) over n steps, subject to the model
M(47), the state bounds M(48)-(49) on speed and acceleration and the slew-rate (jerk) bounds
M(50)-(51). It runs at 100 Hz; c_d = u[1].

How this implementation reads the paper where it leaves room:
- The model state is the tracking error [e, e', e''] of each axis (the reference's own motion is
  fed forward by m_e r''_d in M(39), so the MPC reference is zero, M(44) relative to chi). For a
  hovering reference this is exactly M(43)-(44); for a moving one the bounds limit the feedback's
  correction (speed and acceleration of the error), not the flight.
- The initial state M(45): position error from the estimate; velocity error from the estimate, or,
  where it violates the speed bound, the bound (the nearest admissible value: the reference's value
  of M(45) would make the MPC believe a vehicle going too fast is at rest); acceleration: the c_d
  it applied last (the model's own input: an acceleration estimated by differentiating positions
  is noise).
- Speed bounds are soft (one slack per axis, L1 penalty `speed_slack_weight`) so the QP is
  feasible from every state; acceleration and jerk bounds are hard. With `first_step_slew` the
  first input is also slew-limited against the last applied one (the bound then holds on the
  command itself, not only inside the prediction).

The QP is condensed (u only) and built once as a Drake `MathematicalProgram`; each tick updates
the linear cost term and the bounds. `solver` picks how it is solved. Measured
(bench/controllers.py, docs/benchmarks.md): OSQP's ADMM through Drake needs hundreds to thousands
of iterations on this QP whenever many bounds are active (a large error), far over the 10 ms of a
100 Hz loop, and Drake's wrapper cannot warm-start it; Clarabel's interior point takes about ten
iterations in every case (2.2 ms a tick); DAQP's dual active set (persistent_daqp.py, warm-started
from the last tick's active set, the default) takes 0.6 ms and lands on the exact optimum (within
3.5e-4 m/s^2 of Clarabel at 1e-9 tolerance, where Clarabel at its default 1e-5 is 1.9e-2 off).
A failed solve reuses the last c_d for at most `max_fallback_ticks` (valid,
reason SOLVER_FALLBACK), then reports SOLVER_FAILED (invalid).
"""
import dataclasses as dc

import numpy as np
from pydrake.solvers import MathematicalProgram

from alight.systems.control.controller import ControllerReason
from alight.systems.control.disturbance import DisturbanceGains, DisturbanceLimits
from alight.systems.control.force_controller import ForceController, VehicleModel
from alight.systems.control.program_qp import variable_index
from alight.systems.control.qp_backend import make_qp_backend
from alight.systems.control.so3 import So3Params
from alight.systems.params import bounded, choice


@dc.dataclass
class MpcForceParams:
    model_period: float = bounded(0.05, 0.005, 0.5, "s")  # dt of M(41)-(42)
    horizon: int = bounded(20, 2, 200)                     # n of M(46): 1 s
    Q: list[float] = bounded([500.0, 100.0, 100.0, 500.0, 100.0, 100.0, 100.0, 10.0, 10.0],
                             0.0, 1e6)                     # M(52)
    S: list[float] = bounded([1000.0, 300.0, 300.0, 1000.0, 300.0, 300.0, 100.0, 10.0, 10.0],
                             0.0, 1e6)                     # M(52)
    max_speed: list[float] = bounded([2.0, 2.0, 2.0], 0.05, 30.0, "m/s")           # x, y, z
    max_acceleration: list[float] = bounded([2.0, 2.0, 2.0], 0.05, 30.0, "m/s^2")
    max_jerk: list[float] = bounded([5.0, 5.0, 5.0], 0.05, 500.0, "m/s^3")
    first_step_slew: bool = True
    speed_slack_weight: float = bounded(1e4, 0.0, 1e9)
    # daqp: a persistent, warm-started DAQP workspace (persistent_daqp.py); clarabel, osqp:
    # through Drake; see bench/controllers.py
    solver: str = choice("daqp", "clarabel", "osqp")
    slack_regularization: float = bounded(1e-3, 1e-9, 1.0)  # daqp: curvature of the speed slacks
    solver_tolerance: float = bounded(1e-5, 1e-9, 1e-1)
    max_fallback_ticks: int = bounded(5, 0, 1000)
    disturbance: DisturbanceGains = dc.field(default_factory=DisturbanceGains)


def axis_model(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """A_r(dt, 0), B_r(dt, 1) of M(10), the blocks of M(41)-(42)."""
    return (np.array([[1.0, dt, dt * dt / 2], [0.0, 1.0, dt], [0.0, 0.0, 0.0]]),
            np.array([0.0, 0.0, 1.0]))


def prediction(dt: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Phi (3n x 3) and Gamma (3n x n) with [x_1; ...; x_n] = Phi x_0 + Gamma [u_1; ...; u_n]."""
    A, B = axis_model(dt)
    Phi = np.zeros((3 * n, 3))
    Gamma = np.zeros((3 * n, n))
    power = np.eye(3)
    for i in range(n):
        power = A @ power
        Phi[3 * i:3 * i + 3] = power
        for k in range(i + 1):
            Gamma[3 * i:3 * i + 3, k] = np.linalg.matrix_power(A, i - k) @ B
    return Phi, Gamma


class MpcForceQp:
    """M(46)-(51) for the three axes, condensed on u = [u_x; u_y; u_z] (3n) plus speed slacks (3).

    `solve(x0, u_prev)`: x0 (3, 3) rows [e, e', e''] per axis; u_prev (3) the last applied input.
    Returns (ok, u (3, n), solver status)."""

    def __init__(self, p: MpcForceParams, control_period: float):
        n, dt = p.horizon, p.model_period
        self.n = n
        self._p, self._control_period = p, control_period
        self.Phi, self.Gamma = prediction(dt, n)
        Q, S = np.reshape(p.Q, (3, 3)), np.reshape(p.S, (3, 3))
        # Cost 1/2 sum_{i<n} e Q e + e_n S e_n = 1/2 sum e W e with W_n = 2 S.
        self._W = [np.concatenate([np.tile(Q[a], n - 1), 2.0 * S[a]]) for a in range(3)]
        H = np.zeros((3 * n, 3 * n))
        for a in range(3):
            H[a * n:(a + 1) * n, a * n:(a + 1) * n] = self.Gamma.T @ (
                self._W[a][:, None] * self.Gamma)
        self._H = H
        velocity_rows = np.arange(1, n) * 3 + 1                  # x_2 ... x_n (x_1 is fixed by x0)
        self._Gv, self._Phiv = self.Gamma[velocity_rows], self.Phi[velocity_rows]
        self.prog = MathematicalProgram()
        self.u = self.prog.NewContinuousVariables(3 * n, "u")
        self.s = self.prog.NewContinuousVariables(3, "s")
        self._cost = self.prog.AddQuadraticCost(H, np.zeros(3 * n), self.u, is_convex=True)
        self.prog.AddLinearCost(p.speed_slack_weight * np.ones(3), 0.0, self.s)
        self.prog.AddBoundingBoxConstraint(0.0, np.inf, self.s)
        # Soft speed bounds M(48)-(49): +-(Gv u) - s <= v_max -+ Phiv x0.
        m = n - 1
        A_speed = np.zeros((6 * m, 3 * n + 3))
        for a in range(3):
            rows = slice(2 * m * a, 2 * m * (a + 1))
            block = np.vstack([self._Gv, -self._Gv])
            A_speed[rows, a * n:(a + 1) * n] = block
            A_speed[rows, 3 * n + a] = -1.0
        self._speed = self.prog.AddLinearConstraint(
            A_speed, np.full(6 * m, -np.inf), np.zeros(6 * m), np.concatenate([self.u, self.s]))
        # Slew M(50)-(51): |u_i - u_{i-1}| <= jerk dt, i = 2..n.
        D = np.zeros((m, n))
        D[np.arange(m), np.arange(m)], D[np.arange(m), np.arange(1, n)] = -1.0, 1.0
        slew = np.repeat(np.asarray(p.max_jerk) * dt, m)
        self.prog.AddLinearConstraint(np.kron(np.eye(3), D), -slew, slew, self.u)
        # Acceleration bounds (the acceleration state is the input) and the first-step slew.
        self._amax = np.repeat(p.max_acceleration, n).astype(float)
        self._box = self.prog.AddBoundingBoxConstraint(-self._amax, self._amax, self.u)
        # OSQP (ADMM) needs hundreds to thousands of iterations on this QP when many bounds are
        # active, Clarabel (interior point) about ten, DAQP a few (module docstring)
        self._backend = make_qp_backend(self.prog, p.solver, tolerance=p.solver_tolerance,
                                        max_iter=20000, polishing=True,
                                        regularization=p.slack_regularization)
        self._u_index = variable_index(self.prog, self.u)

    def initial_state(self, e_p: np.ndarray, e_v: np.ndarray, u_prev: np.ndarray) -> np.ndarray:
        """M(45) as read in the module docstring: rows [e, clip(e'), u_prev] per axis."""
        v_max = np.asarray(self._p.max_speed)
        return np.column_stack([e_p, np.clip(e_v, -v_max, v_max), u_prev])

    def solve(self, x0: np.ndarray, u_prev: np.ndarray):
        n, v_max = self.n, np.asarray(self._p.max_speed)
        gradient = np.concatenate([self.Gamma.T @ (self._W[a] * (self.Phi @ x0[a]))
                                   for a in range(3)])
        self._cost.evaluator().UpdateCoefficients(self._H, gradient, 0.0, True)
        upper = np.concatenate([np.concatenate([v_max[a] - self._Phiv @ x0[a],
                                                v_max[a] + self._Phiv @ x0[a]])
                                for a in range(3)])
        self._speed.evaluator().UpdateUpperBound(upper)
        lower, higher = -self._amax.copy(), self._amax.copy()
        if self._p.first_step_slew:
            step = np.asarray(self._p.max_jerk) * self._control_period
            first = np.arange(3) * n
            lower[first] = np.clip(u_prev - step, -self._amax[first], self._amax[first])
            higher[first] = np.clip(u_prev + step, -self._amax[first], self._amax[first])
        self._box.evaluator().set_bounds(lower, higher)
        result = self._backend.solve()
        u = result.x[self._u_index].reshape(3, n)
        return result.ok and bool(np.all(np.isfinite(u))), u, result.status


class MpcForceController(ForceController):
    """M(39) with the MPC above. Ports as `ForceController`. Own state: the last applied c_d (3)
    and the count of consecutive failed solves (1)."""

    def __init__(self, vehicle: VehicleModel, so3: So3Params, params: MpcForceParams,
                 limits: DisturbanceLimits, period: float = 0.01, max_prediction: float = 0.1,
                 acceleration_gain: float = 0.0):
        super().__init__(vehicle, so3, params.disturbance, limits, period,
                         extra_state=np.zeros(4), max_prediction=max_prediction,
                         acceleration_gain=acceleration_gain)
        self._params = params
        self.qp = MpcForceQp(params, period)

    def _feedback_acceleration(self, context, discrete_state, e_p, e_v, reference):
        extra = discrete_state.get_value(self._extra).copy()  # as _activate left it
        u_prev, failures = extra[:3], extra[3]
        ok, u, status = self.qp.solve(self.qp.initial_state(e_p, e_v, u_prev), u_prev)
        if ok:
            discrete_state.set_value(self._extra, np.append(u[:, 0], 0.0))
            return u[:, 0], ControllerReason.OK, float(status)
        failures += 1
        discrete_state.set_value(self._extra, np.append(u_prev, failures))
        reason = ControllerReason.SOLVER_FALLBACK if failures <= self._params.max_fallback_ticks \
            else ControllerReason.SOLVER_FAILED
        return u_prev.copy(), reason, float(status)

    def _activate(self, context, discrete_state, last, estimate):
        super()._activate(context, discrete_state, last, estimate)
        discrete_state.set_value(self._extra, np.zeros(4))

    def _switch_frame(self, context, discrete_state, R_OldNew, p_OldNew):
        super()._switch_frame(context, discrete_state, R_OldNew, p_OldNew)
        extra = discrete_state.get_value(self._extra).copy()
        extra[:3] = R_OldNew.T @ extra[:3]
        discrete_state.set_value(self._extra, extra)
