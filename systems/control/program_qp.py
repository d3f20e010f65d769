"""The data of a QP written as a Drake MathematicalProgram, read from its bindings once.

min 1/2 t'P t + q't  s.t.  l <= A t <= u, with t all decision variables in the program's order.
P and A are read at construction and must not change afterwards (a receding-horizon controller
changes only linear cost terms and bounds per tick, L(27)); `q()` and `bounds()` re-read the
program's current linear cost terms and constraint bounds with one vectorized gather per binding.
`refresh(*positions(changing))` re-reads only the bindings a caller declared as changing into
buffers it keeps (`linear`, `lower`, `upper`): every binding read costs a call into Drake, and
such a controller changes one cost and one constraint of several.
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


def variable_index(prog: MathematicalProgram, variables) -> slice | np.ndarray:
    """The variables' positions among the program's decision variables: a slice where
    contiguous (NumPy indexes a slice without building an index array, which dominated the
    per-tick gather otherwise)."""
    index = np.asarray(prog.FindDecisionVariableIndices(variables), np.intp)
    if len(index) and np.array_equal(index, np.arange(index[0], index[0] + len(index))):
        return slice(int(index[0]), int(index[0]) + len(index))
    return index


class ProgramQp:
    """`ProgramQp(prog)`: `P`, `A` (dense), `box_variable` (per row of A: the variable of a
    bounding-box row, -1 for a general linear row); `q()`, `bounds()` per tick, or
    `refresh(*positions(changing))` and its buffers `linear` (q), `lower`, `upper`."""

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
        quadratic = [(b, self._index(b)) for b in prog.quadratic_costs()]
        linear = [(b, self._index(b)) for b in prog.linear_costs()]
        self.P = np.zeros((n, n))
        for binding, index in quadratic:
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
        # (evaluator, variable index, reader of its linear term), quadratic costs first
        self._costs = [(binding.evaluator(), index, binding.evaluator().b)
                       for binding, index in quadratic] \
            + [(binding.evaluator(), index, binding.evaluator().a) for binding, index in linear]
        self.box_variable = np.concatenate(box_variable).astype(int) if rows \
            else np.zeros(0, int)
        # `refresh`'s buffers: each cost's linear term as last read, their sum q, and l, u; per
        # constrained block its evaluator and its rows of l and u (views); (k, the sum of the
        # terms of the costs before k), k the first cost refreshed (the terms before it are
        # unchanged until a refresh re-reads one of them)
        self._terms = [read() for _, _, read in self._costs]
        self.linear = self._sum(self._terms, np.zeros(n))
        self.lower, self.upper = self.bounds()
        self._bound_rows = [(evaluator, self.lower[rows], self.upper[rows])
                            for evaluator, rows in self._bounded]
        self._prefix: tuple[int, np.ndarray] | None = None

    def _index(self, binding) -> slice | np.ndarray:
        return variable_index(self.prog, binding.variables())

    def _sum(self, terms, out: np.ndarray, start: int = 0) -> np.ndarray:
        """The costs' linear terms summed into `out` (zeroed first), in the costs' order; from
        cost `start` on, on the kept sum of the terms before it (`_terms`, unchanged since)."""
        if start == 0:
            out.fill(0.0)
        else:
            if self._prefix is None or self._prefix[0] != start:
                self._prefix = (start, self._sum(self._terms[:start], np.zeros(self.num_vars)))
            np.copyto(out, self._prefix[1])
        for (_, index, _), term in zip(self._costs[start:], terms[start:]):
            out[index] += term
        return out

    def _read_bounds(self, positions, lower: np.ndarray, upper: np.ndarray) -> None:
        """The bounds of the constraints at `positions` into their rows of `lower`, `upper`."""
        for k in positions:
            evaluator, rows = self._bounded[k]
            lower[rows], upper[rows] = evaluator.lower_bound(), evaluator.upper_bound()

    def q(self) -> np.ndarray:
        """The linear cost term, sum of the quadratic costs' b and the linear costs' a."""
        return self._sum([read() for _, _, read in self._costs], np.zeros(self.num_vars))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """l and u of the rows of A (+-inf where unbounded)."""
        lower, upper = np.empty(len(self.A)), np.empty(len(self.A))
        self._read_bounds(range(len(self._bounded)), lower, upper)
        return lower, upper

    def positions(self, bindings=None) -> tuple[list[int], list[int]]:
        """Where `bindings` (None: all of the program's costs and constraints) are among the
        costs and among the constrained rows' blocks, for `refresh`."""
        if bindings is None:
            return list(range(len(self._costs))), list(range(len(self._bounded)))
        evaluators = [binding.evaluator() for binding in bindings]
        wanted = {id(evaluator) for evaluator in evaluators}
        costs = [k for k, (evaluator, _, _) in enumerate(self._costs) if id(evaluator) in wanted]
        bounded = [k for k, (evaluator, _) in enumerate(self._bounded) if id(evaluator) in wanted]
        found = {id(self._costs[k][0]) for k in costs} \
            | {id(self._bounded[k][0]) for k in bounded}
        if found != wanted:
            raise ValueError("not all of the bindings are costs or constraints of the program")
        return costs, bounded

    def refresh(self, costs: list[int], bounded: list[int], infinity: float | None = None) -> None:
        """Re-reads the linear terms of the costs and the bounds of the constraints at these
        `positions` (ascending) into `linear` (q, summed again) and `lower`, `upper` (their rows,
        within +-`infinity` when given); the other bindings keep the data last read. The buffers
        are overwritten by the next refresh."""
        if costs:
            if self._prefix is not None and costs[0] < self._prefix[0]:
                self._prefix = None  # (a term it summed is re-read)
            for k in costs:
                self._terms[k] = self._costs[k][2]()
            self._sum(self._terms, self.linear, costs[0])
        for k in bounded:
            evaluator, lower, upper = self._bound_rows[k]
            if infinity is None:
                lower[:], upper[:] = evaluator.lower_bound(), evaluator.upper_bound()
            else:
                np.maximum(evaluator.lower_bound(), -infinity, out=lower)
                np.minimum(evaluator.upper_bound(), infinity, out=upper)
