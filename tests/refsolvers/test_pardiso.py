"""MKL PARDISO (refsolvers/pardiso.py): solutions against SciPy's, the ordering kept per pattern, the
inertia of a symmetric indefinite matrix, a singular matrix refused, and the solver "auto" keeps
factors with from KEPT_FACTORS_MIN_DOFS unknowns on."""
from __future__ import annotations

import platform

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from tissuebench.refsolvers import kept_factors, linear_solvers, pardiso
from tissuebench.refsolvers.linear_solvers import (AutoDirectSolver, DirectSolver, KeptFactorSolver,
                                                   LinearSolverError, NgsolveSparseSolver, PardisoSolver,
                                                   direct_solver_for, make_linear_solver)


def test_pardiso_is_installed_where_mkl_has_wheels():
    """A dependency on x86-64 (pyproject's marker): the tests below must not skip there."""
    if platform.machine().lower() in ("x86_64", "amd64"):
        assert pardiso.why_no_pardiso() == ""


pytestmark = pytest.mark.skipif(bool(pardiso.why_no_pardiso()), reason=pardiso.why_no_pardiso() or "-")


def _laplacian_3d(m, shift=0.0):
    """The 7-point Laplacian on an m^3 grid (SPD), plus ``shift`` on the diagonal."""
    one = sp.diags([-np.ones(m - 1), 2 * np.ones(m), -np.ones(m - 1)], [-1, 0, 1])
    eye = sp.identity(m)
    L = sp.kron(sp.kron(one, eye), eye) + sp.kron(sp.kron(eye, one), eye) + sp.kron(sp.kron(eye, eye), one)
    return (L + shift * sp.identity(m ** 3)).tocsr()


def _relres(K, x, b):
    return np.linalg.norm(K @ x - b) / np.linalg.norm(b)


def test_spd_solution_and_the_ordering_kept_while_the_pattern_stays():
    K = _laplacian_3d(12)
    b = np.random.default_rng(0).standard_normal(K.shape[0])
    solver = PardisoSolver()
    x, info = solver.solve(K, b)
    np.testing.assert_allclose(x, spla.spsolve(K.tocsc(), b), rtol=1e-10, atol=1e-12 * np.abs(x).max())
    assert info["solver"] == "pardiso" and info["symbolic"] == "computed" and info["negative_pivots"] == 0
    K2 = (K + sp.diags(np.linspace(0.1, 1.0, K.shape[0]))).tocsr()  # same pattern, other values
    x2, info2 = solver.solve(K2, b)
    assert info2["symbolic"] == "reused" and _relres(K2, x2, b) <= 1e-12
    K3 = _laplacian_3d(10)  # another pattern: ordered again
    _, info3 = solver.solve(K3, np.ones(K3.shape[0]))
    assert info3["symbolic"] == "computed"


def test_symmetric_indefinite_saddle_point_inertia_and_solution():
    """[[A, B^T], [B, -C]] with A SPD (n) and C >= 0 (m): n positive and m negative pivots (Sylvester)."""
    rng = np.random.default_rng(1)
    A = _laplacian_3d(8, shift=0.1)
    n, m = A.shape[0], 60
    B = sp.random(m, n, density=0.05, random_state=rng, format="csr") + sp.eye(m, n, format="csr")
    C = sp.diags(np.full(m, 1e-3))
    K = sp.bmat([[A, B.T], [B, -C]], format="csr")
    b = rng.standard_normal(n + m)
    solver = PardisoSolver()
    x, info = solver.solve(K, b)
    assert _relres(K, x, b) <= 1e-10
    assert info["negative_pivots"] == m


def test_unsymmetric_and_several_right_hand_sides():
    rng = np.random.default_rng(2)
    K = (_laplacian_3d(9) + sp.random(729, 729, density=0.002, random_state=rng) * 0.5).tocsr()
    assert abs(K - K.T).max() > 0.1
    b = rng.standard_normal((729, 3))
    x, _ = PardisoSolver().solve(K, b)
    assert x.shape == (729, 3)
    np.testing.assert_allclose(K @ x, b, atol=1e-10 * np.abs(b).max())


def test_a_symmetric_matrix_without_its_diagonal_is_solved_as_unsymmetric():
    """PARDISO's symmetric storage needs every diagonal entry: [[0, 1], [1, 0]] goes to mtype 11."""
    K = sp.csr_matrix(np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]))
    K.eliminate_zeros()
    solver = PardisoSolver()
    x, _ = solver.solve(K, np.array([1.0, 2.0, 4.0]))
    np.testing.assert_allclose(x, [2.0, 1.0, 2.0], rtol=1e-13)
    assert solver._mtype == 11


@pytest.mark.parametrize("shift, singular", [(0.0, True), (1e-3, False)])
def test_a_singular_matrix_is_refused_and_a_regular_neighbour_solved(shift, singular):
    """The pure-Neumann 3D Laplacian (the constants in its kernel, a body with its rigid modes free)."""
    L = _laplacian_3d(8)
    K = L - sp.diags(np.asarray(L.sum(axis=1)).ravel())  # every row sum zero: the constants in the kernel
    K = (K + shift * sp.identity(K.shape[0])).tocsr()
    b = np.random.default_rng(3).standard_normal(K.shape[0])
    solver = PardisoSolver()
    if singular:
        with pytest.raises(LinearSolverError, match="pardiso solver"):
            solver.solve(K, b)
    else:
        x, _ = solver.solve(K, b)
        assert _relres(K, x, b) <= 1e-9


def test_solve_again_applies_the_last_factors_and_refuses_before_any():
    solver = PardisoSolver()
    with pytest.raises(LinearSolverError, match="no factors"):
        solver.solve_again(np.ones(512))
    K1, K2 = _laplacian_3d(8), _laplacian_3d(8, shift=1.0)
    b = np.random.default_rng(4).standard_normal(512)
    solver.solve(K1, b)
    solver.solve(K2, b)
    x = solver.solve_again(b)
    assert _relres(K2, x, b) <= 1e-13 and _relres(K1, x, b) > 1e-3
    solver.reset()
    with pytest.raises(LinearSolverError, match="no factors"):
        solver.solve_again(b)


def test_bad_input():
    with pytest.raises(ValueError, match="square"):
        PardisoSolver().solve(sp.csr_matrix(np.ones((2, 3))), np.ones(2))


def test_without_mkl_the_solver_says_why_and_auto_keeps_ngsolve_factors(monkeypatch):
    monkeypatch.setattr(pardiso, "_AVAILABLE", ["MKL PARDISO is not available here (ImportError: no mkl_rt)"])
    with pytest.raises(LinearSolverError, match="no mkl_rt"):
        PardisoSolver()
    chosen = AutoDirectSolver()._choose(linear_solvers.KEPT_FACTORS_MIN_DOFS)
    assert isinstance(chosen, KeptFactorSolver) and isinstance(chosen.inner, NgsolveSparseSolver)
    assert isinstance(kept_factors.large_system_solver(), NgsolveSparseSolver)


@pytest.mark.parametrize("offset, kind", [(-1, NgsolveSparseSolver), (0, PardisoSolver)])
def test_the_kept_factors_are_pardiso_from_exactly_the_threshold(offset, kind):
    n = linear_solvers.KEPT_FACTORS_MIN_DOFS + offset
    chosen = AutoDirectSolver()._choose(n)
    inner = chosen.inner if isinstance(chosen, KeptFactorSolver) else chosen
    assert type(inner) is kind
    assert type(direct_solver_for(n)) is kind  # what the h/2 memory probe factorises with
    assert type(direct_solver_for(999)) is DirectSolver and type(direct_solver_for(1000)) is NgsolveSparseSolver
    assert isinstance(make_linear_solver("kept-factor-cg").inner, PardisoSolver)
    assert isinstance(make_linear_solver("pardiso"), PardisoSolver)
