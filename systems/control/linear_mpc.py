"""The landing paper's position controller: linear MPC with soft state constraints, L(19)-(27).

Condensed QP over t = [u_0..u_{N-1}, s]: the predicted states x = Phi x0 + Gamma u (L(23)); cost
L(20) on position and velocity (and angle, rate) errors against the reference and on inputs against
the input that holds the reference velocity; hard bounds on commanded pitch, roll and thrust; soft
bounds on velocity and attitude with slacks s >= 0 penalized by lambda (L(25)-(26)), so the QP is
feasible in every state. The MathematicalProgram (solved by OSQP) is built once; each tick only the
linear cost term and the soft-constraint bounds change (L(27)): a fixed quadratic cost holds the
Hessian, a separate linear cost the per-tick term, so no matrix is handed over per tick, and the
persistent OSQP workspace re-reads only these two bindings. The per-tick arithmetic is the same
operations in the same order as written in `update` (OSQP's iterations are sensitive to the last
bit of its data: a regrouped sum changed the commands of a closed-loop flight by 4e-4 after 13 s).

The reference position moves along the reference velocity over the horizon (L Sec. 6.3 notes the
formulation handles a time-varying reference; a static one over a long horizon lags behind a
moving target by about v * horizon / 2).

The paper's controller has no integral action, so a steady wind leaves a constant offset (L Sec. 8,
left to future work there). With `disturbance_gain` > 0 a constant acceleration disturbance d is
estimated from the one-step velocity prediction error and added to the model, v_dot = L(11) + d
(offset-free MPC): the prediction becomes x = Phi x0 + Gamma u + Psi d and the reference inputs
hold the reference velocity against d. Only its horizontal part (wind) is estimated: the vertical
balance is the identified thrust curve's, and on the ground (legs loaded, the vehicle cannot
follow its commands) a vertical estimate would wind up. Gain 0 is the paper's controller.

The estimate's position and the reference's are moved along their velocities from their stamps to
the tick (at most `max_prediction`): the MPC starts from where the vehicle is now, not where the
odometry saw it (not in the paper; 0 turns it off).
"""
import dataclasses as dc
import enum
import math

import numpy as np
from pydrake.math import RollPitchYaw
from pydrake.solvers import MathematicalProgram

from alight.systems.boundary import (CONTROLLER_STATUS, FC_ATTITUDE, FC_COMMAND, REFERENCE,
                                     STATE_ESTIMATE, CommandMode, VectorLayout)
from alight.systems.control.controller import Controller
from alight.systems.control.disturbance import resolve_auto_source
from alight.systems.control.linear_model import (GRAVITY, NUM_INPUTS, NUM_STATES,
                                                 LinearModelParams, continuous_model, discretize,
                                                 euler_angles, euler_rates, to_navigation)
from alight.systems.control.program_qp import QpResult, variable_index
from alight.systems.control.qp_backend import make_qp_backend
from alight.systems.params import bounded, choice
from alight.systems.rotations import product_floats, quaternion_heading
from alight.systems.thrust_curve import ThrustCurve

# The fields the tick reads, as indices into the vectors' `tolist()`
_E_STAMP, _E_P, _E_V, _E_A, _E_HEADING = (STATE_ESTIMATE.slice(field) for field in
                                          ("stamp", "p_EB", "v_EB", "a_EB", "heading"))
_E_STAMP, _E_HEADING = _E_STAMP.start, _E_HEADING.start
_R_STAMP, _R_P, _R_V, _R_A, _R_HEADING = (REFERENCE.slice(field) for field in
                                          ("stamp", "p", "v", "a", "heading"))
_R_STAMP, _R_HEADING = _R_STAMP.start, _R_HEADING.start
_A_Q, _A_W = FC_ATTITUDE.slice("q_WB"), FC_ATTITUDE.slice("w_B")
_ATTITUDE_THRUST = float(CommandMode.ATTITUDE_THRUST)
_ZERO = np.zeros(1)
if FC_COMMAND.names() != ["stamp", "mode", "q_WD_0", "q_WD_1", "q_WD_2", "q_WD_3", "w_D_0",
                          "w_D_1", "w_D_2", "thrust", "arm"] \
        or CONTROLLER_STATUS.names() != ["valid", "reason", "solver_status"]:
    raise ImportError("linear_mpc writes FC_COMMAND and CONTROLLER_STATUS out by field order")


@dc.dataclass
class LinearMpcParams:
    period: float = bounded(0.05, 0.005, 0.5, "s")          # L Sec. 6.1: 50 ms
    horizon_steps: int = bounded(20, 2, 200)                # 1 s at 50 ms
    weight_position: list[float] = bounded([4.0, 4.0, 8.0], 0.0, 1e6)
    weight_velocity: list[float] = bounded([1.5, 1.5, 2.0], 0.0, 1e6)
    weight_angles: list[float] = bounded([0.0, 0.0], 0.0, 1e6)   # pitch, roll
    weight_rates: list[float] = bounded([0.05, 0.05], 0.0, 1e6)
    weight_input: list[float] = bounded([20.0, 20.0, 0.2], 0.0, 1e6)  # pitch_r, roll_r, T_r
    weight_input_change: list[float] = bounded([200.0, 200.0, 0.05], 0.0, 1e6)  # per step
    max_tilt_command: float = bounded(30.0, 1.0, 60.0, "deg")  # hard input bound
    thrust_acceleration: list[float] = bounded([-6.0, 8.0], -9.81, 30.0, "m/s^2")  # T_r bounds
    max_velocity: list[float] = bounded([6.0, 6.0, 2.5], 0.1, 30.0, "m/s")  # soft
    max_tilt: float = bounded(20.0, 1.0, 60.0, "deg")                       # soft
    slack_penalty: float = bounded(1000.0, 0.0, 1e9)                        # lambda of L(25)
    osqp_eps: float = bounded(1e-4, 1e-8, 1e-1)
    # Offset-free extension (not in the paper): fraction of the velocity prediction error added to
    # the disturbance estimate per tick (0: off, the paper's controller), and its bound.
    disturbance_gain: float = bounded(0.0, 0.0, 1.0)
    # What d is learned from: `velocity`, the one-step velocity prediction error (the
    # odometry's velocity differentiated over a tick, `disturbance_gain` of it per tick);
    # `acceleration`, the state estimate's measured acceleration a_EB (the VIO's: the IMU's
    # specific force rotated, less gravity) less L(11)'s horizontal v_dot at the vehicle's
    # attitude and velocity, low-passed by `acceleration_gain` per tick (a mocap or bank a_EB is
    # a differentiated position, +-10 m/s^2 of noise: not for this); `auto`, acceleration on VIO
    # odometry and velocity on any other (resolved by the stack builder, `resolve_disturbance`).
    # `disturbance_gain` 0 turns the estimate off whatever the source (the paper's MPC).
    disturbance_source: str = choice("velocity", "acceleration", "auto")
    acceleration_gain: float = bounded(0.2, 0.0, 1.0)
    # Safety extension (not in the paper): the reference position is taken at most this far
    # from the estimate (a carrot on the line to it). The soft velocity and tilt bounds of
    # L(25)-(26) give way under a large position error (a 200 m step back to the waypoint flew
    # at 14 m/s against max_velocity 6 m/s, 12 m off the line: bench/faults.py); within it the
    # MPC is unchanged.
    max_position_error: float = bounded(10.0, 0.5, 1e4, "m")
    # Latency (not in the paper): the estimate's position and the reference's are moved along
    # their velocities from their stamps to the tick, by at most this much (0: as given). The
    # mocap source's 30 ms put the vehicle 8 cm ahead of a reference moving at 3 m/s
    # (tests/test_wind_offsets.py), 15 cm at 5 m/s.
    max_prediction: float = bounded(0.1, 0.0, 0.5, "s")
    max_disturbance: float = bounded(3.0, 0.0, 9.81, "m/s^2")
    # Authority for fast targets (not in the paper, issue 23): the soft bounds of L(25)-(26)
    # taken about the reference's motion instead of about hover: per step, the horizontal speed
    # bound max(max_velocity, |v_ref| + speed_margin) per axis, and max_tilt about the tilt that
    # holds the reference's motion against drag and the disturbance (s_u), predicted and
    # commanded. With fixed bounds a car at 8 m/s in 15 km/h wind takes 13 of the 20 degrees to
    # hold its speed and an 8.5 m/s bound closes on it at 0.5 m/s (docs/landing.md "Fast cars").
    reference_authority: bool = False
    speed_margin: float = bounded(3.0, 0.0, 30.0, "m/s")
    # persistent: one warm-started osqp workspace built from the MathematicalProgram;
    # drake: Drake's OsqpSolver, set up cold every tick; daqp: one warm-started DAQP (dual
    # active-set) workspace built from the same program, exact and with a bounded tail
    # (bench/mpc_solve.py compares them).
    solver: str = choice("persistent", "drake", "daqp")
    # daqp only: curvature given to the slacks (DAQP needs a positive-definite Hessian)
    slack_regularization: float = bounded(1e-3, 1e-9, 1.0)


MPC_DISTURBANCE = VectorLayout("mpc_disturbance", [("d_W", 3)])  # the `disturbance` output

# `solver`: the qp_backend kind of each choice
_BACKENDS = {"persistent": "persistent_osqp", "drake": "osqp", "daqp": "daqp"}


def resolve_disturbance(params: LinearMpcParams, estimator: str) -> LinearMpcParams:
    """`params` with `disturbance_source: auto` made `acceleration` on the VIO's odometry (its
    a_EB is measured) and `velocity` on any other."""
    return resolve_auto_source(params, estimator, otherwise="velocity")


class MpcReason(enum.IntEnum):
    """The codes of ControllerReason (force_controller.py) where they mean the same: the control
    manager reads INACTIVE = 1 as "not computed yet", also between this 20 Hz MPC's ticks."""
    OK = 0
    INACTIVE = 1
    BAD_ESTIMATE = 2
    FALLBACK = 4        # solver failed: the previous solution's next input was used once
    SOLVER_FAILED = 5   # failed again: the command is a safe level hover, not to be flown


_OK = float(MpcReason.OK)


def prediction_matrices(Ad: np.ndarray, Bd: np.ndarray, N: int) -> tuple[np.ndarray, np.ndarray]:
    """Phi and Gamma of L(23): x_bar = Phi x0 + Gamma u_bar."""
    n, m = Bd.shape
    Phi = np.zeros((N * n, n))
    Gamma = np.zeros((N * n, N * m))
    power = np.eye(n)
    for k in range(N):
        power = Ad @ power
        Phi[k * n:(k + 1) * n] = power
        for j in range(k + 1):
            Gamma[k * n:(k + 1) * n, j * m:(j + 1) * m] = np.linalg.matrix_power(Ad, k - j) @ Bd
    return Phi, Gamma


def disturbance_matrices(A: np.ndarray, dt: float, N: int) -> tuple[np.ndarray, np.ndarray]:
    """E_d (n x 3), the one-step effect of a constant acceleration disturbance on the state, and
    Psi (N*n x 3), its effect over the horizon: x_bar = Phi x0 + Gamma u_bar + Psi d."""
    E = np.zeros((NUM_STATES, 3))
    E[3:6] = np.eye(3)
    Ad, Ed = discretize(A, E, dt)
    _, Gamma_d = prediction_matrices(Ad, Ed, N)
    return Ed, Gamma_d @ np.tile(np.eye(3), (N, 1))


def soft_constraint_rows() -> np.ndarray:
    """G of one step: +-v_x, +-v_y, +-v_z, +-theta, +-phi <= h."""
    G = np.zeros((10, NUM_STATES))
    for i, state in enumerate([3, 4, 5, 6, 7]):
        G[2 * i, state], G[2 * i + 1, state] = 1.0, -1.0
    return G


class LinearMpcQp:
    """The QP L(26)-(27), built once as a MathematicalProgram; `solve(x0, s_y, s_u)` per tick."""

    def __init__(self, model: LinearModelParams, p: LinearMpcParams):
        N, m = p.horizon_steps, NUM_INPUTS
        self.N = N
        A, B = continuous_model(model)
        self.Ad, self.Bd = discretize(A, B, p.period)
        self.Ed, self.Psi = disturbance_matrices(A, p.period, N)
        self.Phi, self.Gamma = prediction_matrices(self.Ad, self.Bd, N)
        w_state = np.concatenate([p.weight_position, p.weight_velocity, p.weight_angles,
                                  p.weight_rates])
        self.W = np.tile(w_state, N)
        self.Rw = np.tile(p.weight_input, N)
        G = self._G = soft_constraint_rows()
        self.G_bar = np.kron(np.eye(N), G)
        h_step = np.repeat(np.concatenate([p.max_velocity, np.radians([p.max_tilt] * 2)]), 2)
        self.h = np.tile(h_step, N)
        # One slack per bounded quantity and step, shared by its +/- rows (only one side can be
        # violated, so the penalty is still lambda * 1^T (G x - h)_+ of L(25)).
        num_slacks = (len(self.h) + 4 * N) // 2
        self.prog = MathematicalProgram()
        self.u = self.prog.NewContinuousVariables(N * m, "u")
        self.s = self.prog.NewContinuousVariables(num_slacks, "s")
        # Move suppression: sum_k ||u_k - u_{k-1}||^2 weighted, with u_{-1} the input applied last
        # tick (not in L(20); without it the exact slack penalty drives bang-bang attitude
        # commands that the real, delayed attitude loop turns into a limit cycle).
        self.D = np.eye(N * m) - np.eye(N * m, k=-m)
        self.Wd = np.tile(p.weight_input_change, N)
        H = self.Gamma.T @ (self.W[:, None] * self.Gamma) + np.diag(self.Rw) \
            + self.D.T @ (self.Wd[:, None] * self.D)
        self.prog.AddQuadraticCost(2.0 * H, np.zeros(N * m), self.u, is_convex=True)
        self.cost = self.prog.AddLinearCost(np.zeros(N * m), 0.0, self.u)  # 2 f per tick
        self.prog.AddLinearCost(p.slack_penalty * np.ones(num_slacks), 0.0, self.s)
        tilt = np.radians(p.max_tilt_command)
        lower = np.tile([-tilt, -tilt, p.thrust_acceleration[0]], N)
        upper = np.tile([tilt, tilt, p.thrust_acceleration[1]], N)
        self.prog.AddBoundingBoxConstraint(lower, upper, self.u)
        self.prog.AddBoundingBoxConstraint(0.0, np.inf, self.s)
        # Soft rows: predicted velocities and angles (state part, updated per tick from x0),
        # then the commanded pitch and roll themselves (a tilt the vehicle is told to hold).
        G_u = np.kron(np.eye(N), np.kron(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]),
                                         np.array([[1.0], [-1.0]])))
        self.num_state_rows = len(self.h)
        self.h = np.concatenate([self.h, np.full(len(G_u), np.radians(p.max_tilt))])
        self.GGamma = np.vstack([self.G_bar @ self.Gamma, G_u])
        self.soft = self.prog.AddLinearConstraint(
            np.hstack([self.GGamma, -np.kron(np.eye(num_slacks), np.ones((2, 1)))]),
            np.full(len(self.h), -np.inf),
            self.h.copy(), np.concatenate([self.u, self.s]))
        self._u_index = variable_index(self.prog, self.u)
        self._s_index = variable_index(self.prog, self.s)
        self.backend = make_qp_backend(
            self.prog, _BACKENDS[p.solver], tolerance=p.osqp_eps, max_iter=4000,
            regularization=p.slack_regularization, changing=[self.cost, self.soft])
        # `update`'s operands, looked up once: the evaluators it updates, the transposes, and the
        # soft rows' upper bounds (the commanded-tilt rows keep h) with a per-step view of the
        # predicted states' rows
        self._updated = (self.cost.evaluator(), self.soft.evaluator())
        self._GammaT, self._GT = self.Gamma.T, self._G.T
        self._bound = self.h.copy()
        self._bound_states = self._bound[:self.num_state_rows].reshape(N, -1)
        self._h_states = self.h[:self.num_state_rows].reshape(N, -1).copy()  # `about`'s
        self._h_commanded = self._bound[self.num_state_rows:].reshape(N, -1)  # (a view)
        self._limits = (np.array(p.max_velocity[:2]), np.radians(p.max_tilt))
        self.last: QpResult | None = None  # the last solve's result (iterations: bench)

    def update(self, x0: np.ndarray, s_y: np.ndarray, s_u: np.ndarray,
               u_previous: np.ndarray | None = None, d: np.ndarray = np.zeros(3)) -> None:
        """New linear cost term and soft bounds for the state x0, the references (N*n, N*m), the
        input applied last tick (None: no move suppression of the first input) and the estimated
        acceleration disturbance d (N frame): L(27)'s data."""
        free = self.Phi @ x0 + self.Psi @ d  # the predicted states with zero inputs, L(23)
        f = self._GammaT @ (self.W * (free - s_y)) - self.Rw * s_u
        if u_previous is not None:
            # D^T (Wd * e) with e = [u_previous, 0...]: D's first rows are [I 0...], so only the
            # first block of f changes
            f[:NUM_INPUTS] -= self.Wd[:NUM_INPUTS] * u_previous
        f *= 2.0  # the program's cost is 1/2 t'Ht + q't with q = 2 f
        cost, soft = self._updated
        cost.UpdateCoefficients(f, 0.0)
        # h - G x_free, L(25), per step (the commanded-tilt rows keep h)
        np.subtract(self._h_states, free.reshape(self.N, NUM_STATES) @ self._GT,
                    out=self._bound_states)
        soft.UpdateUpperBound(self._bound)

    def about(self, s_y: np.ndarray, s_u: np.ndarray, speed_margin: float) -> None:
        """Soft bounds about the reference's motion (`reference_authority`) for the next
        `update`: the horizontal speed bounds max(max_velocity, |v_ref| + speed_margin) and
        max_tilt about the holding tilt s_u, of the predicted and the commanded pitch and roll."""
        y, u = s_y.reshape(self.N, NUM_STATES), s_u.reshape(self.N, NUM_INPUTS)
        max_velocity, max_tilt = self._limits
        speed = np.maximum(max_velocity, np.abs(y[:, 3:5]) + speed_margin)
        self._h_states[:, 0:4] = np.repeat(speed, 2, axis=1)      # +-v_x, +-v_y
        for rows, hold in ((self._h_states[:, 6:10], y[:, 6:8]), (self._h_commanded, u[:, :2])):
            rows[:, 0::2] = max_tilt + hold                        # +theta, +phi <=
            rows[:, 1::2] = max_tilt - hold                        # -theta, -phi <=

    def solve(self) -> QpResult:
        """Solves the program with its current data; `inputs(result)`, `slacks(result)`."""
        self.last = self.backend.solve()
        return self.last

    def inputs(self, result: QpResult) -> np.ndarray:
        """(N, 3) planned inputs [pitch_r, roll_r, T_r]."""
        return result.x[self._u_index].reshape(self.N, NUM_INPUTS)

    def slacks(self, result: QpResult) -> np.ndarray:
        return result.x[self._s_index]


def carrot(p: list[float], p_ref: list[float], max_distance: float) -> list[float]:
    """`p_ref`, moved toward `p` along the line between them until it is at most
    `max_distance` from `p` (3 floats each)."""
    error = np.array([r - q for r, q in zip(p_ref, p)])
    distance = math.sqrt(error @ error)  # (np.linalg.norm's own formula, without its checks)
    if distance <= max_distance:
        return p_ref
    scale = max_distance / distance
    return [q + e * scale for q, e in zip(p, error.tolist())]


class LinearMpc(Controller):
    """Inputs  as `Controller`: `state_estimate` (position, velocity, heading); `reference`
            (position, velocity, heading); `active`; `last_command`; and `fc_attitude`
            FC_ATTITUDE (pitch, roll and body rates for L(17))
    Outputs `fc_command` FC_COMMAND (attitude+thrust), `controller_status` CONTROLLER_STATUS,
            `prediction` (N x 3 inputs of the last solution, flattened),
            `disturbance` (3) the estimated acceleration disturbance d_W [m/s^2] (zero when off)
    Own state: the previous solution, the consecutive failures, the disturbance estimate.
    """

    def __init__(self, model: LinearModelParams, params: LinearMpcParams):
        if params.disturbance_source == "auto":
            raise ValueError("LinearMpc: disturbance_source 'auto' depends on the odometry; "
                             "resolve it first (resolve_disturbance(params, estimator))")
        self._model, self._p = model, params
        self._curve = ThrustCurve(model.thrust_a, model.thrust_b)
        super().__init__(params.period, self._hover_command(0.0, 0.0))
        self._qp = LinearMpcQp(model, params)
        N = params.horizon_steps
        # s, of the predicted states (a column: times a velocity, the positions per step)
        self._step_times = (np.arange(1, N + 1) * params.period)[:, None]
        self._s_y = np.zeros((N, NUM_STATES))  # `_references`' s_y, rewritten every tick
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        self._solution = self.DeclareDiscreteState(np.full(N * NUM_INPUTS, np.nan))
        self._failures = self.DeclareDiscreteState(1)
        # [d_W (3), velocity predicted for this tick in W (3), NaN: none]
        self._disturbance = self.DeclareDiscreteState(np.concatenate([np.zeros(3),
                                                                      np.full(3, np.nan)]))
        self.DeclareStateOutputPort("prediction", self._solution)
        self._groups = tuple(int(group) for group in (self._command, self._solution, self._failures,
                                                      self._disturbance, self._status))
        self.DeclareVectorOutputPort(
            "disturbance", 3, lambda context, out: out.SetFromVector(
                context.get_discrete_state(self._disturbance).get_value()[:3]))

    def _hover_command(self, stamp: float, heading: float) -> np.ndarray:
        thrust = float(self._curve.thrust(self._model.mass * GRAVITY))
        return FC_COMMAND.pack(stamp=stamp, mode=CommandMode.ATTITUDE_THRUST,
                               q_WD=RollPitchYaw(0, 0, heading).ToQuaternion().wxyz(),
                               w_D=np.zeros(3), thrust=thrust, arm=1.0)

    def _to_command(self, u: np.ndarray, stamp: float, heading: float) -> np.ndarray:
        """Attitude from the commanded pitch/roll and the reference heading; thrust with the
        gravity feedforward and tilt compensation through the thrust curve M(32)."""
        pitch, roll, thrust_acceleration = u.tolist()
        force = self._model.mass * (GRAVITY + thrust_acceleration) / (np.cos(pitch) * np.cos(roll))
        # (FC_COMMAND.pack's vector, written out: stamp, mode, q_WD, w_D = 0, thrust, arm)
        return np.array([stamp, _ATTITUDE_THRUST,
                         *RollPitchYaw(roll, pitch, heading).ToQuaternion().wxyz().tolist(),
                         0.0, 0.0, 0.0, self._thrust(float(force)), 1.0])

    def _thrust(self, force: float) -> float:
        """float(self._curve.thrust(force)): on floats where its value is in (0, 1) (math.sqrt
        is the correctly rounded square root, as np.sqrt; no clipping applies), else the curve's
        own (NumPy) clipping, whose signed zeros and NaN this leaves alone."""
        if force > 0.0:
            thrust = self._curve.a_t * math.sqrt(force) + self._curve.b_t
            if 0.0 < thrust < 1.0:
                return thrust
        return float(self._curve.thrust(force))

    def references(self, reference: np.ndarray, yaw: float,
                   d_N: np.ndarray = np.zeros(3)) -> tuple[np.ndarray, np.ndarray]:
        """s_y (N*n) and s_u (N*m) in N, relative to the reference position at t = 0: the
        reference moving on with its velocity and acceleration (constant over the horizon), and
        the inputs that hold that motion against the drag of L(11) and the disturbance d_N."""
        c, s = float(np.cos(yaw)), float(np.sin(yaw))
        return self._references(to_navigation(REFERENCE.get(reference, "v").tolist(), c, s),
                                np.asarray(d_N, float).tolist(), np.zeros(self._s_y.shape),
                                to_navigation(REFERENCE.get(reference, "a").tolist(), c, s))

    def _references(self, v_N: list[float], d_N: list[float], s_y: np.ndarray,
                    a_N: list[float]) -> tuple[np.ndarray, np.ndarray]:
        """`references` of the reference velocity, acceleration and d_N in N (floats), s_y
        written into `s_y` ((N, n), its last two columns zero). The landing paper's reference
        has no acceleration (L Sec. 6.3: a constant velocity over the horizon); a turning
        target's (systems/mission/landing.py) curves it: p + v t + a t^2 / 2."""
        m = self._model
        (d_x, d_y, d_z) = d_N
        if not any(a_N):   # (the constant-velocity reference: one hold for every step)
            (v_x, v_y, v_z) = v_N
            hold = [(m.c_x * v_x - d_x) / GRAVITY, (d_y - m.c_y * v_y) / GRAVITY,
                    m.c_z * v_z - d_z]
            np.multiply(self._step_times, v_N, out=s_y[:, 0:3])
            s_y[:, 3:6] = v_N
            s_y[:, 6:8] = hold[:2]
            return s_y.ravel(), np.array(hold * self._p.horizon_steps)
        t, a = self._step_times, np.array(a_N)
        v = v_N + t * a                                   # (N, 3) the velocity at each step
        s_y[:, 0:3] = t * v_N + 0.5 * t * t * a
        s_y[:, 3:6] = v
        hold = np.column_stack([(m.c_x * v[:, 0] + a[0] - d_x) / GRAVITY,
                                (d_y - m.c_y * v[:, 1] - a[1]) / GRAVITY,
                                m.c_z * v[:, 2] + a[2] - d_z])
        s_y[:, 6:8] = hold[:, :2]
        return s_y.ravel(), hold.ravel()

    def _update_inactive(self, context, discrete_state):
        """Follows the issued command; no failures, no prediction to compare with."""
        super()._update_inactive(context, discrete_state)
        discrete_state.set_value(self._command, self._last.Eval(context))
        discrete_state.set_value(self._failures, [0.0])
        self._forget_prediction(context, discrete_state)

    def _update_active(self, context, discrete_state, estimate) -> None:
        # On the vectors' elements as floats, read once by index: every operation is the one of
        # the NumPy vector code it replaces (element-wise), in the same order; dot products,
        # matrix products and trigonometric functions stay NumPy's.
        now = context.get_time()
        reference = self._reference.Eval(context)
        r = reference.tolist()
        heading = r[_R_HEADING]
        if estimate is None or not all(map(math.isfinite, r)):
            self._fail(context, discrete_state, now, heading, MpcReason.BAD_ESTIMATE, 0)
            return
        e = estimate.tolist()
        # Position and velocity from odometry; attitude and rates from the flight controller's
        # estimate (fresh, 250 Hz), rotated into the odometry frame by the heading difference.
        attitude = self._attitude.Eval(context).tolist()
        q_WB = attitude[_A_Q]
        half = (e[_E_HEADING] - quaternion_heading(*q_WB)) / 2  # (the heading offset's half)
        q_EB = product_floats(float(np.cos(half)), 0.0, 0.0, float(np.sin(half)), *q_WB)
        v_EB = e[_E_V]
        age = self._age(e[_E_STAMP], now)
        p_EB = [p + v * age for p, v in zip(e[_E_P], v_EB)]
        age = self._age(r[_R_STAMP], now)
        p_ref = carrot(p_EB, [p + (v + 0.5 * a * age) * age
                              for p, v, a in zip(r[_R_P], r[_R_V], r[_R_A])],
                       self._p.max_position_error)
        # model_state(p_EB, v_EB, q_EB, w_B, p_ref)
        theta, phi, yaw = euler_angles(*q_EB)
        phi_dot, theta_dot = euler_rates(phi, theta, attitude[_A_W])
        cos_yaw, sin_yaw = float(np.cos(yaw)), float(np.sin(yaw))
        x0 = np.array(to_navigation([p - q for p, q in zip(p_EB, p_ref)], cos_yaw, sin_yaw)
                      + to_navigation(v_EB, cos_yaw, sin_yaw) + [theta, phi, theta_dot, phi_dot])
        # (state groups by plain int: pydrake converts a DiscreteStateIndex on every call)
        command, solution_group, failures, disturbance, status = self._groups
        previous = context.get_discrete_state().get_value(solution_group)[:NUM_INPUTS]
        if self._p.disturbance_source == "acceleration" and self._p.disturbance_gain > 0:
            d_W = self._measure_disturbance(context, e[_E_A], v_EB, theta, phi, cos_yaw, sin_yaw)
        else:
            d_W = self._estimate_disturbance(context, v_EB)
        d_N = to_navigation(d_W, cos_yaw, sin_yaw)
        d_N_vector = np.array(d_N)
        v_N = to_navigation(r[_R_V], cos_yaw, sin_yaw)
        a_N = to_navigation(r[_R_A], cos_yaw, sin_yaw)
        s_y, s_u = self._references(v_N, d_N, self._s_y, a_N)
        if self._p.reference_authority:
            self._qp.about(s_y, s_u, self._p.speed_margin)
        self._qp.update(x0, s_y, s_u,
                        previous if all(map(math.isfinite, previous.tolist())) else None,
                        d_N_vector)
        result = self._qp.solve()
        solver_status = result.status
        if not result.ok:
            self._fail(context, discrete_state, now, heading, MpcReason.FALLBACK, solver_status)
            return
        solution = result.x[self._qp._u_index]
        u_0 = solution[:NUM_INPUTS]
        v_next_N = (self._qp.Ad @ x0 + self._qp.Bd @ u_0 + self._qp.Ed @ d_N_vector)[3:6]
        discrete_state.set_value(disturbance, np.array(d_W + to_navigation(
            v_next_N.tolist(), float(np.cos(-yaw)), float(np.sin(-yaw)))))
        discrete_state.set_value(command, self._to_command(u_0, now, heading))
        discrete_state.set_value(solution_group, solution)
        discrete_state.set_value(failures, _ZERO)
        discrete_state.set_value(status, np.array([1.0, _OK, float(solver_status)]))

    def _age(self, stamp, now: float) -> float:
        """How long before `now` `stamp` was, clipped to [0, max_prediction]."""
        return min(max(now - float(stamp), 0.0), self._p.max_prediction)

    def _estimate_disturbance(self, context, v_W: list[float]) -> list[float]:
        """d_W moved by `disturbance_gain` of the velocity the model failed to predict over the
        last tick, bounded to `max_disturbance` (no prediction yet, or gain 0: unchanged)."""
        stored = context.get_discrete_state().get_value(self._groups[3]).tolist()
        d_W, v_predicted = stored[:3], stored[3:]
        gain, dt = self._p.disturbance_gain, self._p.period
        if gain <= 0 or not all(map(math.isfinite, v_predicted)):
            return d_W
        # (on floats: the same operations as on 3-vectors, without NumPy's per-call overhead)
        error = [v - v_hat for v, v_hat in zip(v_W, v_predicted)]
        error[2] = 0.0
        d_W = np.array([d + gain * e / dt for d, e in zip(d_W, error)])
        size = math.sqrt(d_W @ d_W)  # (np.linalg.norm's own formula, without its checks)
        return (d_W * min(1.0, self._p.max_disturbance / size) if size > 0 else d_W).tolist()

    def _measure_disturbance(self, context, a_W: list[float], v_W: list[float], theta: float,
                             phi: float, cos_yaw: float, sin_yaw: float) -> list[float]:
        """d_W moved by `acceleration_gain` toward the measured acceleration less L(11)'s
        horizontal v_dot at the attitude and velocity now, bounded to `max_disturbance`
        (unchanged while a_EB is not finite). What the model's own g theta leaves unexplained
        (a climb's larger thrust, a large tilt's tan) is learned too, as the velocity's
        prediction error learns it: d is what makes L(11) predict the vehicle."""
        d_W = context.get_discrete_state().get_value(self._groups[3]).tolist()[:3]
        if not all(map(math.isfinite, a_W)):
            return d_W
        m = self._model
        (v_x, v_y, _) = to_navigation(v_W, cos_yaw, sin_yaw)
        (a_x, a_y, _) = to_navigation(a_W, cos_yaw, sin_yaw)
        measured = to_navigation([a_x - (GRAVITY * theta - m.c_x * v_x),
                                  a_y - (-GRAVITY * phi - m.c_y * v_y), 0.0], cos_yaw, -sin_yaw)
        gain = self._p.acceleration_gain
        d_W = np.array([d + gain * (z - d) for d, z in zip(d_W, measured)])
        size = math.sqrt(d_W @ d_W)
        return (d_W * min(1.0, self._p.max_disturbance / size) if size > 0 else d_W).tolist()

    def _forget_prediction(self, context, discrete_state):
        """Keeps d_W but drops the velocity prediction that no applied command produced."""
        d_W = context.get_discrete_state(self._disturbance).get_value()[:3]
        discrete_state.set_value(self._disturbance, np.concatenate([d_W, np.full(3, np.nan)]))

    def _fail(self, context, discrete_state, now, heading, reason, solver_status):
        """Previous solution's next input once; then an invalid (but finite) level hover command."""
        failures = context.get_discrete_state(self._failures).get_value()[0]
        self._forget_prediction(context, discrete_state)
        previous = context.get_discrete_state(self._solution).get_value().reshape(-1, NUM_INPUTS)
        if reason == MpcReason.FALLBACK and failures == 0 and np.all(np.isfinite(previous[1])):
            command, valid = self._to_command(previous[1], now, heading), 1.0
        else:
            command, valid = self._hover_command(now, heading), 0.0
            reason = MpcReason.SOLVER_FAILED if reason == MpcReason.FALLBACK else reason
        discrete_state.set_value(self._command, command)
        discrete_state.set_value(self._failures, [failures + 1])
        discrete_state.set_value(self._status, CONTROLLER_STATUS.pack(
            valid=valid, reason=reason, solver_status=solver_status))
