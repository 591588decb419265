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
force converges to it at O(h^2), tested) needs dR: with ``Omega = R^T dR`` skew and its
axial vector ``w``, ``R^T dF - dF^T R = Omega S + S Omega``, i.e.
``w = (tr(S) I - S)^{-1} axial(R^T dF - dF^T R)`` (Twizell-Ogden; Chen and Wheeler 1993), so::

    dP = 2 mu dF + lambda (R : dF) R + (lambda (tr S - 3) - 2 mu) R [w]_x.

``tr(S) I - S`` has the eigenvalues ``s_i + s_j`` (pairs of singular values): it is singular
only for a cell inverted through zero volume. The polar decomposition is taken by SVD
(``F = U diag(s) V^T``, ``R = U V^T``) with the sign of the smallest singular value flipped
when ``det F < 0`` (Irving, Teran, Fedkiw 2004), so ``R`` is always a proper rotation.

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


def _axial(W):
    """``(W21 - W12, W02 - W20, W10 - W01)`` of ``W`` (..., 3, 3): ``2 w`` for a skew ``W = [w]_x``."""
    return np.stack([W[..., 2, 1] - W[..., 1, 2], W[..., 0, 2] - W[..., 2, 0], W[..., 1, 0] - W[..., 0, 1]],
                    axis=-1)


def _skew(w):
    """``[w]_x`` of vectors (..., 3): the matrix with ``[w]_x v = w x v``."""
    z = np.zeros(w.shape[:-1])
    return np.stack([np.stack([z, -w[..., 2], w[..., 1]], -1),
                     np.stack([w[..., 2], z, -w[..., 0]], -1),
                     np.stack([-w[..., 1], w[..., 0], z], -1)], -2)


@dataclass(frozen=True)
class Corotational(_EnuMaterial):
    """Corotated linear elasticity W = mu |S - I|^2 + lambda/2 tr(S - I)^2 (module docstring).

    Parameters
    ----------
    E, nu : float
        The small-strain Young's modulus (stress unit) and Poisson ratio of the linear model.
    """

    name = "corotational"

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
        P, R, S, trS = self._stress(F)
        G = np.linalg.inv(trS[..., None, None] * _I - S)  # (tr S I - S)^-1
        c_rot = (lam * (trS - 3.0) - 2.0 * mu)[..., None, None]
        A = np.zeros(F.shape[:-2] + (3, 3, 3, 3))
        for k in range(3):
            for L in range(3):
                # M = R^T E_kL: row a, column L holds R[k, a]
                M = np.zeros(F.shape)
                M[..., :, L] = R[..., k, :]
                w = 0.5 * np.einsum("...ab,...b->...a", G, _axial(M - np.swapaxes(M, -1, -2)))
                dP = c_rot * (R @ _skew(w)) + lam * R[..., k, L][..., None, None] * R
                dP[..., k, L] += 2.0 * mu
                A[..., :, :, k, L] = dP
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
