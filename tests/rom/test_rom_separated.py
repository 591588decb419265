"""The general N-dimensional PGD solver (tissuebench.rom.separated): against the full
tensor solution assembled explicitly, exactness for separable data, error decreasing
with the modes, reproducible seeded initialisation, reported (not raised) failures."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.rom.separated import SeparatedOperator, SeparatedSolution, SeparatedVector
from tissuebench.rom.separated_solver import pgd_solve


def _laplacian(n, h):
    """P1 stiffness of -u'' on n interior nodes, spacing h (Dirichlet ends removed)."""
    return sp.diags([-np.ones(n - 1), 2 * np.ones(n), -np.ones(n - 1)], [-1, 0, 1], format="csr") / h


def _poisson_parametric(nx=15, ns=9):
    """Poisson in x times a parameter: -u'' + 200 s u = sin(pi x) + x^2 cos(s), s in [0, 1]:
    A = K ⊗ W + 200 M_x ⊗ diag(s) W (W: lumped s-measure), not separable, 2 load terms."""
    hx, s = 1.0 / (nx + 1), np.linspace(0.0, 1.0, ns)
    K = _laplacian(nx, hx)
    Mx = sp.diags(np.full(nx, hx), format="csr")
    W = np.diag(np.full(ns, 1.0 / (ns - 1)))
    x = np.arange(1, nx + 1) * hx
    A = SeparatedOperator([(K, W), (200.0 * Mx, np.diag(s) @ W)])
    f = SeparatedVector([(hx * np.sin(np.pi * x), W @ np.ones(ns)), (hx * x**2, W @ np.cos(s))])
    return A, f


def test_2d_poisson_times_parameter_against_the_full_tensor_solution():
    A, f = _poisson_parametric()
    u_full = np.linalg.solve(A.to_dense(), f.to_dense())
    sol = pgd_solve(A, f, max_modes=12, tol=0.0, fixed_point_tol=1e-10, max_fixed_point=100, update_last=True)
    err = np.linalg.norm(sol.to_dense() - u_full) / np.linalg.norm(u_full)
    assert err < 1e-12, sol.message  # measured 2.4e-16 (9 x 15 = 135 unknowns, rank <= 9)
    # the relative residual in separated form equals the one of the assembled tensors (to its
    # round-off floor, ~1e-8: a difference of squares)
    plain = pgd_solve(A, f, max_modes=6, tol=0.0)
    r = np.linalg.norm(f.to_dense() - A.to_dense() @ plain.to_dense()) / np.linalg.norm(f.to_dense())
    assert plain.residuals[-1] == pytest.approx(r, rel=1e-6) and r > 1e-4
    # partial evaluation at a parameter node = the column of the full solution
    j = 4
    u_j = sol.evaluate(1, j)
    assert np.allclose(u_j, u_full.reshape(15, 9)[:, j], rtol=0, atol=1e-9 * np.abs(u_full).max())
    # interpolation weights halfway between two nodes
    w = np.zeros(9)
    w[[4, 5]] = 0.5
    assert np.allclose(sol.evaluate(1, w), 0.5 * (u_full.reshape(15, 9)[:, 4] + u_full.reshape(15, 9)[:, 5]),
                       atol=1e-9 * np.abs(u_full).max())


def test_error_decreases_with_the_number_of_modes():
    A, f = _poisson_parametric(nx=20, ns=15)
    u_full = np.linalg.solve(A.to_dense(), f.to_dense())
    # plain greedy: nested modes, so the n-mode solution is the first n modes of one build
    sol = pgd_solve(A, f, max_modes=10, tol=0.0, fixed_point_tol=1e-10, max_fixed_point=300)
    errs = [np.linalg.norm(sol.truncated(n).to_dense() - u_full) / np.linalg.norm(u_full)
            for n in range(1, sol.n_modes + 1)]
    assert all(b < a for a, b in zip(errs, errs[1:])), errs
    assert errs[0] > 1e-2 and errs[-1] < 2e-6  # measured 4.1e-2 .. 6.8e-7
    # with the update of the parameter functions: faster, monotone down to round-off
    upd = pgd_solve(A, f, max_modes=10, tol=0.0, fixed_point_tol=1e-10, max_fixed_point=100, update_last=True)
    errs_u = []
    for n in range(1, 11):
        part = pgd_solve(A, f, max_modes=n, tol=0.0, fixed_point_tol=1e-10, max_fixed_point=100, update_last=True)
        errs_u.append(np.linalg.norm(part.to_dense() - u_full) / np.linalg.norm(u_full))
    assert all(b < a for a, b in zip(errs_u, errs_u[1:])), errs_u
    assert errs_u[-1] < 1e-11 and all(u <= p for u, p in zip(errs_u[1:], errs[1:]))
    assert np.allclose(upd.to_dense(), part.to_dense(), atol=1e-12 * np.abs(u_full).max())


def test_3d_separable_problem_is_exact_with_one_mode():
    rng = np.random.default_rng(3)
    mats, vecs = [], []
    for n in (6, 5, 4):
        B = rng.standard_normal((n, n))
        mats.append(B @ B.T + n * np.eye(n))
        vecs.append(rng.standard_normal(n))
    A, f = SeparatedOperator([tuple(mats)]), SeparatedVector([tuple(vecs)])
    sol = pgd_solve(A, f, max_modes=5, tol=1e-10)
    exact = np.kron(np.kron(*[np.linalg.solve(M, v) for M, v in zip(mats[:2], vecs[:2])]),
                    np.linalg.solve(mats[2], vecs[2]))
    assert np.allclose(sol.truncated(1).to_dense(), exact, rtol=0, atol=1e-12 * np.abs(exact).max())
    assert sol.residuals[0] < 1e-7
    # the second mode has nothing left to represent
    assert sol.n_modes == 1 or sol.amplitudes[1] <= 1e-10 * sol.amplitudes[0]
    assert sol.stop_reason in ("amplitude", "zero_mode")
    # evaluating two of the three dimensions leaves a vector; a 2D partial evaluation stays separated
    v = sol.evaluate([0, 2], [1, 3])
    assert np.allclose(v, exact.reshape(6, 5, 4)[1, :, 3], atol=1e-12 * np.abs(exact).max())
    part = sol.evaluate(0, 2)
    assert isinstance(part, SeparatedSolution) and np.allclose(part.to_dense(), exact.reshape(6, 5, 4)[2].ravel())


def test_seeded_initialisation_is_reproducible_and_seed_independent_at_convergence():
    A, f = _poisson_parametric()
    a = pgd_solve(A, f, max_modes=3, rng=7)
    b = pgd_solve(A, f, max_modes=3, rng=np.random.default_rng(7))
    for ma, mb in zip(a.modes, b.modes):
        assert all(np.array_equal(x, y) for x, y in zip(ma, mb))
    c = pgd_solve(A, f, max_modes=3, rng=8, fixed_point_tol=1e-12, max_fixed_point=300)
    d = pgd_solve(A, f, max_modes=3, rng=7, fixed_point_tol=1e-12, max_fixed_point=300)
    # converged fixed points: the same modes from another seed
    assert np.allclose(c.to_dense(), d.to_dense(), atol=1e-8 * np.abs(d.to_dense()).max())


def test_fixed_point_not_converging_is_recorded_not_raised():
    A, f = _poisson_parametric()
    sol = pgd_solve(A, f, max_modes=3, max_fixed_point=1, fixed_point_tol=0.0)
    assert sol.n_modes == 3 and sol.converged == [False] * 3 and sol.fixed_point_iterations == [1, 1, 1]
    assert "not converged in 3 mode(s)" in sol.message and sol.stop_reason == "max_modes"


def test_custom_dimension_solver_is_used():
    A, f = _poisson_parametric()
    calls = []

    def solver(M, rhs):
        calls.append(M.shape)
        return np.linalg.solve(M.toarray() if sp.issparse(M) else M, rhs)

    ref = pgd_solve(A, f, max_modes=2)
    sol = pgd_solve(A, f, max_modes=2, dims_solvers=[solver, None])
    assert calls and set(calls) == {(15, 15)}
    assert np.allclose(sol.to_dense(), ref.to_dense(), atol=1e-12 * np.abs(ref.to_dense()).max())


@pytest.mark.parametrize("kwargs, match", [
    ({"max_modes": 0}, "max_modes"), ({"tol": -1.0}, "tol"), ({"max_fixed_point": 2.5}, "max_fixed_point"),
    ({"dims_solvers": [None]}, "dims_solvers"), ({"residual_tol": float("nan")}, "residual_tol")])
def test_bad_options(kwargs, match):
    A, f = _poisson_parametric()
    with pytest.raises(ValueError, match=match):
        pgd_solve(A, f, **kwargs)


def test_bad_operands():
    with pytest.raises(ValueError, match="square"):
        SeparatedOperator([(np.ones((2, 3)), np.eye(2))])
    with pytest.raises(ValueError, match="factor sizes"):
        SeparatedOperator([(np.eye(2), np.eye(3)), (np.eye(2), np.eye(2))])
    A, _ = _poisson_parametric()
    with pytest.raises(ValueError, match="dimension sizes"):
        pgd_solve(A, SeparatedVector([(np.ones(3), np.ones(9))]))
    with pytest.raises(TypeError, match="SeparatedOperator"):
        pgd_solve(np.eye(3), SeparatedVector([(np.ones(3),)]))
