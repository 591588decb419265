"""Energy bookkeeping, explicit stability limit and a nonlinear (Duffing) spring."""
import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import (SecondOrderSystem, critical_time_step, integrate,
                                             make_integrator)


def random_spd_system(n=12, seed=0):
    """Small random SPD (M, K) with one constrained dof (dof 0), zero load."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    K = A @ A.T + n * np.eye(n)
    B = rng.standard_normal((n, n))
    M = B @ B.T / n + np.eye(n)
    sys = SecondOrderSystem.linear(M, K, np.zeros(n), free=np.arange(1, n))
    u0 = np.r_[0.0, rng.standard_normal(n - 1)]
    return sys, u0


def test_trapezoidal_conserves_energy():
    sys, u0 = random_spd_system()
    res = integrate(sys, u0, None, 0.05, 20.0, method="newmark")
    assert res.success
    e0 = res.total_energy[0]
    assert np.max(np.abs(res.total_energy - e0)) / e0 < 1e-10
    assert np.max(np.abs(res.energy_error)) / e0 < 1e-10
    assert np.all(res.u[:, 0] == 0)  # the constrained dof stays at zero


def test_damped_balance_closes_with_dissipation():
    sys, u0 = random_spd_system()
    damped = SecondOrderSystem.linear(sys.M, sys.tangent(None), np.zeros(sys.n), free=sys.free,
                                      alpha_m=0.1, beta_k=0.01)
    res = integrate(damped, u0, None, 0.01, 5.0, method="newmark")
    e0 = res.total_energy[0]
    assert res.total_energy[-1] < 0.5 * e0  # damping took energy out
    assert res.damping_dissipation[-1] > 0.5 * e0
    # the trapezoidal rule with trapezoidal bookkeeping closes the balance to round-off
    assert np.max(np.abs(res.energy_error)) / e0 < 1e-10


# ------------------------------------------------------------------ central difference
def spring_chain(n, m=1.0, k=1.0e4):
    """Fixed-free chain of n masses m [kg] and springs k [N/m] (dof 0 of n+1 fixed)."""
    main = np.full(n + 1, 2 * k)
    main[-1] = k
    K = sp.diags([main, -k * np.ones(n), -k * np.ones(n)], [0, -1, 1]).tocsr()
    return SecondOrderSystem.linear(sp.eye(n + 1) * m, K, np.zeros(n + 1), free=np.arange(1, n + 1))


@pytest.mark.parametrize("n", [30, 2000])  # dense eigvalsh and sparse eigsh paths
def test_critical_step_of_chain(n):
    m, k = 1.0, 1.0e4
    w_max = 2 * np.sqrt(k / m) * np.sin((2 * n - 1) * np.pi / (2 * (2 * n + 1)))
    assert critical_time_step(spring_chain(n, m, k)) == pytest.approx(2 / w_max, rel=1e-8)


def test_central_difference_stability_limit():
    sys = spring_chain(30)
    dt_cr = critical_time_step(sys)
    u0 = np.r_[0.0, np.random.default_rng(1).standard_normal(30)]
    ok = integrate(sys, u0, None, 0.99 * dt_cr, 3000 * dt_cr, method="central_difference")
    assert ok.success and ok.n_steps >= 3000
    e = ok.total_energy
    # bounded: the velocity-Verlet energy oscillates by at most 1/(1 - (0.99)^2) ~ 50x
    assert e.max() < 60 * e[0]
    assert e[-1000:].max() < 1.5 * e[:1000].max()  # and does not trend upwards

    with pytest.raises(ValueError, match="critical time step"):
        integrate(sys, u0, None, 1.1 * dt_cr, 300 * dt_cr, method="central_difference")
    bad = integrate(sys, u0, None, 1.1 * dt_cr, 3000 * dt_cr, method="central_difference", force=True)
    assert bad.status == "blow_up"
    assert 0 < bad.failed_step < 3000 and "step" in bad.message
    assert len(bad.t) == bad.failed_step + 1  # arrays stop at the step where it blew up
    assert np.all(np.isfinite(bad.u))
    print("central difference blow-up at step", bad.failed_step, bad.message)


# ------------------------------------------------------------------ nonlinear spring
k_lin = (2 * np.pi) ** 2
k3 = 10 * k_lin
DUFFING = SecondOrderSystem(
    M=sp.eye(1), internal_force=lambda u: k_lin * u + k3 * u ** 3,
    tangent=lambda u: sp.csr_matrix([[k_lin + 3 * k3 * u[0] ** 2]]), load=lambda t: np.zeros(1),
    strain_energy=lambda u: 0.5 * k_lin * u[0] ** 2 + 0.25 * k3 * u[0] ** 4)
F_SCALE = k_lin + k3  # internal force at u = 1 m [N]


@pytest.mark.parametrize("method, opts", [("newmark", {}), ("hht", {"alpha": -0.1}), ("bathe", {})])
def test_duffing_newton_converges_quadratically(method, opts):
    integ = make_integrator(method, **opts).start(DUFFING, [1.0], [0.0], 0.01)
    for _ in range(200):
        rep = integ.step()
        assert rep.converged and rep.iterations <= 5
        # each sub-step's residual history restarts; quadratic: e_{i+1} <= 10 e_i^2
        e = np.array(rep.residuals) / F_SCALE
        for a, b in zip(e[:-1], e[1:]):
            if b < a:  # skip the jump from the end of sub-step 1 to the start of sub-step 2
                assert b <= 10 * a * a + 1e-13


def test_duffing_trapezoidal_energy_error_is_second_order():
    errs = []
    for dt in (0.01, 0.005, 0.0025):
        res = integrate(DUFFING, [1.0], [0.0], dt, 2.0, method="newmark")
        assert res.success and res.newton_iterations.max() <= 5
        errs.append(np.max(np.abs(res.relative_energy_error)))
    print("Duffing trapezoidal relative energy errors", errs)
    assert errs[0] < 0.02  # 1.24 % at dt = T_lin / 100
    assert errs[0] / errs[1] == pytest.approx(4, rel=0.1)
    assert errs[1] / errs[2] == pytest.approx(4, rel=0.1)


def test_newton_failure_is_reported_not_raised():
    res = integrate(DUFFING, [1.0], [0.0], 0.01, 1.0, method="hht", newton_max_iter=1)
    assert res.status == "newton_failed" and res.failed_step == 1
    assert "Newton did not converge" in res.message
    assert len(res.t) == 1 and res.u.shape == (1, 1)  # truncated to the completed steps


@pytest.mark.parametrize("method", ["newmark", "hht", "bathe", "central_difference"])
def test_damped_sdof_second_order(method):
    """m = 1 kg, T = 1 s, 5 % mass-proportional damping (C = alpha_m M), u0 = 1 m."""
    w, xi = 2 * np.pi, 0.05
    sys = SecondOrderSystem.linear(np.eye(1), [[w * w]], np.zeros(1), alpha_m=2 * xi * w)
    wd = w * np.sqrt(1 - xi ** 2)
    dts = [0.02, 0.01, 0.005, 0.0025]
    errs = []
    for dt in dts:
        res = integrate(sys, [1.0], [0.0], dt, 3.0, method=method)
        ex = np.exp(-xi * w * res.t) * (np.cos(wd * res.t) + xi * w / wd * np.sin(wd * res.t))
        errs.append(np.max(np.abs(res.u[:, 0] - ex)))
    assert np.polyfit(np.log(dts), np.log(errs), 1)[0] == pytest.approx(2.0, abs=0.2)
    # dissipated energy at dt = 2.5 ms vs the exact E(0) - E(3 s) = 16.74915 J, to 1e-3
    t, e = 3.0, np.exp(-xi * w * 3.0)
    u, v = e * (np.cos(wd * t) + xi * w / wd * np.sin(wd * t)), -e * w * w / wd * np.sin(wd * t)
    assert res.damping_dissipation[-1] == pytest.approx(0.5 * w * w * (1 - u * u) - 0.5 * v * v, rel=1e-3)
