"""Amplification matrices of the implicit schemes, written by hand from the papers' formulas.

For the damped oscillator ``u'' + 2 xi omega u' + omega^2 u = 0`` one step of a linear
one-step scheme maps the scaled state ``x = (u, dt v, dt^2 a)`` to ``A x``; the principal
(complex) eigenvalue ``lambda`` of A is the root every computed history obeys once the
spurious root has decayed. The matrices below transcribe the update formulas of the
schemes (Hilber, Hughes, Taylor 1977 for HHT-alpha, Newmark for alpha = 0; Bathe 2007
for the composite scheme) as a linear system ``L x_{n+1} = R x_n`` in the scaled
variables, with ``Om = omega dt`` and ``c = 2 xi Om`` (= dt C / m), ``k = Om^2``
(= dt^2 K / m). They share no code with :mod:`tissuebench.refsolvers.dynamics`, so the
tests can compare the integrators' histories with them.

From the principal root: period elongation ``PE = Om / arg(lambda) - 1`` (undamped),
amplitude decay per cycle ``AD = 1 - |lambda|^(2 pi / arg(lambda))``, and the exponent
``s_bar = ln(lambda) / dt`` of the discrete solution (exact: ``omega (-xi + i sqrt(1 - xi^2))``).
"""
from __future__ import annotations

import numpy as np


def hht_matrix(Om: float, xi: float, alpha: float) -> np.ndarray:
    """HHT-alpha (Hilber's convention alpha in [-1/3, 0]; alpha = 0 is Newmark's trapezoidal rule).

    Equation at t_{n+1}:  a_{n+1} + (1 + alpha)(C v_{n+1} + K u_{n+1}) - alpha (C v_n + K u_n) = 0
    Newmark updates with beta = (1 - alpha)^2 / 4, gamma = 1/2 - alpha.
    """
    b, g = (1 - alpha) ** 2 / 4, 0.5 - alpha
    c, k = 2 * xi * Om, Om ** 2
    L = np.array([[1.0, 0.0, -b],                        # u1 - b A1           = u0 + V0 + (1/2 - b) A0
                  [0.0, 1.0, -g],                        # V1 - g A1           = V0 + (1 - g) A0
                  [(1 + alpha) * k, (1 + alpha) * c, 1.0]])  # A1 + (1+al)(c V1 + k u1) = al (c V0 + k u0)
    R = np.array([[1.0, 1.0, 0.5 - b],
                  [0.0, 1.0, 1.0 - g],
                  [alpha * k, alpha * c, 0.0]])
    return np.linalg.solve(L, R)


def bathe_matrix(Om: float, xi: float) -> np.ndarray:
    """Bathe's composite scheme: trapezoidal rule over dt/2, then the 3-point backward
    Euler formulas v_{n+1} = (u_n - 4 u_h + 3 u_{n+1}) / dt, a_{n+1} = (v_n - 4 v_h + 3 v_{n+1}) / dt.
    """
    c, k = 2 * xi * Om, Om ** 2
    # sub-step 1 (h = dt/2, in dt-scaled variables): u_h = u0 + (V0 + V_h)/4, V_h = V0 + (A0 + A_h)/4
    L1 = np.array([[1.0, -0.25, 0.0], [0.0, 1.0, -0.25], [k, c, 1.0]])
    R1 = np.array([[1.0, 0.25, 0.0], [0.0, 1.0, 0.25], [0.0, 0.0, 0.0]])
    A_half = np.linalg.solve(L1, R1)
    # sub-step 2: 3 u1 - V1 = 4 u_h - u0, 3 V1 - A1 = 4 V_h - V0, A1 + c V1 + k u1 = 0
    L2 = np.array([[3.0, -1.0, 0.0], [0.0, 3.0, -1.0], [k, c, 1.0]])
    R0 = -np.diag([1.0, 1.0, 0.0])
    Rh = np.diag([4.0, 4.0, 0.0])
    return np.linalg.solve(L2, R0 + Rh @ A_half)


def scheme_matrix(scheme: str, Om: float, xi: float, alpha: float = 0.0) -> np.ndarray:
    """``"hht"`` (with ``alpha``), ``"newmark"`` (HHT with alpha = 0) or ``"bathe"``."""
    if scheme == "bathe":
        return bathe_matrix(Om, xi)
    return hht_matrix(Om, xi, alpha if scheme == "hht" else 0.0)


def principal_eigenvalue(A: np.ndarray) -> complex:
    """The eigenvalue with the largest positive imaginary part (the oscillating root)."""
    ev = np.linalg.eigvals(A)
    return complex(ev[np.argmax(ev.imag)])


def prony_root(u: np.ndarray, skip: int = 20) -> complex:
    """Principal root lambda of the recurrence u_{n+1} = c1 u_n + c0 u_{n-1} fitted to the
    history u (n,) by least squares, after ``skip`` steps (the spurious root has decayed)."""
    u = np.asarray(u, dtype=float)[skip:]
    c, *_ = np.linalg.lstsq(np.column_stack([u[1:-1], u[:-2]]), u[2:], rcond=None)
    lam = np.roots([1.0, -c[0], -c[1]])
    return complex(lam[np.argmax(lam.imag)])
