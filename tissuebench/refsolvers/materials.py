"""Hyperelastic materials as strain-energy densities per reference volume.

Every material exposes batched NumPy kernels of the deformation gradient ``F`` of
shape ``(n_cells, n_qp, 3, 3)``:

* :meth:`Material.energy` -> W, shape ``(n_cells, n_qp)``;
* :meth:`Material.stress` -> first Piola-Kirchhoff stress P = dW/dF;
* :meth:`Material.stress_and_tangent` -> (P, A) with A = dP/dF, shape ``(..., 3, 3, 3, 3)``
  indexed ``A[..., i, J, k, L] = dP_iJ / dF_kL``.

Definitions (lambda, mu are the Lame constants):

* linear elastic: W = lambda/2 (tr eps)^2 + mu eps:eps, eps = sym(F - I)
* Saint Venant-Kirchhoff: W = lambda/2 (tr E)^2 + mu E:E, E = (C - I)/2
* compressible neo-Hookean: W = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2
* decoupled compressible neo-Hookean (deal.II code gallery, Cook's membrane):
  W = mu/2 (J^-2/3 I1 - 3) + kappa/4 (J^2 - 1 - 2 ln J), kappa = E / (3 (1 - 2 nu))
* compressible Mooney-Rivlin: W = mu1/2 (J^-2/3 I1 - 3) + mu2/2 (J^-4/3 I2 - 3) + kappa/2 (J-1)^2
* Guccione: W = C/2 (exp(Q) - 1) + kappa/2 (J - 1)^2 with Q in fibre axes.

The NGSolve backend does not use these kernels: it differentiates the same energies
symbolically, which makes the two backends independent implementations.
Units are whatever the user's are (stress = energy per volume).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

_I = np.eye(3)


def _check_positive(name, value):
    if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")


def _check_poisson(nu):
    if not (isinstance(nu, (int, float, np.floating, np.integer)) and math.isfinite(nu) and -1.0 < nu < 0.5):
        raise ValueError(f"nu must lie in (-1, 0.5), got {nu!r}")


def _sym_identity(Ci):
    """I_{C^-1}: (Ci_IK Ci_JL + Ci_IL Ci_JK) / 2."""
    return 0.5 * (np.einsum("...IK,...JL->...IJKL", Ci, Ci) + np.einsum("...IL,...JK->...IJKL", Ci, Ci))


def _outer(A, B):
    return np.einsum("...IJ,...KL->...IJKL", A, B)


def _pk1_tangent(F, S, CC):
    """Push S (PK2) and CC = dS/dE to P = F S and A = dP/dF."""
    P = F @ S
    A = np.einsum("ik,...JL->...iJkL", _I, S) + np.einsum("...iI,...IJKL,...kK->...iJkL", F, CC, F)
    return P, A


class Material:
    """Base class: subclasses implement ``energy`` and ``pk2`` (S and dS/dE from F)."""

    name: str = ""

    def energy(self, F):
        raise NotImplementedError

    def pk2(self, F, tangent=True):
        """Second Piola-Kirchhoff stress S and (if ``tangent``) CC = dS/dE."""
        raise NotImplementedError

    def stress(self, F):
        S, _ = self.pk2(F, tangent=False)
        return F @ S

    def stress_and_tangent(self, F):
        S, CC = self.pk2(F, tangent=True)
        return _pk1_tangent(F, S, CC)

    def energy_and_stress(self, F):
        """(W, P) at once; invariant-based materials share the kinematics (reduced-order
        cubature evaluates both on every iteration)."""
        return self.energy(F), self.stress(F)

    @property
    def is_linear(self) -> bool:
        return False

    def volumetric(self, J):
        """(U, dU/dJ, d2U/dJ2) of the volumetric part U(J) of W, arrays shaped like ``J``.

        An incompressible (mixed u-p) formulation drops U and imposes J = 1 with a Lagrange
        multiplier instead; W - U is then the energy it keeps. Defined for the models of
        nearly incompressible solids (neo-Hookean, Mooney-Rivlin, Guccione).
        """
        raise TypeError(f"material {self.name!r} has no volumetric part for an incompressible formulation")

    def validate_for_mesh(self, n_cells: int) -> None:
        """Check per-cell data (fibres) against the mesh; no-op for isotropic materials."""


@dataclass(frozen=True)
class _EnuMaterial(Material):
    E: float
    nu: float

    def __post_init__(self):
        _check_positive("E", self.E)
        _check_poisson(self.nu)

    @property
    def lame(self):
        lam = self.E * self.nu / ((1 + self.nu) * (1 - 2 * self.nu))
        return lam, self.E / (2 * (1 + self.nu))


@dataclass(frozen=True)
class LinearElastic(_EnuMaterial):
    """Small-strain isotropic linear elasticity (f_int is linear in u)."""

    name = "linear"

    @property
    def is_linear(self):
        return True

    def energy(self, F):
        lam, mu = self.lame
        eps = 0.5 * (F + np.swapaxes(F, -1, -2)) - _I
        tr = np.trace(eps, axis1=-2, axis2=-1)
        return 0.5 * lam * tr**2 + mu * np.einsum("...ij,...ij->...", eps, eps)

    def stress(self, F):
        lam, mu = self.lame
        eps = 0.5 * (F + np.swapaxes(F, -1, -2)) - _I
        return lam * np.trace(eps, axis1=-2, axis2=-1)[..., None, None] * _I + 2 * mu * eps

    def stress_and_tangent(self, F):
        lam, mu = self.lame
        A = lam * _outer(_I, _I) + 2 * mu * _sym_identity(_I)
        return self.stress(F), np.broadcast_to(A, F.shape[:-2] + (3, 3, 3, 3))


@dataclass(frozen=True)
class SaintVenantKirchhoff(_EnuMaterial):
    name = "svk"

    def energy(self, F):
        lam, mu = self.lame
        E = 0.5 * (np.swapaxes(F, -1, -2) @ F - _I)
        return 0.5 * lam * np.trace(E, axis1=-2, axis2=-1) ** 2 + mu * np.einsum("...ij,...ij->...", E, E)

    def pk2(self, F, tangent=True):
        lam, mu = self.lame
        E = 0.5 * (np.swapaxes(F, -1, -2) @ F - _I)
        S = lam * np.trace(E, axis1=-2, axis2=-1)[..., None, None] * _I + 2 * mu * E
        if not tangent:
            return S, None
        CC = lam * _outer(_I, _I) + 2 * mu * _sym_identity(_I)
        return S, np.broadcast_to(CC, F.shape[:-2] + (3, 3, 3, 3))


def _det3(F):
    """det of (..., 3, 3) arrays by the explicit formula (faster than LAPACK on small batches)."""
    return (F[..., 0, 0] * (F[..., 1, 1] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 1])
            - F[..., 0, 1] * (F[..., 1, 0] * F[..., 2, 2] - F[..., 1, 2] * F[..., 2, 0])
            + F[..., 0, 2] * (F[..., 1, 0] * F[..., 2, 1] - F[..., 1, 1] * F[..., 2, 0]))


def _inv_sym3(C, det):
    """Inverse of symmetric (..., 3, 3) C with determinant ``det`` (cofactors)."""
    a, b, c = C[..., 0, 0], C[..., 1, 1], C[..., 2, 2]
    d, e, f = C[..., 0, 1], C[..., 1, 2], C[..., 0, 2]
    out = np.empty_like(C)
    out[..., 0, 0] = b * c - e * e
    out[..., 1, 1] = a * c - f * f
    out[..., 2, 2] = a * b - d * d
    out[..., 0, 1] = out[..., 1, 0] = f * e - d * c
    out[..., 1, 2] = out[..., 2, 1] = d * f - a * e
    out[..., 0, 2] = out[..., 2, 0] = d * e - b * f
    return out / det[..., None, None]


class _InvariantMaterial(Material):
    """W(I1, I2, J): S and CC from the partial derivatives returned by ``_derivs``."""

    def energy_and_stress(self, F):
        # fused only where W and S are entirely the invariant form (not Guccione's fibre part)
        if type(self).energy is not _InvariantMaterial.energy or type(self).pk2 is not _InvariantMaterial.pk2:
            return Material.energy_and_stress(self, F)
        C = np.swapaxes(F, -1, -2) @ F
        I1 = np.trace(C, axis1=-2, axis2=-1)
        I2 = 0.5 * (I1**2 - np.einsum("...ij,...ij->...", C, C))
        J = _det3(F)
        with np.errstate(invalid="ignore", divide="ignore"):
            W, W1, W2, WJ, _, _, _ = self._derivs(I1, I2, J)
            e = lambda a: a[..., None, None]  # noqa: E731
            S = 2 * e(W1 + W2 * I1) * _I - 2 * e(W2) * C + e(WJ * J) * _inv_sym3(C, J * J)
        return W, F @ S

    def _derivs(self, I1, I2, J):
        """Return W, W1, W2, WJ, W1J, W2J, WJJ (W11 = W22 = W12 = 0 for our models)."""
        raise NotImplementedError

    @staticmethod
    def _kinematics(F):
        C = np.swapaxes(F, -1, -2) @ F
        I1 = np.trace(C, axis1=-2, axis2=-1)
        I2 = 0.5 * (I1**2 - np.einsum("...ij,...ij->...", C, C))
        J = np.linalg.det(F)
        return C, I1, I2, J

    def energy(self, F):
        _, I1, I2, J = self._kinematics(F)
        with np.errstate(invalid="ignore", divide="ignore"):
            return self._derivs(I1, I2, J)[0]

    def pk2(self, F, tangent=True):
        C, I1, I2, J = self._kinematics(F)
        with np.errstate(invalid="ignore", divide="ignore"):
            Ci = np.linalg.inv(C)
            _, W1, W2, WJ, W1J, W2J, WJJ = self._derivs(I1, I2, J)
            B = I1[..., None, None] * _I - C
            e = lambda a: a[..., None, None]  # noqa: E731
            S = 2 * e(W1) * _I + 2 * e(W2) * B + e(WJ * J) * Ci
            if not tangent:
                return S, None
            e4 = lambda a: a[..., None, None, None, None]  # noqa: E731
            II = _outer(_I, _I)
            CC = (4 * e4(W2) * (II - _sym_identity(_I))
                  + 2 * e4(J * W1J) * (_outer(_I + 0 * Ci, Ci) + _outer(Ci, _I + 0 * Ci))
                  + 2 * e4(J * W2J) * (_outer(B, Ci) + _outer(Ci, B))
                  + e4(J**2 * WJJ + J * WJ) * _outer(Ci, Ci)
                  - 2 * e4(J * WJ) * _sym_identity(Ci))
            return S, CC


@dataclass(frozen=True)
class NeoHookean(_EnuMaterial, _InvariantMaterial):
    """Compressible neo-Hookean: W = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2."""

    name = "neo_hookean"

    def _derivs(self, I1, I2, J):
        lam, mu = self.lame
        lnJ = np.log(J)
        z = np.zeros_like(J)
        W = 0.5 * mu * (I1 - 3) - mu * lnJ + 0.5 * lam * lnJ**2
        return W, 0.5 * mu + z, z, (-mu + lam * lnJ) / J, z, z, (mu + lam * (1 - lnJ)) / J**2

    def volumetric(self, J):
        """U = lambda/2 (ln J)^2: the incompressible limit keeps mu/2 (I1 - 3) - mu ln J."""
        lam, lnJ = self.lame[0], np.log(J)
        return 0.5 * lam * lnJ**2, lam * lnJ / J, lam * (1 - lnJ) / J**2


@dataclass(frozen=True)
class NeoHookeanDecoupled(_EnuMaterial, _InvariantMaterial):
    """Decoupled compressible neo-Hookean: W = mu/2 (J^-2/3 I1 - 3) + kappa/4 (J^2 - 1 - 2 ln J).

    The isochoric/volumetric split of the deal.II code gallery's Cook membrane
    (``Quasi_static_Finite_strain_Compressible_Elasticity``, Pelteret and McBride 2016)
    with the small-strain moduli of (E, nu): mu = E / (2 (1 + nu)) and the bulk modulus
    kappa = lambda + 2/3 mu = 2 mu (1 + nu) / (3 (1 - 2 nu)).
    """

    name = "neo_hookean_decoupled"

    @property
    def bulk_modulus(self) -> float:
        return self.E / (3 * (1 - 2 * self.nu))

    def _derivs(self, I1, I2, J):
        mu, k = self.lame[1], self.bulk_modulus
        z = np.zeros_like(J)
        Jm23 = J ** (-2 / 3)
        W = 0.5 * mu * (Jm23 * I1 - 3) + 0.25 * k * (J**2 - 1 - 2 * np.log(J))
        W1 = 0.5 * mu * Jm23
        W1J = -mu / 3 * Jm23 / J
        WJ = W1J * I1 + 0.5 * k * (J - 1 / J)
        WJJ = 5 * mu / 9 * Jm23 / J**2 * I1 + 0.5 * k * (1 + 1 / J**2)
        return W, W1, z, WJ, W1J, z, WJJ

    def volumetric(self, J):
        """U = kappa/4 (J^2 - 1 - 2 ln J)."""
        k = self.bulk_modulus
        return 0.25 * k * (J**2 - 1 - 2 * np.log(J)), 0.5 * k * (J - 1 / J), 0.5 * k * (1 + 1 / J**2)


@dataclass(frozen=True)
class MooneyRivlin(_InvariantMaterial):
    """Compressible Mooney-Rivlin: mu1/2 (J^-2/3 I1 - 3) + mu2/2 (J^-4/3 I2 - 3) + kappa/2 (J-1)^2."""

    mu1: float
    mu2: float
    kappa: float
    name = "mooney_rivlin"

    def __post_init__(self):
        _check_positive("mu1", self.mu1)
        if not (math.isfinite(self.mu2) and self.mu2 >= 0):
            raise ValueError(f"mu2 must be a finite number >= 0, got {self.mu2!r}")
        _check_positive("kappa", self.kappa)

    def _derivs(self, I1, I2, J):
        m1, m2, k = self.mu1, self.mu2, self.kappa
        W = 0.5 * m1 * (J ** (-2 / 3) * I1 - 3) + 0.5 * m2 * (J ** (-4 / 3) * I2 - 3) + 0.5 * k * (J - 1) ** 2
        W1, W2 = 0.5 * m1 * J ** (-2 / 3), 0.5 * m2 * J ** (-4 / 3)
        W1J, W2J = -m1 / 3 * J ** (-5 / 3), -2 * m2 / 3 * J ** (-7 / 3)
        WJ = -m1 / 3 * J ** (-5 / 3) * I1 - 2 * m2 / 3 * J ** (-7 / 3) * I2 + k * (J - 1)
        WJJ = 5 * m1 / 9 * J ** (-8 / 3) * I1 + 14 * m2 / 9 * J ** (-10 / 3) * I2 + k
        return W, W1, W2, WJ, W1J, W2J, WJJ

    def volumetric(self, J):
        """U = kappa/2 (J - 1)^2."""
        return _quadratic_penalty(self.kappa, J)


def _quadratic_penalty(kappa, J):
    return 0.5 * kappa * (J - 1) ** 2, kappa * (J - 1), kappa + np.zeros_like(J)


def _fibre_tensor(f, bf, bt, bfs):
    """D with Q = E:D:E for unit fibre directions f, shape (..., 3) -> (..., 3, 3, 3, 3)."""
    f = f / np.linalg.norm(f, axis=-1, keepdims=True)
    # Frame-free form of Q (transversely isotropic about f):
    # Q = bf a^2 + bt (E:E - 2|Ef|^2 + a^2) + 2 bfs (|Ef|^2 - a^2), a = f.E.f
    ff = np.einsum("...i,...j->...ij", f, f)
    ffff = _outer(ff, ff)
    IsI = _sym_identity(_I)
    # |Ef|^2 = E_Ik f_k f_l E_Il -> symmetric 4th-order form
    Efx = 0.25 * (np.einsum("IK,...JL->...IJKL", _I, ff) + np.einsum("IL,...JK->...IJKL", _I, ff)
                  + np.einsum("JK,...IL->...IJKL", _I, ff) + np.einsum("JL,...IK->...IJKL", _I, ff))
    return (bf + bt - 2 * bfs) * ffff + bt * IsI + (2 * bfs - 2 * bt) * Efx


@dataclass(frozen=True)
class Guccione(_InvariantMaterial):
    """Guccione law W = C/2 (exp(Q) - 1) + kappa/2 (J - 1)^2.

    ``fibres`` is one direction, shape (3,), or one per cell, shape (n_cells, 3).
    """

    C: float
    bf: float
    bt: float
    bfs: float
    kappa: float
    fibres: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    name = "guccione"

    def __post_init__(self):
        for n in ("C", "bf", "bt", "bfs", "kappa"):
            _check_positive(n, getattr(self, n))
        f = np.asarray(self.fibres, dtype=float)
        if f.shape[-1:] != (3,) or f.ndim > 2 or not np.all(np.isfinite(f)):
            raise ValueError(f"fibres must be finite with shape (3,) or (n_cells, 3), got {f.shape}")
        if np.any(np.linalg.norm(f, axis=-1) < 1e-12):
            raise ValueError("fibres contains a zero vector")
        object.__setattr__(self, "fibres", f / np.linalg.norm(f, axis=-1, keepdims=True))

    def validate_for_mesh(self, n_cells):
        if self.fibres.ndim == 2 and len(self.fibres) != n_cells:
            raise ValueError(f"fibres has {len(self.fibres)} rows, the mesh has {n_cells} cells")

    def _D(self, F):
        f = self.fibres if self.fibres.ndim == 1 else self.fibres[:, None, :]
        return _fibre_tensor(f, self.bf, self.bt, self.bfs)

    def _derivs(self, I1, I2, J):  # volumetric part only
        z = np.zeros_like(J)
        k = self.kappa
        return 0.5 * k * (J - 1) ** 2, z, z, k * (J - 1), z, z, k + z

    def volumetric(self, J):
        """U = kappa/2 (J - 1)^2: the incompressible limit keeps C/2 (exp(Q) - 1)."""
        return _quadratic_penalty(self.kappa, J)

    def energy(self, F):
        E = 0.5 * (np.swapaxes(F, -1, -2) @ F - _I)
        Q = np.einsum("...IJ,...IJKL,...KL->...", E, self._D(F), E)
        return 0.5 * self.C * (np.exp(Q) - 1) + _InvariantMaterial.energy(self, F)

    def pk2(self, F, tangent=True):
        E = 0.5 * (np.swapaxes(F, -1, -2) @ F - _I)
        D = self._D(F)
        dQ = 2 * np.einsum("...IJKL,...KL->...IJ", D, E)
        eQ = 0.5 * self.C * np.exp(np.einsum("...IJ,...IJ->...", E, 0.5 * dQ))
        Sv, CCv = _InvariantMaterial.pk2(self, F, tangent)
        S = eQ[..., None, None] * dQ + Sv
        if not tangent:
            return S, None
        CC = eQ[..., None, None, None, None] * (_outer(dQ, dQ) + 2 * D) + CCv
        return S, CC


MATERIALS = {cls.name: cls for cls in (LinearElastic, SaintVenantKirchhoff, NeoHookean, NeoHookeanDecoupled,
                                       MooneyRivlin, Guccione)}


def make_material(name, **params) -> Material:
    """Build a material by registry name (or pass a :class:`Material` subclass)."""
    if isinstance(name, type) and issubclass(name, Material):
        return name(**params)
    if name not in MATERIALS:
        raise ValueError(f"unknown material {name!r}; valid: {sorted(MATERIALS)}")
    try:
        return MATERIALS[name](**params)
    except TypeError as exc:
        raise ValueError(f"material {name!r}: {exc}") from None
