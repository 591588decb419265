"""Reduced internal force, tangent and energy of a Galerkin model, from weighted elements.

For a set of elements ``e`` with weights ``w_e``::

    E(q)   = sum_e w_e W_e(u_e)          f_r(q) = sum_e w_e V_e^T f_e(u_e)
    K_r(q) = sum_e w_e V_e^T K_e(u_e) V_e,         u_e = V_e q + (prescribed values of e's fixed dofs)

``V_e`` the rows of the basis at the element's dofs (zero on the fixed ones). Every element
with weight 1 is the exact projection ``V^T f_int(V q)`` (``hyper = "none"``: full assembly,
the accuracy ceiling); a few elements with the weights of an ECSW fit (:mod:`.ecsw`) is the
hyper-reduced force, energy-conserving (a non-negative sum of element energies: its
gradient is the force, its Hessian the tangent).

The sums are evaluated at the elements' quadrature points through the *mode gradients*
``G_r = grad(V_r)`` (3 x 3 per point and mode, computed offline): ``F = I + sum_r G_r q_r``,
``f_r = sum_p w_p P : G_r`` and ``K_rs = sum_p w_p (B G_r) . D (B G_s) + G_r S : G_s`` (``B G =
sym(F^T G)`` in Voigt form, ``D = dS/dE``), so no element vector or matrix is formed: a force
is two products with the (points x 9, r) array of the mode gradients and the material at the
points (:class:`~.kernel.ElementKernel`). Measured (CPU time) on 119 elements of the
neo-Hookean liver, 20 modes: force 0.11 ms and tangent 0.62 ms through element vectors and
matrices, 0.09 ms and 0.36 ms through the mode gradients (``tests/rom/test_galerkin_kernel.py``
checks both against the assembled operators).

:class:`LinearForces`: a linear material's reduced operator is exact and constant, ``f_r = K_r q
+ K_rc u_c``; it needs no sample.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .kernel import _HALF, _VI, _VJ, ElementKernel, cell_geometry

__all__ = ["ReducedForces", "LinearForces", "element_forces"]

_I3 = np.eye(3)
_IJ, _JI = _VI * 3 + _VJ, _VJ * 3 + _VI  # flat (I, J) and (J, I) of the Voigt entries


class ReducedForces:
    """Weighted element sums (module docstring).

    Parameters
    ----------
    kernel : ElementKernel
        Of the elements' cells (their quadrature, shape-function gradients and material).
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
        self.dofs = np.asarray(dofs, dtype=np.int64)
        self.m, self.n_loc = self.dofs.shape
        self.r = basis_full.shape[1]
        self._basis_full = basis_full
        m, q, a, r = kernel.m, kernel.q, kernel.a, self.r
        n = m * q
        V4 = basis_full[self.dofs].reshape(m, a, 3, r)
        # mode gradients at the points, (n, 3 i, 3 J, r): G[p, i, J, r] = sum_a V[e, a, i, r] g[e, q, a, J]
        G = np.einsum("eair,eqaJ->eqiJr", V4, kernel.grad)
        self._G9 = np.ascontiguousarray(G.reshape(n * 9, r))  # one array: views of it are not counted twice
        self._wp = np.repeat(self.weights, q) * kernel.dx.reshape(-1)  # point weights [volume]
        self._fixed = np.asarray(fixed, dtype=np.int64)
        self._lift = self._lift_map(self._fixed, kernel.grad) if len(self._fixed) else None

    def _lift_map(self, fixed, grad):
        """Sparse (n 9, n_c): the deformation gradients of the prescribed values, or None where no
        element has a fixed dof."""
        fixed = np.asarray(fixed, dtype=np.int64)
        pos = np.minimum(np.searchsorted(fixed, self.dofs), len(fixed) - 1)
        e, k = np.nonzero(fixed[pos] == self.dofs)  # element e's local dof k is fixed dof pos[e, k]
        if not len(e):
            return None
        q = self.kernel.q
        a, i = k // 3, k % 3
        rows, cols, vals = [], [], []
        for qq in range(q):
            p = e * q + qq
            for J in range(3):
                rows.append((p * 3 + i) * 3 + J)
                cols.append(pos[e, k])
                vals.append(grad[e, qq, a, J])
        rows, cols, vals = (np.concatenate(x) for x in (rows, cols, vals))
        return sp.csr_matrix((vals, (rows, cols)), shape=(self.m * q * 9, len(fixed)))

    @property
    def size(self) -> int:
        """Number of elements evaluated per call."""
        return self.m

    def _F(self, q, uc):
        """Deformation gradients (n, 3, 3) at the points."""
        F = (self._G9 @ q).reshape(-1, 3, 3) + _I3
        if self._lift is not None and uc is not None:
            F += (self._lift @ uc).reshape(-1, 3, 3)
        return F

    def _P(self, F):
        """(W (n,), P (n, 3, 3)) at the points."""
        k = self.kernel
        if k._invariant:
            return k._invariant_pk1(F)
        W, S, _ = k._stress(F, False)
        return W, np.matmul(F, S)

    def energy(self, q, uc=None) -> float:
        """Weighted strain energy [energy]."""
        return float(self._wp @ self._P(self._F(q, uc))[0])

    def force(self, q, uc=None) -> np.ndarray:
        """Reduced internal force (r,) [force]: ``sum_p w_p P : G_r``."""
        _, P = self._P(self._F(q, uc))
        return (P * self._wp[:, None, None]).reshape(-1) @ self._G9

    def contributions(self, q, uc=None) -> np.ndarray:
        """Per element, its unweighted contribution ``V_e^T f_e`` to the reduced force, (m, r)."""
        _, P = self._P(self._F(q, uc))
        Pw = (P * self.kernel.dx.reshape(-1)[:, None, None]).reshape(self.m, -1)  # (m, q 9)
        return np.einsum("ek,ekr->er", Pw, self._G9.reshape(self.m, -1, self.r))

    def tangent(self, q, uc=None) -> np.ndarray:
        """Reduced tangent (r, r) [force / length], dense."""
        return self.force_and_tangent(q, uc)[1]

    def force_and_tangent(self, q, uc=None):
        """(force (r,), tangent (r, r)) from one evaluation of the points (module docstring)."""
        F = self._F(q, uc)
        _, S, D = self.kernel._stress(F, True)
        n, r, w = len(F), self.r, self._wp
        P = np.matmul(F, S)
        f = (P * w[:, None, None]).reshape(-1) @ self._G9
        G = self._G9.reshape(n, 3, 3, r)
        FtG = np.matmul(F.transpose(0, 2, 1), G.reshape(n, 3, 3 * r)).reshape(n, 9, r)  # F^T G_r
        BG = (FtG.take(_IJ, axis=1) + FtG.take(_JI, axis=1)) * _HALF[None, :, None]  # (n, 6, r): dE of mode r
        K = (BG * w[:, None, None]).reshape(-1, r).T @ np.matmul(D, BG).reshape(-1, r)
        SG = np.matmul(S[:, None], G) * w[:, None, None, None]  # (n, i, J, s) = sum_L S[J, L] G[i, L, s]
        K += self._G9.T @ SG.reshape(-1, r)
        return f, K


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
