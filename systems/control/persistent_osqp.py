"""A MathematicalProgram QP solved by one persistent, warm-started OSQP workspace.

Drake's OsqpSolver sets OSQP up from scratch on every Solve (factorization included) and starts
cold. A receding-horizon controller solves the same program every tick with new linear cost and
bound data only (L(27)), so this keeps one `osqp` workspace: it is set up once from the program's
bindings (program_qp.ProgramQp), and each `solve()` re-reads only the program's linear cost terms
and constraint bounds, hands them to OSQP's `update` and solves from the previous primal-dual
solution. The program stays the single description of the QP (quadratic and linear costs, linear
and bounding-box constraints); its Hessian and constraint matrices must not change after
construction. A caller that changes only some bindings between solves names them (`changing`):
only these are re-read, and OSQP is handed only what they hold (q for costs, l and u for
constraints).

Per tick the workspace is driven through the osqp extension's solver object itself (its
`update_data_vec`, `solve`, `info`, `solution`), the calls the `osqp.OSQP` wrapper makes, without
the wrapper's per-call bookkeeping (a settings-constant lookup per bound vector, a namespace of all
info fields, the derivative cache): at N = 2 that bookkeeping cost as much as OSQP's solve.
"""
import numpy as np
import osqp
from pydrake.solvers import MathematicalProgram
from scipy import sparse

from alight.systems.control.program_qp import ProgramQp, QpResult

SOLVED = (1, 2)  # OSQP status values: solved, solved inaccurate
INFINITY = osqp.constant("OSQP_INFTY")

__all__ = ["PersistentOsqp", "QpResult", "SOLVED"]


class PersistentOsqp:
    """`PersistentOsqp(prog, eps=..., max_iter=..., changing=...)`; `solve()` after updating the
    bindings (those in `changing` only, when given: the others are read once, here)."""

    def __init__(self, prog: MathematicalProgram, eps: float = 1e-4, max_iter: int = 4000,
                 polishing: bool = False, changing=None):
        self.prog = prog
        self.qp = ProgramQp(prog)
        self._changing = self.qp.positions(changing)
        lower, upper = self._clip(self.qp.lower, self.qp.upper)
        self.solver = osqp.OSQP()
        self.solver.setup(P=sparse.triu(sparse.csc_matrix(self.qp.P), format="csc"),
                          q=self.qp.linear, A=sparse.csc_matrix(self.qp.A), l=lower, u=upper,
                          eps_abs=eps, eps_rel=eps, max_iter=max_iter, polishing=polishing,
                          warm_starting=True, verbose=False)
        # The extension's solver object (what osqp.OSQP.update/solve call); None: use the wrapper
        self._workspace = getattr(self.solver, "_solver", None)
        if self._workspace is not None and not all(
                hasattr(self._workspace, name)
                for name in ("update_data_vec", "solve", "info", "solution")):
            self._workspace = None
        self.iterations = 0  # of the last solve

    @staticmethod
    def _clip(lower: np.ndarray, upper: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The bounds, in place, within OSQP's infinity."""
        return np.maximum(lower, -INFINITY, out=lower), np.minimum(upper, INFINITY, out=upper)

    def _data(self) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray | None]:
        """q, l and u re-read from the changing bindings (None: none of them holds it), the
        bounds clipped as read (the other rows were clipped once, at construction)."""
        costs, bounded = self._changing
        qp = self.qp
        qp.refresh(costs, bounded, INFINITY)
        return (qp.linear if costs else None,) + ((qp.lower, qp.upper) if bounded else (None, None))

    def solve(self) -> QpResult:
        """Solves with the program's current linear cost terms and bounds, warm-started."""
        q, lower, upper = self._data()
        workspace = self._workspace
        if workspace is None:
            self.solver.update(q=q, l=lower, u=upper)
            result = self.solver.solve(raise_error=False)  # the status says what failed
            status, iterations = int(result.info.status_val), int(result.info.iter)
            x = np.asarray(result.x, float)
        else:
            workspace.update_data_vec(q=q, l=lower, u=upper)
            workspace.solve()
            info = workspace.info
            status, iterations = int(info.status_val), int(info.iter)
            x = np.asarray(workspace.solution.x, float)  # (a fresh copy per access)
        self.iterations = iterations
        ok = status in SOLVED and x.shape == (self.qp.num_vars,) and bool(np.isfinite(x).all())
        return QpResult(ok, x, status, iterations)
