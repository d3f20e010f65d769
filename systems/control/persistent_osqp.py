"""A MathematicalProgram QP solved by one persistent, warm-started OSQP workspace.

Drake's OsqpSolver sets OSQP up from scratch on every Solve (factorization included) and starts
cold. A receding-horizon controller solves the same program every tick with new linear cost and
bound data only (L(27)), so this keeps one `osqp` workspace: it is set up once from the program's
bindings, and each `solve()` re-reads only the program's linear cost terms and constraint bounds,
hands them to OSQP's `update` and solves from the previous primal-dual solution. The program stays
the single description of the QP (quadratic and linear costs, linear and bounding-box
constraints); its Hessian and constraint matrices must not change after construction.
"""
import dataclasses as dc

import numpy as np
import osqp
from pydrake.solvers import MathematicalProgram
from scipy import sparse

SOLVED = (1, 2)  # OSQP status values: solved, solved inaccurate
INFINITY = osqp.constant("OSQP_INFTY")


@dc.dataclass
class QpResult:
    ok: bool
    x: np.ndarray            # all decision variables, in the program's order
    status: int              # OSQP status value
    iterations: int


class PersistentOsqp:
    """`PersistentOsqp(prog, eps=..., max_iter=...)`; `solve()` after updating the bindings."""

    def __init__(self, prog: MathematicalProgram, eps: float = 1e-4, max_iter: int = 4000,
                 polishing: bool = False):
        self.prog = prog
        costs = len(prog.quadratic_costs()) + len(prog.linear_costs())
        if len(prog.GetAllConstraints()) != len(self._constraints()) \
                or len(prog.GetAllCosts()) != costs:
            raise ValueError("PersistentOsqp solves QPs only: quadratic/linear costs with linear "
                             "and bounding-box constraints")
        n = prog.num_vars()
        # Bindings and their variable indices, looked up once (the lookup dominates otherwise).
        self._quadratic = [(b, self._index(b)) for b in prog.quadratic_costs()]
        self._linear = [(b, self._index(b)) for b in prog.linear_costs()]
        P = np.zeros((n, n))
        for binding, index in self._quadratic:
            P[np.ix_(index, index)] += binding.evaluator().Q()
        self._bound_bindings = self._constraints()
        rows = [self._rows(binding) for binding in self._bound_bindings]
        A = np.vstack(rows) if rows else np.zeros((0, n))
        lower, upper = self._bounds()
        self.solver = osqp.OSQP()
        self.solver.setup(P=sparse.triu(sparse.csc_matrix(P), format="csc"), q=self._q(),
                          A=sparse.csc_matrix(A), l=lower, u=upper, eps_abs=eps, eps_rel=eps,
                          max_iter=max_iter, polishing=polishing, warm_starting=True,
                          verbose=False)

    def _index(self, binding) -> list[int]:
        return self.prog.FindDecisionVariableIndices(binding.variables())

    def _constraints(self):
        return list(self.prog.linear_constraints()) + \
            list(self.prog.linear_equality_constraints()) + \
            list(self.prog.bounding_box_constraints())

    def _rows(self, binding) -> np.ndarray:
        evaluator = binding.evaluator()
        dense = evaluator.GetDenseA() if hasattr(evaluator, "GetDenseA") \
            else np.eye(evaluator.num_constraints())
        rows = np.zeros((evaluator.num_constraints(), self.prog.num_vars()))
        rows[:, self._index(binding)] = dense
        return rows

    def _q(self) -> np.ndarray:
        q = np.zeros(self.prog.num_vars())
        for binding, index in self._quadratic:
            q[index] += binding.evaluator().b()
        for binding, index in self._linear:
            q[index] += binding.evaluator().a()
        return q

    def _bounds(self) -> tuple[np.ndarray, np.ndarray]:
        if not self._bound_bindings:
            return np.zeros(0), np.zeros(0)
        evaluators = [b.evaluator() for b in self._bound_bindings]
        lower = np.concatenate([e.lower_bound() for e in evaluators])
        upper = np.concatenate([e.upper_bound() for e in evaluators])
        return np.maximum(lower, -INFINITY), np.minimum(upper, INFINITY)

    def solve(self) -> QpResult:
        """Solves with the program's current linear cost terms and bounds, warm-started."""
        lower, upper = self._bounds()
        self.solver.update(q=self._q(), l=lower, u=upper)
        result = self.solver.solve(raise_error=False)  # the status says what failed
        status = int(result.info.status_val)
        x = np.asarray(result.x, float)
        ok = status in SOLVED and x.shape == (self.prog.num_vars(),) and np.all(np.isfinite(x))
        return QpResult(ok, x, status, int(result.info.iter))
