"""Each integrator's update formulas on one damped, loaded degree of freedom against a hand
computation of its steps (issue 41): m a + c v + k u = f(t), c = alpha_m m + beta_k k, f = f0 + f1 t.

The recursions below are written from the schemes' papers (Newmark 1959; Hilber, Hughes, Taylor
1977; Bathe 2007; Belytschko et al., box 6.1), not from the package, and solved for the one
unknown of each (sub)step by hand; the integrators must match them to round-off.
"""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate

M, K, ALPHA_M, BETA_K = 2.0, 50.0, 0.3, 0.004
U0, V0, DT, STEPS = 0.1, -0.2, 0.05, 3


def load(t):
    return np.array([3.0 + 4.0 * t])


def _system(alpha_m=ALPHA_M, beta_k=BETA_K):
    return SecondOrderSystem.linear_system(np.array([[M]]), np.array([[K]]), load, alpha_m=alpha_m, beta_k=beta_k)


def _c(alpha_m=ALPHA_M, beta_k=BETA_K):
    return alpha_m * M + beta_k * K


def _f(t):
    return float(load(t)[0])


def _a0(c):
    return (_f(0.0) - c * V0 - K * U0) / M


def newmark_hht(alpha, beta, gamma, c):
    u, v, a, t, out = U0, V0, _a0(c), 0.0, []
    for _ in range(STEPS):
        u_star = u + DT * v + DT * DT * (0.5 - beta) * a
        v_star = v + DT * (1 - gamma) * a
        old = c * v + K * u - _f(t)
        a1 = (alpha * old - (1 + alpha) * (c * v_star + K * u_star - _f(t + DT))) / (
            M + (1 + alpha) * (c * gamma * DT + K * beta * DT * DT))
        u, v, a, t = u_star + beta * DT * DT * a1, v_star + gamma * DT * a1, a1, t + DT
        out.append((u, v, a))
    return out


def backward_euler(c):
    u, v, t, out = U0, V0, 0.0, []
    for _ in range(STEPS):
        t += DT
        u1 = (_f(t) + M * (u / DT ** 2 + v / DT) + c * u / DT) / (M / DT ** 2 + c / DT + K)
        v1 = (u1 - u) / DT
        out.append((u1, v1, (v1 - v) / DT))
        u, v = u1, v1
    return out


def bathe(c):
    u, v, a, t, out, h = U0, V0, _a0(c), 0.0, [], DT / 2
    for _ in range(STEPS):
        # trapezoidal rule over [t, t + h]: v = 2/h (x - u) - v, a = 4/h^2 (x - u) - 4/h v - a
        uh = (_f(t + h) + M * (4 / h ** 2 * u + 4 / h * v + a) + c * (2 / h * u + v)) / (
            4 * M / h ** 2 + 2 * c / h + K)
        vh = 2 / h * (uh - u) - v
        # 3-point backward Euler over [t, t + dt]: v1 = (u - 4 uh + 3 x) / dt, a1 = (v - 4 vh + 3 v1) / dt
        r = (u - 4 * uh) / DT
        s = (v - 4 * vh) / DT
        u1 = (_f(t + DT) - M * (3 * r / DT + s) - c * r) / (9 * M / DT ** 2 + 3 * c / DT + K)
        v1 = 3 * u1 / DT + r
        a1 = 3 * v1 / DT + s
        u, v, a, t = u1, v1, a1, t + DT
        out.append((u, v, a))
    return out


def central_difference(alpha_m, beta_k):
    c = _c(alpha_m, beta_k)
    u, v, a, t, out = U0, V0, _a0(c), 0.0, []
    for _ in range(STEPS):
        v_half = v + 0.5 * DT * a
        u = u + DT * v_half
        t += DT
        if beta_k == 0:  # damping on v_{n+1}: (m + dt/2 c) a = f - k u - c v_half
            a = (_f(t) - K * u - c * v_half) / (M + 0.5 * DT * c)
        else:  # lagged: damping on v_{n+1/2}
            a = (_f(t) - K * u - c * v_half) / M
        v = v_half + 0.5 * DT * a
        out.append((u, v, a))
    return out


def forward_euler(c):
    u, v, a, t, out = U0, V0, _a0(c), 0.0, []
    for _ in range(STEPS):
        u, v, t = u + DT * v, v + DT * a, t + DT
        a = (_f(t) - K * u - c * v) / M
        out.append((u, v, a))
    return out


def _run(method, system=None, **opts):
    res = integrate(system or _system(), [U0], [V0], DT, STEPS * DT, method=method, **opts)
    assert res.success, res.message
    assert res.t.tolist() == pytest.approx([k * DT for k in range(STEPS + 1)], rel=1e-14)
    assert (res.u[0, 0], res.v[0, 0], res.a[0, 0]) == pytest.approx((U0, V0, _a0(_c(system.alpha_m, system.beta_k))
                                                                     if system else _a0(_c())), rel=1e-14)
    return np.column_stack([res.u[1:, 0], res.v[1:, 0], res.a[1:, 0]])


@pytest.mark.parametrize("method, opts, expected", [
    ("newmark", {}, lambda: newmark_hht(0.0, 0.25, 0.5, _c())),
    ("newmark", {"beta": 0.3, "gamma": 0.6}, lambda: newmark_hht(0.0, 0.3, 0.6, _c())),
    ("hht", {"alpha": -0.1}, lambda: newmark_hht(-0.1, 1.1 ** 2 / 4, 0.6, _c())),
    ("hht", {}, lambda: newmark_hht(-0.05, 1.05 ** 2 / 4, 0.55, _c())),  # the default alpha
    ("hht", {"alpha": -1 / 3}, lambda: newmark_hht(-1 / 3, (4 / 3) ** 2 / 4, 0.5 + 1 / 3, _c())),
    ("backward_euler", {}, lambda: backward_euler(_c())),
    ("bathe", {}, lambda: bathe(_c())),
    ("forward_euler", {}, lambda: forward_euler(_c())),
    ("forward_euler", {"lumped": True}, lambda: forward_euler(_c())),
])
def test_one_dof_steps_by_hand(method, opts, expected):
    np.testing.assert_allclose(_run(method, **opts), np.array(expected()), rtol=1e-11, atol=1e-13)


@pytest.mark.parametrize("alpha_m, beta_k", [(ALPHA_M, 0.0), (ALPHA_M, BETA_K), (0.0, 0.0)])
def test_central_difference_steps_by_hand(alpha_m, beta_k):
    system = _system(alpha_m, beta_k)
    np.testing.assert_allclose(_run("central_difference", system), np.array(central_difference(alpha_m, beta_k)),
                               rtol=1e-11, atol=1e-13)


def test_two_dofs_with_coupled_mass_newmark_by_hand():
    # consistent mass couples the dofs: the same recursion in matrix form
    Mm = np.array([[2.0, 0.5], [0.5, 1.0]])
    Kk = np.array([[60.0, -20.0], [-20.0, 30.0]])
    f = np.array([1.0, -2.0])
    system = SecondOrderSystem.linear_system(Mm, Kk, f)
    u, v = np.array([0.1, 0.0]), np.array([0.0, 0.3])
    res = integrate(system, u, v, DT, 2 * DT, method="newmark")
    a = np.linalg.solve(Mm, f - Kk @ u)
    for step in (1, 2):
        u_star, v_star = u + DT * v + DT * DT * 0.25 * a, v + DT * 0.5 * a
        a = np.linalg.solve(Mm + 0.25 * DT * DT * Kk, f - Kk @ u_star)
        u, v = u_star + 0.25 * DT * DT * a, v_star + 0.5 * DT * a
        np.testing.assert_allclose(res.u[step], u, rtol=1e-12)
        np.testing.assert_allclose(res.v[step], v, rtol=1e-12)
        np.testing.assert_allclose(res.a[step], a, rtol=1e-12)
