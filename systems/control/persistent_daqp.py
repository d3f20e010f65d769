"""A MathematicalProgram QP solved by one persistent, warm-started DAQP workspace (option).

DAQP (Arnström, Bemporad, Axehill 2022) is a dual active-set solver for small dense QPs: it
solves to the exact optimum of its active set, and warm-started from the previous tick's active
set it needs a few iterations where the active set changes, where ADMM (OSQP) needs hundreds to
thousands (bench/mpc_solve.py). Like persistent_osqp.py, the workspace is set up once from the
program's bindings (program_qp.ProgramQp); each `solve()` hands DAQP the program's current linear
cost terms and bounds. Bounding-box rows become DAQP's simple bounds, equality rows its immutable
constraints.

DAQP needs a positive-definite Hessian. A variable without curvature of its own (an exact-penalty
slack, L(25)) gets `regularization` on its Hessian diagonal: its cost lambda s becomes
lambda s + regularization/2 s^2. The workspace solves once at construction with the program's
data then, so that the first tick starts from an active set with the slacks at their bounds
(from scratch, DAQP adds them one by one: 7 N + 1 iterations at horizon N). A solve that does not
reach an optimum (iteration limit, cycling) is reported, never used.
"""
import daqp
import numpy as np
from pydrake.solvers import MathematicalProgram

from alight.systems.control.program_qp import ProgramQp, QpResult

OPTIMAL = 1       # DAQP exit flag of an optimal solution
BIG = 1e30        # DAQP's bound for "none"
ACTIVE, IMMUTABLE = 1, 4  # DAQP constraint sense bits: an equality is both


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
        H = self.qp.P.copy()
        flat = np.all(H == 0.0, axis=1)  # variables without curvature of their own
        H[flat, flat] = regularization
        self._general = self.qp.box_variable < 0
        self._box_rows = np.flatnonzero(~self._general)
        self._general_rows = np.flatnonzero(self._general)
        self._box_variables = self.qp.box_variable[self._box_rows]
        self._boxes_overlap = len(np.unique(self._box_variables)) < len(self._box_variables)
        lower, upper = self._bounds()
        sense = np.zeros(len(upper), np.int32)
        sense[n:][lower[n:] == upper[n:]] = ACTIVE | IMMUTABLE
        self.solver = daqp.Model()
        self.solver.settings = {"iter_limit": iter_limit, "eps_prox": 0.0}
        flag, _ = self.solver.setup(H, self.qp.q(), np.ascontiguousarray(self.qp.A[self._general]),
                                    upper, lower, sense)
        if flag < 0:
            raise ValueError(f"DAQP setup failed (exit flag {flag}): the Hessian with "
                             f"regularization {regularization} is not positive definite")
        self.solver.solve()  # the initial active set (see the module docstring)

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """DAQP's bounds: the simple bounds of every variable, then the general rows."""
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

    def solve(self) -> QpResult:
        """Solves with the program's current linear cost terms and bounds, from the previous
        tick's active set."""
        lower, upper = self._bounds()
        self.solver.update(f=self.qp.q(), bupper=upper, blower=lower)
        x, _, flag, info = self.solver.solve()
        x = np.asarray(x, float)
        ok = flag == OPTIMAL and x.shape == (self.qp.num_vars,) and bool(np.all(np.isfinite(x)))
        return QpResult(ok, x, int(flag), int(info["iterations"]))
