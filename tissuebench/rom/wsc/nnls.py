"""Optimised cubature: elements and non-negative weights fitted by NNLS (An, Kim, James 2008).

Training data: the displacement snapshots of reference runs (``Training.snapshots``),
projected on the subspace (:class:`~.subspace.MassProjector`), ``q_s``. For each
training state the exact reduced force ``b_s = T^T U^T f_int(U q_s)`` (full assembly,
offline) and the contributions ``g_e(q_s) = T^T U_e^T f_e(U_e q_s)`` of the candidate
elements give the least-squares system ``sum_e w_e g_e(q_s) = b_s`` (rows of each state
scaled by ``1 / |b_s|`` so that every state counts alike), solved for ``w >= 0`` by
``scipy.optimize.nnls``.

Sizes are kept tractable (NNLS costs about rows x columns x nonzeros): candidates are
``candidates * budget`` elements spread by furthest-point sampling of the centroids;
when the stacked rows outnumber ``sketch * budget`` they are compressed by a seeded
Gaussian sketch (a random row combination that keeps the least-squares geometry in
expectation). If NNLS keeps more than ``budget`` elements, the largest weights are kept
and refitted. Every fourth snapshot is held out: the rule's relative force error on
them (exact, unsketched) is reported, and a build whose error exceeds ``tol`` is
refused (ValueError with the error), so a rule that cannot meet the tolerance never
passes silently.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from scipy.optimize import nnls

from .cubature import Cubature
from .handles import furthest_point_sampling
from .subspace import MassProjector

__all__ = ["nnls_cubature", "element_contributions"]


def element_contributions(sub, kernel, cell_nodes, q) -> sp.csr_matrix:
    """``g_e(q) = T^T U_e^T f_e(U_e q)`` of the kernel's cells as columns, shape (n_z, m)."""
    m, a = cell_nodes.shape
    phi = sp.csr_matrix(sub.phi[cell_nodes.ravel()]).tocoo()  # rows e * a + local node
    u_loc = (sub.phi[cell_nodes.ravel()] @ np.asarray(q).reshape(-1, 3)).reshape(m, -1)
    fe = kernel.forces(u_loc).reshape(m * a, 3)
    e = phi.row // a
    rows = (3 * phi.col[:, None] + np.arange(3)).ravel()
    vals = (phi.data[:, None] * fe[phi.row]).ravel()
    G = sp.csr_matrix((vals, (rows, np.repeat(e, 3))), shape=(sub.n_q, m))
    return sp.csr_matrix(sub.T.T @ G)


def nnls_cubature(sub, backend, training, budget, centroids, tol=0.05, seed=0, candidates=2.0,
                  sketch=1.5, max_snapshots=24) -> Cubature:
    """Fit a cubature rule of at most ``budget`` elements (see the module docstring).

    Raises
    ------
    ValueError
        No training snapshots, fewer than 4 of them, or a held-out fit error above ``tol``.
    """
    tic = time.perf_counter()
    S = training.snapshots
    if S is None or S.shape[1] < 4:
        raise ValueError("wsc cubature='nnls' needs training snapshots (>= 4 reference states) from reference runs")
    pb = backend.problem
    cols = np.unique(np.linspace(0, S.shape[1] - 1, min(max_snapshots, S.shape[1])).round().astype(int))
    cols = cols[np.any(S[:, cols] != 0, axis=0)]  # the rest state carries no force information
    held = cols[3::4]
    train = np.setdiff1d(cols, held)
    proj = MassProjector(sub, backend.mass())
    qs = {int(c): sub.q_of(*proj.project(S[:, c])) for c in cols}
    n_cand = min(pb.mesh.n_cells, max(budget, int(candidates * budget)))
    cand = furthest_point_sampling(centroids, n_cand, seed + 1).indices
    kernel = backend.cell_kernel(cand)
    nodes = pb.layout[1][cand]

    def target(q):
        return sub.z_of(sub.U.T @ backend.internal_force(sub.displacement(q)))

    rows_total = len(train) * sub.n_z
    n_rows = min(rows_total, max(int(sketch * budget), 200))
    rng = np.random.default_rng(seed)
    A, b = np.zeros((n_rows, n_cand)), np.zeros(n_rows)
    dense_rows = rows_total == n_rows
    for i, c in enumerate(train):
        G, bs = element_contributions(sub, kernel, nodes, qs[int(c)]), target(qs[int(c)])
        scale = 1.0 / max(np.linalg.norm(bs), 1e-300)
        if dense_rows:
            A[i * sub.n_z:(i + 1) * sub.n_z] = scale * G.toarray()
            b[i * sub.n_z:(i + 1) * sub.n_z] = scale * bs
        else:  # Gaussian sketch of this state's rows, accumulated
            Sk = rng.standard_normal((n_rows, sub.n_z)) / np.sqrt(n_rows)
            A += scale * (G.T @ Sk.T).T
            b += scale * (Sk @ bs)
    w, _ = nnls(A, b, maxiter=20 * n_cand)
    keep = np.flatnonzero(w > 0)
    if len(keep) > budget:  # keep the heaviest, refit
        keep = keep[np.argsort(w[keep])[::-1][:budget]]
        w_keep, _ = nnls(A[:, keep], b, maxiter=20 * len(keep))
        w = np.zeros_like(w)
        w[keep] = w_keep
        keep = keep[w_keep > 0]
    if not len(keep):
        raise ValueError("wsc cubature='nnls': the fit selected no element (all-zero weights)")
    train_err = float(np.linalg.norm(A[:, keep] @ w[keep] - b) / max(np.linalg.norm(b), 1e-300))
    errors = []
    sel_kernel, sel_nodes = backend.cell_kernel(cand[keep]), pb.layout[1][cand[keep]]
    for c in held:
        G, bs = element_contributions(sub, sel_kernel, sel_nodes, qs[int(c)]), target(qs[int(c)])
        errors.append(float(np.linalg.norm(G @ w[keep] - bs) / max(np.linalg.norm(bs), 1e-300)))
    held_err = max(errors) if errors else float("nan")
    info = {"train_error": train_err, "heldout_error": held_err, "heldout_errors": errors,
            "snapshots_train": len(train), "snapshots_heldout": len(held), "candidates": n_cand,
            "rows": n_rows, "sketched": not dense_rows, "offline_s": time.perf_counter() - tic}
    if tol is not None and not held_err <= tol:
        raise ValueError(f"wsc cubature='nnls': relative force error {held_err:.3g} on held-out snapshots exceeds "
                         f"nnls_tol = {tol:g} with {len(keep)} of {budget} elements (training error {train_err:.3g}); "
                         "raise the budget, the candidates, or nnls_tol")
    return Cubature(cand[keep], w[keep], "nnls", info)
