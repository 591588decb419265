"""Monitored outputs of an interpolated basis without forming the basis (:mod:`.anm_interp`).

The interpolated ANM-POD models (``anm_pod_interp``, ``podi``, ``grassmann``) step in m-space,
but their basis at a new load position, ``B(s)`` (n_free, m), is an O(n m^2) computation that
only :meth:`reconstruct` needs. An output ``y = C u = C B(s) q`` needs only ``C B(s)``
(n_out, m), and every basis they interpolate lies in the span of the stored (aligned) bases
``A_k``, so ``C B(s)`` follows from m-sized quantities computed offline: ``C A_k`` and the
Gram blocks ``A_k^T A_l``.

* PODI: ``B = B0 (B0^T B0)^{-1/2}`` with ``B0 = sum_k w_k A_k`` (the polar factor, as
  :func:`~.anm_interp._polar`): ``C B = (sum_k w_k C A_k) V Λ^{-1/2} V^T`` from the eigenpairs
  of ``B0^T B0 = sum_kl w_k w_l A_k^T A_l``.
* Grassmann (two neighbours, the reference ``r`` the one of larger weight): the log map of
  the other, ``X = (A_o - A_r M) M^{-1} = U S V^T`` (``M = A_r^T A_o``), is decomposed offline
  per neighbour pair; the exp map of ``w_o U atan(S) V^T`` is then
  ``G = A_r V^T cos(σ) V + U sin(σ) V`` with ``σ = w_o atan(S)`` (:func:`~.interpolation.grassmann_exp`,
  the signs of ``σ`` and ``U`` compensating), and its Procrustes rotation onto ``B0`` comes
  from the SVD of ``G^T B0`` (m x m), built from ``A_r^T A_k`` and ``U^T A_k``.

Round-off apart these are the outputs of the reconstructed field (tested); where a step is
degenerate (a nearly singular ``B0^T B0``, no log map) :meth:`InterpolatedOutputs.operator`
returns None and the caller reconstructs.
"""
from __future__ import annotations

import numpy as np

__all__ = ["InterpolatedOutputs"]


class InterpolatedOutputs:
    """``C B(s)`` of the interpolated basis from m-sized quantities (module docstring).

    Parameters
    ----------
    C_free : (n_out, n_free) output functionals on the free dofs
    bases : (k, n_free, m) aligned stored bases
    kind : {"podi", "grassmann"}
    """

    def __init__(self, C_free, bases, kind: str):
        self.kind = kind
        A = np.asarray(bases, float)
        k, _, m = A.shape
        self.CA = np.einsum("on,knm->kom", C_free, A)  # (k, n_out, m)
        self.gram = np.einsum("knm,lnp->klmp", A, A)  # (k, k, m, m): A_k^T A_l
        self.pairs = {}
        if kind == "grassmann":
            for r in range(k):
                for o in (r - 1, r + 1):
                    if 0 <= o < k:
                        self.pairs[(r, o)] = self._log_pair(C_free, A, r, o)

    @staticmethod
    def _log_pair(C_free, A, r, o):
        """(S, Vt, C U, U^T A_r, U^T A_o) of the log map's ``X = U S V^T`` at ``A_r`` towards ``A_o``
        (:func:`~.interpolation.grassmann_log` before its arctangent), None without a log map."""
        M = A[r].T @ A[o]
        if np.linalg.svd(M, compute_uv=False).min() < 1e-12:
            return None
        X = np.linalg.solve(M.T, (A[o] - A[r] @ M).T).T
        U, S, Vt = np.linalg.svd(X, full_matrices=False)
        return S, Vt, C_free @ U, U.T @ A[r], U.T @ A[o]

    def operator(self, idx, w):
        """``C B(s)`` (n_out, m) for the interpolation neighbours ``idx`` with weights ``w`` (as
        :func:`~.interpolation.interpolation_weights` returns them), or None (degenerate: reconstruct)."""
        idx = [int(i) for i in idx]
        w = [float(v) for v in w]
        if len(idx) == 1:
            return self.CA[idx[0]]
        CB0 = sum(wi * self.CA[i] for wi, i in zip(w, idx))
        G0 = sum(wi * wj * self.gram[i, j] for wi, i in zip(w, idx) for wj, j in zip(w, idx))
        if self.kind == "podi":
            lam, V = np.linalg.eigh(G0)
            if lam[0] <= 1e-8 * lam[-1]:
                return None
            return CB0 @ ((V / np.sqrt(lam)) @ V.T)
        if len(idx) != 2:
            return None
        r = idx[int(np.argmax(w))]
        o = idx[0] if r == idx[1] else idx[1]
        pair = self.pairs.get((r, o))
        if pair is None:
            return None
        S, Vt, CU, UA_r, UA_o = pair
        w_o = w[idx.index(o)]
        sigma = w_o * np.arctan(S)
        P0 = (Vt.T * np.cos(sigma)) @ Vt
        P1 = np.sin(sigma)[:, None] * Vt
        w_r = w[idx.index(r)]
        ArB = w_r * self.gram[r, r] + w_o * self.gram[r, o]
        UB = w_r * UA_r + w_o * UA_o
        Wl, _, Zt = np.linalg.svd(P0.T @ ArB + P1.T @ UB)
        return (self.CA[r] @ P0 + CU @ P1) @ (Wl @ Zt)
