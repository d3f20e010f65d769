"""A MathematicalProgram QP solved by one persistent, warm-started DAQP workspace (option).

DAQP (Arnström, Bemporad, Axehill 2022) is a dual active-set solver for small dense QPs: it
solves to the exact optimum of its active set, and warm-started from the previous tick's active
set it needs a few iterations where the active set changes, where ADMM (OSQP) needs hundreds to
thousands (bench/mpc_solve.py). Like persistent_osqp.py, the workspace is set up once from the
program's bindings (program_qp.ProgramQp); each `solve()` hands DAQP the program's current linear
cost terms and bounds. Bounding-box rows become DAQP's simple bounds, equality rows its immutable
constraints.

Exact-penalty slacks (L(25)-(26)): a variable s >= 0 with a positive linear cost lambda and no
curvature, that appears only as -s in one-sided rows g'x - s <= b (one row, or a +-g pair, which
cannot both be violated while b+ + b- >= 0, checked per tick), is not handed to DAQP: its rows
become DAQP soft constraints with linear weight lambda (and 1/SOFT_RHO = 1e-6 curvature, which
DAQP needs), and s = max(0, g'x - b) is recovered. That leaves DAQP the inputs alone (3 N
variables instead of 10 N at horizon N) and none of the slacks' bounds in its active set. A
program with other variables without curvature keeps them, with `regularization` on their
Hessian diagonal (DAQP needs a positive-definite Hessian), and is primed by one solve at
construction (from scratch DAQP adds such slacks' bounds one by one).
A solve that does not reach an optimum (iteration limit, cycling) is reported, never used.
"""
import daqp
import numpy as np
from pydrake.solvers import MathematicalProgram

from alight.systems.control.program_qp import ProgramQp, QpResult

OPTIMAL, SOFT_OPTIMAL = 1, 2  # DAQP exit flags: optimal, optimal with soft constraints violated
PAIR_VIOLATED = -100          # our status: a shared slack's rows could both be violated
NOT_A_PENALTY = -101          # our status: an eliminated slack's cost is no longer positive
BIG = 1e30                    # DAQP's bound for "none"
ACTIVE, IMMUTABLE, SOFT = 1, 4, 8  # DAQP constraint sense bits (an equality: active, immutable)
SOFT_RHO = 1e6                # DAQP's reciprocal quadratic weight of a soft constraint's slack


class PersistentDaqp:
    """`PersistentDaqp(prog, regularization=..., iter_limit=...)`; `solve()` after updating the
    bindings."""

    def __init__(self, prog: MathematicalProgram, regularization: float = 1e-3,
                 iter_limit: int = 1000):
        if regularization <= 0:
            raise ValueError(f"regularization must be > 0 (got {regularization})")
        self.prog = prog
        self.qp = ProgramQp(prog)
        n = self.qp.num_vars
        general = self.qp.box_variable < 0
        self._box_rows = np.flatnonzero(~general)
        self._general_rows = np.flatnonzero(general)
        self._box_variables = self.qp.box_variable[self._box_rows]
        self._boxes_overlap = len(np.unique(self._box_variables)) < len(self._box_variables)
        flat = np.all(self.qp.P == 0.0, axis=1)  # variables without curvature of their own
        lower, upper = self._all_bounds()
        slack_rows = self._penalty_slacks(flat, lower, upper)
        self._slack = np.zeros(n, bool)
        self._slack[list(slack_rows)] = True
        self._keep = np.flatnonzero(~self._slack)
        self._slack_index = np.flatnonzero(self._slack)
        # DAQP's bounds: the kept variables' simple bounds, then the general rows'
        self._daqp_index = np.concatenate([self._keep, n + np.arange(len(self._general_rows))])
        G = self.qp.A[self._general_rows]
        row_slack = np.full(len(G), -1)
        for slack, rows in slack_rows.items():
            row_slack[rows] = slack
        self._soft = np.flatnonzero(row_slack >= 0)         # general rows that become soft
        self._soft_slack = row_slack[self._soft]
        # per eliminated slack: its variable and its (first, last) row among the soft rows
        position = {row: k for k, row in enumerate(self._soft)}
        self._slack_variables = np.array(list(slack_rows), int)
        self._slack_first = np.array([position[rows[0]] for rows in slack_rows.values()], int)
        self._slack_last = np.array([position[rows[-1]] for rows in slack_rows.values()], int)
        paired = self._slack_first != self._slack_last
        self._pair_rows = (self._soft[self._slack_first[paired]],
                           self._soft[self._slack_last[paired]])
        self._G_soft = G[np.ix_(self._soft, self._keep)]
        H = self.qp.P[np.ix_(self._keep, self._keep)].copy()
        H[flat[self._keep], flat[self._keep]] = regularization
        sense = np.zeros(len(self._keep) + len(G), np.int32)
        sense[len(self._keep):][lower[n:] == upper[n:]] = ACTIVE | IMMUTABLE
        sense[len(self._keep) + self._soft] = SOFT
        self.solver = daqp.Model()
        self.solver.settings = {"iter_limit": iter_limit, "eps_prox": 0.0}
        q = self.qp.q()
        flag, _ = self.solver.setup(H, q[self._keep], np.ascontiguousarray(G[:, self._keep]),
                                    *self._daqp_bounds(lower, upper), sense)
        if flag < 0:
            raise ValueError(f"DAQP setup failed (exit flag {flag}): the Hessian with "
                             f"regularization {regularization} is not positive definite")
        self._weights = None
        self._set_soft_weights(q)
        self.solver.solve()  # the initial active set (see the module docstring)

    def _penalty_slacks(self, flat, lower, upper) -> dict[int, list[int]]:
        """{slack variable: its general rows} of the exact-penalty slacks (module docstring)."""
        n, q = self.qp.num_vars, self.qp.q()
        G = self.qp.A[self._general_rows]
        row_lower = lower[n:]
        slacks = {}
        for j in np.flatnonzero(flat & (q > 0) & (lower[:n] == 0.0) & (upper[:n] >= BIG)):
            column = G[:, j]
            rows = np.flatnonzero(column).tolist()
            if not rows or np.any(column[rows] != -1.0) or np.any(row_lower[rows] > -BIG) \
                    or np.any(np.count_nonzero(G[rows][:, flat], axis=1) != 1) \
                    or np.any(self.qp.P[:, j] != 0.0) or len(rows) > 2:
                continue
            if len(rows) == 2:
                others = ~flat
                if not np.array_equal(G[rows[0], others], -G[rows[1], others]):
                    continue
            slacks[int(j)] = rows
        return slacks

    def _set_soft_weights(self, q: np.ndarray) -> None:
        """The soft rows' linear weights from their slacks' costs (when these changed)."""
        weights = q[self._slack_index]
        if self._weights is not None and np.array_equal(weights, self._weights):
            return
        self._weights = weights
        w = np.zeros(len(self._keep) + len(self._general_rows))
        w[len(self._keep) + self._soft] = q[self._soft_slack]
        rho = np.full(len(w), SOFT_RHO)
        self.solver.soft_weights(rho_l=rho, rho_u=rho, w_l=w, w_u=w)

    def _all_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The simple bounds of every variable, then the general rows' (clipped to +-BIG)."""
        lower_rows, upper_rows = self.qp.bounds()
        n = self.qp.num_vars
        m = n + len(self._general_rows)
        lower, upper = np.full(m, -BIG), np.full(m, BIG)
        if self._boxes_overlap:  # a variable in several bounding boxes: their intersection
            np.maximum.at(lower, self._box_variables, lower_rows[self._box_rows])
            np.minimum.at(upper, self._box_variables, upper_rows[self._box_rows])
        else:
            lower[self._box_variables] = lower_rows[self._box_rows]
            upper[self._box_variables] = upper_rows[self._box_rows]
        lower[n:], upper[n:] = lower_rows[self._general_rows], upper_rows[self._general_rows]
        return np.maximum(lower, -BIG, out=lower), np.minimum(upper, BIG, out=upper)

    def _daqp_bounds(self, lower, upper) -> tuple[np.ndarray, np.ndarray]:
        """DAQP's: the kept variables' simple bounds, then the general rows'."""
        return upper[self._daqp_index], lower[self._daqp_index]

    def solve(self) -> QpResult:
        """Solves with the program's current linear cost terms and bounds, from the previous
        tick's active set."""
        lower, upper = self._all_bounds()
        n = self.qp.num_vars
        row_upper = upper[n:]
        if len(self._pair_rows[0]) and \
                (row_upper[self._pair_rows[0]] + row_upper[self._pair_rows[1]]).min() < 0.0:
            return QpResult(False, np.full(n, np.nan), PAIR_VIOLATED, 0)
        q = self.qp.q()
        if len(self._slack_index) and q[self._slack_index].min() <= 0.0:
            return QpResult(False, np.full(n, np.nan), NOT_A_PENALTY, 0)
        self._set_soft_weights(q)
        upper_daqp, lower_daqp = self._daqp_bounds(lower, upper)
        self.solver.update(f=q[self._keep], bupper=upper_daqp, blower=lower_daqp)
        kept, _, flag, info = self.solver.solve()
        x = np.zeros(n)
        x[self._keep] = kept
        if len(self._soft):  # s = max(0, g'x - b) over the slack's rows
            violation = self._G_soft @ kept - row_upper[self._soft]
            x[self._slack_variables] = np.maximum(
                np.maximum(violation[self._slack_first], violation[self._slack_last]), 0.0)
        ok = flag in (OPTIMAL, SOFT_OPTIMAL) and bool(np.all(np.isfinite(x)))
        return QpResult(ok, x, int(flag), int(info["iterations"]))
