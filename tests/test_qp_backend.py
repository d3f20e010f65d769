"""Every QP back end solves the same MathematicalProgram to the same optimum; a bad name is refused."""
import numpy as np
import pytest
from pydrake.solvers import MathematicalProgram

from alight.systems.control.qp_backend import KINDS, make_qp_backend


def penalty_program():
    """min (u - 3)^2 + 10 s  s.t.  u - s <= 1, s >= 0, -5 <= u <= 5 (an exact L1 penalty, as
    L(25)): the penalty outweighs the pull, so u = 1, s = 0; with the bound moved to -1 the
    constraint still binds."""
    prog = MathematicalProgram()
    u, s = prog.NewContinuousVariables(1, "u"), prog.NewContinuousVariables(1, "s")
    prog.AddQuadraticCost([[2.0]], [-6.0], u, is_convex=True)
    prog.AddLinearCost([10.0], 0.0, s)
    soft = prog.AddLinearConstraint(np.array([[1.0, -1.0]]), [-np.inf], [1.0], [u[0], s[0]])
    prog.AddBoundingBoxConstraint(-5.0, 5.0, u)
    prog.AddBoundingBoxConstraint(0.0, np.inf, s)
    return prog, soft


@pytest.mark.parametrize("kind", KINDS)
def test_each_back_end_reaches_the_exact_penalty_optimum_tick_after_tick(kind):
    prog, soft = penalty_program()
    backend = make_qp_backend(prog, kind, tolerance=1e-7, max_iter=20000, polishing=True)
    for bound, expected in ((1.0, 1.0), (-1.0, -1.0), (4.0, 3.0)):
        soft.evaluator().UpdateUpperBound([bound])
        result = backend.solve()
        assert result.ok, (kind, result.status)
        assert result.x == pytest.approx([expected, 0.0], abs=1e-4), kind


def test_an_unknown_back_end_is_refused_with_the_known_ones_named():
    prog, _ = penalty_program()
    with pytest.raises(ValueError, match="unknown QP back end 'gurobi'.*daqp.*clarabel"):
        make_qp_backend(prog, "gurobi")
