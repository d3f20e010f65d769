"""The QP back ends a controller's MathematicalProgram is solved by, behind one call.

A controller builds its QP once as a Drake `MathematicalProgram` and updates its linear cost terms
and bounds every tick (L(27), M(46)); `make_qp_backend(prog, kind, ...)` returns the object whose
`solve()` solves the program's current data and returns a `QpResult` (all decision variables in
the program's order, the back end's status and iterations):

- "daqp": one warm-started DAQP workspace (persistent_daqp.py: dual active set, exact; the
  exact-penalty slacks become soft constraints),
- "persistent_osqp": one warm-started OSQP workspace (persistent_osqp.py),
- "osqp", "clarabel": Drake's OsqpSolver or ClarabelSolver, set up from scratch at every solve
  (`DrakeQp`; Drake's wrappers do not warm-start).

Each controller keeps its own names for these in its parameter file and maps them here.
"""
import numpy as np
from pydrake.solvers import ClarabelSolver, MathematicalProgram, OsqpSolver, SolverOptions

from alight.systems.control.persistent_daqp import PersistentDaqp
from alight.systems.control.persistent_osqp import PersistentOsqp
from alight.systems.control.program_qp import QpResult

KINDS = ("daqp", "persistent_osqp", "osqp", "clarabel")


class DrakeQp:
    """`solve()` through a Drake solver with fixed options, cold at every call."""

    def __init__(self, prog: MathematicalProgram, solver, options: SolverOptions):
        self.prog, self.solver, self.options = prog, solver, options
        self.iterations = 0  # of the last solve

    def solve(self) -> QpResult:
        result = self.solver.Solve(self.prog, None, self.options)
        x = result.GetSolution(self.prog.decision_variables())
        details = result.get_solver_details()
        # OSQP reports its own status value; Clarabel's is 0 solved, 1 otherwise
        status = int(details.status_val) if hasattr(details, "status_val") \
            else 0 if result.is_success() else 1
        self.iterations = int(getattr(details, "iter", getattr(details, "iterations", -1)))
        return QpResult(result.is_success() and bool(np.isfinite(x).all()), x, status,
                        self.iterations)


def make_qp_backend(prog: MathematicalProgram, kind: str, tolerance: float = 1e-4,
                    max_iter: int = 4000, polishing: bool = False,
                    regularization: float = 1e-3, changing=None):
    """The back end `kind` (KINDS) for `prog`. `tolerance`, `max_iter`, `polishing`: OSQP's
    eps_abs = eps_rel, iteration limit and polishing (Clarabel: its gap and feasibility
    tolerances); `regularization`: DAQP's curvature of variables without any; `changing`: the
    bindings the persistent OSQP workspace re-reads per solve (None: all)."""
    if kind == "daqp":
        return PersistentDaqp(prog, regularization)
    if kind == "persistent_osqp":
        return PersistentOsqp(prog, tolerance, max_iter, polishing=polishing, changing=changing)
    options = SolverOptions()
    if kind == "osqp":
        for key, value in (("eps_abs", tolerance), ("eps_rel", tolerance),
                           ("max_iter", max_iter), ("polishing", int(polishing))):
            options.SetOption(OsqpSolver.id(), key, value)
        return DrakeQp(prog, OsqpSolver(), options)
    if kind == "clarabel":
        for key in ("tol_gap_abs", "tol_gap_rel", "tol_feas"):
            options.SetOption(ClarabelSolver.id(), key, tolerance)
        return DrakeQp(prog, ClarabelSolver(), options)
    raise ValueError(f"unknown QP back end {kind!r} (one of {', '.join(KINDS)})")
