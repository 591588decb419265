"""DEIM: empirical interpolation of the internal force (Chaturantabut & Sorensen 2010).

The internal force on the free dofs is approximated in a basis ``U`` (n_free, p) of its own
snapshots, from its values at ``p`` interpolation dofs ``P`` chosen greedily from ``U``
(Algorithm 1 of the paper, pyMOR's ``deim``)::

    f_int(u) ~ U (P^T U)^-1 P^T f_int(u),      f_r(q) ~ D P^T f_int(u(q)),  D = V^T U (P^T U)^-1

``P^T f_int`` needs only the elements around the interpolation dofs (the "reduced mesh"): their
element force vectors, summed onto the sampled dofs. The reduced tangent is ``D P^T K V``, not
symmetric in general, and the approximation is not the gradient of an energy (the contrast
with ECSW, :mod:`.ecsw`); :meth:`DeimForces.energy` is None, and the energy balance of a run is
accumulated from the work of the forces.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..pod import pod_basis
from .forces import ReducedForces, element_forces

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
    """The DEIM reduced force and tangent on the elements around the interpolation dofs.

    ``select`` (p, m n_loc) sums the element force entries onto the sampled dofs; ``D`` (r, p).
    """

    def bind(self, select, D, info):
        self.select, self.D, self.info = select, np.ascontiguousarray(D), info
        return self

    def energy(self, q, uc=None):
        return None

    def force(self, q, uc=None):
        _, fe = self.kernel.energies_and_forces(self.local(q, uc))
        return self.D @ (self.select @ fe.ravel())

    def tangent(self, q, uc=None):
        _, Ke = self.kernel.forces_and_tangents(self.local(q, uc))
        return self.D @ (self.select @ np.matmul(Ke, self.V_loc).reshape(-1, self.r))

    def force_and_tangent(self, q, uc=None):
        fe, Ke = self.kernel.forces_and_tangents(self.local(q, uc))
        return (self.D @ (self.select @ fe.ravel()),
                self.D @ (self.select @ np.matmul(Ke, self.V_loc).reshape(-1, self.r)))


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
    local = dofs_all[cells].ravel()
    row_of = {int(d): j for j, d in enumerate(sampled)}
    entries = [(row_of[int(d)], k) for k, d in enumerate(local) if int(d) in row_of]
    rows, cols = np.array(entries).T
    select = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(sampled), len(local)))
    info = {"force_modes": int(U.shape[1]), "force_rank": int(pod.rank), "elements": int(len(cells)),
            "interpolation_dofs": int(len(idx)), "force_energy_captured": float(pod.energy_captured),
            "condition_PtU": float(np.linalg.cond(U[idx])), "offline_s": time.perf_counter() - tic}
    return deim.bind(select, D, info)
