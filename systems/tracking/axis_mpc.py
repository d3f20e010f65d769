"""One axis of the MPC tracker, M Sec. 4.1: a linear MPC on a chain of integrators.

The virtual vehicle of M Sec. 4.1 is, per axis (x, y, z, heading), the chain position ->
velocity -> acceleration -> jerk driven by the snap, held over each step h of a uniform grid
(h a whole number of tracker periods). Every h the QP

    min  sum_k w_p (p_k - r_k)^2 + w_v (v_k - r'_k)^2 + w_t (v_N^2 + a_N^2 + j_N^2)
         + w_s s_k^2 + rho sum_d (e_d + e_d^2 / 10)
    s.t. x_{k+1} = A_h x_k + B_h s_k  (condensed),  x_0 = the virtual state now,
         -lo_d,k - e_d <= x_k[d] <= up_d,k + e_d,  e_d >= 0  for d = velocity, acceleration,
         jerk and k = 1..N (soft: one slack e_d per derivative over the horizon),
         -lo_snap <= s_k <= up_snap  (hard)

is solved for one axis, and the tracker plays the plan tick by tick until the next solve: the
grid is aligned with the solves, so the virtual vehicle moves exactly as planned and the
previous plan, shifted by one step, is feasible again (the horizon's last step aside). Between
grid points the jerk is linear, the acceleration quadratic and the velocity cubic in time; the
bounds are tightened by the largest bulge between grid points (snap h^2/8 on the acceleration,
jerk h^2/8 on the velocity), so they hold at every instant, not only on the grid. The exact L1
penalty keeps the slacks at zero whenever the bounds can be met; they keep the QP feasible from a
start outside them (a hand-over, a group switched to a slower one). A slack prices an excess
once however long it lasts, but only a plan's first step is played before the axis solves again,
and that step sheds the excess as fast as the hard snap bound allows (the excess at the first
steps, the pulled-in goal and the terminal rest all ask for it): in closed loop the vehicle gets
back within the bounds as fast as the group allows, and no faster (tests/test_mpc_tracker.py
hands it starts over slow's speed, acceleration and jerk). One slack per step, or the bounds
relaxed along the fastest return into them, got back no faster there and made OSQP reach
max_iter more often (docs/controllers.md). The program is built once as a
Drake MathematicalProgram and solved by one persistent, warm-started workspace; per solve only
the goal (a linear cost term) and the bounds change. The default back end is DAQP's dual active
set (`PersistentDaqp`): it solves each QP to its active set's exact optimum; the tracker's tick
then takes 1.2-1.7 ms at p99 and 4.2 ms at worst, no solve failing, where OSQP (`solver: osqp`,
ADMM to `osqp_eps`) failed up to 2.1 % of them, took up to 17.8 ms at p99 and 20 ms at worst
(`python bench/trackers.py --part tracker`), and made the closed loop depend on the machine's
rounding (docs/controllers.md, "The tracker's QP back end").
"""
import dataclasses as dc

import numpy as np
from pydrake.solvers import MathematicalProgram

from alight.systems.control.linear_model import discretize
from alight.systems.control.qp_backend import make_qp_backend
from alight.systems.params import bounded, choice

ORDER = 4        # position, velocity, acceleration, jerk; driven by the snap


@dc.dataclass
class AxisMpcParams:
    """Grid and weights of one axis QP (the same for all four axes)."""
    step: float = bounded(0.1, 0.01, 1.0, "s")         # h, a whole number of tracker periods
    horizon: int = bounded(25, 3, 200)                  # steps N
    weight_position: float = bounded(1.0, 1e-6, 1e6)    # w_p per m^2 (rad^2) and step
    weight_velocity: float = bounded(0.15, 0.0, 1e6)     # w_v per (m/s)^2 and step
    weight_terminal: float = bounded(1.0, 0.0, 1e6)     # w_t on v_N^2 + a_N^2
    weight_snap: float = bounded(1e-4, 0.0, 1e6)        # w_s
    slack_weight: float = bounded(1e3, 1.0, 1e9)        # rho (linear), and rho_2 = rho / 10
    solver: str = choice("daqp", "osqp")               # the QP back end (module docstring)
    osqp_eps: float = bounded(1e-3, 1e-9, 1e-2)        # osqp: with polishing
    max_iter: int = bounded(2000, 10, 100000)           # osqp: ADMM iterations


@dc.dataclass
class AxisLimits:
    """Magnitudes of the bounds of one axis, (4, N) or (4, 1): `up` bounds +derivative, `lo`
    bounds -derivative; rows velocity, acceleration, jerk, snap."""
    up: np.ndarray      # (4, N)
    lo: np.ndarray      # (4, N)


def chain(h: float) -> tuple[np.ndarray, np.ndarray]:
    """A_h, B_h of the integrator chain (p, v, a, j; snap held over h), exact."""
    B = np.zeros((ORDER, 1))
    B[-1, 0] = 1.0
    return discretize(np.eye(ORDER, k=1), B, h)


def prediction(h: float, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Condensed chain: x_k = Phi[k-1] x_0 + Gamma[k-1] j, k = 1..N; Phi (N, 3, 3),
    Gamma (N, 3, N)."""
    A, B = chain(h)
    Phi, Gamma = np.zeros((N, ORDER, ORDER)), np.zeros((N, ORDER, N))
    power = np.eye(ORDER)
    for k in range(N):
        power = A @ power
        Phi[k] = power
        Gamma[k] = (A @ Gamma[k - 1]) if k else 0.0
        Gamma[k, :, k] = B[:, 0]
    return Phi, Gamma


class AxisMpc:
    """The QP of the module docstring for one axis, built once: `update(...)`, then `solve()`
    -> (ok, snaps (N), states (N+1, 4), the solver's status, iterations)."""

    def __init__(self, params: AxisMpcParams):
        p, N = params, params.horizon
        self.N, self.step = N, p.step
        self.prog = prog = MathematicalProgram()
        self._Phi, self._Gamma = prediction(self.step, N)
        self.snap = prog.NewContinuousVariables(N, "s")
        self.slack = prog.NewContinuousVariables(3, "e")      # velocity, acceleration, jerk
        ones = np.ones((N, 1))
        self._state_bounds = []
        for d in range(3):
            variables = np.append(self.snap, self.slack[d])
            G = self._Gamma[:, d + 1, :]
            upper = prog.AddLinearConstraint(np.hstack([G, -ones]), np.full(N, -np.inf),
                                             np.zeros(N), variables)
            lower = prog.AddLinearConstraint(np.hstack([G, ones]), np.zeros(N),
                                             np.full(N, np.inf), variables)
            self._state_bounds.append((upper, lower))
        prog.AddBoundingBoxConstraint(0.0, np.inf, self.slack)
        self._snap_bounds = prog.AddBoundingBoxConstraint(np.zeros(N), np.zeros(N), self.snap)
        # Tracked rows: p_1..p_N, v_1..v_N (toward the goal), v_N, a_N, j_N (toward rest).
        self._rows = np.vstack([self._Gamma[:, 0, :], self._Gamma[:, 1, :],
                                self._Gamma[-1, 1:, :]])
        self._row_weights = np.concatenate([np.full(N, p.weight_position),
                                            np.full(N, p.weight_velocity),
                                            np.full(3, p.weight_terminal)])
        self._Q = 2.0 * self._rows.T @ (self._row_weights[:, None] * self._rows) \
            + 2.0 * p.weight_snap * np.eye(N)
        self._tracking = prog.AddQuadraticCost(self._Q, np.zeros(N), self.snap, is_convex=True)
        prog.AddLinearCost(np.full(3, p.slack_weight), 0.0, self.slack)
        prog.AddQuadraticCost(0.2 * p.slack_weight * np.eye(3), np.zeros(3), self.slack,
                              is_convex=True)
        self.solver = make_qp_backend(prog, "daqp" if p.solver == "daqp" else "persistent_osqp",
                                      tolerance=p.osqp_eps, max_iter=p.max_iter, polishing=True)
        self._snap_index = prog.FindDecisionVariableIndices(self.snap)
        self._x0 = np.zeros(ORDER)

    def update(self, x0: np.ndarray, goal: np.ndarray, limits: AxisLimits) -> None:
        """x0: [p, v, a, j] now; goal: (2, N) positions and velocities at k h, k = 1..N;
        limits: the bounds."""
        N = self.N
        up = np.broadcast_to(limits.up, (4, N))
        lo = np.broadcast_to(limits.lo, (4, N))
        self._x0 = np.asarray(x0, float).copy()
        free = self._Phi @ self._x0                   # (N, 4): the motion without snap
        bulge = self.step ** 2 / 8.0
        margins = [bulge * up[2], bulge * up[3], 0.0], [bulge * lo[2], bulge * lo[3], 0.0]
        for d, (upper, lower) in enumerate(self._state_bounds):
            upper.evaluator().UpdateUpperBound(up[d] - margins[0][d] - free[:, d + 1])
            lower.evaluator().UpdateLowerBound(-(lo[d] - margins[1][d]) - free[:, d + 1])
        self._snap_bounds.evaluator().set_bounds(-lo[3], up[3])
        goal = np.asarray(goal, float)
        targets = np.concatenate([goal[0], goal[1], np.zeros(3)])
        offsets = np.concatenate([free[:, 0], free[:, 1], free[-1, 1:]])
        self._tracking.evaluator().UpdateCoefficients(
            self._Q, 2.0 * self._rows.T @ (self._row_weights * (offsets - targets)), 0.0, True)

    def solve(self):
        result = self.solver.solve()
        snaps = result.x[self._snap_index] if result.ok else np.full(self.N, np.nan)
        states = np.vstack([self._x0, self._Phi @ self._x0 + self._Gamma @ snaps])
        return result.ok, snaps, states, result.status, result.iterations


def horizontal_factors(w: np.ndarray, step: float, previous: np.ndarray,
                       floor: float, thresholds: np.ndarray) -> np.ndarray:
    """Per-axis shares of the horizontal norm limits, (4 derivatives, N steps, 2 axes).

    The horizontal limits bound the norm of the x-y derivative (M Sec. 7.5); the decoupled axes
    get limit * share on x and y. Velocity and acceleration: the shares are |u| of a unit
    direction u per step, so the norm stays within the limit when the motion follows u (exact on
    a straight line). w (N, 2) is the velocity the vehicle is asked for along the horizon (goal
    velocity plus position error over a time constant): the velocity direction is w's (else the
    step before's, else `previous`), the acceleration direction that of dw/dt where it exceeds
    thresholds[1] (a circle gets centripetal acceleration), else the velocity's. Shares are
    floored at `floor` so that no axis is frozen: the norm can exceed the limit by
    sqrt(1 + floor^2) at most (0.5 % for 0.1). Jerk and snap change direction too fast to be
    predicted this way: each axis gets 1/sqrt(2) of their limits (a square inside the circle,
    never over the norm, 29 % short of it along an axis)."""
    N = len(w)
    u = np.zeros((4, N, 2))
    last = previous
    for k in range(N):
        norm = np.linalg.norm(w[k])
        last = w[k] / norm if norm > thresholds[0] else last
        u[0, k] = last
    change = np.gradient(w, step, axis=0) if N > 1 else np.zeros_like(w)
    norms = np.linalg.norm(change, axis=1)
    strong = norms > thresholds[1]
    u[1] = u[0]
    u[1, strong] = change[strong] / norms[strong, None]
    shares = np.maximum(np.abs(u), floor)
    shares[2:] = 1.0 / np.sqrt(2.0)
    return shares
