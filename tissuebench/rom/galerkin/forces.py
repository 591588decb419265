"""Reduced internal force, tangent and energy of a Galerkin model, from weighted elements.

For a set of elements ``e`` with weights ``w_e``::

    E(q)   = sum_e w_e W_e(u_e)          f_r(q) = sum_e w_e V_e^T f_e(u_e)
    K_r(q) = sum_e w_e V_e^T K_e(u_e) V_e,         u_e = V_e q + (prescribed values of e's fixed dofs)

``V_e`` the rows of the basis at the element's dofs (zero on the fixed ones). Every element
with weight 1 is the exact projection ``V^T f_int(V q)`` (``hyper = "none"``: full assembly,
the accuracy ceiling); a few elements with the weights of an ECSW fit (:mod:`.ecsw`) is the
hyper-reduced force, energy-conserving (a non-negative sum of element energies: its
gradient is the force, its Hessian the tangent). Element quantities come from
:class:`~.kernel.ElementKernel`.

:class:`LinearForces`: a linear material's reduced operator is exact and constant, ``f_r = K_r q
+ K_rc u_c``; it needs no sample.
"""
from __future__ import annotations

import numpy as np

from .kernel import ElementKernel, cell_geometry

__all__ = ["ReducedForces", "LinearForces", "element_forces"]


class ReducedForces:
    """Weighted element sums (module docstring).

    Parameters
    ----------
    kernel : ElementKernel
        Of the elements' cells.
    dofs : (m, n_loc) int array
        Global dofs of each element's local dofs.
    weights : (m,) array
    basis_full : (ndof, r) array
        The basis on every dof (zero rows on the fixed ones).
    fixed : (n_c,) int array
        The fixed dofs in the order of the prescribed values ``u_c`` the methods take (sorted).
    cells : (m,) int array
        Mesh cell of each element (reported).
    """

    def __init__(self, kernel: ElementKernel, dofs, weights, basis_full, fixed, cells):
        self.kernel, self.cells = kernel, np.asarray(cells, dtype=np.int64)
        self.weights = np.asarray(weights, float)
        dofs = np.asarray(dofs, dtype=np.int64)
        self.m, self.n_loc = dofs.shape
        self.r = basis_full.shape[1]
        self.V_loc = np.ascontiguousarray(basis_full[dofs])  # (m, n_loc, r)
        self._V = self.V_loc.reshape(-1, self.r)
        self._wV = np.ascontiguousarray((self.weights[:, None, None] * self.V_loc).reshape(-1, self.r))
        fixed = np.asarray(fixed, dtype=np.int64)
        pos = np.searchsorted(fixed, dofs)
        on_fixed = (pos < len(fixed)) & (fixed[np.minimum(pos, max(len(fixed) - 1, 0))] == dofs) if len(fixed) \
            else np.zeros(dofs.shape, bool)
        # prescribed values gathered as uc_pad[index]: the last entry of uc_pad is a zero
        self._lift = np.where(on_fixed, pos, len(fixed)) if on_fixed.any() else None

    @property
    def size(self) -> int:
        """Number of elements evaluated per call."""
        return self.m

    def local(self, q, uc=None) -> np.ndarray:
        """Element displacements (m, n_loc) at reduced coordinates q (r,) and prescribed values uc."""
        u = (self._V @ q).reshape(self.m, self.n_loc)
        if self._lift is not None and uc is not None:
            u += np.append(uc, 0.0)[self._lift]
        return u

    def energy(self, q, uc=None) -> float:
        """Weighted strain energy [energy]."""
        W, _ = self.kernel.energies_and_forces(self.local(q, uc))
        return float(self.weights @ W)

    def force(self, q, uc=None) -> np.ndarray:
        """Reduced internal force (r,) [force]."""
        _, fe = self.kernel.energies_and_forces(self.local(q, uc))
        return self._wV.T @ fe.ravel()

    def tangent(self, q, uc=None) -> np.ndarray:
        """Reduced tangent (r, r) [force / length], dense."""
        _, Ke = self.kernel.forces_and_tangents(self.local(q, uc))
        return self._wV.T @ np.matmul(Ke, self.V_loc).reshape(-1, self.r)

    def force_and_tangent(self, q, uc=None):
        """(force (r,), tangent (r, r)) from one evaluation of the elements."""
        fe, Ke = self.kernel.forces_and_tangents(self.local(q, uc))
        return self._wV.T @ fe.ravel(), self._wV.T @ np.matmul(Ke, self.V_loc).reshape(-1, self.r)


class LinearForces:
    """A linear material: ``f_r = K_r q + K_rc u_c``, ``K_r`` constant (module docstring).

    Parameters
    ----------
    K_r : (r, r) array
    K_rc : (r, n_c) array or None
        Coupling to the prescribed values (None without a prescribed motion).
    """

    size = 0

    def __init__(self, K_r, K_rc=None):
        self.K_r, self.K_rc = np.asarray(K_r, float), K_rc

    def force(self, q, uc=None):
        f = self.K_r @ q
        return f if self.K_rc is None or uc is None else f + self.K_rc @ uc

    def tangent(self, q, uc=None):
        return self.K_r

    def force_and_tangent(self, q, uc=None):
        return self.force(q, uc), self.K_r

    def energy(self, q, uc=None):
        f = self.force(q, uc)
        return 0.5 * float(q @ f) if uc is None or self.K_rc is None else None


def element_forces(backend, cells, weights, basis_full, fixed, cls=None) -> ReducedForces:
    """:class:`ReducedForces` (or its subclass ``cls``) of ``cells`` of ``backend``'s problem with ``weights``."""
    cells = np.asarray(cells, dtype=np.int64)
    grad, dx = cell_geometry(backend, cells)
    kernel = ElementKernel(grad, dx, backend.problem.material, cells)
    dofs = backend.element_dofs()[cells]
    return (cls or ReducedForces)(kernel, dofs, weights, basis_full, fixed, cells)
