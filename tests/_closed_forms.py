"""Closed forms written by hand for the verification tests (no package constants are read).

``lame_from(E, nu)``: Lame constants; ``principal_stress`` / ``uniaxial_closed_form``:
first Piola-Kirchhoff stresses of F = diag(l1, l2, l2) for SVK, compressible neo-Hookean
and compressible Mooney-Rivlin (W = mu1/2 (J^-2/3 I1 - 3) + mu2/2 (J^-4/3 I2 - 3) + kappa/2 (J - 1)^2),
and the homogeneous uniaxial state with traction-free sides.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import brentq

from tissuebench.refsolvers.materials import MooneyRivlin, NeoHookean, SaintVenantKirchhoff


def lame_from(E, nu):
    """Lame constants (lambda, mu) [Pa] from Young's modulus E [Pa] and Poisson's ratio nu,
    computed here so that an error in the package's ``material.lame`` cannot cancel."""
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def principal_stress(material, l1, l2):
    """P11 and P22 of F = diag(l1, l2, l2) from W(l1, l2, l3) written by hand."""
    if isinstance(material, SaintVenantKirchhoff):
        lam, mu = lame_from(material.E, material.nu)
        e = 0.5 * (np.array([l1, l2, l2]) ** 2 - 1)
        S = lam * e.sum() + 2 * mu * e
        return l1 * S[0], l2 * S[1]
    if isinstance(material, NeoHookean):
        lam, mu = lame_from(material.E, material.nu)
        lnJ = math.log(l1 * l2 * l2)
        return mu * (l1 - 1 / l1) + lam * lnJ / l1, mu * (l2 - 1 / l2) + lam * lnJ / l2
    if isinstance(material, MooneyRivlin):
        m1, m2, k = material.mu1, material.mu2, material.kappa
        l = np.array([l1, l2, l2])
        J = l.prod()
        I1 = (l ** 2).sum()
        I2 = l1**2 * l2**2 * 2 + l2**4
        # dW/dl_i = m1 J^-2/3 (l_i - I1/(3 l_i)) + m2 J^-4/3 (l_i (I1 - l_i^2) - 2 I2/(3 l_i)) + k (J-1) J / l_i
        dW = (m1 * J ** (-2 / 3) * (l - I1 / (3 * l)) + m2 * J ** (-4 / 3) * (l * (I1 - l**2) - 2 * I2 / (3 * l))
              + k * (J - 1) * J / l)
        return dW[0], dW[1]
    raise TypeError(material)


def uniaxial_closed_form(material, l1):
    """(lateral stretch, P11) with traction-free sides, by brentq on P22(l2) = 0."""
    l2 = brentq(lambda s: principal_stress(material, l1, s)[1], 0.3, 1.5, xtol=1e-15, rtol=1e-15)
    return l2, principal_stress(material, l1, l2)[0]
