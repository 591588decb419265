"""CG preconditioned by kept factors (kept_factors.py), solve_again of the direct solvers, and the
statics' "auto" taking it from KEPT_FACTORS_MIN_DOFS unknowns on."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.cases.bar import bar_tension
from tissuebench.refsolvers import make_backend
from tissuebench.refsolvers import linear_solvers
from tissuebench.refsolvers.linear_solvers import (AmgCgSolver, AutoDirectSolver, DirectSolver, KeptFactorSolver,
                                                   LinearSolverError, NgsolveSparseSolver)
from tissuebench.refsolvers.newton import newton_solve


def _laplacian(n, shift=4.0):
    return sp.diags([-np.ones(n - 1), shift * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()


def _relres(K, x, b):
    return np.linalg.norm(K @ x - b) / np.linalg.norm(b)


@pytest.mark.parametrize("make", [DirectSolver, lambda: NgsolveSparseSolver(taskmanager=False), AutoDirectSolver])
def test_solve_again_applies_the_last_factors_and_refuses_before_any(make):
    solver = make()
    with pytest.raises(LinearSolverError, match="no factors|solve first"):
        solver.solve_again(np.ones(1200))
    K1, K2 = _laplacian(1200), _laplacian(1200, 5.0)
    b = np.random.default_rng(0).standard_normal(1200)
    solver.solve(K1, b)
    solver.solve(K2, b)
    x = solver.solve_again(b)  # K2's factors, the last solved
    assert _relres(K2, x, b) <= 1e-13 and _relres(K1, x, b) > 1e-3


def test_amg_keeps_no_factors_and_cannot_be_kept():
    with pytest.raises(LinearSolverError, match="keeps no factors"):
        AmgCgSolver().solve_again(np.ones(3))
    with pytest.raises(TypeError, match="keeps no factors"):
        KeptFactorSolver(AmgCgSolver())


@pytest.mark.parametrize("kw", [{"max_iterations": 0}, {"max_iterations": 2.5}, {"refactor_share": 0.0}])
def test_kept_factor_solver_bad_options(kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        KeptFactorSolver(DirectSolver(), **kw)


@pytest.fixture(scope="module")
def tangents():
    """The ci bar's free tangents at two stretches: close, not equal (a Newton's successive ones)."""
    pb = bar_tension("ci").problem
    be = make_backend("skfem", pb)
    out = []
    for stretch in (0.10, 0.12):
        u = np.zeros(pb.ndof)
        u[0::3] = stretch * pb.nodes[:, 0]
        out.append(be.tangent(u)[pb.free_dofs][:, pb.free_dofs].tocsr())
    return out


def test_the_second_system_is_solved_by_cg_with_the_first_factors_to_its_tolerance(tangents):
    K1, K2 = tangents
    b = np.random.default_rng(1).standard_normal(K1.shape[0])
    solver = KeptFactorSolver(DirectSolver(), refactor_share=1e9)
    x1, info1 = solver.solve(K1, b, rtol=1e-6)
    assert info1["factorised"] == "no kept factors" and _relres(K1, x1, b) <= 1e-12  # factorised: exact
    x2, info2 = solver.solve(K2, b, rtol=1e-6)
    assert info2["solver"] == "kept-factor-cg" and info2["factor_s"] == 0.0
    assert 1 <= info2["iterations"] <= 10  # close tangents: the kept factors precondition well
    assert 1e-12 < _relres(K2, x2, b) <= 1e-6  # to the forcing term, not beyond
    assert solver.counts["factorisations"] == 1 and solver.counts["cg_solves"] == 1


def test_a_cg_that_does_not_reach_the_tolerance_factorises_afresh(tangents):
    K1, _ = tangents
    b = np.random.default_rng(2).standard_normal(K1.shape[0])
    far = (K1 + sp.diags(np.linspace(0, 5, K1.shape[0]) * abs(K1.diagonal()).max())).tocsr()
    solver = KeptFactorSolver(DirectSolver(), max_iterations=1, refactor_share=1e9)
    solver.solve(K1, b)
    x, info = solver.solve(far, b, rtol=1e-10)
    assert info["factorised"].startswith("CG with kept factors") and info["cg_iterations"] == 1
    assert _relres(far, x, b) <= 1e-12 and solver.counts["cg_failures"] == 1
    assert solver.counts["factorisations"] == 2


@pytest.mark.parametrize("share, factorised", [(1e-12, True), (1e12, False)])
def test_a_cg_dearer_than_its_share_of_a_factorisation_refreshes_the_factors(tangents, share, factorised):
    """Both sides of the rule: a CG solve that cost more than ``refactor_share`` of the last
    factorisation makes the next call factorise; a cheaper one keeps the factors."""
    K1, K2 = tangents
    b = np.ones(K1.shape[0])
    solver = KeptFactorSolver(DirectSolver(), refactor_share=share)
    solver.solve(K1, b)
    solver.solve(K2, b, rtol=1e-6)
    _, info = solver.solve(K2, b, rtol=1e-6)
    assert ("factorised" in info) is factorised


def test_auto_takes_the_kept_factors_from_its_threshold_and_newton_reaches_the_same_state(monkeypatch):
    """Newton on the ci bar with "auto" above the (lowered) threshold: CG with kept factors at
    Newton's forcing term, and the converged state that of the direct solves to the tolerance."""
    bar = bar_tension("ci")
    be = make_backend("skfem", bar.problem)
    direct = newton_solve(be, 0.3, n_increments=3, linear_solver="cholesky")
    monkeypatch.setattr(linear_solvers, "KEPT_FACTORS_MIN_DOFS", 10)
    auto = AutoDirectSolver()
    monkeypatch.setattr(type(be), "make_linear_solver", lambda self, name="auto", **kw: auto)
    kept = newton_solve(be, 0.3, n_increments=3)
    assert isinstance(auto.chosen, KeptFactorSolver) and auto.iterative
    assert auto.chosen.counts["cg_solves"] > 0 and auto.chosen.counts["factorisations"] < sum(
        i.iterations for i in kept.increments)
    assert direct.success and kept.success
    assert np.linalg.norm(kept.u - direct.u) <= 1e-6 * np.linalg.norm(direct.u)


@pytest.mark.parametrize("offset, kind", [(-1, NgsolveSparseSolver), (0, KeptFactorSolver)])
def test_auto_chooses_the_kept_factors_from_exactly_its_threshold(offset, kind):
    chosen = AutoDirectSolver()._choose(linear_solvers.KEPT_FACTORS_MIN_DOFS + offset)
    assert type(chosen) is kind


def test_the_ngsolve_backend_takes_ngsolve_at_every_size_and_the_kept_factors_from_the_threshold():
    """``verify`` runs on NGSolve by default: its "auto" is the same choice with NGSolve's LDL^T also
    below NGSOLVE_MIN_DOFS (its "direct" stays the plain factorisation)."""
    be = make_backend("ngsolve", bar_tension("ci").problem)
    auto = be.make_linear_solver("auto")
    assert isinstance(auto, AutoDirectSolver) and isinstance(be.make_linear_solver("direct"), NgsolveSparseSolver)
    assert type(auto._choose(60)) is NgsolveSparseSolver
    assert type(auto._choose(linear_solvers.KEPT_FACTORS_MIN_DOFS)) is KeptFactorSolver


def test_kept_factor_cg_by_name_keeps_the_large_system_solvers_factors():
    from tissuebench.refsolvers.kept_factors import large_system_solver
    from tissuebench.refsolvers.linear_solvers import make_linear_solver

    solver = make_linear_solver("kept-factor-cg", max_iterations=5)
    assert isinstance(solver, KeptFactorSolver) and type(solver.inner) is type(large_system_solver())
    assert solver.max_iterations == 5
