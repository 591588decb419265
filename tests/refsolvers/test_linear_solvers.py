"""Linear solvers: reuse of orderings, factorisations and AMG hierarchies is exact when the
sparsity pattern is identical and refused when it differs; AMG-CG reaches its tolerance;
the forcing term follows Eisenstat-Walker."""
import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tissuebench.cases.bar import bar_tension
from tissuebench.refsolvers import make_backend
from tissuebench.refsolvers.linear_solvers import (AmgCgSolver, DirectSolver, LinearSolverError, SparsityPattern,
                                                   forcing_term, make_linear_solver, rigid_body_modes)


@pytest.fixture(scope="module")
def bar():
    return bar_tension("ci")


def _tangent(bar, stretch, shear=0.0):
    """Free-dof tangent of the ci bar at a homogeneous stretch (plus a small shear)."""
    pb = bar.problem
    be = make_backend("skfem", pb)
    x = pb.nodes
    u = np.zeros(pb.ndof)
    u[0::3] = stretch * x[:, 0]
    u[1::3] = shear * x[:, 0]
    free = pb.free_dofs
    return be.tangent(u)[free][:, free].tocsr()


@pytest.fixture(scope="module")
def tangents(bar):
    """Two tangents with one pattern, and the first with an extra coupling (new pattern)."""
    K1, K2 = _tangent(bar, 0.1), _tangent(bar, 0.25, 0.05)
    n = K1.shape[0]
    extra = sp.coo_matrix(([1e-3 * abs(K1).max()] * 2, ([0, n - 1], [n - 1, 0])), shape=K1.shape)
    K3 = (K1 + extra).tocsr()
    assert K3.nnz == K1.nnz + 2
    return K1, K2, K3


def _rhs(n, seed=0):
    return np.random.default_rng(seed).standard_normal(n)


def _relres(K, x, b):
    return np.linalg.norm(K @ x - b) / np.linalg.norm(b)


# ---------------------------------------------------------------- patterns and forcing term
def test_sparsity_pattern_embeds_a_matrix_with_fewer_entries(tangents):
    """A tangent that lost entries (SciPy drops exact zeros) is written on the stored
    pattern with zeros there, value for value; an entry outside the pattern -> None."""
    K1, _, K3 = tangents
    pat = SparsityPattern()
    assert pat.embed(K1) is None  # nothing stored
    pat.store(K3)
    E = pat.embed(K1)
    assert pat.matches(E) and E.nnz == K3.nnz
    assert abs(E - K1).max() == 0.0
    pat.store(K1)
    assert pat.embed(K3) is None
    # widened: K3 on the union of K1's pattern and its own (here K3's, a superset)
    W = pat.widened(K3)
    assert W.nnz == K3.nnz and abs(W - K3).max() == 0.0
    n = K1.shape[0]
    other = sp.coo_matrix(([1.0, 1.0], ([1, n - 2], [n - 2, 1])), shape=K1.shape)
    pat.store(K3)
    K4 = (K1 + other).tocsr()
    W = pat.widened(K4)  # two entries of K3 not in K4, two of K4 not in K3
    assert W.nnz == K3.nnz + 2 and abs(W - K4).max() == 0.0 and (W.data == 0).sum() == 2


def test_sparsity_pattern_matches_exactly_and_tests_symmetry(tangents):
    K1, K2, K3 = tangents
    pat = SparsityPattern()
    assert not pat.matches(K1)
    pat.store(K1)
    assert pat.matches(K1) and pat.matches(K2) and not pat.matches(K3)
    assert pat.is_symmetric(K2)
    N = K2.copy()
    N.data[5] *= 1.0 + 1e-9  # one entry off: K is no longer symmetric
    assert abs(N - N.T).max() > 1e-12 * abs(N).max() and not pat.is_symmetric(N)


def test_forcing_term_eisenstat_walker():
    assert forcing_term(1.0, None, None, 1e-12, eta_max=1e-3) == 1e-3  # first iteration
    # choice 2: 0.9 (res / res_prev)^2
    assert forcing_term(1e-3, 1e-1, 1e-3, 1e-15, eta_max=0.5) == pytest.approx(0.9e-4)
    # safeguard: not below 0.9 eta_prev^2 when that exceeds 0.1
    assert forcing_term(1e-3, 1.0, 0.4, 1e-15, eta_max=0.5) == pytest.approx(0.9 * 0.16)
    # floor: no more accuracy than 0.5 tol / res
    assert forcing_term(1e-6, 1.0, 1e-3, 1e-9, eta_max=0.5) == pytest.approx(5e-4)
    assert forcing_term(1e-12, 1.0, 1e-3, 1e-9, eta_max=1e-2) == 1e-2  # capped


# ---------------------------------------------------------------- direct solvers
def test_superlu_reuses_ordering_only_for_the_same_pattern(tangents):
    K1, K2, K3 = tangents
    b = _rhs(K1.shape[0])
    solver = DirectSolver()
    for K, expected in [(K1, "computed"), (K2, "reused"), (K3, "computed"), (K3, "reused"), (K1, "computed")]:
        x, info = solver.solve(K, b)
        assert info["symbolic"] == expected
        fresh = spla.splu(K.tocsc(), permc_spec="MMD_AT_PLUS_A").solve(b)
        assert np.abs(x - fresh).max() <= 1e-10 * np.abs(fresh).max()
        assert _relres(K, x, b) <= 1e-12
    # the reused ordering factorises with exactly the fill of the fresh minimum-degree ordering
    solver.reset()
    lu_fresh = solver.factorize(K2)
    lu_reused = solver.factorize(K2)
    assert lu_fresh.q is None and lu_reused.q is not None  # the second one ran on the stored ordering
    assert lu_reused.lu.L.nnz + lu_reused.lu.U.nnz == lu_fresh.lu.L.nnz + lu_fresh.lu.U.nnz


@pytest.mark.ngsolve
def test_ngsolve_cholesky_refactorises_in_place_only_for_the_same_pattern(tangents):
    K1, K2, K3 = tangents
    b = _rhs(K1.shape[0], 1)
    solver = make_linear_solver("cholesky", taskmanager=False)
    n = K1.shape[0]
    other = sp.coo_matrix(([1e-3 * abs(K1).max()] * 2, ([1, n - 2], [n - 2, 1])), shape=K1.shape)
    K4 = (K1 + other).tocsr()  # an entry outside K3's pattern
    # K2 and K1 after K3: their pattern is K3's less two entries, written on it (reused)
    for K, expected in [(K1, "computed"), (K2, "reused"), (K3, "computed"), (K3, "reused"), (K2, "reused"),
                        (K1, "reused"), (K4, "computed")]:
        x, info = solver.solve(K, b)
        assert info["symbolic"] == expected and info["inverse"] == "sparsecholesky"
        assert _relres(K, x, b) <= 1e-12
    # same pattern, values no longer symmetric: a new factorisation of another type
    N = K2.copy()
    N.data *= 1.0 + 0.01 * np.random.default_rng(4).random(N.nnz)
    x, info = solver.solve(N, b)
    assert info["symbolic"] == "computed" and info["inverse"] == "umfpack"
    assert _relres(N, x, b) <= 1e-12


# ---------------------------------------------------------------- AMG-CG
def _amg(bar, **kw):
    pb = bar.problem
    return AmgCgSolver(coords=pb.nodes, free_dofs=pb.free_dofs, **kw)


def test_rigid_body_modes_are_the_zero_energy_modes_of_the_unconstrained_tangent(bar):
    pb = bar.problem
    K = make_backend("skfem", pb).tangent(np.zeros(pb.ndof))
    B = rigid_body_modes(pb.nodes)
    assert np.abs(K @ B).max() <= 1e-10 * abs(K).max() * np.abs(B).max()
    assert np.linalg.matrix_rank(B) == 6


@pytest.mark.parametrize("rtol", [1e-3, 1e-8, 1e-11])
def test_amg_cg_reaches_its_tolerance(bar, tangents, rtol):
    K = tangents[1]
    b = _rhs(K.shape[0], 2)
    x, info = _amg(bar).solve(K, b, rtol=rtol)
    assert info["solver"] == "amg-cg" and info["rtol"] == rtol
    assert _relres(K, x, b) <= rtol and info["relative_residual"] == pytest.approx(_relres(K, x, b))
    exact = spla.spsolve(K.tocsc(), b)
    # CG error bound: |x - x*| <= cond(K) rtol |x*|; with the tangent's condition well below 1e4
    assert np.linalg.norm(x - exact) <= 1e4 * rtol * np.linalg.norm(exact)


def test_amg_cg_fixed_rtol_overrides_the_callers(bar, tangents):
    K = tangents[0]
    _, info = _amg(bar, rtol=1e-10).solve(K, _rhs(K.shape[0]), rtol=1e-2)
    assert info["rtol"] == 1e-10 and info["relative_residual"] <= 1e-10


def test_amg_hierarchy_reused_for_the_same_pattern_rebuilt_for_another(bar, tangents):
    K1, K2, K3 = tangents
    b = _rhs(K1.shape[0], 3)
    solver = _amg(bar)
    for K, expected in [(K1, "built"), (K1, "reused"), (K2, "reused"), (K3, "built"), (K3, "reused")]:
        x, info = solver.solve(K, b, rtol=1e-9)
        assert info["hierarchy"] == expected
        assert _relres(K, x, b) <= 1e-9
    # reuse on the same matrix: the very same preconditioned iterations, hence the same x
    solver.reset()
    x_built, _ = solver.solve(K2, b, rtol=1e-9)
    x_reused, info = solver.solve(K2, b, rtol=1e-9)
    assert info["hierarchy"] == "reused"
    np.testing.assert_array_equal(x_reused, x_built)


def test_amg_rebuilds_an_aged_hierarchy_and_on_symmetry_change(bar, tangents):
    K1, K2, _ = tangents
    b = _rhs(K1.shape[0], 5)
    solver = _amg(bar, rebuild_factor=1.0)
    solver.solve(_tangent(bar, 0.0), b, rtol=1e-9)  # same pattern as K1, K2
    # the hierarchy of the unstretched tangent needs more iterations per decade on K2
    _, aged = solver.solve(K2, b, rtol=1e-9)
    _, info = solver.solve(K2, b, rtol=1e-9)
    assert aged["hierarchy"] == "reused" and info["hierarchy"] == "built"
    assert info["iterations"] < aged["iterations"]
    N = K2.copy()
    N.data *= 1.0 + 0.01 * np.random.default_rng(6).random(N.nnz)
    x, info = solver.solve(N, b, rtol=1e-9)
    assert info["hierarchy"] == "built" and info["solver"] == "amg-gmres"
    assert _relres(N, x, b) <= 1e-9


def test_amg_cg_failure_is_an_error_not_a_nan(bar, tangents):
    K = tangents[1]
    solver = _amg(bar, maxiter=2)
    with pytest.raises(LinearSolverError, match="no convergence"):
        solver.solve(K, _rhs(K.shape[0]), rtol=1e-12)


@pytest.mark.parametrize("kw", [{"rtol": 0.0}, {"rtol": 1.5}, {"maxiter": 0}, {"rebuild_factor": 0.5}])
def test_amg_cg_bad_options(kw):
    name = next(iter(kw))
    with pytest.raises(ValueError, match=name):
        AmgCgSolver(**kw)


def test_run_command_offers_every_linear_solver():
    from tissuebench.cli import _parser
    from tissuebench.refsolvers.linear_solvers import LINEAR_SOLVERS

    action = next(a for a in _parser()._subparsers._group_actions[0].choices["run"]._actions
                  if a.dest == "linear_solver")
    assert sorted(action.choices) == sorted(LINEAR_SOLVERS)


@pytest.mark.parametrize("n", [60, 1500])  # SuperLU below NGSOLVE_MIN_DOFS, NGSolve from it on
@pytest.mark.parametrize("symmetric", [True, False])
def test_factorized_solves_one_and_many_right_hand_sides(n, symmetric):
    from tissuebench.refsolvers.sparse_direct import NGSOLVE_MIN_DOFS, factorized

    assert (n >= NGSOLVE_MIN_DOFS) == (n == 1500)
    rng = np.random.default_rng(3)
    lap = sp.diags([-np.ones(n - 1), 4 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1])
    K = (lap + (0 if symmetric else sp.diags([0.5 * np.ones(n - 2)], [2]))).tocsr()
    B = rng.standard_normal((n, 3))
    solve = factorized(K)
    X = solve(B)
    assert X.shape == (n, 3)
    assert np.linalg.norm(K @ X - B) <= 1e-12 * np.linalg.norm(B)
    assert np.allclose(solve(B[:, 1]), X[:, 1], rtol=0, atol=1e-13 * np.abs(X).max())


@pytest.mark.parametrize("n", [60, 1500])
def test_factorized_refuses_a_singular_matrix(n):
    from tissuebench.refsolvers.sparse_direct import factorized

    K = sp.diags(np.r_[np.ones(n - 1), 0.0]).tocsr()
    with pytest.raises(LinearSolverError, match="factorized|cholesky"):
        factorized(K)(np.ones(n))


@pytest.mark.parametrize("n, chosen", [(60, "DirectSolver"), (1500, "NgsolveSparseSolver")])
def test_auto_takes_ngsolve_from_1000_dofs_and_solves_to_round_off(n, chosen):
    """The statics' default: SuperLU below NGSOLVE_MIN_DOFS, NGSolve's LDL^T from it on (a user's
    13k-dof kidney: 12 min 46 s with SuperLU MMD, 1 min 10 s with LDL^T)."""
    from tissuebench.refsolvers.linear_solvers import AutoDirectSolver

    lap = sp.diags([-np.ones(n - 1), 4 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1]).tocsr()
    b = _rhs(n)
    solver = make_linear_solver()
    assert isinstance(solver, AutoDirectSolver)
    x, info = solver.solve(lap, b)
    assert type(solver.chosen).__name__ == chosen and "fallback" not in info
    assert _relres(lap, x, b) <= 1e-13


def test_auto_falls_back_to_superlu_when_ldlt_is_inaccurate(monkeypatch):
    """LDL^T does not pivot: a solution whose residual is not small is solved again by SuperLU."""
    from tissuebench.refsolvers.linear_solvers import AutoDirectSolver, NgsolveSparseSolver

    n = 1200
    rng = np.random.default_rng(1)
    K = (sp.diags(4 * np.ones(n)) + sp.random(n, n, density=3 / n, random_state=2)).tocsr()
    K = (K + K.T).tocsr()
    b = rng.standard_normal(n)
    original = NgsolveSparseSolver.solve

    def damaged(self, K, b, rtol=None):
        x, info = original(self, K, b, rtol)
        return x * (1 + 1e-4), info  # what an unpivoted factorisation of an indefinite matrix can give
    monkeypatch.setattr(NgsolveSparseSolver, "solve", damaged)
    solver = AutoDirectSolver()
    x, info = solver.solve(K, b)
    assert "residual" in info["fallback"] and isinstance(solver.chosen, DirectSolver)
    assert _relres(K, x, b) <= 1e-12
