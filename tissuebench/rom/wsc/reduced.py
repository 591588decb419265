"""Reduced internal force, energy and tangent by cubature: O(sample elements) per call.

For sample elements ``e`` with weights ``w_e`` (:mod:`.cubature`)::

    E(q)   = sum_e w_e W_e(U_e q)                   (strain energy)
    f_q(q) = sum_e w_e U_e^T f_e(U_e q)             (reduced internal force, eq. 15-16)
    K_q(q) = sum_e w_e U_e^T K_e(U_e q) U_e         (reduced tangent)

``U_e q`` is gathered through the skinning weights of the element nodes: the blended
affine map of node i, ``B_i = sum_j w_ij A_j`` (a sparse (a m) x k product with the
12 entries of every A_j), applied to ``[1, X_i]``; the force goes back the same way,
``f_A[j] = sum_i w_e w_ij [1, X_i] (x) f_i``. No full-size vector is formed; the blended
maps are formed once per distinct node of the samples (a node shared by sample elements --
paper cube, 2820 samples: 11 280 element nodes, 7143 distinct -- is blended once, and its
weighted element forces are summed before they are projected). Element
energies, force vectors and tangents come from the backend's
:meth:`~tissuebench.refsolvers.backends.base.Backend.cell_kernel`.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.sparse as sp

__all__ = ["CubatureForces"]


class CubatureForces:
    """Cubature evaluation of the reduced energy, force and tangent.

    Parameters
    ----------
    subspace : Subspace
    backend : Backend
        Provides ``cell_kernel(cells)`` and ``problem.layout``.
    cubature : Cubature
    """

    def __init__(self, subspace, backend, cubature):
        self.cubature = cubature
        self.kernel = backend.cell_kernel(cubature.cells)
        cell_nodes = backend.problem.layout[1][cubature.cells]  # (m, a)
        self.m, self.a = cell_nodes.shape
        self.n_q = subspace.n_q
        self.phi = sp.csr_matrix(subspace.phi[cell_nodes.ravel()])  # (m a, 4 k)
        nodes, self.row_node = np.unique(cell_nodes.ravel(), return_inverse=True)  # distinct nodes, (m a,)
        self.W = sp.csr_matrix(subspace.weights[nodes])  # (n_u, k)
        self.WT = sp.csr_matrix(self.W.T)  # (k, n_u)
        self.Xt = np.column_stack([np.ones(len(nodes)), subspace.nodes[nodes]])  # (n_u, 4)
        w_rows = np.repeat(cubature.weights, self.a)
        # weighted sum of the element-node forces onto the distinct nodes, (n_u, m a)
        self.gather_w = sp.csr_matrix((w_rows, (self.row_node, np.arange(len(w_rows)))),
                                      shape=(len(nodes), len(w_rows)))
        self.w = cubature.weights

    def local(self, q) -> np.ndarray:
        """Element displacements ``U_e q``, shape (m, 3 a)."""
        B = (self.W @ np.asarray(q).reshape(-1, 12)).reshape(-1, 4, 3)  # blended affine maps
        return np.einsum("rb,rbc->rc", self.Xt, B)[self.row_node].reshape(self.m, -1)

    def project(self, fe) -> np.ndarray:
        """``sum_e w_e U_e^T f_e`` of element force vectors (m, 3 a): the reduced force (n_q,)."""
        f = self.gather_w @ fe.reshape(-1, 3)  # (n_u, 3)
        G = (self.Xt[:, :, None] * f[:, None, :]).reshape(-1, 12)
        return (self.WT @ G).ravel()

    def energy_and_force(self, q):
        """(E [energy], f_q (n_q,) [force]) at q."""
        W, fe = self.kernel.energies_and_forces(self.local(q))
        return float(self.w @ W), self.project(fe)

    def force(self, q) -> np.ndarray:
        return self.energy_and_force(q)[1]

    @cached_property
    def _U_loc(self) -> sp.csr_matrix:
        """``U_e`` of all samples stacked, shape (3 a m, n_q)."""
        return sp.csr_matrix(sp.kron(self.phi, sp.identity(3), format="csr"))

    def force_and_tangent(self, q):
        """(f_q (n_q,), K_q dense (n_q, n_q)) at q."""
        fe, Ke = self.kernel.forces_and_tangents(self.local(q))
        n = Ke.shape[1]
        rows = (np.arange(self.m)[:, None, None] * n + np.arange(n)[None, :, None]).repeat(n, axis=2)
        cols = (np.arange(self.m)[:, None, None] * n + np.arange(n)[None, None, :]).repeat(n, axis=1)
        B = sp.csr_matrix(((self.w[:, None, None] * Ke).ravel(), (rows.ravel(), cols.ravel())),
                          shape=(self.m * n, self.m * n))
        U = self._U_loc
        K = (U.T @ (B @ U)).toarray()
        return self.project(fe), 0.5 * (K + K.T)
