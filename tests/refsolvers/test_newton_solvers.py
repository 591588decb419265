"""Newton with every linear solver: the same iterates and converged state as the direct
solver (exact solvers to round-off, AMG-CG to its forcing term), on both backends."""
import numpy as np
import pytest

from tissuebench.cases.bar import bar_tension
from tissuebench.refsolvers import make_backend
from tissuebench.refsolvers.newton import NewtonOptions, newton_solve

BACKENDS = ["skfem", pytest.param("ngsolve", marks=pytest.mark.ngsolve)]
SOLVERS = ["direct", "cholesky", "amg-cg", "pardiso"]


@pytest.fixture(scope="module", params=BACKENDS)
def runs(request):
    """The ci bar pulled to 30 % in 3 increments with each linear solver."""
    case = bar_tension("ci")
    be = make_backend(request.param, case.problem)
    return {s: newton_solve(be, 1.0, n_increments=3, linear_solver=s) for s in SOLVERS}


@pytest.mark.parametrize("solver", SOLVERS)
def test_same_newton_iterations_and_converged_state(runs, solver):
    ref, run = runs["direct"], runs[solver]
    assert ref.success and run.success
    assert [i.iterations for i in run.increments] == [i.iterations for i in ref.increments]
    # Newton stops at |r| <= 1e-9 f_ref: two converged states differ by far less than 1e-8
    assert np.linalg.norm(run.u - ref.u) <= 1e-8 * np.linalg.norm(ref.u)
    table = run.table()
    assert (table["factor_s"] <= table["solve_s"]).all() and (table["residual_s"] > 0).all()


def test_exact_solvers_give_the_same_iterates(runs):
    """Residual histories of SuperLU, NGSolve Cholesky and PARDISO agree to 1e-6 relative for every
    iterate above 1e-6 of the largest (below, round-off of the residual dominates)."""
    pairs = [*zip(runs["cholesky"].increments, runs["direct"].increments),
             *zip(runs["pardiso"].increments, runs["direct"].increments)]
    for a, b in pairs:
        ra, rb = np.array(a.residual_norms), np.array(b.residual_norms)
        big = rb > 1e-6 * rb.max()
        np.testing.assert_allclose(ra[big], rb[big], rtol=1e-6)


def test_amg_iterates_follow_the_direct_ones(runs):
    """Inexact Newton (linear solves to the forcing term, <= 1e-4): the first two iterates of
    every increment within 1 % of exact Newton's residuals; later ones are governed by the
    forcing term (soft-mode errors the residual criterion admits), not compared."""
    for a, b in zip(runs["amg-cg"].increments, runs["direct"].increments):
        ra, rb = np.array(a.residual_norms[1:3]), np.array(b.residual_norms[1:3])
        np.testing.assert_allclose(ra, rb, rtol=1e-2)
    assert sum(i.linear_iterations for i in runs["amg-cg"].increments) > len(runs["amg-cg"].increments)


def test_forcing_max_is_validated():
    for bad in (0.0, 1.0, -1e-3, "1e-3"):
        with pytest.raises(ValueError, match="forcing_max"):
            NewtonOptions(forcing_max=bad)
