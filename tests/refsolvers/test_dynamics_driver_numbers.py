"""The front door ``integrate``, the registry and the input checks against hand-computed numbers.

By hand: step counts ceil((t_end - t0)/dt - 1e-9), at least 1; 1-dof oscillators marched by
hand (central difference in half-step form, forward Euler, Newmark, one Newton iteration of a
cubic spring); forward Euler multiplies m v^2/2 + k u^2/2 by exactly 1 + (omega dt)^2 per step
(m = k = dt = 1: energies 0.5, 1, 2, 4, ... exact in floats); eigenvalues of 2x2 blocks. Each
threshold (blow-up factor, growth_tol, asymmetry 1e-10 max|M|, LU pivots 1e-14 max|pivot|,
DENSE_LIMIT) is checked on both sides of its boundary.
"""
from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import (INTEGRATORS, HHT, BackwardEuler, Bathe, CentralDifference,
                                             ForwardEuler, Newmark, SecondOrderSystem, integrate,
                                             make_integrator)
from tissuebench.refsolvers.dynamics import checks
from tissuebench.refsolvers.dynamics.base import Integrator
from tissuebench.refsolvers.dynamics.checks import DENSE_LIMIT, check_spd_mass, check_vector
from tissuebench.refsolvers.dynamics.driver import _n_steps

NAMES = ["backward_euler", "bathe", "central_difference", "forward_euler", "hht", "newmark"]
NEWTON_OPTS = ("['newton_rtol', 'newton_atol', 'newton_utol', 'newton_max_iter', 'newton_tangent', "
               "'newton_iterations', 'linear_solver']")


def one_dof(m=1.0, k=1.0):
    """m a + k u = 0: no load, no damping."""
    return SecondOrderSystem.linear(np.array([[m]]), np.array([[k]]), np.zeros(1))


def raises_exactly(exc_type, message, func, *args, **kwargs):
    with pytest.raises(exc_type, match="^" + re.escape(message) + "$") as info:
        func(*args, **kwargs)
    return info


def forward_euler_by_hand(m, k, u, v, dt, n):
    """States and energies m v^2/2 + k u^2/2 of n forward Euler steps."""
    us, vs, es = [u], [v], [0.5 * m * v * v + 0.5 * k * u * u]
    for _ in range(n):
        u, v = u + dt * v, v - dt * k * u / m
        us.append(u), vs.append(v), es.append(0.5 * m * v * v + 0.5 * k * u * u)
    return np.array(us), np.array(vs), np.array(es)


# ------------------------------------------------------------------ 1. step count
@pytest.mark.parametrize("dt, t0, t_end, n", [
    (0.1, 0.0, 1.0, 10),            # 1.0 / 0.1 == 10.0
    (0.1, 0.0, 0.3, 3),             # 0.3 / 0.1 = 2.9999999999999996
    (0.1, 0.0, 0.7, 7),             # 0.7 / 0.1 = 6.999999999999999
    (0.1, 0.0, 0.25, 3),            # 2.5 -> 3
    (0.2, 1.0, 1.5, 3),             # t0 != 0: 0.5 / 0.2 = 2.5 -> 3
    (1.0, 0.0, 3.0 + 0.5e-9, 3),    # inside the 1e-9 slack
    (1.0, 0.0, 3.0 + 1.5e-9, 4),    # outside it
    (0.5, -1.0, 0.5, 3),            # negative t0
    (1.0, 0.0, 1.0, 1),             # one step exactly
    (1.0, 0.0, 1e-12, 1),           # ceil(1e-12 - 1e-9) = 0, raised to 1
])
def test_n_steps_by_hand(dt, t0, t_end, n):
    assert _n_steps(dt, t0, t_end) == n


def test_integrate_takes_the_counted_steps_and_times():
    res = integrate(one_dof(), [1.0], None, 0.1, 0.25, method="forward_euler", growth_tol=1.0)
    assert res.n_steps == 3 and res.success and res.message == "3 steps completed"
    np.testing.assert_allclose(res.t, [0.0, 0.1, 0.2, 0.3], rtol=0, atol=1e-15)
    res = integrate(one_dof(), [1.0], None, 0.2, 1.5, method="forward_euler", t0=1.0, growth_tol=1.0)
    assert res.n_steps == 3 and res.message == "3 steps completed"
    np.testing.assert_allclose(res.t, [1.0, 1.2, 1.4, 1.6], rtol=0, atol=1e-15)
    assert res.t[0] == 1.0
    res = integrate(one_dof(), [1.0], None, 1.0, 1e-12, method="forward_euler", growth_tol=1.0)
    assert res.n_steps == 1 and list(res.t) == [0.0, 1.0]
    # by hand: forward Euler with m = k = 1, dt = 0.1 from (1, 0)
    res = integrate(one_dof(), [1.0], None, 0.1, 0.3, method="forward_euler", growth_tol=1.0)
    us, vs, _ = forward_euler_by_hand(1.0, 1.0, 1.0, 0.0, 0.1, 3)
    np.testing.assert_allclose(res.u[:, 0], us, rtol=1e-15)
    np.testing.assert_allclose(res.v[:, 0], vs, rtol=1e-15)
    assert res.method == "forward_euler" and res.dt == 0.1 and res.options == {}
    assert list(res.newton_iterations) == [0, 0, 0, 0] and res.converged.all() and res.wall_time[0] == 0
    # store_every = 2 over 5 steps: 0, 2, 4 and the last one
    res = integrate(one_dof(), [1.0], None, 0.1, 0.5, method="forward_euler", growth_tol=1.0, store_every=2)
    assert list(res.stored_steps) == [0, 2, 4, 5] and res.u.shape == (4, 1)


@pytest.mark.parametrize("t0, t_end, shown", [
    (0.0, 0.0, "t_end=0.0, t0=0.0"),
    (1.0, 1.0, "t_end=1.0, t0=1.0"),
    (2, 1, "t_end=1.0, t0=2.0"),
    (0.0, -0.5, "t_end=-0.5, t0=0.0"),
    (0.0, np.inf, "t_end=inf, t0=0.0"),
    (0.0, np.nan, "t_end=nan, t0=0.0"),
    (-np.inf, 1.0, "t_end=1.0, t0=-inf"),
])
def test_bad_total_time_message(t0, t_end, shown):
    msg = f"total time t_end - t0 must be > 0, got {shown}"
    raises_exactly(ValueError, msg, _n_steps, 0.1, t0, t_end)
    raises_exactly(ValueError, msg, integrate, one_dof(), None, None, 0.1, t_end, t0=t0)


def test_dt_is_checked_before_the_times_and_the_times_before_blowup_factor():
    raises_exactly(ValueError, "dt must be a finite time step > 0, got -1.0", integrate, one_dof(), None, None,
                   -1.0, 0.0, blowup_factor=1.0)
    raises_exactly(ValueError, "total time t_end - t0 must be > 0, got t_end=0.0, t0=0.0", integrate, one_dof(),
                   None, None, 0.1, 0.0, blowup_factor=1.0)
    raises_exactly(ValueError, "blowup_factor must be a finite number > 1, got 1.0", integrate, one_dof(),
                   None, None, 0.1, 1.0, method="no_such_method", blowup_factor=1.0)


# ------------------------------------------------------------------ 2. blow-up
@pytest.mark.parametrize("factor, shown", [(1.0, "1.0"), (1, "1"), (0.5, "0.5"), (-3.0, "-3.0"),
                                           (np.nan, "nan"), (np.inf, "inf"), (-np.inf, "-inf")])
def test_blowup_factor_refused(factor, shown):
    raises_exactly(ValueError, f"blowup_factor must be a finite number > 1, got {shown}", integrate,
                   one_dof(), [1.0], None, 0.1, 0.3, blowup_factor=factor)


def test_blowup_factor_just_above_one_accepted():
    # backward Euler dissipates: KE + IE never exceeds 1.0000001 x the initial energy
    res = integrate(one_dof(), [1.0], None, 0.1, 0.3, method="backward_euler", blowup_factor=1.0000001)
    assert res.status == "success" and res.n_steps == 3 and res.failed_step is None


def test_central_difference_blow_up_by_hand():
    m, k, dt, factor = 1.0, 100.0, 0.21, 10.0       # omega = 10, dt_cr = 0.2 < dt
    u, v = 1.0, 0.0
    a = -k * u / m
    us, es = [u], [0.5 * m * v * v + 0.5 * k * u * u]
    supplied = es[0]                                 # KE0 + IE0 = 50 J; no load, no damping
    while es[-1] <= factor * supplied:
        v_half = v + 0.5 * dt * a
        u = u + dt * v_half
        a = -k * u / m
        v = v_half + 0.5 * dt * a
        us.append(u), es.append(0.5 * m * v * v + 0.5 * k * u * u)
    n = len(es) - 1                                  # first step above 10 x 50 J
    assert n == 3 and es[n - 1] <= factor * supplied < es[n]
    res = integrate(one_dof(m, k), [1.0], None, dt, 40 * dt, method="central_difference", force=True,
                    blowup_factor=factor)
    assert res.status == "blow_up" and res.failed_step == n and not res.success
    assert res.message == (f"step {n} (t={n * dt:.6g}): energy {es[n]:.3e} J exceeds "
                           f"{factor:.1e} x the energy supplied ({supplied:.3e} J)")
    assert res.message == "step 3 (t=0.63): energy 6.260e+02 J exceeds 1.0e+01 x the energy supplied (5.000e+01 J)"
    assert res.n_steps == n and len(res.t) == n + 1 and list(res.stored_steps) == [0, 1, 2, 3]
    # issue 54: the step that blew up was computed and is the last in the arrays; none was rejected
    assert res.blow_up_step == n == res.n_steps and res.rejected_step is None
    np.testing.assert_allclose(res.u[:, 0], us, rtol=1e-13)
    np.testing.assert_allclose(res.total_energy, es, rtol=1e-13)
    assert res.method == "central_difference" and res.options == {"force": True}
    # one step more tolerance (factor just above E_n / S) lets step n pass
    later = integrate(one_dof(m, k), [1.0], None, dt, 40 * dt, method="central_difference", force=True,
                      blowup_factor=es[n] / supplied * (1 + 1e-9))
    assert later.failed_step == n + 1
    # the last state is kept whatever store_every says
    sparse = integrate(one_dof(m, k), [1.0], None, dt, 40 * dt, method="central_difference", force=True,
                       blowup_factor=factor, store_every=100)
    assert list(sparse.stored_steps) == [0, n] and sparse.u[:, 0] == pytest.approx([us[0], us[n]], rel=1e-13)


def test_failed_step_kinds_in_the_result_and_the_reference_info():
    """Issue 54: one step index, two meanings, now two names beside the kept ``failed_step``; a success
    has none; the reference's info (stored with the cache) carries all three."""
    from tissuebench.reference.result import dynamics_output

    ok = integrate(one_dof(), [1.0], None, 1.0, 2.0, method="forward_euler", growth_tol=100.0)
    blown = integrate(one_dof(), [1.0], None, 1.0, 10.0, method="forward_euler", blowup_factor=4.0)
    assert (ok.failed_step, ok.rejected_step, ok.blow_up_step) == (None, None, None)
    assert (blown.failed_step, blown.rejected_step, blown.blow_up_step) == (3, None, 3) and blown.n_steps == 3
    for res in (ok, blown):
        info = dynamics_output(res, [{}] * len(res.t), {}, 1)["info"]
        assert (info["failed_step"], info["rejected_step"], info["blow_up_step"]) == \
            (res.failed_step, res.rejected_step, res.blow_up_step)


def test_blow_up_threshold_is_strict_forward_euler_doubling():
    # m = k = dt = 1 from (1, 0): (1,0) (1,-1) (0,-2) (-2,-2) (-4,0): energies 0.5, 1, 2, 4, 8 exactly
    us, vs, es = forward_euler_by_hand(1.0, 1.0, 1.0, 0.0, 1.0, 4)
    assert list(es) == [0.5, 1.0, 2.0, 4.0, 8.0] and list(us) == [1, 1, 0, -2, -4]
    at = integrate(one_dof(), [1.0], None, 1.0, 10.0, method="forward_euler", blowup_factor=4.0)
    # step 2: 2.0 == 4 x 0.5 is not flagged; step 3: 4.0 > 2.0 is
    assert at.status == "blow_up" and at.failed_step == 3
    assert at.message == "step 3 (t=3): energy 4.000e+00 J exceeds 4.0e+00 x the energy supplied (5.000e-01 J)"
    assert list(at.total_energy) == [0.5, 1.0, 2.0, 4.0] and list(at.u[:, 0]) == [1.0, 1.0, 0.0, -2.0]
    below = integrate(one_dof(), [1.0], None, 1.0, 10.0, method="forward_euler", blowup_factor=3.999)
    assert below.failed_step == 2 and below.message.startswith("step 2 (t=2): energy 2.000e+00 J exceeds 4.0e+00")
    # a blow-up keeps its status: the growth check (ratio 8 > 1.001) applies only to a success
    assert at.energy_growth_ratio == 8.0 and below.energy_growth_ratio == 4.0
    # nothing supplied, nothing grows: zero energy is never a blow-up
    rest = integrate(one_dof(), None, None, 1.0, 5.0, method="forward_euler", blowup_factor=1.5)
    assert rest.status == "success" and rest.message == "5 steps completed" and rest.energy_growth_ratio == 1.0


def test_blow_up_scale_is_the_size_of_negative_supplied_energy():
    # m = k = dt = 1 from rest (E0 = 0), load 1, -1, 0.9, 0 at t = 0, 1, 2, 3; forward Euler:
    # (u, v) = (0, 0) (0, 1) (1, 0); W_2 = 1/2 (-1 + 0.9) (1 - 0) = -0.05 J, E_2 = k u^2 / 2 = 0.5 J
    # step 1: nothing supplied yet (scale 0), no check; step 2: 0.5 > 5 x |-0.05|
    loads = [1.0, -1.0, 0.9, 0.0]
    sys = SecondOrderSystem.linear(np.eye(1), np.eye(1), lambda t: np.array([loads[round(t)]]))
    res = integrate(sys, None, None, 1.0, 3.0, method="forward_euler", blowup_factor=5.0)
    assert res.status == "blow_up" and res.failed_step == 2
    assert res.message == "step 2 (t=2): energy 5.000e-01 J exceeds 5.0e+00 x the energy supplied (5.000e-02 J)"
    assert res.external_work == pytest.approx([0.0, 0.0, -0.05], abs=1e-16)
    assert list(res.u[:, 0]) == [0.0, 0.0, 1.0] and list(res.v[:, 0]) == [0.0, 1.0, 0.0]


def test_infinite_energy_is_a_blow_up_even_when_the_threshold_overflows():
    # dt = 0.25, omega = 10: u_n+1 = -4.25 u_n - u_n-1 (dyadic, exact); energy x ~16 a step; with
    # blowup_factor = 1e307 the threshold 1e307 x 50 J is inf, so only the non-finite energy stops it
    m, k, dt = 1.0, 100.0, 0.25
    u, v = np.float64(1.0), np.float64(0.0)
    a = -k * u / m
    n = 0
    with np.errstate(over="ignore"):
        while True:
            n += 1
            v_half = v + 0.5 * dt * a
            u = u + dt * v_half
            a = -k * u / m
            v = v_half + 0.5 * dt * a
            if not np.isfinite(0.5 * m * v * v + 0.5 * k * u * u):
                break
        assert np.isfinite(u) and np.isfinite(v) and n == 255
        res = integrate(one_dof(m, k), [1.0], None, dt, 300 * dt, method="central_difference", force=True,
                        blowup_factor=1e307)
    assert res.status == "blow_up" and res.failed_step == n
    assert res.message == (f"step {n} (t={n * dt:.6g}): energy inf J exceeds 1.0e+307 x the energy "
                           f"supplied (5.000e+01 J)")
    assert res.u[-1, 0] == u and np.all(np.isfinite(res.u))


# ------------------------------------------------------------------ 3. energy growth
def test_forward_euler_growth_ratio_by_hand():
    # m = k = 1, dt = 1/8: (1 + 1/64)^3 = 274625 / 262144 exactly
    ratio = 274625 / 262144
    _, _, es = forward_euler_by_hand(1.0, 1.0, 1.0, 0.0, 0.125, 3)
    assert es[-1] / es[0] == ratio
    res = integrate(one_dof(), [1.0], None, 0.125, 0.375, method="forward_euler")
    assert res.energy_growth_ratio == ratio and res.status == "energy_growth" and res.n_steps == 3
    assert res.message == "3 steps completed, but the energy grew: energy_growth_ratio = 1.04761 > 1 + 0.001"
    # an explicit growth_tol replaces the default; the comparison is strict
    exact = integrate(one_dof(), [1.0], None, 0.125, 0.375, method="forward_euler", growth_tol=ratio - 1)
    assert exact.status == "success" and exact.message == "3 steps completed"
    below = integrate(one_dof(), [1.0], None, 0.125, 0.375, method="forward_euler", growth_tol=0.0476)
    assert below.status == "energy_growth"
    assert below.message == "3 steps completed, but the energy grew: energy_growth_ratio = 1.04761 > 1 + 0.0476"
    # m = 2, k = 8 (omega = 2), dt = 0.05: ratio (1.01)^n
    res = integrate(one_dof(2.0, 8.0), [0.3], [-0.4], 0.05, 0.5, method="forward_euler")
    assert res.energy_growth_ratio == pytest.approx(1.01 ** 10, rel=1e-13)
    assert res.message == f"10 steps completed, but the energy grew: energy_growth_ratio = {1.01 ** 10:.6g} > 1 + 0.001"


def test_forward_euler_default_growth_tol_boundary():
    # one step, m = k = 1: ratio 1 + dt^2
    inside = integrate(one_dof(), [1.0], None, 0.03, 0.03, method="forward_euler")
    assert inside.energy_growth_ratio == pytest.approx(1.0009, rel=1e-14)
    assert inside.status == "success" and inside.message == "1 steps completed"
    dt = 0.0011 ** 0.5
    outside = integrate(one_dof(), [1.0], None, dt, dt, method="forward_euler")
    assert outside.status == "energy_growth" and not outside.success and outside.failed_step is None
    assert outside.message == "1 steps completed, but the energy grew: energy_growth_ratio = 1.0011 > 1 + 0.001"
    # growth_tol = 0 is a tolerance, not "use the default"
    zero = integrate(one_dof(), [1.0], None, 0.03, 0.03, method="forward_euler", growth_tol=0)
    assert zero.status == "energy_growth"
    assert zero.message == "1 steps completed, but the energy grew: energy_growth_ratio = 1.0009 > 1 + 0"
    loose = integrate(one_dof(), [1.0], None, dt, dt, method="forward_euler", growth_tol=0.002)
    assert loose.status == "success"


def test_newmark_growth_checked_only_when_asked():
    # Newmark beta = 1/4, gamma = 0.4 < 1/2 amplifies; m = 1, k = 4, dt = 0.1, 20 steps by hand:
    # (1 + beta dt^2 k) u1 = u0 + dt v0 + dt^2 (1/2 - beta) a0,  v1 = v0 + dt ((1 - gamma) a0 + gamma a1)
    k, dt, beta, gamma, n = 4.0, 0.1, 0.25, 0.4, 20
    u, v = 1.0, 0.0
    a = -k * u
    es = [0.5 * v * v + 0.5 * k * u * u]
    for _ in range(n):
        u1 = (u + dt * v + dt * dt * (0.5 - beta) * a) / (1 + beta * dt * dt * k)
        a1 = -k * u1
        v = v + dt * ((1 - gamma) * a + gamma * a1)
        u, a = u1, a1
        es.append(0.5 * v * v + 0.5 * k * u * u)
    ratio = max(es) / es[0]
    assert ratio > 1.01
    opts = dict(method="newmark", beta=beta, gamma=gamma)
    plain = integrate(one_dof(1.0, k), [1.0], None, dt, n * dt, **opts)
    assert plain.energy_growth_ratio == pytest.approx(ratio, rel=1e-12)
    assert plain.status == "success" and plain.message == f"{n} steps completed"
    assert plain.options == {"beta": beta, "gamma": gamma}
    assert list(plain.newton_iterations) == [0] + [1] * n and plain.converged.all()  # one linear solve a step
    flagged = integrate(one_dof(1.0, k), [1.0], None, dt, n * dt, growth_tol=1e-3, **opts)
    assert flagged.status == "energy_growth"
    assert flagged.message == (f"{n} steps completed, but the energy grew: energy_growth_ratio = "
                               f"{ratio:.6g} > 1 + 0.001")
    assert integrate(one_dof(1.0, k), [1.0], None, dt, n * dt, growth_tol=ratio - 1 + 1e-9, **opts).success


# ------------------------------------------------------------------ 4. step failures
def test_newton_failure_message_by_hand():
    # m = 1, f_int = u + 10 u^3, Newmark (beta 1/4), dt = 0.1 from (1, 0): a0 = -11, r_ref = 11 N
    # r(u) = 400 (u - 1) + 11 + u + 10 u^3, J(u) = 400 + 1 + 30 u^2; predictor u = 1 - 0.005 * 11
    def f_int(u):
        return u + 10.0 * u ** 3

    cubic = SecondOrderSystem(M=sp.identity(1, format="csr"), internal_force=f_int,
                              tangent=lambda u: sp.csr_matrix([[1.0 + 30.0 * u[0] ** 2]]),
                              load=lambda t: np.zeros(1))
    u = 0.945
    r = 400.0 * (u - 1.0) + 11.0 + f_int(u)
    u = u - r / (401.0 + 30.0 * u * u)
    r1 = 400.0 * (u - 1.0) + 11.0 + f_int(u)
    tol = 1e-14 * 11.0
    seen = []
    res = integrate(cubic, [1.0], [0.0], 0.1, 1.0, method="newmark", newton_max_iter=1, newton_rtol=1e-14,
                    observe=lambda t, x: seen.append(t) or {"t": t})
    assert res.status == "newton_failed" and res.failed_step == 1
    assert res.message == (f"step 1: t=0.1: Newton did not converge in 1 iterations "
                           f"(||r|| = {abs(r1):.3e} N, tolerance {tol:.3e} N)")
    assert res.message.startswith("step 1: t=0.1: Newton did not converge in 1 iterations (||r|| = ")
    assert res.message.endswith("tolerance 1.100e-13 N)")
    assert res.n_steps == 0 and list(res.stored_steps) == [0] and res.u.shape == (1, 1) and res.u[0, 0] == 1.0
    assert seen == [0.0] and res.observations == [{"t": 0.0}]
    # issue 54: the failed step was not computed: the arrays end before it
    assert res.rejected_step == 1 == res.n_steps + 1 and res.blow_up_step is None
    # the same options, enough iterations: success
    ok = integrate(cubic, [1.0], [0.0], 0.1, 0.2, method="newmark", newton_rtol=1e-10)
    assert ok.success and ok.n_steps == 2


@pytest.mark.parametrize("method", ["central_difference", "forward_euler"])
def test_non_finite_explicit_step_is_a_blow_up(method):
    # f_int = 100 u up to |u| = 1.2, nan beyond; u1 = 1.5 for both schemes from (1, 10), dt = 0.1
    def f_int(u):
        return np.where(np.abs(u) > 1.2, np.nan, 100.0 * u)

    spring = SecondOrderSystem(M=sp.identity(1, format="csr"), internal_force=f_int,
                               tangent=lambda u: sp.csr_matrix([[100.0]]), load=lambda t: np.zeros(1),
                               strain_energy=lambda u: 50.0 * float(u[0]) ** 2)
    with np.errstate(invalid="ignore"):
        res = integrate(spring, [1.0], [10.0], 0.1, 1.0, method=method)
    assert res.status == "blow_up" and res.failed_step == 1
    assert res.message == "step 1: non-finite state at t=0.1"
    assert res.n_steps == 0 and list(res.u[:, 0]) == [1.0] and list(res.v[:, 0]) == [10.0]
    # a blow_up status, but of a step that was never recorded: rejected, not an energy blow-up (issue 54)
    assert res.rejected_step == 1 and res.blow_up_step is None


# ------------------------------------------------------------------ 5. observe
def test_observe_every_completed_step_with_the_full_displacement():
    # dof 0 held at zero; dof 1: m = k = 1, forward Euler dt = 0.5 from u = 1:
    # u = 1, 1, 0.75, 0.25 (v = 0, -0.5, -1, -1.375)
    sys = SecondOrderSystem.linear(np.eye(2), np.array([[2.0, -1.0], [-1.0, 1.0]]), np.zeros(2), free=[1])
    calls = []

    def observe(t, u):
        calls.append((t, u.copy()))
        return {"t": t, "u1": float(u[1]), "n": len(u)}

    res = integrate(sys, [0.0, 1.0], None, 0.5, 1.5, method="forward_euler", observe=observe, growth_tol=1.0)
    assert res.success and res.n_steps == 3
    assert res.observations == [{"t": 0.0, "u1": 1.0, "n": 2}, {"t": 0.5, "u1": 1.0, "n": 2},
                                {"t": 1.0, "u1": 0.75, "n": 2}, {"t": 1.5, "u1": 0.25, "n": 2}]
    assert [list(u) for _, u in calls] == [[0.0, 1.0], [0.0, 1.0], [0.0, 0.75], [0.0, 0.25]]
    assert list(res.v[:, 1]) == [0.0, -0.5, -1.0, -1.375]
    # without observe: an empty list; on a blow-up: steps 0..failed_step (observed before the check)
    assert integrate(sys, [0.0, 1.0], None, 0.5, 1.5, method="forward_euler").observations == []
    boom = integrate(one_dof(), [1.0], None, 1.0, 10.0, method="forward_euler", blowup_factor=4.0,
                     observe=lambda t, u: (t, float(u[0])))
    assert boom.observations == [(0.0, 1.0), (1.0, 1.0), (2.0, 0.0), (3.0, -2.0)]


# ------------------------------------------------------------------ 6. registry
def test_integrators_table():
    assert INTEGRATORS == {"hht": HHT, "bathe": Bathe, "newmark": Newmark, "backward_euler": BackwardEuler,
                           "central_difference": CentralDifference, "forward_euler": ForwardEuler}
    assert sorted(INTEGRATORS) == NAMES


def test_make_integrator_by_name_class_and_instance():
    nm = make_integrator("newmark")
    assert type(nm) is Newmark and (nm.alpha, nm.beta, nm.gamma) == (0.0, 0.25, 0.5)
    hht = make_integrator("hht", alpha=-0.1)
    assert type(hht) is HHT and hht.alpha == -0.1 and hht.beta == (1.1 ** 2) / 4 and hht.gamma == 0.6
    assert type(make_integrator(Bathe)) is Bathe
    fe = make_integrator(ForwardEuler, lumped=True)
    assert type(fe) is ForwardEuler and fe.lumped is True
    cd = make_integrator("central_difference", force=True)
    assert type(cd) is CentralDifference and cd.force is True
    assert make_integrator(hht) is hht and hht.alpha == -0.1
    raises_exactly(ValueError, "options ['alpha'] given with an already configured integrator",
                   make_integrator, hht, alpha=-0.2)
    raises_exactly(ValueError, "options ['alpha', 'newton_rtol'] given with an already configured integrator",
                   make_integrator, hht, newton_rtol=1e-8, alpha=-0.2)
    # an instance goes straight through integrate too
    res = integrate(one_dof(), [1.0], None, 0.1, 0.2, method=make_integrator("forward_euler"), growth_tol=1.0)
    assert res.method == "forward_euler" and res.n_steps == 2


@pytest.mark.parametrize("what, shown", [("x", "'x'"), ("HHT", "'HHT'"), ("", "''"), (3, "3"), (None, "None"),
                                         (dict, "<class 'dict'>"), (SecondOrderSystem, repr(SecondOrderSystem))])
def test_make_integrator_unknown(what, shown):
    raises_exactly(ValueError, f"unknown integrator {shown}; valid: {NAMES}", make_integrator, what)


def test_make_integrator_misspelt_option():
    info = raises_exactly(ValueError, f"HHT: unknown option(s) ['alhpa']; valid Newton options: {NEWTON_OPTS}",
                          make_integrator, "hht", alhpa=-0.1)
    assert str(info.value).startswith("HHT: ")
    info = raises_exactly(ValueError, "ForwardEuler: got an unexpected keyword argument 'force'",
                          make_integrator, "forward_euler", force=True)
    assert info.value.__cause__ is None and info.value.__suppress_context__
    raises_exactly(ValueError, "CentralDifference: got an unexpected keyword argument 'lumped'",
                   make_integrator, CentralDifference, lumped=True)


def test_make_integrator_takes_a_user_subclass():
    class Mine(ForwardEuler):
        name = "mine"

    assert issubclass(Mine, Integrator) and type(make_integrator(Mine, lumped=True)) is Mine
    res = integrate(one_dof(), [1.0], None, 0.5, 1.0, method=Mine, growth_tol=1.0)
    us, _, _ = forward_euler_by_hand(1.0, 1.0, 1.0, 0.0, 0.5, 2)
    assert res.method == "mine" and list(res.u[:, 0]) == list(us) == [1.0, 1.0, 0.75]


# ------------------------------------------------------------------ 7. checks
def test_check_vector_by_hand():
    out = check_vector("x", [1, 2, 3], 3)
    assert out.dtype == np.float64 and out.shape == (3,) and list(out) == [1.0, 2.0, 3.0]
    raises_exactly(ValueError, "x must have shape (3,), got (2,)", check_vector, "x", [1.0, 2.0], 3)
    raises_exactly(ValueError, "x must have shape (3,), got (1, 3)", check_vector, "x", [[1.0, 2.0, 3.0]], 3)
    raises_exactly(ValueError, "v0 must have shape (1,), got ()", check_vector, "v0", 1.0, 1)
    raises_exactly(ValueError, "x contains a non-finite value nan at index 1", check_vector, "x",
                   [0.0, np.nan, np.inf], 3)
    raises_exactly(ValueError, "x contains a non-finite value inf at index 1", check_vector, "x",
                   [0.0, np.inf, np.nan], 3)
    raises_exactly(ValueError, "y contains a non-finite value -inf at index 2", check_vector, "y",
                   [0.0, 5.0, -np.inf], 3)
    raises_exactly(ValueError, "x contains a non-finite value nan at index 0", check_vector, "x", [np.nan], 1)


def csr(a):
    return sp.csr_matrix(np.asarray(a, dtype=float))


def test_check_spd_mass_cheap_checks():
    raises_exactly(ValueError, "M has no free dofs", check_spd_mass, sp.csr_matrix((0, 0)))
    raises_exactly(ValueError, "M contains non-finite entries", check_spd_mass, csr([[1.0, np.nan], [np.nan, 1.0]]))
    raises_exactly(ValueError, "M contains non-finite entries", check_spd_mass, csr([[1.0, 0.0], [0.0, np.inf]]))
    raises_exactly(ValueError, "M is not positive definite: diagonal entry M[1,1] = 0.0 <= 0",
                   check_spd_mass, csr(np.diag([1.0, 0.0, 2.0])))
    raises_exactly(ValueError, "M is not positive definite: diagonal entry M[2,2] = -0.5 <= 0",
                   check_spd_mass, csr(np.diag([1.0, 2.0, -0.5])))
    raises_exactly(ValueError, "M is not positive definite: diagonal entry M[1,1] = -1.0 <= 0",
                   check_spd_mass, csr(np.diag([1.0, -1.0, -2.0])))
    # tiny but positive: refused as on the sparse path (issue 54; a24e7fa's Cholesky accepted it)
    raises_exactly(ValueError, "M is not positive definite: Cholesky pivots not all clearly positive (smallest "
                   "1.000e-300, largest 1.000e+00: below 1e-14 x the largest)", check_spd_mass,
                   csr(np.diag([1.0, 1e-300])))
    assert check_spd_mass(csr([[2.0, 1.0], [1.0, 2.0]])) is None


def test_check_spd_mass_symmetry_boundary():
    at = 1e-10 * 4.0                                  # max|M| = 4: the threshold is 4e-10
    assert check_spd_mass(csr([[4.0, 0.0], [at, 4.0]])) is None
    assert check_spd_mass(csr([[4.0, 0.0], [3e-10, 4.0]])) is None
    raises_exactly(ValueError, "M is not symmetric: max |M - M^T| = 4.000e-10", check_spd_mass,
                   csr([[4.0, 0.0], [np.nextafter(at, 1.0), 4.0]]))
    raises_exactly(ValueError, "M is not symmetric: max |M - M^T| = 5.000e-10", check_spd_mass,
                   csr([[4.0, 0.0], [5e-10, 4.0]]))
    raises_exactly(ValueError, "M is not symmetric: max |M - M^T| = 2.000e-10", check_spd_mass,
                   csr([[1.0, 0.0], [2e-10, 1.0]]))
    assert check_spd_mass(csr([[1.0, 0.0], [1e-10, 1.0]])) is None
    # the scale is max |M| (3 here, an off-diagonal -3), not max M = 1: 2e-10 < 3e-10 is symmetric enough,
    # and the matrix then fails as indefinite (eigenvalues of [[1, -3], [-3, 1]]: 4 and -2)
    raises_exactly(ValueError, "M is not positive definite: smallest eigenvalue -2.000e+00", check_spd_mass,
                   csr([[1.0, -3.0, 0.0], [-3.0, 1.0, 0.0], [2e-10, 0.0, 1.0]]))


@pytest.mark.parametrize("a, shown", [
    ([[1.0, 2.0], [2.0, 1.0]], "-1.000e+00"),             # eigenvalues 3, -1
    ([[2.0, 1.5], [1.5, 1.0]], "-8.114e-02"),             # (3 - sqrt(10)) / 2 = -0.0811388...
    ([[5.0, 0.0, 0.0], [0.0, 1.0, 3.0], [0.0, 3.0, 1.0]], "-2.000e+00"),
])
def test_check_spd_mass_dense_indefinite(a, shown):
    assert float(shown) == pytest.approx(np.linalg.eigvalsh(np.array(a))[0], rel=1e-3)
    raises_exactly(ValueError, f"M is not positive definite: smallest eigenvalue {shown}", check_spd_mass, csr(a))


def test_dense_limit_boundary(monkeypatch):
    assert DENSE_LIMIT == 1500
    indefinite = csr([[2.0, 1.5], [1.5, 1.0]])        # eigenvalues (3 -+ sqrt(10)) / 2: one negative
    monkeypatch.setattr(checks, "DENSE_LIMIT", 2)     # n == limit: dense (eigenvalue message)
    raises_exactly(ValueError, "M is not positive definite: smallest eigenvalue -8.114e-02", check_spd_mass,
                   indefinite)
    monkeypatch.setattr(checks, "DENSE_LIMIT", 1)     # n > limit: sparse LU (pivot message)
    # the ordering takes dof 1 first: pivots 1 and 2 - 1.5^2 / 1 = -0.25
    raises_exactly(ValueError, LU_MSG.format("-2.500e-01", "1.000e+00"), check_spd_mass, indefinite)


N_BIG = DENSE_LIMIT + 100
LU_MSG = ("M is not positive definite: LU pivots not all clearly positive (smallest {}, largest {}: below 1e-14 x "
          "the largest)")


def big_with_block(block, at=700, n=N_BIG):
    """Identity of n > DENSE_LIMIT dofs with a 2x2 block at (at, at)."""
    M = sp.lil_matrix(sp.identity(n))
    M[at:at + 2, at:at + 2] = block
    return M.tocsr()


def test_check_spd_mass_sparse_path():
    tri = sp.diags([-np.ones(N_BIG - 1), 4.0 * np.ones(N_BIG), -np.ones(N_BIG - 1)], [-1, 0, 1], format="csr")
    assert check_spd_mass(tri) is None
    assert check_spd_mass(big_with_block([[1.0, 0.5], [0.5, 1.0]])) is None
    raises_exactly(ValueError, LU_MSG.format("-2.500e-01", "1.000e+00"), check_spd_mass,   # dof 701 first, as above
                   big_with_block([[2.0, 1.5], [1.5, 1.0]]))
    raises_exactly(ValueError, "M is singular: Factor is exactly singular", check_spd_mass,
                   big_with_block([[1.0, 1.0], [1.0, 1.0]]))
    # tiny positive diagonal: refused by the sparse pivot test, as by the dense one (test_check_spd_mass_cheap_checks)
    d = np.ones(DENSE_LIMIT + 1)
    d[-1] = 1e-300
    raises_exactly(ValueError, LU_MSG.format("1.000e-300", "1.000e+00"), check_spd_mass, sp.diags(d, format="csr"))


def test_check_spd_mass_sparse_pivot_ratio_boundary():
    d = 4.0 * np.ones(N_BIG)                          # max |pivot| = 4, threshold 1e-14 x 4
    d[900] = 1e-14 * 4.0
    assert check_spd_mass(sp.diags(d, format="csr")) is None
    d[900] = np.nextafter(1e-14 * 4.0, 0.0)
    raises_exactly(ValueError, LU_MSG.format("4.000e-14", "4.000e+00"), check_spd_mass, sp.diags(d, format="csr"))
    d[900] = 3e-14
    with pytest.raises(ValueError, match="LU pivots"):
        check_spd_mass(sp.diags(d, format="csr"))


@pytest.mark.parametrize("n, factorisation", [(2, "Cholesky"), (N_BIG, "LU")])
def test_check_spd_mass_pivot_ratio_is_the_same_on_both_paths(n, factorisation):
    """Issue 54: a24e7fa's dense path took any positive definite M (a 1e-300 diagonal beside 4), its sparse
    path refused pivots below 1e-14 x the largest; both refuse now, on both sides of the same ratio (the
    Cholesky pivots are L's squared diagonal: a relative margin of 1e-12 is far above its round-off)."""
    d = 4.0 * np.ones(n)
    d[1] = 4e-14 * (1 + 1e-12)
    assert check_spd_mass(sp.diags(d, format="csr")) is None
    msg = ("M is not positive definite: {} pivots not all clearly positive (smallest {}, largest 4.000e+00: below "
           "1e-14 x the largest)")
    d[1] = 4e-14 * (1 - 1e-12)
    raises_exactly(ValueError, msg.format(factorisation, "4.000e-14"), check_spd_mass, sp.diags(d, format="csr"))
    d[1] = 1e-300
    raises_exactly(ValueError, msg.format(factorisation, "1.000e-300"), check_spd_mass, sp.diags(d, format="csr"))


def test_check_spd_mass_dense_refuses_a_mass_singular_to_round_off():
    # [[1, 1], [1, 1 + 2^-50]]: Cholesky succeeds with pivots 1 and 2^-50 = 8.9e-16 < 1e-14
    e = 2.0 ** -50
    raises_exactly(ValueError, "M is not positive definite: Cholesky pivots not all clearly positive (smallest "
                   "8.882e-16, largest 1.000e+00: below 1e-14 x the largest)", check_spd_mass,
                   csr([[1.0, 1.0], [1.0, 1.0 + e]]))
    assert check_spd_mass(csr([[1.0, 1.0], [1.0, 1.0 + 2.0 ** -46]])) is None   # 1.4e-14 is clear


def test_sparse_path_refuses_an_indefinite_block_row_pivoting_would_hide():
    # [[1, 2], [2, 1]] (eigenvalues 3, -1): diagonal pivots 1 and 1 - 4 = -3; a row swap would give 2 and 1.5
    raises_exactly(ValueError, LU_MSG.format("-3.000e+00", "3.000e+00"), check_spd_mass,
                   big_with_block([[1.0, 2.0], [2.0, 1.0]]))
    raises_exactly(ValueError, LU_MSG.format("-3.000e+00", "3.000e+00"), check_spd_mass,
                   big_with_block([[1.0, 2.0], [2.0, 1.0]], at=0))


def test_the_abstract_integrator_is_refused_as_bad_input():
    from tissuebench.refsolvers.dynamics.base import Integrator
    from tissuebench.refsolvers.dynamics.registry import make_integrator
    with pytest.raises(ValueError, match=r"^Integrator is abstract \(it does not implement _advance\); valid: "):
        make_integrator(Integrator)
