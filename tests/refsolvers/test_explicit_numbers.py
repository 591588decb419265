"""The explicit schemes (``dynamics.explicit``) against numbers computed by hand.

By hand: row sums of small mass matrices; the largest omega^2 of 2x2 pencils by the quadratic
formula and of a fixed-fixed chain of n equal masses m and springs k, (k/m) 2 (1 - cos(n pi/(n+1)));
the critical step (2/omega)(sqrt(1 + xi^2) - xi), xi = alpha_m/(2 omega) + beta_k omega/2; and the
steps of central difference in half-step form (Belytschko et al., Nonlinear Finite Elements,
box 6.1) and of lumped forward Euler with a prescribed motion of a fixed dof, whose velocity and
acceleration are difference quotients. Every threshold is checked on both sides.
"""
from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.refsolvers.dynamics import explicit
from tissuebench.refsolvers.dynamics.explicit import (CentralDifference, ForwardEuler, critical_time_step,
                                                      lumped_mass, max_frequency)


def raises_exactly(exc_type, message, func, *args, **kwargs):
    with pytest.raises(exc_type, match="^" + re.escape(message) + "$"):
        func(*args, **kwargs)


def chain(n, k):
    """Stiffness [N/m] of n masses between two walls joined by n + 1 springs k."""
    return sp.diags([np.full(n, 2 * k), np.full(n - 1, -k), np.full(n - 1, -k)], [0, -1, 1]).tocsr()


def chain_omega_max(n, k, m):
    return np.sqrt(k / m * 2 * (1 - np.cos(n * np.pi / (n + 1))))


# ------------------------------------------------------------------ 1. lumped_mass
def test_lumped_mass_row_sums():
    M = np.array([[2.0, 0.5, 0.25], [0.5, 3.0, 0.25], [0.25, 0.25, 1.0]])
    assert lumped_mass(M).tolist() == [2.75, 3.75, 1.5]
    assert lumped_mass(sp.csr_matrix(M)).tolist() == [2.75, 3.75, 1.5]
    # rows, not columns (column sums would be 2.25, 4.5, 1.0)
    assert lumped_mass(np.array([[2.0, 0.5, 0.0], [0.25, 3.0, 0.0], [0.0, 1.0, 1.0]])).tolist() == [2.5, 3.25, 2.0]


def test_lumped_mass_refuses_non_positive_row_sums():
    # the first offending row is named: row 1 sums to 0.0, row 2 to -0.5
    raises_exactly(ValueError, "lumped mass: row sum 1 is 0.0 <= 0; the mass cannot be lumped",
                   lumped_mass, np.array([[1.0, 0.0, 0.0], [0.0, 1.0, -1.0], [0.0, -1.0, 0.5]]))
    raises_exactly(ValueError, "lumped mass: row sum 1 is -0.5 <= 0; the mass cannot be lumped",
                   lumped_mass, np.array([[1.0, 0.5], [0.5, -1.0]]))
    raises_exactly(ValueError, "lumped mass: row sum 0 is 0.0 <= 0; the mass cannot be lumped",
                   lumped_mass, np.array([[1.0, -1.0], [-1.0, 2.0]]))
    # a tiny positive row sum is a mass
    assert lumped_mass(np.array([[1.0, 0.0], [0.0, 1e-300]])).tolist() == [1.0, 1e-300]


# ------------------------------------------------------------------ 2. max_frequency
def test_max_frequency_dense_chain_closed_form():
    n, k, m = 5, 40.0, 2.5
    assert max_frequency(chain(n, k), np.full(n, m)) == pytest.approx(chain_omega_max(n, k, m), rel=1e-12)
    assert max_frequency(chain(n, k).toarray(), np.full(n, m)) == pytest.approx(chain_omega_max(n, k, m), rel=1e-12)
    # unequal masses: the generalised eigenproblem K phi = lambda diag(m) phi
    md = np.array([1.0, 2.0, 0.5, 3.0, 1.5])
    lam = sla.eigh(chain(n, k).toarray(), np.diag(md), eigvals_only=True)[-1]
    assert max_frequency(chain(n, k), md) == pytest.approx(np.sqrt(lam), rel=1e-12)
    # one dof: sqrt(k / m) exactly
    assert max_frequency(np.array([[36.0]]), np.array([4.0])) == 3.0


def test_max_frequency_sparse_chain_closed_form():
    n, k, m = 1600, 40.0, 2.5   # > DENSE_LIMIT = 1500: eigsh, tol 1e-8 on omega^2
    assert n > explicit.DENSE_LIMIT == 1500
    assert max_frequency(chain(n, k), np.full(n, m)) == pytest.approx(chain_omega_max(n, k, m), rel=1e-8)
    # the tolerance resolves the second largest omega, 1.4e-6 (relative) below the largest
    w2 = np.sqrt(k / m * 2 * (1 - np.cos((n - 1) * np.pi / (n + 1))))
    assert 1 - w2 / chain_omega_max(n, k, m) > 100 * 1e-8


def test_max_frequency_dense_limit_boundary(monkeypatch):
    calls = []
    eigvalsh, eigsh = explicit.sla.eigvalsh, explicit.spla.eigsh
    monkeypatch.setattr(explicit.sla, "eigvalsh", lambda *a, **kw: calls.append("dense") or eigvalsh(*a, **kw))
    monkeypatch.setattr(explicit.spla, "eigsh", lambda *a, **kw: calls.append("sparse") or eigsh(*a, **kw))
    monkeypatch.setattr(explicit, "DENSE_LIMIT", 4)
    for n, path in [(4, "dense"), (5, "sparse")]:
        calls.clear()
        w = max_frequency(chain(n, 40.0), np.full(n, 2.5))
        assert calls == [path]
        assert w == pytest.approx(chain_omega_max(n, 40.0, 2.5), rel=1e-8)
        # the largest omega^2, not the largest |omega^2|: diag(1, 2, 3, 4, -10)[:n] gives omega = 2
        calls.clear()
        assert max_frequency(sp.diags([1.0, 2.0, 3.0, 4.0, -10.0][:n]), np.ones(n)) == pytest.approx(2.0, rel=1e-8)
        assert calls == [path]


def test_max_frequency_symmetrises_its_input():
    # S K S with S = diag(1, 1/sqrt(2)) is [[4, 1/sqrt2], [3/sqrt2, 1]]; its symmetric part
    # [[4, sqrt2], [sqrt2, 1]] has lambda_max = (5 + sqrt(17)) / 2 (lower triangle: (5 + sqrt(27)) / 2)
    K = np.array([[4.0, 1.0], [3.0, 2.0]])
    assert max_frequency(K, np.array([1.0, 2.0])) == pytest.approx(np.sqrt((5 + np.sqrt(17)) / 2), rel=1e-13)
    assert max_frequency(K.T, np.array([1.0, 2.0])) == pytest.approx(np.sqrt((5 + np.sqrt(17)) / 2), rel=1e-13)


def test_max_frequency_without_positive_stiffness_is_zero():
    assert max_frequency(np.zeros((3, 3)), np.ones(3)) == 0.0
    assert max_frequency(-np.eye(2), np.array([1.0, 2.0])) == 0.0   # omega^2 < 0 is clipped, not nan
    assert max_frequency(sp.csr_matrix((3, 3)), np.ones(3)) == 0.0


# ------------------------------------------------------------------ 3. critical_time_step
# dofs 0, 1 free and 2 fixed: M_ff = [[2, 1], [1, 3]] lumps to (3, 4) (row sums of the full M would
# give 3.5 for dof 0); K_ff = [[30, -12], [-12, 40]]: det(K - lam diag(3, 4)) = 12 (lam^2 - 20 lam + 88),
# lam_max = 10 + 2 sqrt(3). The stiff fixed dof must not enter.
M3 = np.array([[2.0, 1.0, 0.5], [1.0, 3.0, 0.0], [0.5, 0.0, 1.0]])
K3 = np.array([[30.0, -12.0, -100.0], [-12.0, 40.0, 0.0], [-100.0, 0.0, 500.0]])
W3 = np.sqrt(10 + 2 * np.sqrt(3))


def sys3(alpha_m=0.0, beta_k=0.0, K=K3):
    return SecondOrderSystem.linear_system(M3, K, np.zeros(3), free=[0, 1], alpha_m=alpha_m, beta_k=beta_k)


@pytest.mark.parametrize("alpha_m, beta_k", [(0.0, 0.0), (0.7, 0.0), (0.0, 0.02), (0.7, 0.02)])
def test_critical_time_step_by_hand(alpha_m, beta_k):
    xi = alpha_m / (2 * W3) + beta_k * W3 / 2
    dt_cr = 2 / W3 * (np.sqrt(1 + xi * xi) - xi)
    assert critical_time_step(sys3(alpha_m, beta_k)) == pytest.approx(dt_cr, rel=1e-13)


def test_critical_time_step_without_stiffness_is_infinite():
    assert critical_time_step(sys3(K=np.zeros((3, 3)))) == float("inf")
    assert critical_time_step(sys3(0.7, 0.02, K=np.zeros((3, 3)))) == float("inf")


# ------------------------------------------------------------------ 4. CentralDifference
def one_dof(m=1.0, k=4.0):
    return SecondOrderSystem.linear_system(np.array([[m]]), np.array([[k]]), np.zeros(1))


def test_central_difference_step_limit_boundary():
    # omega = sqrt(4 / 1) = 2: dt_cr = 1 exactly
    assert CentralDifference().dt_critical is None
    integ = CentralDifference().start(one_dof(), [0.1], None, 1.0)
    assert integ.dt_critical == 1.0 and integ.step().converged
    dt = 1.0 * (1 + 1e-9)
    raises_exactly(ValueError, f"dt = {dt!r} exceeds the critical time step dt_cr = 1.0 of central difference; "
                   "pass force=True to run anyway", CentralDifference().start, one_dof(), [0.1], None, dt)
    forced = CentralDifference(force=1).start(one_dof(), [0.1], None, dt)
    assert forced.force is True and forced.dt_critical == 1.0 and forced.dt == dt
    # dt equal to the computed limit of a 2-dof system is accepted, just above it is not
    dt_cr = critical_time_step(sys3())
    assert CentralDifference().start(sys3(), None, None, dt_cr).dt_critical == dt_cr
    with pytest.raises(ValueError, match="exceeds the critical time step"):
        CentralDifference().start(sys3(), None, None, dt_cr * (1 + 1e-9))
    # the limit includes the damping
    damped = sys3(0.7, 0.02)
    with pytest.raises(ValueError, match="exceeds the critical time step"):
        CentralDifference().start(damped, None, None, 0.999 * 2 / W3)


def test_central_difference_lumped_operators():
    integ = CentralDifference().start(sys3(), None, None, 0.01)
    np.testing.assert_array_equal(integ.mass_ff.toarray(), np.diag([3.0, 4.0]))
    # all dofs: the free ones as the steps lump them (M_ff's rows: 3, 4, not the full rows' 3.5, 4),
    # the fixed one over M_cc (1.0, not the full row's 1.5); the energy balance uses this one mass
    np.testing.assert_array_equal(integ.mass_full.toarray(), np.diag([3.0, 4.0, 1.0]))
    np.testing.assert_array_equal(integ.solve_mass(np.array([3.0, 2.0])), [1.0, 0.5])
    assert integ.damping_full is None and integ.coupling_force(np.array([0.1]), np.array([2.0])) == 0.0


@pytest.mark.parametrize("alpha_m, beta_k", [(0.0, 0.0), (0.7, 0.0), (0.0, 0.02), (0.7, 0.02)])
def test_lumped_damping_on_all_dofs_by_hand(alpha_m, beta_k):
    # C_L = alpha_m diag(3, 4, 1) + beta_k K3; its free-fixed block is beta_k K3[(0, 1), 2] = beta_k (-100, 0)
    # (the consistent C_fc would add alpha_m M_fc = alpha_m (0.5, 0)); a_c exerts nothing (no M_fc)
    system = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=[0, 1], alpha_m=alpha_m, beta_k=beta_k,
                                             prescribed=lambda t: np.array([0.0]))
    for integ in (CentralDifference().start(system, None, None, 0.01),
                  ForwardEuler(lumped=True).start(system, None, None, 0.01)):
        if alpha_m == beta_k == 0.0:
            assert integ.damping_full is None
        else:
            np.testing.assert_allclose(integ.damping_full.toarray(), alpha_m * np.diag([3.0, 4.0, 1.0]) + beta_k * K3,
                                       rtol=1e-15, atol=0)
        vc, ac = np.array([0.1]), np.array([2.0])
        expected = beta_k * np.array([-10.0, 0.0])
        np.testing.assert_allclose(integ.coupling_force(vc, ac), expected if beta_k else 0.0, rtol=1e-15, atol=0)
        v = np.array([0.3, -0.2])
        np.testing.assert_allclose(integ.damping_force(v), alpha_m * np.array([0.9, -0.8]) + beta_k *
                                   np.array([11.4, -11.6]), rtol=1e-14, atol=0)
    # the consistent forward Euler keeps the system's C_full
    held = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=[0, 1], alpha_m=alpha_m, beta_k=beta_k)
    assert ForwardEuler().start(held, None, None, 0.01).damping_full is held.C_full


@pytest.mark.parametrize("alpha_m, beta_k", [(0.0, 0.0), (0.7, 0.0), (0.0, 0.02), (0.7, 0.02)])
def test_central_difference_damping_force_by_hand(alpha_m, beta_k):
    # C_L v = alpha_m diag(3, 4) v + beta_k K_ff v, v = (0.3, -0.2): K_ff v = (11.4, -11.6)
    v = np.array([0.3, -0.2])
    expected = alpha_m * np.array([0.9, -0.8]) + beta_k * np.array([11.4, -11.6])
    integ = CentralDifference().start(sys3(alpha_m, beta_k), None, None, 0.01)
    np.testing.assert_allclose(integ.damping_force(v), expected, rtol=1e-14, atol=0)
    assert integ.damping_force(v).shape == (2,)


# ------------------------------------------------------------------ 5. prescribed motion
# dofs 0, 2 free, dof 1 follows g(t) = 0.03 + 0.01 t + 0.2 t^2. MA has a coupled M_ff
# ([[2, 0.25], [0.25, 1.5]] lumps to (2.25, 1.75)); MB a diagonal M_ff (2, 1.5); both have M_fc = 0.5.
MA = np.array([[2.0, 0.5, 0.25], [0.5, 3.0, 0.5], [0.25, 0.5, 1.5]])
MB = np.array([[2.0, 0.5, 0.0], [0.5, 3.0, 0.5], [0.0, 0.5, 1.5]])
KP = np.array([[40.0, -15.0, -5.0], [-15.0, 35.0, -20.0], [-5.0, -20.0, 25.0]])
FREE, FIXED = [0, 2], [1]
DT, STEPS = 0.05, 4


def load_p(t):
    return np.array([1.0 + 2.0 * t, 7.0, -0.5 + 3.0 * t])


def g(t):
    return np.array([0.03 + 0.01 * t + 0.2 * t * t])


def prescribed_system(M, alpha_m, beta_k):
    return SecondOrderSystem.linear_system(M, KP, load_p, free=FREE, alpha_m=alpha_m, beta_k=beta_k, prescribed=g)


def initial_full(vc0):
    return np.array([0.1, 0.03, -0.05]), np.array([0.2, vc0, -0.1])


def by_hand(method, M, alpha_m, beta_k, vc0):
    """Full (u, v, a) per step: free dofs by the scheme, dof 1 by difference quotients of g."""
    m = M[np.ix_(FREE, FREE)].sum(axis=1)                        # lumped M_ff
    Kff, Kfc = KP[np.ix_(FREE, FREE)], KP[np.ix_(FREE, FIXED)]
    C = alpha_m * np.diag(m) + beta_k * Kff                      # C_L; C_L,fc = beta_k K_fc

    def rhs(t, u, uc):
        return load_p(t)[FREE] - Kff @ u - Kfc @ uc

    u0, v0 = initial_full(vc0)
    u, v, uc, vc, ac, t = u0[FREE], v0[FREE], g(0.0), np.array([vc0]), np.zeros(1), 0.0
    a = (rhs(t, u, uc) - C @ v - beta_k * Kfc @ vc) / m
    out = [(u, v, a, uc, vc, ac)]
    for _ in range(STEPS):
        t += DT
        uc1 = g(t)
        vc1 = (uc1 - uc) / DT
        ac, uc, vc = (vc1 - vc) / DT, uc1, vc1
        if method == "central_difference":
            v_half = v + 0.5 * DT * a
            u = u + DT * v_half
            if beta_k == 0:     # (M_L + dt/2 C_L) a1 = f - f_int - C_L v_half, C_L diagonal
                a = (rhs(t, u, uc) - C @ v_half) / (m + 0.5 * DT * alpha_m * m)
            else:               # lagged damping on v_half, with the coupling beta_k K_fc v_c1
                a = (rhs(t, u, uc) - C @ v_half - beta_k * Kfc @ vc) / m
            v = v_half + 0.5 * DT * a
        else:
            u, v = u + DT * v, v + DT * a
            a = (rhs(t, u, uc) - C @ v - beta_k * Kfc @ vc) / m
        out.append((u, v, a, uc, vc, ac))

    def full(f, c):
        x = np.zeros(3)
        x[FREE], x[FIXED] = f, c
        return x
    return [np.array([full(s[i], s[i + 3]) for s in out]) for i in range(3)]


@pytest.mark.parametrize("method, M, alpha_m, beta_k, vc0", [
    ("central_difference", MA, 0.3, 0.0, 0.0),
    ("central_difference", MA, 0.3, 0.004, 0.0),
    ("central_difference", MA, 0.0, 0.004, 0.01),
    ("central_difference", MA, 0.0, 0.0, 0.01),
    ("forward_euler", MA, 0.0, 0.004, 0.01),
    ("forward_euler", MA, 0.0, 0.0, 0.01),
    ("forward_euler", MB, 0.3, 0.004, 0.0),
    # issue 54: mass-proportional damping with a moving support (a0 took alpha_m M_fc v_c0), and forward
    # Euler's damping with a coupled M_ff (it took alpha_m M_ff, not alpha_m M_L)
    ("central_difference", MA, 0.3, 0.004, 0.01),
    ("central_difference", MA, 0.3, 0.0, 0.01),
    ("forward_euler", MA, 0.3, 0.004, 0.01),
    ("forward_euler", MA, 0.3, 0.0, 0.0),
])
def test_prescribed_motion_steps_by_hand(method, M, alpha_m, beta_k, vc0):
    system = prescribed_system(M, alpha_m, beta_k)
    u0, v0 = initial_full(vc0)
    opts = {"lumped": True} if method == "forward_euler" else {}
    res = integrate(system, u0, v0, DT, STEPS * DT, method=method, growth_tol=10.0, **opts)
    assert res.success and res.method == method and res.n_steps == STEPS, res.message
    u, v, a = by_hand(method, M, alpha_m, beta_k, vc0)
    np.testing.assert_allclose(res.u, u, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res.v, v, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res.a, a, rtol=1e-12, atol=1e-13)
    # fixed dof: g(t_n), then (g_1 - g_0)/dt = 0.01 + 0.2 dt and (v_c1 - v_c0)/dt
    assert res.u[1, 1] == pytest.approx(0.03 + 0.01 * DT + 0.2 * DT ** 2, rel=1e-14)
    assert res.v[1, 1] == pytest.approx(0.01 + 0.2 * DT, rel=1e-13)
    assert res.a[1, 1] == pytest.approx((0.01 + 0.2 * DT - vc0) / DT, rel=1e-12)
    assert res.a[2, 1] == pytest.approx(0.4, rel=1e-11)         # g'' once both quotients are inside
    # the forces the scheme keeps after the last step
    integ = (CentralDifference() if method == "central_difference" else ForwardEuler(lumped=True))
    integ.start(system, u0, v0, DT)
    for _ in range(STEPS):
        assert integ.step().converged
    np.testing.assert_allclose(integ.f_ext, load_p(integ.t)[FREE], rtol=1e-15)
    np.testing.assert_allclose(integ.f_int, KP[FREE] @ u[-1], rtol=1e-12)
    np.testing.assert_allclose((integ.uc, integ.vc, integ.ac), (u[-1, FIXED], v[-1, FIXED], a[-1, FIXED]),
                               rtol=1e-12)


# 2 dofs: dof 0 free, dof 1 follows g(t) = 0.1 t; M = [[2, 1], [1, 4]] lumps to M_L = diag(2, 4) (M_ff, M_cc; the
# full rows would give 3, 5), K = [[10, -4], [-4, 8]], no load, alpha_m = 0.5, beta_k = 0.01: C_L = diag(1, 2) +
# 0.01 K, C_L,ff = 1.1, C_L,fc = -0.04 (the consistent C_fc = 0.5 - 0.04 = 0.46). u0 = (0.02, 0), v0 = (0.3, 0.1).
M2, K2 = np.array([[2.0, 1.0], [1.0, 4.0]]), np.array([[10.0, -4.0], [-4.0, 8.0]])


def two_dof():
    return SecondOrderSystem.linear_system(M2, K2, np.zeros(2), free=[0], alpha_m=0.5, beta_k=0.01,
                                           prescribed=lambda t: np.array([0.1 * t]))


@pytest.mark.parametrize("method", ["central_difference", "forward_euler"])
def test_starting_acceleration_with_a_moving_support_by_hand(method):
    # a0 = (-10 (0.02) - 1.1 (0.3) + 0.04 (0.1)) / 2 = (-0.2 - 0.33 + 0.004) / 2 = -0.263; with the consistent
    # coupling 0.46 (0.1) the numerator loses alpha_m M_fc v_c0 = 0.05 more: -0.288 (a24e7fa), the same as the steps'
    integ = CentralDifference() if method == "central_difference" else ForwardEuler(lumped=True)
    integ.start(two_dof(), [0.02, 0.0], [0.3, 0.1], 0.1)
    assert integ.a[0] == pytest.approx(-0.263, rel=1e-14)
    assert integ.a[0] != pytest.approx(-0.288, rel=1e-3)
    assert (integ.uc.tolist(), integ.vc.tolist(), integ.ac.tolist()) == ([0.0], [0.1], [0.0])


def test_central_difference_step_with_a_moving_support_by_hand():
    # v_half = 0.3 + 0.05 (-0.263) = 0.28685, u1 = 0.02 + 0.1 v_half = 0.048685, u_c1 = 0.01, v_c1 = 0.1, a_c1 = 0;
    # a1 = (-10 u1 + 4 (0.01) + 0.04 (0.1) - 1.1 v_half) / 2 = (-0.48685 + 0.044 - 0.315535) / 2 = -0.3791925,
    # v1 = v_half + 0.05 a1 = 0.267890375
    integ = CentralDifference().start(two_dof(), [0.02, 0.0], [0.3, 0.1], 0.1)
    assert integ.step().converged
    assert integ.u[0] == pytest.approx(0.048685, rel=1e-14)
    assert integ.a[0] == pytest.approx(-0.3791925, rel=1e-14)
    assert integ.v[0] == pytest.approx(0.267890375, rel=1e-14)
    assert (integ.uc[0], integ.vc[0], integ.ac[0]) == pytest.approx((0.01, 0.1, 0.0), rel=1e-14, abs=1e-15)


def test_forward_euler_step_with_a_moving_support_by_hand():
    # u1 = 0.02 + 0.1 (0.3) = 0.05, v1 = 0.3 + 0.1 (-0.263) = 0.2737;
    # a1 = (-10 (0.05) + 4 (0.01) + 0.04 (0.1) - 1.1 (0.2737)) / 2 = (-0.5 + 0.044 - 0.30107) / 2 = -0.378535
    integ = ForwardEuler(lumped=True).start(two_dof(), [0.02, 0.0], [0.3, 0.1], 0.1)
    assert integ.step().converged
    assert (integ.u[0], integ.v[0], integ.a[0]) == pytest.approx((0.05, 0.2737, -0.378535), rel=1e-14)


@pytest.mark.parametrize("method", ["central_difference", "forward_euler"])
def test_energy_bookkeeping_with_a_moving_support_by_hand(method):
    # step 0: KE = 1/2 (2 (0.3)^2 + 4 (0.1)^2) = 0.11 (the full rows' diag(3, 5) gave 0.16), IE = 1/2 10 (0.02)^2
    # = 0.002; the support force R_c = 4 a_c + (C_L v)_c + (K u)_c = 0 + (-0.04 (0.3) + (2 + 0.08) 0.1) - 0.08
    # = -0.012 + 0.208 - 0.08 = 0.116 N
    opts = {"lumped": True} if method == "forward_euler" else {}
    res = integrate(two_dof(), [0.02, 0.0], [0.3, 0.1], 0.1, 0.1, method=method, growth_tol=10.0, **opts)
    assert res.success, res.message
    assert res.kinetic_energy[0] == pytest.approx(0.11, rel=1e-14)
    assert res.strain_energy[0] == pytest.approx(0.002, rel=1e-14)
    # step 1: the support force with the step's state; the reaction work by the trapezoidal rule on du_c = 0.01
    u1, v1, a1 = res.u[1], res.v[1], res.a[1]
    r1 = 4.0 * a1[1] + (-0.04 * v1[0] + 2.08 * v1[1]) + (-4.0 * u1[0] + 8.0 * u1[1])
    assert res.reaction_work[1] == pytest.approx(0.5 * (0.116 + r1) * 0.01, rel=1e-13)
    assert res.kinetic_energy[1] == pytest.approx(0.5 * (2 * v1[0] ** 2 + 4 * v1[1] ** 2), rel=1e-14)
    # the dissipation: 1/2 (C_L v0 + C_L v1) . du over both dofs
    C_L = np.diag([1.0, 2.0]) + 0.01 * K2
    du = u1 - np.array([0.02, 0.0])
    d = 0.5 * float((C_L @ (np.array([0.3, 0.1]) + v1)) @ du)
    assert res.damping_dissipation[1] == pytest.approx(d, rel=1e-13)


def energy_errors(method, dts, alpha_m, beta_k):
    """Largest |energy_error| over [0, 1] s on the prescribed 3-dof system, started on the motion (v_c0 = g'(0))."""
    opts = {"lumped": True} if method == "forward_euler" else {}
    out = []
    for dt in dts:
        u0, v0 = initial_full(0.01)
        res = integrate(prescribed_system(MA, alpha_m, beta_k), u0, v0, dt, 1.0, method=method, growth_tol=10.0,
                        **opts)
        assert res.success, res.message
        out.append(np.abs(res.energy_error).max())
    return np.array(out)


@pytest.mark.parametrize("method", ["central_difference", "forward_euler"])
@pytest.mark.parametrize("alpha_m, beta_k", [(0.0, 0.0), (0.3, 0.004)])
def test_energy_error_with_a_moving_support_shrinks_with_dt(method, alpha_m, beta_k):
    # both schemes are first order in the balance here (the fixed dofs' velocity is a backward difference
    # quotient): halving dt halves the error. a24e7fa: 0.11-0.18 J at every dt (the kinetic energy took the
    # full rows' lumped mass, 3.5 for dof 0 where the steps use 2.25); the energies are ~1.3 J
    dts = np.array([0.01, 0.005, 0.0025])
    err = energy_errors(method, dts, alpha_m, beta_k)
    order = np.polyfit(np.log(dts), np.log(err), 1)[0]
    assert order > 0.9, (err, order)
    assert err[-1] < 0.3 * err[0], err      # two halvings: 0.25 at order 1, ~1 on a24e7fa
    assert err[0] < (3e-3 if method == "central_difference" else 6e-2), err


def test_forward_euler_prescribed_motion_needs_lumped():
    system = prescribed_system(MA, 0.0, 0.0)
    raises_exactly(ValueError, "forward_euler: a prescribed motion needs lumped=True (the consistent mass "
                   "couples the free dofs to the prescribed acceleration)",
                   ForwardEuler().start, system, None, None, DT)
    assert ForwardEuler(lumped=1).start(system, None, None, DT).lumped is True
    # fixed dofs held at zero need no lumping
    held = SecondOrderSystem.linear_system(MA, KP, load_p, free=FREE)
    integ = ForwardEuler().start(held, None, None, DT)
    assert integ.mass_ff is held.M_ff and integ.mass_full is held.M


def test_forward_euler_lumped_operators():
    integ = ForwardEuler(lumped=True).start(prescribed_system(MA, 0.0, 0.0), None, None, DT)
    np.testing.assert_array_equal(integ.mass_ff.toarray(), np.diag([2.25, 1.75]))
    # one mass on all dofs: M_ff's row sums on the free dofs (not the full rows' 2.75, 2.25), M_cc on dof 1
    np.testing.assert_array_equal(integ.mass_full.toarray(), np.diag([2.25, 3.0, 1.75]))


# ------------------------------------------------------------------ 6. non-finite steps
def follower(f0):
    """M = I, K = I, load f0 + 0.1 u (a follower load: non-finite u makes it non-finite)."""
    return SecondOrderSystem.linear_system(np.eye(2), np.eye(2), lambda t, u: f0 + 0.1 * u,
                                           load_depends_on_u=True)


def assert_unchanged(integ, before):
    assert integ.t == before[0]
    for x, y in zip((integ.u, integ.v, integ.a, integ.f_ext, integ.f_int), before[1:]):
        np.testing.assert_array_equal(x, y)


def snapshot(integ):
    return integ.t, integ.u.copy(), integ.v.copy(), integ.a.copy(), integ.f_ext.copy(), integ.f_int.copy()


def test_central_difference_non_finite_displacement_is_a_failed_step():
    # a0 = (0, 1.5e308); dt = 3.4567891 (forced): v_half = (0, 2.6e308) = (0, inf), u1 = (0, inf)
    integ = CentralDifference(force=True).start(follower(np.array([0.0, 1.5e308])), None, None, 3.4567891)
    assert integ.a.tolist() == [0.0, 1.5e308]
    before = snapshot(integ)
    rep = integ.step()
    assert (rep.converged, rep.iterations, rep.message) == (False, 0, "non-finite displacement at t=3.45679")
    assert_unchanged(integ, before)
    # one step of dt = 0.5 (< dt_cr = 2 / sqrt(1 - 0.1)) stays finite: u1 = (0, 0.5^2/2 1.5e308)
    ok = CentralDifference().start(follower(np.array([0.0, 1.5e308])), None, None, 0.5)
    assert ok.step().converged and ok.u.tolist() == [0.0, 0.125 * 1.5e308] and ok.t == 0.5


@pytest.mark.parametrize("v0, f0", [
    ([0.0, 1e308], [0.0, 0.0]),        # u1 = (0, 2.3e308) = (0, inf), v1 = v0
    ([0.0, 0.0], [0.0, 1.5e308]),      # u1 = 0, v1 = (0, 3.5e308) = (0, inf)
])
def test_forward_euler_non_finite_state_is_a_failed_step(v0, f0):
    integ = ForwardEuler().start(follower(np.array(f0)), None, v0, 2.3456789)
    before = snapshot(integ)
    rep = integ.step()
    assert (rep.converged, rep.iterations, rep.message) == (False, 0, "non-finite state at t=2.34568")
    assert_unchanged(integ, before)
    assert integ.step().message == "non-finite state at t=2.34568"   # retried from the same state
