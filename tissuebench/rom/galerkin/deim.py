"""DEIM: empirical interpolation of the internal force (Chaturantabut & Sorensen 2010).

The internal force on the free dofs is split into its linear part at rest and the nonlinear
remainder, ``f_int(u) = K_0 u + g(u)``. The linear part is projected exactly (``V^T K_0 V``,
``r x r``, formed once); the remainder is approximated in a basis ``U`` (n_free, m) of its own
snapshots, from its values at ``p >= m`` sampled dofs ``P``::

    g(u) ~ U (P^T U)^+ P^T g(u),      f_r(q) ~ D P^T f_int(u(q)) + (V^T K_0 V - D P^T K_0 V) q,
    D = V^T U (P^T U)^+

(plus the same two terms in the prescribed values ``u_c`` of a prescribed motion). With ``p = m``,
``(P^T U)^+ = (P^T U)^-1`` and the remainder is interpolated exactly at the sampled dofs, chosen
greedily from ``U`` (Algorithm 1 of the paper, pyMOR's ``deim``);
with ``p > m`` the fit is least squares over more dofs (gappy POD, "oversampled DEIM"), the dofs
past the first ``m`` chosen one at a time to raise the smallest singular value of ``P^T U``
(the point selection "E" of Peherstorfer, Drmac & Gugercin 2020, SIAM J. Sci. Comput. 42,
A2837), which bounds the fit's amplification of what ``U`` does not span.

Why the linear part is kept out of the fit (issue 52; measured on the dome of
``examples/nearly_incompressible_organ`` in motion, neo-Hookean nu = 0.49, 2154 dofs, 30 modes,
59 force modes, on the states of a held-out run): fitting the whole force, the reduced tangent
``D P^T K V`` (the exact derivative of the fitted force) was off by up to 32 % of ``V^T K V``
and its symmetric part indefinite (smallest eigenvalue -12 N/m, against +0.23 N/m for
``V^T K V``). A force whose Jacobian is indefinite feeds the reduced motion: the run's error
grew to 14 % at t = 0.285 s and 150 % at 0.305 s, and the Newton matrix was singular at 0.31 s,
although the interpolation was well conditioned (cond P^T U = 32). The stiff volumetric
response is nearly linear at these strains; with the linear part exact the tangent's error is
7.7 %, its symmetric part positive definite (smallest eigenvalue 0.21 N/m), and the run errs
by 0.84 % (full assembly 0.77 %). Oversampling alone (``p = 2 m``: 1.5 %, ``4 m``: 1.4 %) holds
the run but leaves the tangent indefinite (-1.1 and -0.34 N/m); the two together: 0.78 %, so
``p = 2 m`` is :class:`~.method.PodGalerkin`'s default.

``P^T f_int`` needs only the elements around the sampled dofs (the "reduced mesh"): the
stresses at their quadrature points, mapped onto the sampled dofs by the shape-function
gradients. The reduced tangent is not symmetric in general, and the approximation is not the
gradient of an energy (the contrast with ECSW, :mod:`.ecsw`); :meth:`DeimForces.energy` is
None, and the energy balance of a run is accumulated from the work of the forces.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from ..pod import pod_basis
from .forces import _IJ, _JI, ReducedForces, element_forces
from .kernel import _HALF, _VOIGT

__all__ = ["deim_indices", "oversampled_indices", "least_squares_coefficients", "DeimForces", "deim_forces"]

#: ``P^T U`` with a smallest singular value below this fraction of its largest cannot be fitted
SINGULAR_RTOL = 1e-12


def deim_indices(U) -> np.ndarray:
    """The DEIM interpolation indices of the columns of ``U`` (n, p), in the greedy order."""
    U = np.asarray(U, float)
    idx = [int(np.argmax(np.abs(U[:, 0])))]
    for j in range(1, U.shape[1]):
        c = np.linalg.solve(U[idx, :j], U[idx, j])
        idx.append(int(np.argmax(np.abs(U[:, j] - U[:, :j] @ c))))
    return np.array(idx, dtype=np.int64)


def oversampled_indices(U, samples: int) -> np.ndarray:
    """``samples`` row indices of ``U`` (n, m): the DEIM indices first, then one row at a time
    the one of largest ``g + |u_i|^2 - sqrt((g + |u_i|^2)^2 - 4 g (w . u_i)^2)``, with ``g =
    s_{m-1}^2 - s_m^2`` and ``w`` the right singular vector of the smallest singular value ``s_m``
    of the rows chosen so far (for ``m = 1``, the largest ``u_i^2``): a lower bound of the gain
    of ``s_m^2`` the row brings (Peherstorfer, Drmac & Gugercin 2020, Algorithm 1).

    Raises
    ------
    ValueError
        ``samples`` below the columns of ``U`` or above its rows (names the value).
    """
    U = np.asarray(U, float)
    n, m = U.shape
    if not m <= samples <= n:
        raise ValueError(f"oversampled_indices: samples must lie in [{m}, {n}] (the force modes, the rows), "
                         f"got {samples!r}")
    idx = list(deim_indices(U))
    norms = np.einsum("ij,ij->i", U, U)
    taken = np.zeros(n, bool)
    taken[idx] = True
    while len(idx) < samples:
        if m == 1:
            gain = norms.copy()
        else:
            _, s, Wt = np.linalg.svd(U[idx], full_matrices=False)
            g = s[-2] ** 2 - s[-1] ** 2
            a = g + norms
            gain = a - np.sqrt(np.maximum(a * a - 4.0 * g * (U @ Wt[-1]) ** 2, 0.0))
        gain[taken] = -np.inf
        i = int(np.argmax(gain))
        idx.append(i)
        taken[i] = True
    return np.array(idx, dtype=np.int64)


def least_squares_coefficients(VtU, PtU) -> np.ndarray:
    """``D = V^T U (P^T U)^+`` (r, p) by a least-squares solve (no pseudo-inverse formed): for a
    square ``P^T U`` it is ``V^T U (P^T U)^-1``, the interpolation.

    Raises
    ------
    ValueError
        ``P^T U`` of (numerically) lower rank than its columns: the sampled dofs cannot tell the
        force modes apart (its singular values named).
    """
    PtU = np.asarray(PtU, float)
    s = np.linalg.svd(PtU, compute_uv=False)
    if s.size == 0 or not s[-1] > SINGULAR_RTOL * s[0]:
        raise ValueError(f"pod_galerkin DEIM: the sampled rows of the force basis have rank below its {PtU.shape[1]} "
                         f"modes (singular values of P^T U from {s[0] if s.size else 0:.3e} to "
                         f"{s[-1] if s.size else 0:.3e}): fewer deim_modes")
    # D (P^T U) = V^T U in the least-squares sense: the minimum-norm X of (P^T U)^T X = (V^T U)^T
    return np.linalg.lstsq(PtU.T, np.asarray(VtU, float).T, rcond=None)[0].T


class DeimForces(ReducedForces):
    """The DEIM reduced force and tangent from the quadrature points of the elements around the
    sampled dofs (the mode gradients of :class:`~.forces.ReducedForces`).

    ``select`` (p, points x 9) maps the points' first Piola-Kirchhoff stresses to the internal
    force at the sampled dofs (``f_d = sum_p dx P_iJ g_aJ`` for dof ``d`` = component i of node a);
    ``D`` (r, p); ``A_q`` (r, r) and ``A_c`` (r, n_c), the linear part's correction
    ``V^T K_0 V - D P^T K_0 V`` and ``V^T K_0fc - D P^T K_0fc`` (module docstring; None: none).
    """

    def bind(self, select, D, info, A_q=None, A_c=None):
        self.select, self.D, self.info = select, np.ascontiguousarray(D), info
        self.A_q = None if A_q is None else np.ascontiguousarray(A_q)
        self.A_c = None if A_c is None else np.ascontiguousarray(A_c)
        return self

    def energy(self, q, uc=None):
        return None

    def _linear(self, f, q, uc):
        if self.A_q is not None:
            f = f + self.A_q @ q
        if self.A_c is not None and uc is not None:
            f = f + self.A_c @ uc
        return f

    def force(self, q, uc=None):
        _, P = self._P(self._F(q, uc))
        return self._linear(self.D @ (self.select @ (P * self._wp[:, None, None]).ravel()), q, uc)

    def tangent(self, q, uc=None):
        return self.force_and_tangent(q, uc)[1]

    def force_and_tangent(self, q, uc=None):
        """``(D P^T f_int + A_q q + A_c u_c, D P^T K V + A_q)``: ``dP/dq_r = G_r S + F dS_r``,
        ``dS_r = D_mat dE(G_r)``."""
        F = self._F(q, uc)
        _, S, Dm = self.kernel._stress(F, True)
        n, r, w = len(F), self.r, self._wp[:, None, None]
        G = self._G9.reshape(n, 3, 3, r)
        FtG = np.matmul(F.transpose(0, 2, 1), G.reshape(n, 3, 3 * r)).reshape(n, 9, r)
        BG = (FtG.take(_IJ, axis=1) + FtG.take(_JI, axis=1)) * _HALF[None, :, None]
        dS = np.matmul(Dm, BG)[:, _VOIGT]  # (n, 3, 3, r)
        dP = np.matmul(G.transpose(0, 3, 1, 2), S[:, None]) + np.matmul(F[:, None], dS.transpose(0, 3, 1, 2))
        f = self.select @ (np.matmul(F, S) * w).ravel()
        K = self.D @ (self.select @ (dP * w[:, None]).transpose(0, 2, 3, 1).reshape(-1, r))
        return self._linear(self.D @ f, q, uc), (K if self.A_q is None else K + self.A_q)


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


def deim_forces(backend, basis, free, basis_full, fixed, full_states, modes: int,
                oversampling: float = 1.0) -> DeimForces:
    """The DEIM forces of a basis (module docstring).

    Parameters
    ----------
    backend : Backend
    basis : (n_free, r) array
    free, fixed : int arrays
        Free dofs of ``basis``'s rows; fixed dofs (sorted).
    full_states : list of (ndof,) arrays
        Full displacements of the training states (projected snapshots) whose internal forces,
        less their linear part ``K_0 u``, are the force snapshots.
    modes : int
        Force modes ``m`` (at most the rank of the force snapshots).
    oversampling : float, >= 1
        Sampled dofs per force mode: ``p = ceil(oversampling m)`` (1: interpolation), at most the
        free dofs.

    Raises
    ------
    ValueError
        The sampled rows of the force basis are rank deficient (:func:`least_squares_coefficients`).
    """
    tic = time.perf_counter()
    free, fixed = np.asarray(free), np.asarray(fixed, dtype=np.int64)
    K0 = sp.csr_matrix(backend.tangent(np.zeros(backend.ndof)))[free]
    F = np.column_stack([backend.internal_force(u)[free] - K0 @ u for u in full_states])
    pod = pod_basis(F, n_modes=int(modes))
    U = pod.modes
    m = U.shape[1]
    idx = oversampled_indices(U, min(int(np.ceil(float(oversampling) * m - 1e-9)), U.shape[0]))
    PtU = U[idx]
    D = least_squares_coefficients(basis.T @ U, PtU)  # V^T U (P^T U)^+
    K0V = K0 @ basis_full  # K_0ff V: the basis is zero on the fixed dofs
    A_q = basis.T @ K0V - D @ K0V[idx]
    K0c = K0[:, fixed] if len(fixed) else None
    A_c = None if K0c is None or K0c.nnz == 0 else (K0c.T @ basis).T - D @ K0c[idx].toarray()
    dofs_all = backend.element_dofs()
    sampled = free[idx]
    cells = np.flatnonzero(np.isin(dofs_all, sampled).any(axis=1))
    deim = element_forces(backend, cells, np.ones(len(cells)), basis_full, fixed, cls=DeimForces)
    select = _select(deim, dofs_all[cells], sampled)
    info = {"force_modes": int(m), "force_rank": int(pod.rank), "elements": int(len(cells)),
            "interpolation_dofs": int(len(idx)), "force_energy_captured": float(pod.energy_captured),
            "condition_PtU": float(np.linalg.cond(PtU)), "offline_s": time.perf_counter() - tic}
    return deim.bind(select, D, info, A_q, A_c)
