"""The data of a QP written as a Drake MathematicalProgram, read from its bindings once.

min 1/2 t'P t + q't  s.t.  l <= A t <= u, with t all decision variables in the program's order.
P and A are read at construction and must not change afterwards (a receding-horizon controller
changes only linear cost terms and bounds per tick, L(27)); `q()` and `bounds()` re-read the
program's current linear cost terms and constraint bounds with one vectorized gather per binding.
The persistent QP back ends (persistent_osqp.py, persistent_daqp.py) set their workspaces up from
this and hand it the new vectors each tick.
"""
import dataclasses as dc

import numpy as np
from pydrake.solvers import MathematicalProgram


@dc.dataclass
class QpResult:
    ok: bool
    x: np.ndarray            # all decision variables, in the program's order
    status: int              # the back end's status value
    iterations: int


class ProgramQp:
    """`ProgramQp(prog)`: `P`, `A` (dense), `box_variable` (per row of A: the variable of a
    bounding-box row, -1 for a general linear row); `q()`, `bounds()` per tick."""

    def __init__(self, prog: MathematicalProgram):
        self.prog = prog
        self._constraints = list(prog.linear_constraints()) \
            + list(prog.linear_equality_constraints()) + list(prog.bounding_box_constraints())
        costs = len(prog.quadratic_costs()) + len(prog.linear_costs())
        if len(prog.GetAllConstraints()) != len(self._constraints) \
                or len(prog.GetAllCosts()) != costs:
            raise ValueError("a persistent QP back end solves QPs only: quadratic/linear costs "
                             "with linear and bounding-box constraints")
        n = self.num_vars = prog.num_vars()
        # Bindings and their variable indices, looked up once (the lookup dominates otherwise).
        self._quadratic = [(b, self._index(b)) for b in prog.quadratic_costs()]
        self._linear = [(b, self._index(b)) for b in prog.linear_costs()]
        self.P = np.zeros((n, n))
        for binding, index in self._quadratic:
            rows = np.arange(n)[index]
            self.P[np.ix_(rows, rows)] += binding.evaluator().Q()
        rows, box_variable = [], []
        num_general = len(self._constraints) - len(prog.bounding_box_constraints())
        for k, binding in enumerate(self._constraints):
            index = self._index(binding)
            evaluator = binding.evaluator()
            is_box = k >= num_general  # (a BoundingBoxConstraint is a LinearConstraint too)
            variables = np.arange(n)[index]
            dense = np.eye(len(variables)) if is_box else evaluator.GetDenseA()
            block = np.zeros((evaluator.num_constraints(), n))
            block[:, variables] = dense
            rows.append(block)
            box_variable.append(variables if is_box else np.full(len(dense), -1))
        self.A = np.vstack(rows) if rows else np.zeros((0, n))
        ends = np.cumsum([len(block) for block in rows]).tolist()
        # (evaluator, rows of A): an evaluator is updated in place, so it is looked up once
        self._bounded = [(binding.evaluator(), slice(end - len(block), end))
                         for binding, end, block in zip(self._constraints, ends, rows)]
        self._quadratic = [(binding.evaluator(), index) for binding, index in self._quadratic]
        self._linear = [(binding.evaluator(), index) for binding, index in self._linear]
        self.box_variable = np.concatenate(box_variable).astype(int) if rows \
            else np.zeros(0, int)

    def _index(self, binding) -> slice | np.ndarray:
        """The binding's variables' positions: a slice where contiguous (NumPy indexes a slice
        without building an index array, which dominated the per-tick gather otherwise)."""
        index = np.asarray(self.prog.FindDecisionVariableIndices(binding.variables()), np.intp)
        if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
            return slice(int(index[0]), int(index[0]) + len(index))
        return index

    def q(self) -> np.ndarray:
        """The linear cost term, sum of the quadratic costs' b and the linear costs' a."""
        q = np.zeros(self.num_vars)
        for evaluator, index in self._quadratic:
            q[index] += evaluator.b()
        for evaluator, index in self._linear:
            q[index] += evaluator.a()
        return q

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """l and u of the rows of A (+-inf where unbounded)."""
        lower, upper = np.empty(len(self.A)), np.empty(len(self.A))
        for evaluator, rows in self._bounded:
            lower[rows], upper[rows] = evaluator.lower_bound(), evaluator.upper_bound()
        return lower, upper
