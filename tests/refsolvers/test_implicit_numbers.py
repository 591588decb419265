"""The implicit schemes by their numbers where the one-dof recursions of test_integrator_updates.py do
not reach (issue 41): a prescribed motion of a fixed dof entering the free row through the coupled
mass, damping and stiffness; each Newton iterate of a nonlinear spring; the failure messages; and a
new system or step invalidating the kept factorisation.

The recursions are written from the schemes' papers (Newmark 1959; Hilber, Hughes, Taylor 1977;
Bathe 2007) with the fixed dof moved by the scheme's own kinematics, as the module docstring of
``tissuebench.refsolvers.dynamics.system`` states, and solved by hand for the one free unknown.
"""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import SecondOrderSystem
from tissuebench.refsolvers.dynamics.implicit import HHT, Bathe, BackwardEuler, Newmark, NewmarkFamily

# dof 0 free, dof 1 follows g(t); consistent mass couples them
MM = np.array([[2.0, 0.5], [0.5, 1.0]])
KK = np.array([[60.0, -20.0], [-20.0, 30.0]])
A_M, B_K, DT, STEPS = 0.3, 0.004, 0.05, 3
U0, V0 = 0.1, -0.2
m, mfc, k, kfc = 2.0, 0.5, 60.0, -20.0
c, cfc = A_M * m + B_K * k, A_M * mfc + B_K * kfc


def g(t):
    return 0.05 + 0.01 * t + 0.2 * t * t


def f(t):
    return 3.0 + 4.0 * t


def _system(**kw):
    return SecondOrderSystem.linear_system(MM, KK, lambda t: np.array([f(t), 7.0]), free=[0], alpha_m=A_M,
                                           beta_k=B_K, prescribed=lambda t: np.array([g(t)]), **kw)


def _start(integ):
    return integ.start(_system(), np.array([U0, g(0.0)]), np.array([V0, 0.01]), DT)


def _a0():
    # the fixed dof starts with g's velocity 0.01 and zero acceleration
    return (f(0.0) - k * U0 - kfc * g(0.0) - c * V0 - cfc * 0.01) / m


def newmark_hht(alpha, beta, gamma):
    u, v, a, uc, vc, ac, t, out = U0, V0, _a0(), g(0.0), 0.01, 0.0, 0.0, []
    for _ in range(STEPS):
        t1 = t + DT
        uc1 = g(t1)
        ac1 = (uc1 - uc - DT * vc) / (beta * DT * DT) - (0.5 / beta - 1.0) * ac
        vc1 = vc + DT * ((1 - gamma) * ac + gamma * ac1)
        u_star = u + DT * v + DT * DT * (0.5 - beta) * a
        v_star = v + DT * (1 - gamma) * a
        old = c * v + cfc * vc + k * u + kfc * uc - f(t)
        a1 = (alpha * old - mfc * ac1 - (1 + alpha) * (c * v_star + cfc * vc1 + k * u_star + kfc * uc1 - f(t1))) / (
            m + (1 + alpha) * (c * gamma * DT + k * beta * DT * DT))
        u, v, a = u_star + beta * DT * DT * a1, v_star + gamma * DT * a1, a1
        uc, vc, ac, t = uc1, vc1, ac1, t1
        out.append((u, v, a, uc, vc, ac))
    return out


def backward_euler():
    u, v, uc, vc, t, out = U0, V0, g(0.0), 0.01, 0.0, []
    for _ in range(STEPS):
        t += DT
        uc1 = g(t)
        vc1 = (uc1 - uc) / DT
        ac1 = (vc1 - vc) / DT
        u1 = (f(t) - mfc * ac1 - cfc * vc1 - kfc * uc1 + m * (u / DT ** 2 + v / DT) + c * u / DT) / (
            m / DT ** 2 + c / DT + k)
        v1 = (u1 - u) / DT
        out.append((u1, v1, (v1 - v) / DT, uc1, vc1, ac1))
        u, v, uc, vc = u1, v1, uc1, vc1
    return out


def bathe():
    u, v, a, uc, vc, ac, t, out, h = U0, V0, _a0(), g(0.0), 0.01, 0.0, 0.0, [], DT / 2
    for _ in range(STEPS):
        # trapezoidal rule over [t, t + h] on both dofs
        uch = g(t + h)
        vch = 2 / h * (uch - uc) - vc
        ach = 2 / h * (vch - vc) - ac
        uh = (f(t + h) - mfc * ach - cfc * vch - kfc * uch + m * (4 / h ** 2 * u + 4 / h * v + a)
              + c * (2 / h * u + v)) / (4 * m / h ** 2 + 2 * c / h + k)
        vh = 2 / h * (uh - u) - v
        # 3-point backward Euler over [t, t + dt]
        uc1 = g(t + DT)
        vc1 = (uc - 4 * uch + 3 * uc1) / DT
        ac1 = (vc - 4 * vch + 3 * vc1) / DT
        r, s = (u - 4 * uh) / DT, (v - 4 * vh) / DT
        u1 = (f(t + DT) - mfc * ac1 - cfc * vc1 - kfc * uc1 - m * (3 * r / DT + s) - c * r) / (
            9 * m / DT ** 2 + 3 * c / DT + k)
        v1 = 3 * u1 / DT + r
        u, v, a, uc, vc, ac, t = u1, v1, 3 * v1 / DT + s, uc1, vc1, ac1, t + DT
        out.append((u, v, a, uc, vc, ac))
    return out


def _steps(integ):
    out = []
    for _ in range(STEPS):
        rep = integ.step()
        assert rep.converged and rep.iterations == (2 if isinstance(integ, Bathe) else 1), rep
        # the forces kept as the state are those at the step's solution, not at its predictor
        assert integ.f_ext[0] == pytest.approx(f(integ.t), rel=1e-14)
        assert integ.f_int[0] == pytest.approx(k * integ.u[0] + kfc * integ.uc[0], rel=1e-12)
        out.append((integ.u[0], integ.v[0], integ.a[0], integ.uc[0], integ.vc[0], integ.ac[0]))
    return np.array(out)


@pytest.mark.parametrize("make, expected", [
    (lambda: Newmark(), lambda: newmark_hht(0.0, 0.25, 0.5)),
    (lambda: Newmark(beta=0.3, gamma=0.6), lambda: newmark_hht(0.0, 0.3, 0.6)),
    (lambda: HHT(alpha=-0.1), lambda: newmark_hht(-0.1, 1.1 ** 2 / 4, 0.6)),
    (lambda: BackwardEuler(), backward_euler),
    (lambda: Bathe(), bathe),
], ids=["newmark", "newmark(0.3,0.6)", "hht", "backward_euler", "bathe"])
def test_a_prescribed_motion_enters_the_free_row_by_hand(make, expected):
    integ = _start(make())
    assert integ.a[0] == pytest.approx(_a0(), rel=1e-14)
    np.testing.assert_allclose(_steps(integ), np.array(expected()), rtol=1e-11, atol=1e-13)
    assert integ.t == pytest.approx(STEPS * DT, rel=1e-14)


# ---------------------------------------------------------------------------- a nonlinear spring
K3, F0 = 4000.0, 400.0


def _spring():
    return SecondOrderSystem(M=np.array([[m]]), internal_force=lambda u: k * u + K3 * u ** 3,
                             tangent=lambda u: np.array([[k + 3 * K3 * u[0] ** 2]]),
                             load=lambda t: np.array([F0 * min(t / DT, 1.0)]), alpha_m=A_M, beta_k=B_K)


def _fint(u):
    return k * u + K3 * u ** 3


def _hand_newmark_step(alpha, beta, gamma, u, v, a, t, rtol):
    """One step's Newton on the HHT residual: (u1, v1, a1, |r| history)."""
    cc = A_M * m + B_K * k  # Rayleigh damping with the tangent at u = 0

    def kin(x):
        a1 = (x - u - DT * v) / (beta * DT * DT) - (0.5 / beta - 1.0) * a
        return v + DT * ((1 - gamma) * a + gamma * a1), a1

    def res(x):
        v1, a1 = kin(x)
        return m * a1 + (1 + alpha) * (cc * v1 + _fint(x) - F0 * min((t + DT) / DT, 1.0)) \
            - alpha * (cc * v + _fint(u) - F0 * min(t / DT, 1.0))

    x = u + DT * v + 0.5 * DT * DT * a
    norms = [abs(res(x))]
    r_ref = max(abs(F0 * min(t / DT, 1.0)), abs(_fint(u)), abs(m * a))
    tol = rtol * max(r_ref, norms[0])
    while norms[-1] > tol:
        x -= res(x) / (m / (beta * DT * DT) + (1 + alpha) * (cc * gamma / (beta * DT) + k + 3 * K3 * x * x))
        norms.append(abs(res(x)))
        assert len(norms) < 30, norms
    return (x, *kin(x), norms)


@pytest.mark.parametrize("make, params", [(lambda: HHT(alpha=-0.2, newton_rtol=1e-12), (-0.2, 1.44 / 4, 0.7)),
                                          (lambda: Newmark(newton_rtol=1e-12), (0.0, 0.25, 0.5))])
def test_each_newton_iterate_of_a_nonlinear_step_by_hand(make, params):
    integ = make().start(_spring(), np.array([0.0]), np.array([0.0]), DT)
    u, v, a, t = 0.0, 0.0, 0.0, 0.0
    for _ in range(3):
        u, v, a, norms = _hand_newmark_step(*params, u, v, a, t, 1e-12)
        rep = integ.step()
        t += DT
        assert rep.converged and rep.iterations == len(norms) - 1 >= 3
        np.testing.assert_allclose(rep.residuals[:3], norms[:3], rtol=1e-9)
        np.testing.assert_allclose((integ.u[0], integ.v[0], integ.a[0]), (u, v, a), rtol=1e-10)
        assert integ.f_int[0] == pytest.approx(_fint(u), rel=1e-12)
        assert integ.f_ext[0] == pytest.approx(F0 * min(t / DT, 1.0), rel=1e-14)


def test_bathe_counts_both_sub_steps_iterations():
    integ = Bathe(newton_rtol=1e-12).start(_spring(), np.array([0.0]), np.array([0.0]), DT)
    rep = integ.step()
    assert rep.converged and rep.message == ""
    # both sub-steps iterate from their own predictors: two histories, each ending within tolerance
    starts = [i for i in range(1, len(rep.residuals)) if rep.residuals[i] > rep.residuals[i - 1]]
    assert len(starts) == 1 and rep.iterations == len(rep.residuals) - 2
    assert rep.residuals[starts[0] - 1] <= 1e-12 * F0 and rep.residuals[-1] <= 1e-12 * F0
    assert integ.f_ext[0] == F0 and integ.f_int[0] == pytest.approx(_fint(integ.u[0]), rel=1e-12)
    m_a = m * integ.a[0] + (A_M * m + B_K * k) * integ.v[0] + integ.f_int[0] - integ.f_ext[0]
    assert abs(m_a) <= 1e-9 * F0  # the equation of motion holds at t + dt


def test_failures_say_when_and_which_sub_step():
    integ = HHT(newton_max_iter=1, newton_rtol=1e-14).start(_spring(), np.array([0.0]), np.array([0.0]), DT)
    rep = integ.step()
    assert not rep.converged and rep.message.startswith("t=0.05: Newton did not converge in 1 iterations")
    assert integ.t == 0.0 and integ.u[0] == 0.0  # the state is not advanced
    integ = Bathe(newton_max_iter=1, newton_rtol=1e-14).start(_spring(), np.array([0.0]), np.array([0.0]), DT)
    rep = integ.step()
    assert rep.message.startswith("t=0.025 (first sub-step): Newton did not converge in 1 iterations")

    # at rest and unloaded over the first half step, loaded over the second
    system = _spring()
    system.load = lambda t: np.array([0.0 if t <= 0.5 * DT + 1e-15 else F0])
    integ = Bathe(newton_max_iter=1, newton_rtol=1e-14).start(system, np.array([0.0]), np.array([0.0]), DT)
    rep = integ.step()
    assert not rep.converged and rep.iterations == 1
    assert rep.message.startswith("t=0.05 (second sub-step): Newton did not converge in 1 iterations")
    assert integ.t == 0.0


@pytest.mark.parametrize("make", [Newmark, HHT, BackwardEuler, Bathe])
def test_a_new_system_or_step_forgets_the_kept_factorisation(make):
    def one(K, dt):
        return SecondOrderSystem.linear_system(np.array([[m]]), np.array([[K]]), np.array([F0]))

    integ = make()
    integ.start(one(k, DT), None, None, DT).step()
    for K, dt in ((4 * k, DT), (k, 2 * DT)):
        integ.start(one(K, dt), None, None, dt).step()
        fresh = make().start(one(K, dt), None, None, dt)
        fresh.step()
        assert integ.u[0] == pytest.approx(fresh.u[0], rel=1e-14), (K, dt)


# ---------------------------------------------------------------------------- parameters
def test_scheme_parameters():
    h = HHT(alpha=-0.2)
    assert (h.alpha, h.beta, h.gamma) == (-0.2, pytest.approx(0.36), pytest.approx(0.7))
    assert (HHT().alpha, HHT().beta, HHT().gamma) == (-0.05, pytest.approx(1.05 ** 2 / 4), pytest.approx(0.55))
    assert (Newmark().alpha, Newmark().beta, Newmark().gamma) == (0.0, 0.25, 0.5)
    assert (BackwardEuler().beta, BackwardEuler().gamma, BackwardEuler.order) == (1.0, 1.0, 1)
    assert HHT.order == Newmark.order == Bathe.order == 2
    assert all(s.implicit for s in (HHT, Newmark, Bathe, BackwardEuler))
    assert (HHT.name, Newmark.name, Bathe.name, BackwardEuler.name) == ("hht", "newmark", "bathe", "backward_euler")
    assert HHT(alpha=-1 / 3).alpha == -1 / 3 and HHT(alpha=0.0).alpha == 0.0


@pytest.mark.parametrize("make, message", [
    (lambda: HHT(alpha=1e-12), "alpha must lie in [-1/3, 0], got 1e-12"),
    (lambda: HHT(alpha=-1 / 3 - 1e-9), f"alpha must lie in [-1/3, 0], got {-1 / 3 - 1e-9!r}"),
    (lambda: NewmarkFamily(alpha=float("nan")), "alpha must be finite, got nan"),
    (lambda: Newmark(beta=float("inf")), "beta must be finite, got inf"),
    (lambda: Newmark(gamma=float("nan")), "gamma must be finite, got nan"),
    (lambda: Newmark(beta=0.0), "beta must be > 0 (explicit Newmark is not supported here), got 0.0"),
    (lambda: Newmark(gamma=0.0), "gamma must be > 0, got 0.0"),
    (lambda: Newmark(bogus=1), "Newmark: unknown option(s) ['bogus']"),
    (lambda: Bathe(bogus=1), "Bathe: unknown option(s) ['bogus']"),
])
def test_bad_parameters_are_refused_naming_them(make, message):
    with pytest.raises(ValueError) as err:
        make()
    assert str(err.value).startswith(message)


def test_the_smallest_accepted_parameters():
    n = Newmark(beta=1e-300, gamma=1e-300)
    assert (n.beta, n.gamma) == (1e-300, 1e-300)
    assert Bathe(linear_solver="cholesky").newton_opts.linear_solver == "cholesky"


# ------------------------------------------------------- a nonlinear spring to a moving support, a follower load
# dof 0 free, tied to dof 1 (moving as G(t)) by k (x - g) + K3 (x - g)^3; the load F - KF x follows the free dof
KF, FC = 15.0, 40.0


def G(t):
    return 0.02 + 0.3 * t


def _moving(F=FC):
    def internal(u):
        d = u[0] - u[1]
        s = k * d + K3 * d ** 3
        return np.array([s, -s])

    def tangent(u):
        e = k + 3 * K3 * (u[0] - u[1]) ** 2
        return sp.csr_matrix([[e, -e], [-e, e]])
    return SecondOrderSystem(M=np.diag([m, 1.0]), internal_force=internal, tangent=tangent,
                             load=lambda t, u: np.array([F - KF * u[0], 0.0]), load_depends_on_u=True,
                             load_tangent=lambda t, u: sp.csr_matrix([[-KF, 0.0], [0.0, 0.0]]), free=[0],
                             prescribed=lambda t: np.array([G(t)]))


def _fi(x, g_):
    return k * (x - g_) + K3 * (x - g_) ** 3


def _newton_by_hand(res, jac, x, r_ref, rtol):
    norms = [abs(res(x))]
    tol = rtol * max(r_ref, norms[0])
    while norms[-1] > tol:
        x -= res(x) / jac(x)
        norms.append(abs(res(x)))
        assert len(norms) < 30, norms
    return x, norms


def _hand_moving_newmark(alpha, beta, gamma, u, v, t, rtol, F=FC):
    a = (F - KF * u - _fi(u, G(t))) / m
    r_ref = max(abs(F - KF * u), abs(_fi(u, G(t))), abs(m * a), 1e-300)

    def kin(x):
        a1 = (x - u - DT * v) / (beta * DT * DT) - (0.5 / beta - 1.0) * a
        return v + DT * ((1 - gamma) * a + gamma * a1), a1

    def res(x):
        return m * kin(x)[1] + (1 + alpha) * (_fi(x, G(t + DT)) - F + KF * x) - alpha * (_fi(u, G(t)) - F + KF * u)

    def jac(x):
        return m / (beta * DT * DT) + (1 + alpha) * (k + 3 * K3 * (x - G(t + DT)) ** 2 + KF)
    return _newton_by_hand(res, jac, u + DT * v + 0.5 * DT * DT * a, r_ref, rtol)


def _hand_moving_bathe(u, v, t, rtol, F=FC):
    """(u1, |r| histories of both sub-steps, iterations, iterations of the first sub-step)."""
    h = DT / 2
    a = (F - KF * u - _fi(u, G(t))) / m
    r_ref = max(abs(F - KF * u), abs(_fi(u, G(t))), abs(m * a), 1e-300)

    def trap(x):
        vv = 2 / h * (x - u) - v
        return vv, 2 / h * (vv - v) - a
    uh, n1 = _newton_by_hand(lambda x: m * trap(x)[1] + _fi(x, G(t + h)) - F + KF * x,
                             lambda x: 4 * m / h ** 2 + k + 3 * K3 * (x - G(t + h)) ** 2 + KF,
                             u + h * v + 0.5 * h * h * a, r_ref, rtol)
    vh, ah = trap(uh)

    def back(x):
        vv = (u - 4 * uh + 3 * x) / DT
        return vv, (v - 4 * vh + 3 * vv) / DT
    u1, n2 = _newton_by_hand(lambda x: m * back(x)[1] + _fi(x, G(t + DT)) - F + KF * x,
                             lambda x: 9 * m / DT ** 2 + k + 3 * K3 * (x - G(t + DT)) ** 2 + KF,
                             uh + h * vh + 0.5 * h * h * ah, r_ref, rtol)
    return u1, n1 + n2, len(n1) + len(n2) - 2, len(n1) - 1


@pytest.mark.parametrize("make, params", [(lambda: HHT(alpha=-0.2, newton_rtol=1e-12), (-0.2, 1.44 / 4, 0.7)),
                                          (lambda: Newmark(newton_rtol=1e-12), (0.0, 0.25, 0.5)),
                                          (lambda: BackwardEuler(newton_rtol=1e-12), (0.0, 1.0, 1.0))])
def test_newton_on_a_moving_support_with_a_follower_load_by_hand(make, params):
    integ = make().start(_moving(), np.array([0.0, G(0.0)]), np.array([0.0, 0.3]), DT)
    x, norms = _hand_moving_newmark(*params, 0.0, 0.0, 0.0, 1e-12)
    if isinstance(integ, BackwardEuler):  # its own kinematics: v1 = (x - u0)/dt, a1 = (v1 - v0)/dt
        a0 = (FC - _fi(0.0, G(0.0))) / m

        def res(y):
            return m * (y / DT) / DT + _fi(y, G(DT)) - FC + KF * y
        x, norms = _newton_by_hand(res, lambda y: m / DT ** 2 + k + 3 * K3 * (y - G(DT)) ** 2 + KF, 0.5 * DT * DT * a0,
                                   max(FC, abs(_fi(0.0, G(0.0))), abs(m * a0)), 1e-12)
    rep = integ.step()
    assert rep.converged and rep.iterations == len(norms) - 1 >= 2
    np.testing.assert_allclose(rep.residuals, norms, rtol=1e-8, atol=1e-11)
    assert integ.u[0] == pytest.approx(x, rel=1e-11) and integ.uc[0] == pytest.approx(G(DT), rel=1e-15)
    assert integ.f_ext[0] == pytest.approx(FC - KF * x, rel=1e-12)
    assert integ.f_int[0] == pytest.approx(_fi(x, G(DT)), rel=1e-10)


def test_bathe_on_a_moving_support_with_a_follower_load_by_hand():
    integ = Bathe(newton_rtol=1e-12).start(_moving(), np.array([0.0, G(0.0)]), np.array([0.4, 0.3]), DT)
    x, norms, iterations, _ = _hand_moving_bathe(0.0, 0.4, 0.0, 1e-12)
    rep = integ.step()
    assert rep.converged and rep.iterations == iterations >= 3
    np.testing.assert_allclose(rep.residuals, norms, rtol=1e-8, atol=1e-11)
    assert integ.u[0] == pytest.approx(x, rel=1e-11)
    assert integ.f_ext[0] == pytest.approx(FC - KF * x, rel=1e-12)


@pytest.mark.parametrize("u0, F", [(0.15, 40.0),   # the load is the largest force term of the step
                                   (0.2, 20.0),    # the internal force is
                                   (-0.1, 40.0)])  # the inertia is
@pytest.mark.parametrize("scheme", ["newmark", "bathe"])
def test_the_step_force_scale_is_the_largest_of_load_internal_force_and_inertia(u0, F, scheme):
    a0 = (F - KF * u0 - _fi(u0, G(0.0))) / m
    terms = sorted([abs(F - KF * u0), abs(_fi(u0, G(0.0))), abs(m * a0)])
    assert terms[-1] > 1.3 * terms[-2]  # one term leads
    r_ref = terms[-1]

    def hand(rtol):
        if scheme == "newmark":
            _, norms = _hand_moving_newmark(0.0, 0.25, 0.5, u0, 0.0, 0.0, rtol, F)
            return norms, len(norms) - 1, len(norms) - 1
        _, norms, iterations, first = _hand_moving_bathe(u0, 0.0, 0.0, rtol, F)
        return norms, iterations, first
    norms = hand(1e-9)[0]
    assert r_ref > norms[0]  # the scale, not the predictor's residual, sets the tolerance
    for j in ((1, 2) if scheme == "newmark" else (1,)):  # Bathe's 2nd sub-step cannot reach the 2nd's round-off
        # 10 % above the j-th residual: the next largest term (1.3 x smaller) as the scale would need one more
        rtol = norms[j] / r_ref * 1.1
        hand_norms, iterations, first = hand(rtol)
        assert first == j
        make = Newmark if scheme == "newmark" else Bathe
        integ = make(newton_rtol=rtol).start(_moving(F), np.array([u0, G(0.0)]), np.array([0.0, 0.3]), DT)
        rep = integ.step()
        assert rep.converged and rep.iterations == iterations, (j, rep.residuals, hand_norms)
        np.testing.assert_allclose(rep.residuals, hand_norms, rtol=1e-8, atol=1e-11)


def test_a_tiny_load_from_rest_is_still_solved():
    # a load switched on from rest: r_ref is the floor 1e-300 and the predictor's residual sets the scale
    def run(scale, make):
        s = SecondOrderSystem.linear_system(np.array([[m]]), np.array([[k]]), lambda t: np.array([scale * t]))
        integ = make().start(s, None, None, DT)
        assert integ.step().converged
        return integ.u[0]
    for make in (Newmark, HHT, BackwardEuler, Bathe):
        assert run(1e-140, make) / 1e-140 == pytest.approx(run(1.0, make), rel=1e-12) and run(1.0, make) > 0


@pytest.mark.parametrize("make, kept", [(Newmark, 1), (HHT, 1), (BackwardEuler, 1), (Bathe, 2)])
def test_a_linear_run_forms_its_effective_matrix_once_per_sub_step_kind(make, kept):
    s = _system()
    calls = []
    tangent = s.tangent
    s.tangent = lambda u: calls.append(1) or tangent(u)
    integ = make().start(s, np.array([U0, g(0.0)]), np.array([V0, 0.01]), DT)
    calls.clear()
    for _ in range(STEPS):
        rep = integ.step()
        assert rep.converged and len(rep.residuals) == kept  # one exact solve: no residual after it
    assert len(calls) == kept


@pytest.mark.parametrize("make", [lambda c: Newmark(linear_solver=c), lambda c: Bathe(linear_solver=c)])
def test_the_linear_solver_option_reaches_the_step_solver(make):
    for choice in ("direct", "cholesky"):
        integ = _start(make(choice))
        integ.step()
        solvers = [integ._lu] if hasattr(integ, "_lu") else [integ._lu1, integ._lu2]
        assert [s.name for s in solvers] == [choice] * len(solvers)


def test_newton_options_reach_every_scheme():
    for make in (Newmark, HHT, BackwardEuler, Bathe):
        assert make(newton_max_iter=3, newton_rtol=1e-6).newton_opts.max_iter == 3
    n = NewmarkFamily()
    assert (n.alpha, n.beta, n.gamma) == (0.0, 0.25, 0.5)
    assert HHT(alpha=-1.0 / 3.0 - 1e-15).alpha == -1.0 / 3.0 - 1e-15


@pytest.mark.parametrize("make", [Newmark, HHT, BackwardEuler, Bathe])
def test_a_linear_follower_load_is_a_spring_to_the_scheme(make):
    # F - KF u_f + KC u_c on the free dof is the same system as stiffness k + KF and coupling kfc - KC
    KC = 9.0

    def follower():
        return SecondOrderSystem.linear_system(
            MM, KK, lambda t, u: np.array([f(t) - KF * u[0] + KC * u[1], 7.0]), free=[0], alpha_m=A_M, beta_k=B_K,
            prescribed=lambda t: np.array([g(t)]), load_depends_on_u=True,
            load_tangent=lambda t, u: sp.csr_matrix([[-KF, KC], [0.0, 0.0]]))

    def spring():
        return SecondOrderSystem.linear_system(
            MM, KK + np.array([[KF, -KC], [0.0, 0.0]]), lambda t: np.array([f(t), 7.0]), free=[0], alpha_m=A_M,
            beta_k=0.0, prescribed=lambda t: np.array([g(t)]))

    a, b = (make().start(s, np.array([U0, g(0.0)]), np.array([V0, 0.01]), DT) for s in (follower(), spring()))
    if B_K:  # the Rayleigh damping reads the tangent at 0 of f_int alone: give the spring system the same
        b.system.beta_k, b.system.alpha_m = B_K, A_M
        b.system.__dict__["C_ff"] = a.system.C_ff
        b.system.__dict__["C_fc"] = a.system.C_fc
        b.start(b.system, np.array([U0, g(0.0)]), np.array([V0, 0.01]), DT)
    for _ in range(STEPS):
        assert a.step().converged and b.step().converged
        assert a.u[0] == pytest.approx(b.u[0], rel=1e-11) and a.v[0] == pytest.approx(b.v[0], rel=1e-10)
        assert a.f_ext[0] == pytest.approx(f(a.t) - KF * a.u[0] + KC * a.uc[0], rel=1e-12)
