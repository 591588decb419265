"""Undamped SDOF (m = 1 kg, k = (2 pi)^2 N/m, T = 1 s): period elongation, amplitude
decay and spectral radius at infinity of HHT-alpha and Bathe.

Period and amplitude are measured from the computed displacement history: the
discrete solution of a linear one-step scheme satisfies u_{n+1} = c1 u_n + c0 u_{n-1}
(after the spurious root has decayed), so a least-squares fit of (c1, c0) (Prony) gives
the principal root rho exp(i Omega_bar) exactly up to round-off:
PE = Omega / Omega_bar - 1, amplitude decay per cycle AD = 1 - rho^(2 pi / Omega_bar).
Both are compared with the closed forms from the principal eigenvalue of each scheme's
amplification matrix, transcribed by hand from the papers (tests/_amplification.py).
"""
import numpy as np
import pytest

from _amplification import principal_eigenvalue, scheme_matrix
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate, make_integrator

K = (2 * np.pi) ** 2
SDOF = SecondOrderSystem.linear(np.eye(1), [[K]], np.zeros(1))
DT_T = (0.01, 0.05, 0.1, 0.2)
SCHEMES = {"hht(0)": ("hht", {"alpha": 0.0}), "hht(-0.1)": ("hht", {"alpha": -0.1}),
           "hht(-1/3)": ("hht", {"alpha": -1 / 3}), "bathe": ("bathe", {})}


def principal_root(u, skip=20):
    """(rho, Omega_bar) of the dominant complex root fitted to the history u (n,)."""
    u = u[skip:]
    c, *_ = np.linalg.lstsq(np.column_stack([u[1:-1], u[:-2]]), u[2:], rcond=None)
    lam = np.roots([1.0, -c[0], -c[1]])
    lam = lam[np.argmax(lam.imag)]
    return abs(lam), abs(np.angle(lam))


def elongation_and_decay(method, opts, dt_T):
    res = integrate(SDOF, [1.0], [0.0], dt_T, 10.0, method=method, **opts)
    assert res.success, res.message
    rho, wbar = principal_root(res.u[:, 0])
    return 2 * np.pi * dt_T / wbar - 1.0, 1.0 - rho ** (2 * np.pi / wbar)


@pytest.fixture(scope="module")
def table():
    """{scheme: {dt/T: (PE, AD)}}, printed with ``pytest -s``."""
    out = {name: {r: elongation_and_decay(m, o, r) for r in DT_T} for name, (m, o) in SCHEMES.items()}
    for name, row in out.items():
        print(name, "  ".join(f"dt/T={r}: PE={pe:.4%} AD={ad:.4%}" for r, (pe, ad) in row.items()))
    return out


def test_trapezoidal_period_elongation(table):
    pe, ad = table["hht(0)"][0.1]
    # exact value for the trapezoidal rule: Omega / (2 atan(Omega/2)) - 1 = 3.2075 %
    assert pe == pytest.approx(0.0321, abs=0.0005)
    omega = 2 * np.pi * 0.1
    assert pe == pytest.approx(omega / (2 * np.arctan(omega / 2)) - 1, rel=1e-6)
    for r in DT_T:
        assert abs(table["hht(0)"][r][1]) < 1e-9  # no amplitude decay


def test_bathe_period_elongation_is_omega2_over_24(table):
    for r in (0.01, 0.05):
        omega = 2 * np.pi * r
        assert table["bathe"][r][0] == pytest.approx(omega ** 2 / 24, rel=0.10)


def closed_form(name, dt_T):
    """(PE, AD) from the principal eigenvalue of the scheme's amplification matrix written
    by hand from the papers' update formulas (tests/_amplification.py), undamped."""
    method, opts = SCHEMES[name]
    lam = principal_eigenvalue(scheme_matrix(method, 2 * np.pi * dt_T, 0.0, opts.get("alpha", 0.0)))
    wbar = abs(np.angle(lam))
    return 2 * np.pi * dt_T / wbar - 1.0, 1.0 - abs(lam) ** (2 * np.pi / wbar)


def test_hht_published_values(table):
    """HHT alpha = -0.1 at dt/T = 0.1: period elongation 3.95 %, amplitude decay 1.31 % per
    cycle (closed form 3.9506 %, 1.3146 %), both beyond the trapezoidal rule's (3.21 %, 0)."""
    pe, ad = closed_form("hht(-0.1)", 0.1)
    assert pe == pytest.approx(0.039506, abs=1e-6) and ad == pytest.approx(0.013146, abs=1e-6)
    pe, ad = table["hht(-0.1)"][0.1]  # and the integrator's history
    assert pe == pytest.approx(0.039506, abs=1e-6) and ad == pytest.approx(0.013146, abs=1e-6)


@pytest.mark.parametrize("name", SCHEMES)
def test_elongation_and_decay_match_the_closed_forms(table, name):
    """The integrators' histories reproduce PE and AD of the amplification matrix at every
    dt/T: to 1e-8 absolute (measured <= 1.5e-13; the Prony fit is exact up to round-off)."""
    for r in DT_T:
        pe, ad = table[name][r]
        pe_cf, ad_cf = closed_form(name, r)
        assert pe == pytest.approx(pe_cf, abs=1e-8), (r, pe, pe_cf)
        assert ad == pytest.approx(ad_cf, abs=1e-8), (r, ad, ad_cf)


def test_dissipation_ordering(table):
    for r in DT_T:
        ad = {name: table[name][r][1] for name in SCHEMES}
        # more negative alpha dissipates more; all dissipative schemes decay (AD > 0)
        assert 0 < ad["hht(-0.1)"] < ad["hht(-1/3)"]
        assert ad["bathe"] > 0
        # Bathe's period error is below the trapezoidal rule's at every step size
        assert table["bathe"][r][0] < table["hht(0)"][r][0]


# ------------------------------------------------------------------ spectral radius
def amplification_matrix(method, opts, dt_T):
    """One step applied to the unit basis of scaled states (u, dt v, dt^2 a)."""
    integ = make_integrator(method, **opts).start(SDOF, [1.0], [0.0], dt_T)
    D = np.array([1.0, dt_T, dt_T ** 2])  # scaling keeps the entries O(1) at huge dt
    A = np.zeros((3, 3))
    for j in range(3):
        x = np.eye(3)[j] / D
        integ.set_state(0.0, x[:1], x[1:2], x[2:])
        assert integ.step().converged
        A[:, j] = np.array([integ.u[0], integ.v[0], integ.a[0]]) * D
    return A


def char_poly(A):
    """Coefficients [1, c2, c1, c0] of det(lambda I - A) from invariants (not eigenvalues)."""
    tr = np.trace(A)
    return np.array([1.0, -tr, 0.5 * (tr ** 2 - np.trace(A @ A)), -np.linalg.det(A)])


@pytest.mark.parametrize("alpha", [0.0, -0.1, -1 / 3])
def test_hht_spectral_radius_at_infinity(alpha):
    rho_inf = (1 + alpha) / (1 - alpha)
    spurious = alpha / (1 + alpha)  # the third root at infinity
    A = amplification_matrix("hht", {"alpha": alpha}, 1e4)
    expected = np.poly([-rho_inf, -rho_inf, spurious])
    assert np.max(np.abs(char_poly(A) - expected)) < 1e-6
    rho = np.max(np.abs(np.linalg.eigvals(A)))
    if alpha > -1 / 3:
        assert rho == pytest.approx(rho_inf, abs=1e-6)
    else:
        # alpha = -1/3: the three roots coalesce at -1/2, so at finite Omega they sit
        # O(Omega^(-2/3)) away (a property of the scheme, 4.9e-4 at dt/T = 1e4)
        assert rho == pytest.approx(0.5, abs=1e-3)
        rho6 = np.max(np.abs(np.linalg.eigvals(amplification_matrix("hht", {"alpha": alpha}, 1e6))))
        assert abs(rho6 - 0.5) < abs(rho - 0.5) / 10


def test_bathe_spectral_radius_at_infinity():
    A = amplification_matrix("bathe", {}, 1e4)
    assert np.max(np.abs(char_poly(A)[1:])) < 1e-6  # A tends to a nilpotent matrix: rho_inf = 0
    rho = np.max(np.abs(np.linalg.eigvals(A)))
    omega = 2 * np.pi * 1e4
    # the radius decays like 5 / Omega (7.96e-5 at dt/T = 1e4), so it is 0 only in the limit
    assert rho <= 1e-4
    assert rho * omega == pytest.approx(5.0, rel=1e-3)
