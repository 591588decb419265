"""The direct solver of the implicit schemes' Newton matrices (``linear_solver`` option).

SuperLU and NGSolve's sparse factorisation are independent implementations: a nonlinear
Mooney-Rivlin bar pulled in dynamics gives the same history with either (1e-10), in each
implicit scheme, and ``"auto"`` takes NGSolve from NGSOLVE_MIN_DOFS unknowns on (the
paper-size ventricle waited 210 s per SuperLU factorisation, 1.5 s with NGSolve).
"""
import numpy as np
import pytest
import scipy.sparse as sp

from test_dynamics_prescribed import CUBE_MR, bar, ramp
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.refsolvers.dynamics.step_newton import (NGSOLVE_MIN_DOFS, REUSE_MIN_DOFS, StepSolver, newton,
                                                     newton_options, step_solver_name)
from tissuebench.refsolvers.linear_solvers import LinearSolverError


def test_auto_takes_ngsolve_from_the_threshold_on():
    assert step_solver_name("auto", NGSOLVE_MIN_DOFS - 1) == "direct"
    assert step_solver_name("auto", NGSOLVE_MIN_DOFS) == "cholesky"
    assert step_solver_name("direct", 10 ** 6) == "direct"


@pytest.mark.parametrize("choice", ["direct", "cholesky"])
def test_step_solver_solves_symmetric_and_nonsymmetric_systems(choice):
    rng = np.random.default_rng(3)
    n = 60
    A = sp.random(n, n, density=0.1, random_state=rng) + 10.0 * sp.eye(n)
    for J in (A + A.T, A):  # SPD-like (LDL^T), then non-symmetric (a follower load: UMFPACK)
        b = rng.standard_normal(n)
        x = StepSolver(choice).solve(J, b)
        assert np.linalg.norm(J @ x - b) <= 1e-12 * np.linalg.norm(b)


@pytest.mark.parametrize("choice", ["direct", "cholesky"])
def test_cached_factors_are_kept_while_the_key_stays(choice):
    J = sp.diags([2.0, 4.0, 8.0], format="csr")
    builds = []
    s = StepSolver(choice)

    def build():
        builds.append(1)
        return J
    for _ in range(3):
        np.testing.assert_allclose(s.solve_cached("linear", build, np.ones(3)), [0.5, 0.25, 0.125])
    assert len(builds) == 1
    s.solve_cached("other", build, np.ones(3))
    assert len(builds) == 2


@pytest.mark.parametrize("choice", ["direct", "cholesky"])
def test_a_singular_newton_matrix_is_a_linear_solver_error(choice):
    with pytest.raises(LinearSolverError):
        StepSolver(choice).solve(sp.csr_matrix(np.zeros((3, 3))), np.ones(3))


def test_unknown_linear_solver_is_refused_naming_it():
    with pytest.raises(ValueError, match="linear_solver.*'lu'"):
        newton_options("HHT", {"linear_solver": "lu"})
    with pytest.raises(ValueError, match="linear_solver"):
        integrate(SecondOrderSystem.linear_system(np.eye(2), np.eye(2), np.ones(2)), None, None, 0.1, 0.2,
                  method="hht", linear_solver="lu")


@pytest.mark.parametrize("method", ["hht", pytest.param("bathe", marks=pytest.mark.slow), "backward_euler"])
def test_superlu_and_ngsolve_give_the_same_nonlinear_history(method):
    be = bar(CUBE_MR, [0.024, 0.0, 0.0])      # pulled to 30 % strain in 0.2 s
    system = SecondOrderSystem.from_backend(be, ramp(0.2))
    runs = {c: integrate(system, None, None, 0.01, 0.3, method=method, linear_solver=c)
            for c in ("direct", "cholesky")}
    for res in runs.values():
        assert res.success, res.message
    a, b = runs["direct"], runs["cholesky"]
    scale = np.abs(a.u).max()
    assert scale > 1e-3
    assert np.abs(a.u - b.u).max() <= 1e-10 * scale
    assert np.array_equal(a.newton_iterations, b.newton_iterations)


# ------------------------------------------------------------------ modified Newton, dense matrices
def _cubic(n, calls):
    """``r(u) = u + u^3 - b`` on n unknowns (a diagonal Jacobian, counted in ``calls``)."""
    b = np.linspace(0.5, 2.0, n)

    def jacobian(u):
        calls.append(1)
        return sp.diags(1.0 + 3.0 * u ** 2, format="csr")
    return (lambda u: u + u ** 3 - b), jacobian


@pytest.mark.parametrize("n, reused", [(REUSE_MIN_DOFS - 1, False), (REUSE_MIN_DOFS, True)])
def test_auto_keeps_the_newton_matrix_from_the_threshold_on(n, reused):
    calls = []
    residual, jacobian = _cubic(n, calls)
    u, rep = newton(np.ones(n), residual, jacobian, 1.0, newton_options("HHT", {"newton_rtol": 1e-12}))
    assert rep.converged and np.linalg.norm(residual(u)) <= 1e-12 * np.sqrt(n) * 3
    # Newton forms J at every iteration; modified Newton only when the contraction is poor
    assert (len(calls) < rep.iterations) == reused, (len(calls), rep.iterations)


def test_a_kept_matrix_that_does_not_reduce_the_residual_is_formed_again():
    calls = []
    residual, jacobian = _cubic(4, calls)
    solver = StepSolver("direct")
    solver.solve_cached("newton", lambda: -1.0 * sp.eye(4, format="csr"), np.ones(4))  # a wrong kept matrix
    opts = newton_options("HHT", {"newton_rtol": 1e-12, "newton_tangent": "reuse"})
    u, rep = newton(np.ones(4), residual, jacobian, 1.0, opts, solver=solver)
    assert rep.converged and np.linalg.norm(residual(u)) <= 1e-11
    assert len(calls) >= 1 and all(np.diff(rep.residuals) < 0)  # the discarded iterate is not in the history


def test_modified_newton_gives_the_newton_history_with_fewer_matrices():
    be = bar(CUBE_MR, [0.024, 0.0, 0.0])
    runs, formed = {}, {}
    for tangent in ("iteration", "reuse"):
        count = []
        system = SecondOrderSystem.from_backend(be, ramp(0.2))
        tangent_of = system.tangent
        system.tangent = lambda u, f=tangent_of, c=count: c.append(1) or f(u)
        runs[tangent] = integrate(system, None, None, 0.01, 0.2, method="hht", newton_tangent=tangent,
                                  newton_rtol=1e-11)
        formed[tangent] = len(count)
        assert runs[tangent].success, runs[tangent].message
    a, b = runs["iteration"].u, runs["reuse"].u
    assert np.abs(a - b).max() <= 1e-8 * np.abs(a).max()
    assert formed["reuse"] < 0.7 * formed["iteration"], formed


def test_a_dense_newton_matrix_is_solved_by_lapack_and_a_singular_one_refused():
    J = np.array([[4.0, 1.0], [1.0, 3.0]])
    s = StepSolver("auto")
    np.testing.assert_allclose(s.solve(J, np.array([1.0, 2.0])), np.linalg.solve(J, [1.0, 2.0]))
    assert s.name is None  # no sparse solver was set up for it
    np.testing.assert_allclose(StepSolver("auto").solve_cached("k", lambda: J, np.array([1.0, 2.0])),
                               np.linalg.solve(J, [1.0, 2.0]))
    with pytest.raises(LinearSolverError):
        StepSolver("auto").solve(np.ones((2, 2)), np.ones(2))


def test_an_unknown_newton_tangent_is_refused_naming_it():
    with pytest.raises(ValueError, match="newton_tangent.*'sometimes'"):
        newton_options("HHT", {"newton_tangent": "sometimes"})


def test_a_secant_update_meets_the_secant_condition_on_dense_factors_only():
    rng = np.random.default_rng(6)
    J = np.diag([2.0, 3.0, 5.0]) + 0.1 * rng.standard_normal((3, 3))
    s = StepSolver("auto")
    s.solve_cached("newton", lambda: J, np.ones(3))
    du, dr = rng.standard_normal(3), rng.standard_normal(3)
    assert s.dense and s.secant_update(du, dr)
    np.testing.assert_allclose(s.solve_cached("newton", lambda: J, dr), du, rtol=1e-12)  # J_new du = dr
    sparse = StepSolver("direct")
    sparse.solve_cached("newton", lambda: sp.csr_matrix(J), np.ones(3))
    assert not sparse.dense and not sparse.secant_update(du, dr)
