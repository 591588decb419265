"""Skinning weights: normalised radial basis functions around the handles (wsc paper §2.3).

Kernel (the paper leaves ``b_r`` open; ours): the modified Shepard (Franke-Little)
function with compact support radius ``r``::

    b_r(d) = ((r - d)_+ / (r d))^2,        w_ij = b_r(d_ij) / sum_l b_r(d_il)

with ``d_ij`` the Euclidean distance from node i to handle j. It is singular at d = 0,
so the normalised weight of a handle at its own node is exactly 1 and all others 0
(the weights interpolate, whatever the support), and it vanishes smoothly (C1) at
``d = r``. Rows sum to 1 (partition of unity), hence ``x = sum_j w_j A_j [X; 1]``
reproduces any affine map shared by all handles exactly. The support is
``r = support * R``, ``R`` the covering radius of the handles (every node lies within
``R`` of a handle), so ``support > 1`` guarantees every node sees a handle.

Boundary handles: each Dirichlet set gets its own handle whose distance is the distance
to the set (with its own, smaller support ``group_radius``); nodes of the set take
weight 1 on it (and 0 elsewhere), so its affine map alone moves them -- the prescribed
motion is imposed through that handle.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

__all__ = ["shepard_kernel", "skinning_weights"]


def shepard_kernel(d, radius: float) -> np.ndarray:
    """Franke-Little weight ``((r - d)_+ / (r d))^2`` (inf at d = 0, 0 for d >= r)."""
    d = np.asarray(d, dtype=float)
    with np.errstate(divide="ignore"):
        return (np.maximum(radius - d, 0.0) / (radius * d)) ** 2


def skinning_weights(nodes, handle_points, radius: float, groups=(), group_radius: float | None = None) \
        -> sp.csr_matrix:
    """Normalised weights of every node on every handle, shape (n_nodes, k + len(groups)).

    Parameters
    ----------
    nodes : (n, 3) array
        Node coordinates (all discretisation nodes).
    handle_points : (k, 3) array
        Handle positions (mesh vertices).
    radius : float
        Support radius r of the kernel [length].
    groups : sequence of (m_g,) int arrays
        Node sets with a boundary handle each (columns k, k + 1, ...); a node in several
        sets belongs to the last one.
    group_radius : float, optional
        Support radius of the boundary handles (default ``radius``).

    Raises
    ------
    ValueError
        A node outside the support of every handle (radius too small).
    """
    X = np.asarray(nodes, dtype=float)
    H = np.asarray(handle_points, dtype=float).reshape(-1, 3)
    if not (np.isfinite(radius) and radius > 0):
        raise ValueError(f"radius must be a finite length > 0, got {radius!r}")
    k, n = len(H), len(X)
    lists = cKDTree(H).query_ball_point(X, radius) if k else [[] for _ in range(n)]
    rows = np.repeat(np.arange(n), [len(c) for c in lists])
    cols = np.fromiter((j for c in lists for j in c), dtype=np.int64, count=len(rows))
    dist = np.linalg.norm(X[rows] - H[cols], axis=1)
    rg = radius if group_radius is None else float(group_radius)
    radii = np.full(len(dist), radius)
    for g, members in enumerate(groups):
        d_g, _ = cKDTree(X[np.asarray(members)]).query(X, distance_upper_bound=rg)
        near = np.flatnonzero(np.isfinite(d_g))
        rows = np.concatenate([rows, near])
        cols = np.concatenate([cols, np.full(len(near), k + g)])
        dist = np.concatenate([dist, d_g[near]])
        radii = np.concatenate([radii, np.full(len(near), rg)])
    b = shepard_kernel(dist, radii)
    keep = b > 0
    rows, cols, b = rows[keep], cols[keep], b[keep]
    # a node on a handle (d = 0, b = inf) takes that handle alone
    at = np.isinf(b)
    on_handle = np.zeros(n, dtype=bool)
    on_handle[rows[at]] = True
    b = np.where(on_handle[rows], at.astype(float), b)
    W = sp.csr_matrix((b, (rows, cols)), shape=(n, k + len(groups)))
    W.sum_duplicates()
    for g, members in enumerate(groups):  # set members: their boundary handle alone
        members = np.asarray(members)
        W = _replace_rows(W, members, k + g)
    total = np.asarray(W.sum(axis=1)).ravel()
    if np.any(total <= 0):
        i = int(np.flatnonzero(total <= 0)[0])
        raise ValueError(f"skinning_weights: node {i} at {X[i]} lies outside the support radius {radius:.4g} "
                         "of every handle; increase the support")
    return sp.csr_matrix(sp.diags(1.0 / total) @ W)


def _replace_rows(W, rows, col):
    """``W`` with the given rows replaced by the unit row e_col."""
    keep = np.ones(W.shape[0])
    keep[rows] = 0.0
    E = sp.csr_matrix((np.ones(len(rows)), (rows, np.full(len(rows), col))), shape=W.shape)
    return sp.csr_matrix(sp.diags(keep) @ W + E)
