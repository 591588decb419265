"""DEIM: empirical interpolation of the internal force (Chaturantabut & Sorensen 2010).

The internal force on the free dofs is approximated in a basis ``U`` (n_free, p) of its own
snapshots, from its values at ``p`` interpolation dofs ``P`` chosen greedily from ``U``
(Algorithm 1 of the paper, pyMOR's ``deim``)::

    f_int(u) ~ U (P^T U)^-1 P^T f_int(u),      f_r(q) ~ D P^T f_int(u(q)),  D = V^T U (P^T U)^-1

``P^T f_int`` needs only the elements around the interpolation dofs (the "reduced mesh"): the
stresses at their quadrature points, mapped onto the sampled dofs by the shape-function
gradients. The reduced tangent is ``D P^T K V``, not symmetric in general, and the
approximation is not the gradient of an energy (the contrast with ECSW, :mod:`.ecsw`);
:meth:`DeimForces.energy` is None, and the energy balance of a run is accumulated from the work
of the forces.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..pod import pod_basis
from .forces import _IJ, _JI, ReducedForces, element_forces
from .kernel import _HALF, _VOIGT

__all__ = ["deim_indices", "DeimForces", "deim_forces"]


def deim_indices(U) -> np.ndarray:
    """The DEIM interpolation indices of the columns of ``U`` (n, p), in the greedy order."""
    U = np.asarray(U, float)
    idx = [int(np.argmax(np.abs(U[:, 0])))]
    for j in range(1, U.shape[1]):
        c = np.linalg.solve(U[idx, :j], U[idx, j])
        idx.append(int(np.argmax(np.abs(U[:, j] - U[:, :j] @ c))))
    return np.array(idx, dtype=np.int64)


class DeimForces(ReducedForces):
    """The DEIM reduced force and tangent from the quadrature points of the elements around the
    interpolation dofs (the mode gradients of :class:`~.forces.ReducedForces`).

    ``select`` (p, points x 9) maps the points' first Piola-Kirchhoff stresses to the internal
    force at the sampled dofs (``f_d = sum_p dx P_iJ g_aJ`` for dof ``d`` = component i of node a);
    ``D`` (r, p).
    """

    def bind(self, select, D, info):
        self.select, self.D, self.info = select, np.ascontiguousarray(D), info
        return self

    def energy(self, q, uc=None):
        return None

    def force(self, q, uc=None):
        _, P = self._P(self._F(q, uc))
        return self.D @ (self.select @ (P * self._wp[:, None, None]).ravel())

    def tangent(self, q, uc=None):
        return self.force_and_tangent(q, uc)[1]

    def force_and_tangent(self, q, uc=None):
        """``(D P^T f_int, D P^T K V)``: ``dP/dq_r = G_r S + F dS_r``, ``dS_r = D_mat dE(G_r)``."""
        F = self._F(q, uc)
        _, S, Dm = self.kernel._stress(F, True)
        n, r, w = len(F), self.r, self._wp[:, None, None]
        G = self._G9.reshape(n, 3, 3, r)
        FtG = np.matmul(F.transpose(0, 2, 1), G.reshape(n, 3, 3 * r)).reshape(n, 9, r)
        BG = (FtG.take(_IJ, axis=1) + FtG.take(_JI, axis=1)) * _HALF[None, :, None]
        dS = np.matmul(Dm, BG)[:, _VOIGT]  # (n, 3, 3, r)
        dP = np.matmul(G.transpose(0, 3, 1, 2), S[:, None]) + np.matmul(F[:, None], dS.transpose(0, 3, 1, 2))
        f = self.select @ (np.matmul(F, S) * w).ravel()
        K = self.select @ (dP * w[:, None]).transpose(0, 2, 3, 1).reshape(-1, r)
        return self.D @ f, self.D @ K


def _select(forces, dofs, sampled) -> sp.csr_matrix:
    """(p, points x 9): the sampled dofs' internal force from the points' weighted stresses."""
    kernel, q = forces.kernel, forces.kernel.q
    row_of = {int(d): j for j, d in enumerate(sampled)}
    e, k = np.nonzero(np.isin(dofs, sampled))
    rows_d = np.array([row_of[int(d)] for d in dofs[e, k]], dtype=np.int64)
    a, i = k // 3, k % 3
    rows, cols, vals = [], [], []
    for qq in range(q):
        for J in range(3):
            rows.append(rows_d)
            cols.append(((e * q + qq) * 3 + i) * 3 + J)
            vals.append(kernel.grad[e, qq, a, J])
    rows, cols, vals = (np.concatenate(x) for x in (rows, cols, vals))
    return sp.csr_matrix((vals, (rows, cols)), shape=(len(sampled), kernel.m * q * 9))


def deim_forces(backend, basis, free, basis_full, fixed, full_states, modes: int) -> DeimForces:
    """The DEIM forces of a basis (module docstring).

    Parameters
    ----------
    backend : Backend
    basis : (n_free, r) array
    free, fixed : int arrays
        Free dofs of ``basis``'s rows; fixed dofs (sorted).
    full_states : list of (ndof,) arrays
        Full displacements of the training states (projected snapshots) whose internal forces
        are the force snapshots.
    modes : int
        Force modes ``p`` (at most the rank of the force snapshots).
    """
    tic = time.perf_counter()
    F = np.column_stack([backend.internal_force(u)[free] for u in full_states])
    pod = pod_basis(F, n_modes=int(modes))
    U = pod.modes
    idx = deim_indices(U)
    D = np.linalg.solve(U[idx].T, U.T @ basis).T  # V^T U (P^T U)^-1
    dofs_all = backend.element_dofs()
    sampled = np.asarray(free)[idx]
    cells = np.flatnonzero(np.isin(dofs_all, sampled).any(axis=1))
    deim = element_forces(backend, cells, np.ones(len(cells)), basis_full, fixed, cls=DeimForces)
    select = _select(deim, dofs_all[cells], sampled)
    info = {"force_modes": int(U.shape[1]), "force_rank": int(pod.rank), "elements": int(len(cells)),
            "interpolation_dofs": int(len(idx)), "force_energy_captured": float(pod.energy_captured),
            "condition_PtU": float(np.linalg.cond(U[idx])), "offline_s": time.perf_counter() - tic}
    return deim.bind(select, D, info)
