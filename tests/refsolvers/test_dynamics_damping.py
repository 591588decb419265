"""Rayleigh damping (C = alpha_m M + beta_k K0) against the exact decay of damped oscillators.

SDOF: m = 1 kg, k = (2 pi)^2 N/m (omega = 2 pi rad/s, T = 1 s), damping ratio xi = 0.05
given once by stiffness-proportional damping only (beta_k = 2 xi / omega, since
xi = beta_k omega / 2) and once by mass-proportional damping only (alpha_m = 2 xi omega,
since xi = alpha_m / (2 omega)). Exact free decay u ~ exp(s t), s = omega (-xi + i sqrt(1 - xi^2)):

- logarithmic decrement per damped period  delta = 2 pi xi / sqrt(1 - xi^2) = 0.314553,
  i.e. the amplitude ratio of successive peaks exp(-delta) = 0.730115;
- damped period  T_d = T / sqrt(1 - xi^2) = 1.001252 s.

Measured from the computed history: the discrete root lambda (Prony fit, exact for a
linear one-step scheme), s_bar = ln(lambda) / dt, delta_bar = -2 pi Re(s_bar) / Im(s_bar),
T_d_bar = 2 pi / Im(s_bar).

The 2-DOF system (omega_2 = sqrt(6) omega_1) checks that the damping ratio depends on the
frequency as Rayleigh damping says (beta_k: proportional to omega_i; alpha_m: to 1/omega_i),
against the amplification-matrix root of each mode (tests/_amplification.py).
"""
import numpy as np
import pytest

from _amplification import principal_eigenvalue, prony_root, scheme_matrix
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate

W, XI = 2 * np.pi, 0.05
RAYLEIGH = {"beta_k": {"beta_k": 2 * XI / W}, "alpha_m": {"alpha_m": 2 * XI * W}}
IMPLICIT = {"newmark": ("newmark", {}), "hht(-0.05)": ("hht", {"alpha": -0.05}),
            "hht(-0.1)": ("hht", {"alpha": -0.1}), "bathe": ("bathe", {})}
DELTA = 2 * np.pi * XI / np.sqrt(1 - XI ** 2)
T_D = 2 * np.pi / (W * np.sqrt(1 - XI ** 2))


def sdof(kind):
    return SecondOrderSystem.linear(np.eye(1), [[W * W]], np.zeros(1), **RAYLEIGH[kind])


def decrement_and_period(lam: complex, dt: float):
    """(delta_bar, T_d_bar) [-, s] of the discrete root lam of a scheme with step dt [s]."""
    s = np.log(lam) / dt
    return -2 * np.pi * s.real / s.imag, 2 * np.pi / s.imag


def measured_root(system, method, opts, dt, t_end=10.0, u0=(1.0,), observe=lambda u: u[:, 0]):
    res = integrate(system, list(u0), None, dt, t_end, method=method, **opts)
    assert res.success, res.message
    return prony_root(observe(res.u))


def test_exact_decay_constants():
    # the numbers quoted in the module docstring
    assert DELTA == pytest.approx(0.314553, abs=1e-6)
    assert np.exp(-DELTA) == pytest.approx(0.730115, abs=1e-6)
    assert T_D == pytest.approx(1.001252, abs=1e-6)


@pytest.mark.parametrize("scheme", IMPLICIT)
@pytest.mark.parametrize("kind", RAYLEIGH)
def test_rayleigh_decay_converges_to_the_exact_one(kind, scheme):
    """delta_bar and T_d_bar converge to the exact values at second order. The schemes'
    error is O(Om^2) (Om = omega dt): the trapezoidal rule's exponent is
    s (1 + (s dt)^2 / 12 + ...), i.e. -Om^2/6 on xi and +Om^2/12 on T_d; HHT and Bathe add
    terms of the same order. Measured at dt/T = 0.005: |error| 8e-5..2.2e-4 on delta,
    4e-5..1e-4 on T_d; bound Om^2 / 4 = 2.5e-4. A factor 2 on beta_k or alpha_m makes the
    delta error 100 %."""
    method, opts = IMPLICIT[scheme]
    dts = np.array([0.02, 0.01, 0.005])
    err = np.array([np.array(decrement_and_period(measured_root(sdof(kind), method, opts, dt), dt))
                    / (DELTA, T_D) - 1 for dt in dts])  # (3, 2): delta, T_d
    order = np.log2(np.abs(err[:-1] / err[1:]))
    assert np.all(np.abs(order - 2) < 0.1), (order, err)
    Om = W * dts[-1]
    assert np.all(np.abs(err[-1]) < Om ** 2 / 4), err


def test_central_difference_beta_k_decay_is_first_order():
    """Explicit central difference with beta_k > 0 applies the damping at the lagged
    v_{n+1/2} (first order): the delta error is about xi Om / 2 (measured +1.4e-3 at
    dt/T = 0.01, +7.5e-4 at 0.005), T_d within 2e-3."""
    dts = np.array([0.01, 0.005, 0.0025])
    err = np.array([np.array(decrement_and_period(measured_root(sdof("beta_k"), "central_difference", {}, dt),
                                                  dt)) / (DELTA, T_D) - 1 for dt in dts])
    order = np.log2(np.abs(err[:-1, 0] / err[1:, 0]))
    assert np.all(np.abs(order - 1) < 0.15), (order, err)
    assert 0 < err[0, 0] < XI * W * dts[0] / 2 * 1.5, err
    assert np.all(np.abs(err[:, 1]) < 2e-3), err


# ------------------------------------------------------------------ 2 DOF: per-mode damping ratios
K2 = W * W * np.array([[5.0, -2.0], [-2.0, 2.0]])  # M = I: omega_1^2 = W^2, omega_2^2 = 6 W^2
MODES = np.array([[1.0, 2.0], [2.0, -1.0]]).T / np.sqrt(5)  # columns: M-orthonormal modes
OMEGAS = W * np.array([1.0, np.sqrt(6.0)])
RAYLEIGH_2DOF = {"beta_k": ({"beta_k": 0.04 / W}, 0.02 * OMEGAS / W),          # xi_i = beta_k omega_i / 2
                 "alpha_m": ({"alpha_m": 0.1 * W}, 0.05 * W / OMEGAS)}         # xi_i = alpha_m / (2 omega_i)


def test_two_dof_modes():
    assert np.allclose(K2 @ MODES, MODES * OMEGAS ** 2) and np.allclose(MODES.T @ MODES, np.eye(2))


@pytest.mark.parametrize("scheme", IMPLICIT)
@pytest.mark.parametrize("kind", RAYLEIGH_2DOF)
def test_rayleigh_damping_ratio_of_each_mode(kind, scheme):
    """Started in mode i, the response stays in mode i (Rayleigh damping is classical); its
    discrete root equals the amplification-matrix root at (omega_i dt, xi_i) to 1e-9
    (measured 1e-14). dt = T_1 / 40: the schemes' own delta errors are 0.14-0.41 % (mode 1) and
    0.8-2.4 % (mode 2) there, so the match is to the scheme, not merely to the physics."""
    method, opts = IMPLICIT[scheme]
    rayleigh, xis = RAYLEIGH_2DOF[kind]
    system = SecondOrderSystem.linear(np.eye(2), K2, np.zeros(2), **rayleigh)
    dt = 1.0 / 40
    for i in range(2):
        lam = measured_root(system, method, opts, dt, t_end=8.0, u0=MODES[:, i],
                            observe=lambda u, mode=MODES[:, i]: u @ mode)
        expected = principal_eigenvalue(scheme_matrix(method, OMEGAS[i] * dt, xis[i], opts.get("alpha", 0.0)))
        assert abs(lam - expected) < 1e-9, (i, lam, expected)
        # and the root is within the scheme's O(Om^2) of the exact decay of mode i
        delta, _ = decrement_and_period(lam, dt)
        exact = 2 * np.pi * xis[i] / np.sqrt(1 - xis[i] ** 2)
        assert delta == pytest.approx(exact, rel=(OMEGAS[i] * dt) ** 2 / 4)
