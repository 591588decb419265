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
from tissuebench.refsolvers.dynamics.step_newton import (NGSOLVE_MIN_DOFS, StepSolver, newton_options,
                                                     step_solver_name)
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


@pytest.mark.parametrize("method", ["hht", "bathe", "backward_euler"])
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
