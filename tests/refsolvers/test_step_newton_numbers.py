"""The implicit schemes' per-step Newton loop by its numbers (issue 41): each iterate, residual and
count of :func:`newton` against a hand iteration of one scalar equation, ``r(u) = u + u^3 - 2``
(root 1, ``r' = 1 + 3 u^2``), written from the rules stated in the module's docstring (full
Newton; modified Newton with its refresh ratios 0.05 and, for a dense matrix with Broyden's
secant update, 0.2), and every tolerance and option at its boundary on both sides."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics.step_newton import (NewtonOptions, StepSolver, _dense_factor, newton,
                                                     newton_options, step_solver_name)
from tissuebench.refsolvers.linear_solvers import LinearSolverError


def r_of(u):
    return u + u ** 3 - 2.0


def dr_of(u):
    return 1.0 + 3.0 * u ** 2


def residual(u):
    return np.array([r_of(u[0])])


def sparse_jacobian(u):
    return sp.csr_matrix([[dr_of(u[0])]])


def dense_jacobian(u):
    return np.array([[dr_of(u[0])]])


def hand_newton(u, n):
    """(iterates, |r| of each) of n full Newton iterations from u."""
    us = [u]
    for _ in range(n):
        us.append(us[-1] - r_of(us[-1]) / dr_of(us[-1]))
    return us, [abs(r_of(x)) for x in us]


def hand_modified(u, tol, max_iter=25, kept=None, ratio=0.05, secant=False, utol=1e-12):
    """Modified Newton by the docstring's rules: (u, iterations, |r| history, converged).
    ``kept``: a matrix factorised before the call under the key "newton"."""
    r, norms, J = r_of(u), [abs(r_of(u))], kept
    refresh = kept is None
    for it in range(1, max_iter + 1):
        fresh = refresh
        if refresh:
            J = dr_of(u)
        du = -r / J
        r_new = r_of(u + du)
        if not fresh and not abs(r_new) < norms[-1]:
            refresh = True  # the iterate of a kept matrix that does not reduce |r| is discarded (it counts)
            continue
        u, dr, r = u + du, r_new - r, r_new
        norms.append(abs(r))
        if abs(r) <= tol or abs(du) <= utol * abs(u):
            return u, it, norms, True
        refresh = abs(r) > ratio * norms[-2]
        if not refresh and secant:
            J = dr / du  # Broyden's update of a 1 x 1 matrix is the secant
    return u, max_iter, norms, False


def opts(**kw):
    return NewtonOptions(**{"rtol": 1e-13, "tangent": "iteration", **kw})


# ---------------------------------------------------------------------------- full Newton
def test_full_newton_follows_the_hand_iterates():
    us, norms = hand_newton(0.8, 6)
    tol = 1e-10 * 2.0  # rtol * max(r_ref, |r(predictor)|): r_ref = 2 > |r0| = 0.688
    n = next(k for k, x in enumerate(norms) if x <= tol)
    u0 = np.array([0.8])
    u, rep = newton(u0, residual, sparse_jacobian, 2.0, opts(rtol=1e-10))
    assert rep.converged and rep.message == "" and rep.iterations == n == 4
    np.testing.assert_allclose(rep.residuals, norms[:n + 1], rtol=1e-9, atol=1e-300)
    assert u[0] == pytest.approx(us[n], rel=1e-15)
    assert u0[0] == 0.8  # the predictor is not changed in place


@pytest.mark.parametrize("k", [2, 3])
def test_absolute_tolerance_stops_at_the_first_residual_at_or_below_it(k):
    _, norms = hand_newton(0.8, 6)
    at = newton(np.array([0.8]), residual, sparse_jacobian, 0.0, opts(rtol=0.0, atol=norms[k], utol=0.0))[1]
    below = newton(np.array([0.8]), residual, sparse_jacobian, 0.0,
                   opts(rtol=0.0, atol=norms[k] * (1 - 1e-9), utol=0.0))[1]
    assert (at.iterations, below.iterations) == (k, k + 1)


def test_relative_tolerance_takes_the_larger_of_r_ref_and_the_predictors_residual():
    _, norms = hand_newton(0.8, 6)
    # r_ref = 100 dominates |r0| = 0.688: rtol * 100 = |r_2| stops at iteration 2
    assert newton(np.array([0.8]), residual, sparse_jacobian, 100.0,
                  opts(rtol=norms[2] * (1 + 1e-12) / 100.0, utol=0.0))[1].iterations == 2
    # r_ref = 0 (a load switched on from rest): the predictor's residual is the scale
    assert newton(np.array([0.8]), residual, sparse_jacobian, 0.0,
                  opts(rtol=norms[2] * (1 + 1e-12) / norms[0], utol=0.0))[1].iterations == 2
    # an absolute tolerance above the relative one wins
    assert newton(np.array([0.8]), residual, sparse_jacobian, 0.0,
                  opts(rtol=1e-30, atol=norms[1], utol=0.0))[1].iterations == 1


def test_a_predictor_within_tolerance_takes_no_iteration_on_both_sides_of_it():
    r0 = abs(r_of(0.8))
    u, rep = newton(np.array([0.8]), residual, sparse_jacobian, 0.0, opts(rtol=0.0, atol=r0, utol=0.0))
    assert rep.converged and rep.iterations == 0 and rep.residuals == [r0] and u[0] == 0.8
    rep = newton(np.array([0.8]), residual, sparse_jacobian, 0.0, opts(rtol=0.0, atol=r0 * (1 - 1e-12), utol=0.0))[1]
    assert rep.iterations == 1


def test_a_small_update_ends_the_iterations_on_both_sides_of_utol():
    us, _ = hand_newton(0.8, 6)
    k = 3
    ratio = abs(us[k] - us[k - 1]) / abs(us[k])
    assert newton(np.array([0.8]), residual, sparse_jacobian, 0.0, opts(rtol=1e-300, utol=ratio))[1].iterations == k
    assert newton(np.array([0.8]), residual, sparse_jacobian, 0.0,
                  opts(rtol=1e-300, utol=ratio * (1 - 1e-6)))[1].iterations == k + 1


def test_a_newton_that_does_not_converge_is_reported_with_its_numbers():
    _, norms = hand_newton(0.0, 2)
    u, rep = newton(np.array([0.0]), residual, sparse_jacobian, 1.0, opts(rtol=1e-12, max_iter=2))
    tol = 1e-12 * 2.0
    assert not rep.converged and rep.iterations == 2
    assert rep.message == (f"Newton did not converge in 2 iterations (||r|| = {norms[2]:.3e} N, "
                           f"tolerance {tol:.3e} N)")
    np.testing.assert_allclose(rep.residuals, norms, rtol=1e-12)


def test_a_non_finite_residual_and_a_singular_matrix_are_reported():
    def nan_after_start(u):
        return residual(u) if u[0] == 0.8 else np.array([np.nan])
    u, rep = newton(np.array([0.8]), nan_after_start, sparse_jacobian, 1.0, opts())
    assert (rep.converged, rep.iterations, rep.message) == (False, 1, "non-finite residual in Newton iteration 1")

    rep = newton(np.array([0.8]), residual, lambda u: sp.csr_matrix((1, 1)), 1.0, opts())[1]
    assert not rep.converged and rep.iterations == 1 and rep.message.startswith("singular Newton matrix: ")


def test_a_linear_step_is_one_solve_with_the_factors_kept_under_its_key():
    solver = StepSolver("direct")
    u, rep = newton(np.array([0.8]), residual, sparse_jacobian, 1.0, opts(), linear=True, solver=solver)
    assert rep.converged and rep.iterations == 1 and rep.residuals == [abs(r_of(0.8))]
    assert u[0] == pytest.approx(0.8 - r_of(0.8) / dr_of(0.8), rel=1e-15)
    assert solver.key == "linear"
    # the next linear step reuses the factors: a different Jacobian is not formed
    u2 = newton(np.array([0.5]), residual, lambda u: sp.csr_matrix([[99.0]]), 1.0, opts(), linear=True,
                solver=solver)[0]
    assert u2[0] == pytest.approx(0.5 - r_of(0.5) / dr_of(0.8), rel=1e-15)


# ---------------------------------------------------------------------------- modified Newton
@pytest.mark.parametrize("u0", [0.0, 0.8, 3.0])
def test_modified_newton_follows_the_hand_rules(u0):
    tol = 1e-13 * max(1.0, abs(r_of(u0)))
    u_h, it_h, norms_h, ok = hand_modified(u0, tol)
    u, rep = newton(np.array([u0]), residual, sparse_jacobian, 1.0, opts(tangent="reuse"))
    assert ok and rep.converged and rep.iterations == it_h
    np.testing.assert_allclose(rep.residuals, norms_h, rtol=1e-8, atol=1e-15)
    assert u[0] == pytest.approx(u_h, rel=1e-14)


def test_a_kept_matrix_that_does_not_reduce_the_residual_costs_an_iteration():
    solver = StepSolver("direct")
    solver.solve_cached("newton", lambda: sp.csr_matrix([[-1.0]]), np.ones(1))
    tol = 1e-13
    u_h, it_h, norms_h, _ = hand_modified(0.8, tol, kept=-1.0)
    u, rep = newton(np.array([0.8]), residual, sparse_jacobian, 1.0, opts(tangent="reuse"), solver=solver)
    assert rep.converged and rep.iterations == it_h and len(rep.residuals) == it_h  # one discarded
    np.testing.assert_allclose(rep.residuals, norms_h, rtol=1e-8, atol=1e-15)
    # factors kept under another key are not the Newton matrix's: formed fresh, nothing discarded
    solver = StepSolver("direct")
    solver.solve_cached("linear", lambda: sp.csr_matrix([[-1.0]]), np.ones(1))
    rep = newton(np.array([0.8]), residual, sparse_jacobian, 1.0, opts(tangent="reuse"), solver=solver)[1]
    assert rep.iterations == hand_modified(0.8, tol)[1] == len(rep.residuals) - 1


def test_a_kept_dense_matrix_follows_the_iterates_by_secant_updates():
    for u0 in (0.3, 1.2, 1.5, 3.0):
        tol = 1e-13 * max(1.0, abs(r_of(u0)))
        u_h, it_h, norms_h, ok = hand_modified(u0, tol, ratio=0.2, secant=True)
        u, rep = newton(np.array([u0]), residual, dense_jacobian, 1.0, opts(tangent="reuse"))
        assert ok and rep.converged and rep.iterations == it_h, (u0, rep.iterations, it_h)
        np.testing.assert_allclose(rep.residuals, norms_h, rtol=1e-6, atol=1e-15)
        # without the secant updates, at either refresh ratio, the count differs
        assert it_h not in (hand_modified(u0, tol, ratio=0.05)[1], hand_modified(u0, tol, ratio=0.2)[1])


def test_modified_newton_reports_its_failures():
    u, rep = newton(np.array([0.0]), residual, sparse_jacobian, 1.0, opts(tangent="reuse", max_iter=2))
    _, _, norms, _ = hand_modified(0.0, 2e-13, max_iter=2)
    assert not rep.converged and rep.iterations == 2
    assert rep.message == (f"modified Newton did not converge in 2 iterations (||r|| = {norms[-1]:.3e} N, "
                           f"tolerance {2e-13:.3e} N)")
    rep = newton(np.array([0.8]), residual, lambda u: sp.csr_matrix((1, 1)), 1.0, opts(tangent="reuse"))[1]
    assert not rep.converged and rep.iterations == 1 and rep.message.startswith("singular Newton matrix: ")
    rep = newton(np.array([0.8]), lambda u: residual(u) if u[0] == 0.8 else np.array([np.inf]),
                 sparse_jacobian, 1.0, opts(tangent="reuse"))[1]
    assert (rep.converged, rep.iterations, rep.message) == (False, 1, "non-finite residual in Newton iteration 1")


def test_modified_newton_stops_on_a_small_update_and_keeps_the_input():
    us, _ = hand_newton(0.8, 1)
    ratio = abs(us[1] - us[0]) / abs(us[1])
    u0 = np.array([0.8])
    u, rep = newton(u0, residual, sparse_jacobian, 0.0, opts(tangent="reuse", rtol=1e-300, utol=ratio))
    assert rep.converged and rep.iterations == 1 and u[0] == pytest.approx(us[1], rel=1e-15) and u0[0] == 0.8
    rep = newton(u0, residual, sparse_jacobian, 0.0, opts(tangent="reuse", rtol=1e-300, utol=ratio * (1 - 1e-9)))[1]
    assert rep.iterations > 1


# ---------------------------------------------------------------------------- options and solvers
@pytest.mark.parametrize("field, value, message", [
    ("rtol", -1e-300, "newton rtol must be finite and >= 0, got -1e-300"),
    ("atol", float("nan"), "newton atol must be finite and >= 0, got nan"),
    ("utol", float("inf"), "newton utol must be finite and >= 0, got inf"),
    ("max_iter", 0, "newton max_iter must be an integer >= 1, got 0"),
    ("max_iter", 2.5, "newton max_iter must be an integer >= 1, got 2.5"),
    ("linear_solver", "lu", "linear_solver must be one of ['auto', 'direct', 'cholesky'], got 'lu'"),
    ("tangent", "never", "newton_tangent must be one of ['auto', 'iteration', 'reuse'], got 'never'"),
])
def test_newton_options_refuse_values_naming_them(field, value, message):
    with pytest.raises(ValueError) as err:
        NewtonOptions(**{field: value})
    assert str(err.value) == message


def test_newton_options_accept_their_boundaries():
    o = NewtonOptions(rtol=0.0, atol=0.0, utol=1e-300, max_iter=1)
    assert (o.rtol, o.atol, o.utol, o.max_iter) == (0.0, 0.0, 1e-300, 1)
    assert NewtonOptions(rtol=0.0, atol=1e-9, utol=0.0).atol == 1e-9
    assert NewtonOptions(rtol=1e-9, atol=0.0, utol=0.0).rtol == 1e-9
    with pytest.raises(ValueError, match=r"^newton tolerances: rtol, atol and utol are all 0$"):
        NewtonOptions(rtol=0.0, atol=0.0, utol=0.0)
    assert NewtonOptions() == NewtonOptions(1e-10, 0.0, 1e-12, 25, "auto", "auto")


def test_newton_options_from_keywords():
    o = newton_options("HHT", {"newton_rtol": 1e-6, "newton_atol": 2.0, "newton_utol": 3e-9, "newton_max_iter": 7,
                               "newton_tangent": "reuse", "linear_solver": "cholesky"})
    assert o == NewtonOptions(1e-6, 2.0, 3e-9, 7, "cholesky", "reuse")
    assert newton_options("Bathe", {}) == NewtonOptions()
    with pytest.raises(ValueError) as err:
        newton_options("Bathe", {"newton_maxiter": 3, "alpha": 1})
    assert str(err.value) == ("Bathe: unknown option(s) ['alpha', 'newton_maxiter']; valid Newton options: "
                              "['newton_rtol', 'newton_atol', 'newton_utol', 'newton_max_iter', 'newton_tangent', "
                              "'newton_iterations', 'linear_solver']")


def test_step_solver_names():
    assert step_solver_name("cholesky", 1) == "cholesky" and step_solver_name("direct", 10 ** 7) == "direct"
    s = StepSolver("direct")
    assert (s.choice, s.name, s.key, s.has_factors, s.dense) == ("direct", None, None, False, False)
    np.testing.assert_allclose(s.solve(sp.csr_matrix([[4.0, 1.0], [1.0, 3.0]]), np.array([1.0, 2.0])),
                               np.linalg.solve([[4.0, 1.0], [1.0, 3.0]], [1.0, 2.0]), rtol=1e-14)
    assert s.name == "direct"


def test_a_dense_matrix_is_refused_from_a_pivot_ratio_of_1e_14_on():
    with pytest.raises(LinearSolverError, match="dense LU: singular matrix"):
        _dense_factor(np.diag([1.0, 1e-14]))
    np.testing.assert_allclose(_dense_factor(np.diag([1.0, 2e-14]))(np.array([1.0, 1.0])), [1.0, 5e13], rtol=1e-14)
    with pytest.raises(LinearSolverError):
        _dense_factor(np.array([[np.inf, 0.0], [0.0, 1.0]]))
    with pytest.raises(LinearSolverError):
        _dense_factor(np.zeros((2, 2)))


def test_kept_factors_switch_between_dense_and_sparse_and_are_forgotten_on_refresh():
    s = StepSolver("direct")
    A = np.array([[4.0, 1.0], [1.0, 3.0]])
    b = np.array([1.0, 2.0])
    np.testing.assert_allclose(s.solve_cached("a", lambda: A, b), np.linalg.solve(A, b), rtol=1e-14)
    assert s.dense and s.has_factors and s.key == "a"
    np.testing.assert_allclose(s.solve_cached("b", lambda: sp.csr_matrix(2 * A), b), np.linalg.solve(2 * A, b),
                               rtol=1e-14)
    assert not s.dense and s.key == "b" and s.name == "direct"
    s.refresh()
    assert (s.has_factors, s.key, s.dense) == (False, None, False)
    c = StepSolver("cholesky")
    np.testing.assert_allclose(c.solve_cached("k", lambda: sp.csr_matrix(A), b), np.linalg.solve(A, b), rtol=1e-12)
    assert c.name == "cholesky"


def test_broydens_update_is_the_rank_one_formula():
    J = np.array([[4.0, 1.0], [0.5, 3.0]])
    du, dr = np.array([0.3, -0.2]), np.array([1.0, 0.7])
    s = StepSolver("auto")
    s.solve_cached("newton", lambda: J, np.ones(2))
    assert s.secant_update(du, dr) is True
    expected = J + np.outer(dr - J @ du, du) / (du @ du)
    b = np.array([0.4, -1.3])
    np.testing.assert_allclose(s.solve_cached("newton", lambda: J, b), np.linalg.solve(expected, b), rtol=1e-13)
    assert s.secant_update(np.zeros(2), dr) is False


def _exact_update_ratio():
    """(u0, utol) with utol * |u1| == |du| exactly in floating point for Newton's first update from u0."""
    for u0 in np.linspace(0.5, 1.5, 101):
        du = -r_of(u0) / dr_of(u0)
        u1 = u0 + du
        ratio = abs(du) / abs(u1)
        if ratio * abs(u1) == abs(du) and abs(du) > 1e-3:
            return float(u0), ratio
    raise AssertionError("no start with an exact update ratio")


@pytest.mark.parametrize("tangent", ["iteration", "reuse"])
def test_an_update_exactly_at_utol_ends_the_iterations(tangent):
    u0, ratio = _exact_update_ratio()
    rep = newton(np.array([u0]), residual, sparse_jacobian, 0.0, opts(tangent=tangent, rtol=1e-300, utol=ratio))[1]
    assert rep.converged is True and rep.iterations == 1 and rep.message == ""


def test_a_small_update_counts_relative_to_a_small_solution_without_a_floor_of_one():
    b = 2e-3  # root near 2e-3: |u| < 1

    def res(u):
        return u + u ** 3 - b
    du1 = -res(0.0)  # the first update from 0 (r' = 1)
    u, rep = newton(np.array([0.0]), res, lambda u: sp.csr_matrix([[1.0 + 3.0 * u[0] ** 2]]), 0.0,
                    opts(rtol=1e-300, utol=1.0))
    assert rep.converged and rep.iterations == 1 and u[0] == du1  # |du| <= 1.0 * |u|
    for tangent in ("iteration", "reuse"):
        rep = newton(np.array([0.0]), res, lambda u: sp.csr_matrix([[1.0 + 3.0 * u[0] ** 2]]), 0.0,
                     opts(tangent=tangent, rtol=1e-300, utol=0.5))[1]
        assert rep.iterations > 1  # |du| = |u| after the first update: 0.5 |u| does not end it


@pytest.mark.parametrize("k", [1, 2])
def test_modified_newton_absolute_tolerance_at_a_residual(k):
    _, _, norms, _ = hand_modified(0.8, 0.0, max_iter=6)
    at = newton(np.array([0.8]), residual, sparse_jacobian, 0.0, opts(tangent="reuse", rtol=0.0, atol=norms[k],
                                                                      utol=0.0))[1]
    assert at.converged is True and at.iterations == k and at.message == "" and at.residuals == norms[:k + 1]


def test_failures_keep_their_residual_history_and_say_false():
    def bad_second(u):
        return residual(u) if u[0] > 1.01 or u[0] == 0.8 else np.array([np.nan])
    for tangent in ("iteration", "reuse"):
        u, rep = newton(np.array([0.8]), residual, lambda u: sp.csr_matrix((1, 1)), 1.0, opts(tangent=tangent))
        assert rep.converged is False and rep.residuals == [abs(r_of(0.8))]
        u, rep = newton(np.array([0.0]), residual, sparse_jacobian, 1.0, opts(tangent=tangent, max_iter=1))
        assert rep.converged is False and len(rep.residuals) == 2 and rep.residuals[0] == 2.0
    # the second iterate's residual is NaN: the check reads the latest residual, not the first one's
    u, rep = newton(np.array([0.8]), bad_second, sparse_jacobian, 1.0, opts())
    assert (rep.converged, rep.iterations) == (False, 2) and rep.message == "non-finite residual in Newton iteration 2"
    assert len(rep.residuals) == 3 and np.isnan(rep.residuals[-1])
    u, rep = newton(np.array([0.8]), lambda u: residual(u) if u[0] == 0.8 else np.array([np.nan]), sparse_jacobian,
                    1.0, opts(tangent="reuse"))
    assert rep.converged is False and rep.residuals == [abs(r_of(0.8))]


def test_success_messages_are_empty():
    r0 = abs(r_of(0.8))
    assert newton(np.array([0.8]), residual, sparse_jacobian, 0.0, opts(rtol=0.0, atol=r0))[1].message == ""
    assert newton(np.array([0.8]), residual, sparse_jacobian, 1.0, opts(), linear=True)[1].message == ""
    assert newton(np.array([0.8]), residual, sparse_jacobian, 1.0, opts(tangent="reuse"))[1].message == ""


def test_factors_kept_under_another_key_are_not_trusted_as_the_newton_matrix():
    # from 0 the first Newton update raises |r| (2 -> 8): taken as a kept matrix's it would be discarded
    solver = StepSolver("direct")
    solver.solve_cached("linear", lambda: sp.csr_matrix([[1.0]]), np.ones(1))
    rep = newton(np.array([0.0]), residual, sparse_jacobian, 1.0, opts(tangent="reuse"), solver=solver)[1]
    assert rep.iterations == hand_modified(0.0, 2e-13)[1] and rep.residuals[1] == 8.0


def test_a_kept_matrix_that_leaves_the_residual_equal_is_discarded():
    def res(u):  # from 2 with the kept slope 3/4 the update lands on -2, where |r| is equal (3)
        return np.array([u[0] ** 2 - 1.0])
    solver = StepSolver("direct")
    solver.solve_cached("newton", lambda: sp.csr_matrix([[0.75]]), np.ones(1))
    u, rep = newton(np.array([2.0]), res, lambda u: sp.csr_matrix([[2.0 * u[0]]]), 1.0, opts(tangent="reuse"),
                    solver=solver)
    assert rep.converged and u[0] == pytest.approx(1.0, rel=1e-12) and 3.0 not in rep.residuals[1:]


def test_dense_pivot_checks_by_their_numbers():
    with pytest.raises(LinearSolverError, match=r"^dense LU: singular matrix$"):
        _dense_factor(np.array([[np.nan, 0.0], [0.0, 1.0]]))
    with pytest.raises(LinearSolverError, match=r"^dense LU: singular matrix$"):
        _dense_factor(np.diag([4.0, 3e-14]))                       # 3e-14 <= 1e-14 * 4
    np.testing.assert_allclose(_dense_factor(np.diag([1e-3, 5e-17]))(np.array([1e-3, 5e-17])), [1.0, 1.0])
    np.testing.assert_allclose(_dense_factor(np.array([[2, 1], [1, 3]]))(np.array([3.0, 4.0])), [1.0, 1.0])


def test_the_step_solver_takes_ngsolve_for_cholesky():
    from tissuebench.refsolvers.linear_solvers import DirectSolver, NgsolveSparseSolver
    assert StepSolver().choice == "auto"
    for choice, kind in (("cholesky", NgsolveSparseSolver), ("direct", DirectSolver)):
        s = StepSolver(choice)
        s.solve(sp.csr_matrix(np.diag([2.0, 4.0])), np.ones(2))
        assert isinstance(s._solver, kind)


# ---------------------------------------------------------------------------- scaled norms, round-off floor (issue 54)
TINY = 2.0 ** -664   # 1.0e-200: its square underflows (np.linalg.norm([TINY]) == 0.0)


def test_scaled_norm_by_hand():
    from tissuebench.refsolvers.newton import scaled_norm

    assert np.linalg.norm([3 * TINY, 4 * TINY]) == 0.0 and scaled_norm([3 * TINY, 4 * TINY]) == 5 * TINY
    assert scaled_norm([3e200, -4e200]) == pytest.approx(5e200, rel=1e-15)     # np.linalg.norm: inf
    assert scaled_norm([3.0, 4.0]) == 5.0 and scaled_norm(np.array([[3.0], [-4.0]])) == 5.0
    assert scaled_norm([0.0, 0.0]) == 0.0 and scaled_norm([]) == 0.0
    assert scaled_norm([1.0, np.inf]) == np.inf and np.isnan(scaled_norm([1.0, np.nan]))
    assert scaled_norm([5e-324]) == 5e-324                                   # the smallest subnormal


def linear_residual(f):
    return lambda u: np.array([4.0 * u[0] - f])


def linear_jacobian(u):
    return sp.csr_matrix([[4.0]])


@pytest.mark.parametrize("f", [2.0 ** -400, TINY])
def test_a_residual_below_1e_154_n_is_iterated_like_any_other(f):
    """Both sides of the underflow of ||r||^2 (~1e-154 N): 1e-120 N and 1e-200 N are solved by one Newton
    iteration (u = f / 4, exact in binary). a24e7fa: ||r(0)|| = 0 for 1e-200 N, "converged" in 0 iterations
    at u = 0."""
    u, rep = newton(np.array([0.0]), linear_residual(f), linear_jacobian, f, opts(rtol=1e-10))
    assert rep.converged and rep.iterations == 1 and rep.residuals == [f, 0.0] and u[0] == f / 4


FLOOR = 1e-12


def test_a_step_whose_forces_are_all_below_the_floor_fails_at_once_saying_so():
    # r_ref = 5e-13 and ||r(0)|| = 4e-13 are both under the floor 1e-12: no iteration, said
    u, rep = newton(np.array([0.0]), linear_residual(4e-13), linear_jacobian, 5e-13, opts(), floor=FLOOR)
    assert not rep.converged and rep.iterations == 0 and rep.residuals == [4e-13] and u[0] == 0.0
    assert rep.message == ("the step's forces are below round-off: the largest, 5.000e-13 N, is under the round-off "
                           "floor 1.000e-12 N of the internal force (machine epsilon x the force of a unit strain of "
                           "the body), so the strains they cause are below double precision: a load far too small "
                           "for the body's stiffness (is its length or load unit right?)")
    # at the floor itself: refused; a force scale just above it: a step like any other, the floor its tolerance:
    # a residual under the floor is converged as it is (the predictor is as good as round-off allows), one
    # just above it takes an iteration
    assert not newton(np.array([0.0]), linear_residual(4e-13), linear_jacobian, FLOOR, opts(), floor=FLOOR)[1].converged
    u, rep = newton(np.array([0.0]), linear_residual(4e-13), linear_jacobian, FLOOR * (1 + 1e-12), opts(), floor=FLOOR)
    assert rep.converged and rep.iterations == 0 and u[0] == 0.0
    f = FLOOR * (1 + 1e-12)
    u, rep = newton(np.array([0.0]), linear_residual(f), linear_jacobian, 0.0, opts(), floor=FLOOR)
    assert rep.converged and rep.iterations == 1 and u[0] == f / 4
    # nothing to do (a system at rest): no residual, no failure
    u, rep = newton(np.array([0.0]), linear_residual(0.0), linear_jacobian, 1e-300, opts(), floor=FLOOR)
    assert rep.converged and rep.iterations == 0 and rep.message == ""


def test_the_floor_is_the_tolerance_when_above_rtol_times_the_scale():
    # r = u + u^3 - 2 from 0.8: |r_k| of the hand iterates; a floor between |r_2| and |r_1| stops at iteration 2,
    # where rtol * 2 (2e-13) alone takes 4; a floor below rtol * 2 changes nothing
    _, norms = hand_newton(0.8, 6)
    floor = 0.5 * (norms[1] + norms[2])
    assert newton(np.array([0.8]), residual, sparse_jacobian, 2.0, opts(utol=0.0), floor=floor)[1].iterations == 2
    assert newton(np.array([0.8]), residual, sparse_jacobian, 2.0, opts(utol=0.0),
                  floor=norms[2] * (1 - 1e-9))[1].iterations == 3
    assert newton(np.array([0.8]), residual, sparse_jacobian, 2.0, opts(utol=0.0), floor=1e-14)[1].iterations == \
        newton(np.array([0.8]), residual, sparse_jacobian, 2.0, opts(utol=0.0))[1].iterations
    # modified Newton as well
    _, it, _, ok = hand_modified(0.8, floor, utol=0.0)
    rep = newton(np.array([0.8]), residual, sparse_jacobian, 2.0, opts(utol=0.0, tangent="reuse"), floor=floor)[1]
    assert ok and rep.converged and rep.iterations == it


@pytest.mark.parametrize("tangent, what", [("iteration", "Newton"), ("reuse", "modified Newton")])
def test_a_failure_names_the_floor_when_there_is_one(tangent, what):
    u, rep = newton(np.array([0.0]), residual, sparse_jacobian, 2.0, opts(max_iter=1, tangent=tangent), floor=1e-15)
    r1 = abs(r_of(2.0))  # one full Newton step from 0: u = 2
    assert rep.message == (f"{what} did not converge in 1 iterations (||r|| = {r1:.3e} N, tolerance 2.000e-13 N, "
                           "round-off floor 1.000e-15 N)")
    rep = newton(np.array([0.0]), residual, sparse_jacobian, 2.0, opts(max_iter=1, tangent=tangent))[1]
    assert rep.message.endswith("tolerance 2.000e-13 N)")


def test_a_run_whose_forces_were_resolved_is_converged_at_the_floor_not_refused():
    """The other side of the refusal: the same step (r_ref 5e-13, ||r(0)|| 4e-13 under the floor) after a run whose
    forces exceeded the floor (a motion decayed below round-off) is converged as it is."""
    u, rep = newton(np.array([0.0]), linear_residual(4e-13), linear_jacobian, 5e-13, opts(), floor=FLOOR,
                    peak=FLOOR * (1 + 1e-12))
    assert rep.converged and rep.iterations == 0 and u[0] == 0.0
    assert not newton(np.array([0.0]), linear_residual(4e-13), linear_jacobian, 5e-13, opts(), floor=FLOOR,
                      peak=FLOOR)[1].converged


# ------------------------------------------------------------ a fixed Newton budget (issue 52)
@pytest.mark.parametrize("tangent", ["iteration", "reuse"])
@pytest.mark.parametrize("k, within", [(1, False), (2, False), (12, True)])
def test_a_fixed_budget_does_exactly_k_iterations_and_says_when_the_residual_is_above_tolerance(tangent, k, within):
    """``iterations = k``: k iterations whatever the residual (a converged step does not stop
    early: its cost is the budget's), the state advanced, and ``within_tolerance`` on both sides."""
    calls = []

    def counted(u):
        calls.append(u[0])
        return residual(u)

    opts = NewtonOptions(rtol=1e-10, tangent=tangent, iterations=k)
    u, rep = newton(np.array([0.0]), counted, sparse_jacobian, 2.0, opts)
    assert rep.converged and rep.iterations == k and len(calls) == k + 1  # the predictor's residual and one a step
    assert rep.within_tolerance is within and (rep.message == "") is within
    if not within:
        assert f"fixed budget of {k} Newton iterations" in rep.message and "above the tolerance" in rep.message
    if tangent == "iteration":
        assert u[0] == pytest.approx(hand_newton(0.0, k)[0][-1], rel=1e-14)
    free = newton(np.array([0.0]), residual, sparse_jacobian, 2.0, NewtonOptions(rtol=1e-10, tangent=tangent))[1]
    assert free.iterations < 12  # without the budget it stops at the tolerance


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "3"])
def test_a_fixed_budget_must_be_a_positive_integer(bad):
    with pytest.raises(ValueError, match="newton_iterations"):
        newton_options("HHT", {"newton_iterations": bad})
    assert newton_options("HHT", {"newton_iterations": 3}).iterations == 3
