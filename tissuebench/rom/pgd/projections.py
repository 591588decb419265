"""Online use of the PGD modes à la POD (pgd-vademecum-cutting §2.1, eqs. 10-19).

* **srb** (space reduced basis): the parameter is particularised first, then the
  standard weak form is projected on span{X_i}: ``(X^T K X) beta = X^T f(s_p)``, the
  field is ``X beta``. The span is what matters, so the basis is made K-orthonormal
  offline (``Phi = X V Λ^{-1/2}`` from ``X^T K X = V Λ V^T``, directions with
  ``λ <= rcond λ_max`` dropped: nearly dependent modes) and the reduced matrix is the
  identity: ``q = Phi^T f(s_p)``.
* **prb** (parametric reduced basis): the solution is sought as
  ``sum_i beta_i X_i(x) S_i(s)`` in the doubly weak form with the load fixed at s_p
  (eq. 14 for N modes): ``(alpha ∘ X^T K X) beta = gamma ∘ (X^T f(s_p))`` with
  ``alpha_ij = int S_i S_j``, ``gamma_i = int S_i`` (eq. 15); the field at s_p is
  ``sum_i beta_i S_i(s_p) X_i``, i.e. the coefficients on X are ``q = beta ∘ S(s_p)``.
  One mode: ``beta_prb = (gamma / alpha) beta_srb`` (eq. 18), and, S being the exact
  projection given X, ``beta_srb = S(s_p)`` (eq. 19). The exact vademecum would need
  ``beta = 1``: prb is not consistent, which is the paper's point (srb is better).

Both reduced matrices are factorised offline; with cuts they are the leading block of
the coupled system (28) (:mod:`.cutting_method`).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .vademecum import Vademecum

__all__ = ["SrbProjection", "PrbProjection", "PROJECTIONS", "make_projection"]

PROJECTIONS = ("srb", "prb")


class SrbProjection:
    """Galerkin on span{X_i} with a K-orthonormal basis (module docstring).

    Attributes
    ----------
    basis : (n_free, r) K-orthonormal columns (r <= N)
    K_r : (r, r) reduced stiffness (identity up to round-off)
    loads_r : (r, n_s) reduced load of each parameter node
    """

    name = "srb"

    def __init__(self, vademecum: Vademecum, rcond: float = 1e-12):
        X, K = vademecum.X, vademecum.family.K
        lam, V = np.linalg.eigh(0.5 * ((X.T @ (K @ X)) + (X.T @ (K @ X)).T))
        keep = lam > rcond * lam.max()
        self.vademecum = vademecum
        self.basis = np.ascontiguousarray(X @ (V[:, keep] / np.sqrt(lam[keep])))
        self.K_r = self.basis.T @ (K @ self.basis)
        self.loads_r = np.asarray((vademecum.family.loads.T @ self.basis).T)
        self.n_dropped = int((~keep).sum())

    def coefficients(self, rows, values, S_p=None) -> np.ndarray:
        """``q = Phi^T f`` for a load ``values`` on the free-dof ``rows`` (S_p unused)."""
        return values @ self.basis[rows]

    def coefficients_at(self, j: int) -> np.ndarray:
        """``q`` of the load at parameter node ``j`` (precomputed reduced load)."""
        return self.loads_r[:, j].copy()


class PrbProjection:
    """Doubly weak form on {X_i S_i} (module docstring).

    Attributes
    ----------
    basis : (n_free, N) the space modes X (coefficients ``q = beta ∘ S(s_p)``)
    K_r : (N, N) ``alpha ∘ (X^T K X)``; gamma : (N,)
    """

    name = "prb"

    def __init__(self, vademecum: Vademecum, rcond: float = 1e-12):
        X, K = vademecum.X, vademecum.family.K
        KX = X.T @ (K @ X)
        self.vademecum, self.basis = vademecum, np.ascontiguousarray(X)
        self.K_r = vademecum.alpha * 0.5 * (KX + KX.T)
        self.gamma = vademecum.gamma
        # pseudo-inverse through eigh: modes with (near) identical X_i S_i make K_r singular
        lam, V = np.linalg.eigh(self.K_r)
        keep = lam > rcond * lam.max()
        self._inv = (V[:, keep] / lam[keep]) @ V[:, keep].T
        self.loads_r = np.asarray((vademecum.family.loads.T @ X).T) * self.gamma[:, None]
        self.n_dropped = int((~keep).sum())

    def beta(self, rows, values) -> np.ndarray:
        """``beta`` of eq. 14 (N modes) for a load ``values`` on the free-dof ``rows``."""
        x = values @ self.basis[rows]
        x *= self.gamma
        return self._inv @ x

    def coefficients(self, rows, values, S_p) -> np.ndarray:
        """Coefficients on X at s_p: ``beta ∘ S(s_p)``."""
        b = self.beta(rows, values)
        b *= S_p
        return b

    def coefficients_at(self, j: int) -> np.ndarray:
        return (self._inv @ self.loads_r[:, j]) * self.vademecum.S[j]


def make_projection(name: str, vademecum: Vademecum, rcond: float = 1e-12):
    """An :class:`SrbProjection` or :class:`PrbProjection` of ``vademecum``."""
    if name == "srb":
        return SrbProjection(vademecum, rcond)
    if name == "prb":
        return PrbProjection(vademecum, rcond)
    raise ValueError(f"projection = {name!r}; valid: {list(PROJECTIONS)}")


def srb_beta_in_modes(vademecum: Vademecum, rows, values) -> np.ndarray:
    """``beta_srb`` on the original modes X (not the orthonormalised basis): the solution
    of ``(X^T K X) beta = X^T f`` (for the identities of eqs. 18-19)."""
    X, K = vademecum.X, vademecum.family.K
    return sla.solve(X.T @ (K @ X), X[rows].T @ values, assume_a="pos")
