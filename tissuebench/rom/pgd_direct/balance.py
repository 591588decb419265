"""Coordinates of the previous state in which greedy PGD converges: balancing the step map.

The step map of a linear system is ``z(p) = sum_j z_j p_j + z_lam lam``: one column per
state coordinate. Greedy PGD recovers it with one mode per coordinate when the columns
are orthogonal in the norm of the final solve; with correlated columns of comparable
weight (``M^{-1} K phi_j`` in a velocity update) the best rank-one term mixes
coordinates, leaves cross terms in the residual, and the enrichment converges slowly
(measured on wave_block, 8 POD modes, forward Euler: 40 modes for a 10 % residual; on
clamped_beam, Bathe, 4 modes: 200 modes for a 1e-4 error instead of 9). A change of
coordinates that makes the columns orthogonal removes most of this: each POD basis is
rotated within its own space (eigenvectors of the Gram matrix of its columns, largest
first), so every parameter stays a coordinate of one field (the paper's ``G_i(u^n)``,
``H_i(u^{n-1})``) and the separated SVK force keeps its displacement coordinates. The
spaces spanned, the projection and the exact step map are unchanged: only the
parametrisation the PGD sees. (Rotating all state coordinates together, displacement and
velocity mixed, was measured too and is not better: the dominant state direction of a
quasi-static response is then parallel to the load column, a tie greedy PGD resolves
slowly — clamped_beam, HHT: 150 modes in the acceleration solve instead of 10.) The
columns come from the scheme applied to unit coordinates (:class:`~.schemes.VectorAlgebra`;
a nonlinear system is linearised at rest).
"""
from __future__ import annotations

import numpy as np

from .schemes import StepOperators, VectorAlgebra

__all__ = ["rotate_fields", "step_columns"]


def step_columns(ops: StepOperators, scheme, bases: dict, dt: float, scales: dict, **options):
    """Step-map columns of every state coordinate and their Gram matrix.

    Returns
    -------
    G : (P_s, P_s) array
        ``Z^T W Z`` with ``Z`` the stacked outputs (scaled by ``scales``) of unit
        coordinates, in state order (field by field), and ``W`` the block mass.
    """
    lin = StepOperators(ops.M, ops.K, ops.f, ops.C)
    alg = VectorAlgebra(lin)
    fields = scheme.state_fields(ops.C is not None)
    zero = np.zeros(ops.n)
    cols = []
    for field in fields:
        for j in range(bases[field].shape[1]):
            state = {f: zero for f in fields}
            state[field] = bases[field][:, j]
            nxt = alg.step(scheme, state, dt, 0.0, **options)
            cols.append([scales.get(k, 1.0) * nxt[k] for k in scheme.outputs])
    n_out = len(scheme.outputs)
    G = sum(np.array([c[k] for c in cols]) @ (ops.M @ np.array([c[k] for c in cols]).T) for k in range(n_out))
    return 0.5 * (G + G.T)


def _eig_desc(G):
    lam, V = np.linalg.eigh(G)
    order = np.argsort(lam)[::-1]
    return np.sqrt(np.maximum(lam[order], 0.0)), V[:, order]


def _break_ties(lam, V, C, rtol=1e-6):
    """Within clusters of (relatively) equal eigenvalues of G, rotate to diagonalise C.

    Any orthonormal basis of a degenerate eigenspace keeps the columns orthogonal; the one
    that also decorrelates the training coordinates (covariance C) gives coordinates of
    distinct amplitude, so the PGD terms have distinct weights (ties between equal-weight
    terms stall its fixed point: the velocity columns of forward Euler are all equal).
    """
    V = V.copy()
    i = 0
    while i < len(lam):
        j = i + 1
        while j < len(lam) and abs(lam[j] - lam[i]) <= rtol * max(abs(lam[0]), 1e-300):
            j += 1
        if j - i > 1:
            Vc = V[:, i:j]
            mu, W = np.linalg.eigh(Vc.T @ C @ Vc)
            V[:, i:j] = Vc @ W[:, np.argsort(mu)[::-1]]
        i = j
    return V


def rotate_fields(sb, ops, scheme, dt, scales, basis_of: dict | None = None, covariances: dict | None = None,
                  **options) -> dict:
    """Rotate each basis of ``sb`` (:class:`~.operators.StateBases`) in place ("field" balancing).

    ``basis_of`` maps each state field to its basis (default ``scheme.basis``). Fields
    sharing a basis (u and u_prev; u and v with ``velocity_basis="displacement"``) sum
    their Gram blocks. ``covariances`` (basis -> covariance of its training coordinates)
    break ties between equal singular values (:func:`_break_ties`). Returns basis name ->
    singular values of its columns (decreasing).
    """
    basis_of = scheme.basis if basis_of is None else basis_of
    fields = scheme.state_fields(ops.C is not None)
    bases = {f: sb.bases[basis_of[f]] for f in fields}
    G = step_columns(ops, scheme, bases, dt, scales, **options)
    offs = np.concatenate([[0], np.cumsum([bases[f].shape[1] for f in fields])])
    out = {}
    for kind in dict.fromkeys(basis_of[f] for f in fields):
        idx = [i for i, f in enumerate(fields) if basis_of[f] == kind]
        Gk = sum(G[offs[i]:offs[i + 1], offs[i]:offs[i + 1]] for i in idx)
        sing, V = _eig_desc(Gk)
        if covariances is not None and kind in covariances:
            V = _break_ties(sing**2, V, covariances[kind])
        sb.rotate(kind, V)
        out[kind] = sing
    return out

