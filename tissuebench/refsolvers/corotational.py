"""Corotational linear elasticity: linear stiffness in the frame rotated by the polar decomposition of F.

What practitioners run when a linear model must survive large rotations (SOFA's
``TetrahedronFEMForceField`` method ``"polar"``, Vega FEM's corotational linear material;
Mueller and Gross 2004, "Interactive virtual materials", GI 2004; Georgii and Westermann
2008, "Corotated finite elements made fast and stable"). With the polar decomposition
``F = R S`` (``R`` a rotation, ``S`` symmetric), the element force is the linear element's,
evaluated in the rotated frame and rotated back::

    f_e = R K_e (R^T x_e - X_e)

On a P1 tetrahedron F is constant, and this force is exactly the gradient of the strain
energy density of the *corotated* linear material (McAdams, Zhu, Selle, Empey, Tamstorf,
Teran, Sifakis 2011, "Efficient elasticity for character skinning with contact and
collisions", SIGGRAPH, eq. 2-4)::

    W(F) = mu |S - I|^2 + lambda / 2 tr(S - I)^2,   P = dW/dF = R sigma(S - I)
         = 2 mu (F - R) + lambda (tr S - 3) R,

``sigma(e) = lambda tr(e) I + 2 mu e`` the linear stress, because ``sigma(S - I) S`` is
symmetric (the terms of dR/dx drop out; ``tests/refsolvers/test_corotational.py`` checks the element
force against ``R K_e (R^T x - X)`` on random tetrahedra). :class:`Corotational` is that
material, so the rotation is per quadrature point: per element on P1 tetrahedra (the
SOFA/Vega method), per Gauss point on Q1 hexahedra (SOFA's hexahedra take one rotation per
element instead; the two agree to the variation of the rotation over a cell).

Its consistent tangent (Newton converges quadratically; a central finite difference of the
force converges to it at O(h^2), tested) needs dR. In the frame of the signed SVD
``F = U diag(s) V^T`` (Teran, Sifakis, Irving, Fedkiw 2005, "Robust quasistatic finite elements
and flesh simulation", SCA) it is the linear elastic tangent plus one term per pair of singular
values, along the pair's *twist* ``T_ab = (u_a v_b^T - u_b v_a^T) / sqrt 2`` (the variation of R)::

    A = 2 mu I + lambda R (x) R + sum_{a<b} gamma_ab T_ab (x) T_ab,
    gamma_ab = 2 (lambda (tr S - 3) - 2 mu) / (s_a + s_b),

the same as ``dP = 2 mu dF + lambda (R : dF) R + (lambda (tr S - 3) - 2 mu) R [w]_x`` with
``w = (tr(S) I - S)^{-1} axial(R^T dF - dF^T R)`` (Twizell-Ogden; Chen and Wheeler 1993), whose
``(tr S I - S)`` has the eigenvalues ``s_a + s_b``. The twist stiffness ``2 mu + gamma_ab`` is
negative in a compressed cell (it is 0 at rest: an infinitesimal rotation costs nothing); it is
kept (clamping it at 0, Teran et al.'s positive definite projection, turns Newton's quadratic
convergence into a linear one under a point load: measured, no convergence in 15 iterations).
``s_a + s_b`` vanishes only in a cell inverted with its two smallest stretches equal, where R is
not differentiable (which stretch carries the sign switches: the energy has a kink there); the
tangent takes ``s_a + s_b >= 1e-8`` so that it stays finite. Where the kink is convex
(``lambda (tr S - 3) > 2 mu``) an energy minimum can sit on it, and then the model has no
equilibrium to converge to (no zero residual): measured on a soft half ellipsoid (E = 3 kPa,
nu = 0.49, 4.5k nodes) under a 1.5 N probe, a cell at stretches (4.23, 0.1475, -0.1475) holds
the residual at 8e-4 N whatever the solver; the static step then fails within its budget.

The polar decomposition is taken by SVD (``R = U V^T``) with the sign of the smallest singular
value flipped when ``det F < 0`` (Irving, Teran, Fedkiw 2004, "Invertible finite elements for
robust simulation of large deformation", SCA), so ``R`` is always a proper rotation and W, P and A
are defined through inversion: :attr:`Corotational.invertible` tells the static Newton
(:mod:`~tissuebench.refsolvers.newton`) not to refuse a state with ``det F <= 0``, as it must
for the hyperelastic materials (``log J``). This is the model's own answer, not a tolerance:
under a point load the corotational equilibrium itself inverts the cells under the load (no
energy barrier as ``J -> 0``; the neo-Hookean reference has one), from 0.275 N on the tutorial's
kidney (4.5k nodes); refusing them stopped every step from there on.

Properties (tested): the tangent at F = I is the linear elastic one (same Lame constants),
so corotational FE equals linear FE at small load; W and the internal force vanish under any
rigid rotation of the whole body (objectivity), however large.

The NumPy kernels here serve the scikit-fem backend, which takes any :class:`Material` with
``stress_and_tangent``. The NGSolve backend differentiates a symbolic energy and NGSolve's
coefficient functions have no polar decomposition (matrix square root); tr sqrt(C) has a
closed form in the invariants of C (Hoger and Carlson 1984) whose derivatives are singular at
equal principal stretches, i.e. at the undeformed state where the linear limit must hold. So
corotational FE runs on scikit-fem (``tissuebench.rom.fe_baselines`` builds it there whatever
the case's backend).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .materials import (Guccione, LinearElastic, Material, MooneyRivlin, NeoHookean, NeoHookeanDecoupled,
                        SaintVenantKirchhoff, _EnuMaterial)

__all__ = ["Corotational", "polar_decomposition", "small_strain_moduli"]

_I = np.eye(3)
_I4 = np.einsum("ik,JL->iJkL", _I, _I)  # dF_iJ / dF_kL

#: the smallest ``s_a + s_b`` the tangent divides by (module docstring): stretches are O(1)
PAIR_FLOOR = 1e-8


def polar_decomposition(F):
    """``(R, S, s, V)`` of ``F = R S`` for a batch of 3x3 matrices, shape (..., 3, 3).

    ``R`` is a proper rotation (det +1), ``S = V diag(s) V^T`` symmetric, ``s`` the singular
    values with the smallest one negated where ``det F < 0`` (an inverted cell).
    """
    F = np.asarray(F, dtype=float)
    U, s, Vt = np.linalg.svd(F)
    flip = np.linalg.det(U) * np.linalg.det(Vt) < 0
    if np.any(flip):  # the reflection goes to the smallest singular value (last column of U)
        U = U.copy()
        s = s.copy()
        U[flip, :, 2] *= -1.0
        s[flip, 2] *= -1.0
    R = U @ Vt
    V = np.swapaxes(Vt, -1, -2)
    S = (V * s[..., None, :]) @ Vt
    return R, S, s, V


@dataclass(frozen=True)
class Corotational(_EnuMaterial):
    """Corotated linear elasticity W = mu |S - I|^2 + lambda/2 tr(S - I)^2 (module docstring).

    Parameters
    ----------
    E, nu : float
        The small-strain Young's modulus (stress unit) and Poisson ratio of the linear model.
    """

    name = "corotational"
    #: W, P and A are defined (and continuous) for det F <= 0 (the Irving flip): Newton need not
    #: refuse an inverted state, which is where the model's equilibrium lies under a point load
    invertible = True

    def energy(self, F):
        lam, mu = self.lame
        s = polar_decomposition(F)[2]
        return mu * np.sum((s - 1.0) ** 2, axis=-1) + 0.5 * lam * (np.sum(s, axis=-1) - 3.0) ** 2

    def _stress(self, F):
        lam, mu = self.lame
        R, S, s, _ = polar_decomposition(F)
        trS = np.sum(s, axis=-1)
        P = 2.0 * mu * (F - R) + lam * (trS - 3.0)[..., None, None] * R
        return P, R, S, trS

    def stress(self, F):
        return self._stress(np.asarray(F, dtype=float))[0]

    def energy_and_stress(self, F):
        return self.energy(F), self.stress(F)

    def stress_and_tangent(self, F):
        """``(P, A)`` with ``A[..., i, J, k, L] = dP_iJ / dF_kL`` (consistent, module docstring)."""
        lam, mu = self.lame
        F = np.asarray(F, dtype=float)
        R, _, s, V = polar_decomposition(F)
        U = R @ V  # the signed SVD's left vectors (det +1)
        trS = np.sum(s, axis=-1)
        P = 2.0 * mu * (F - R) + lam * (trS - 3.0)[..., None, None] * R
        c_rot = lam * (trS - 3.0) - 2.0 * mu
        A = 2.0 * mu * _I4 + lam * R[..., :, :, None, None] * R[..., None, None, :, :]
        for a, b in ((0, 1), (0, 2), (1, 2)):
            # s_a + s_b >= 0 (the negated one is the smallest); 0 only on the kink (module docstring)
            gamma = 2.0 * c_rot / np.maximum(s[..., a] + s[..., b], PAIR_FLOOR)
            T = (U[..., :, a, None] * V[..., None, :, b] - U[..., :, b, None] * V[..., None, :, a]) / np.sqrt(2.0)
            A += gamma[..., None, None, None, None] * T[..., :, :, None, None] * T[..., None, None, :, :]
        return P, A

    def pk2(self, F, tangent=True):
        raise NotImplementedError("corotational: the backends use stress / stress_and_tangent (P = R sigma(S - I))")


def small_strain_moduli(material: Material) -> tuple[float, float]:
    """``(E, nu)`` of the linear elasticity a material reduces to at small strain.

    Linear elastic, Saint Venant-Kirchhoff, both neo-Hookeans: their own (E, nu) (their Lame
    constants at F = I). Mooney-Rivlin: shear modulus mu1 + mu2 and bulk modulus kappa,
    ``E = 9 kappa mu / (3 kappa + mu)``, ``nu = (3 kappa - 2 mu) / (2 (3 kappa + mu))``.
    Guccione is anisotropic at small strain: ValueError (no isotropic moduli).
    """
    if isinstance(material, (LinearElastic, SaintVenantKirchhoff, NeoHookean, NeoHookeanDecoupled, Corotational)):
        return float(material.E), float(material.nu)
    if isinstance(material, MooneyRivlin):
        mu, kappa = material.mu1 + material.mu2, material.kappa
        return 9.0 * kappa * mu / (3.0 * kappa + mu), (3.0 * kappa - 2.0 * mu) / (2.0 * (3.0 * kappa + mu))
    if isinstance(material, Guccione):
        raise ValueError("small_strain_moduli: the Guccione material is anisotropic at small strain (fibres); "
                         "it has no isotropic (E, nu)")
    raise ValueError(f"small_strain_moduli: no small-strain moduli known for material {material.name!r}")
