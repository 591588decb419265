"""ECSW: energy-conserving sampling and weighting of the reduced internal force.

Farhat, Avery, Chapman, Cortial (2014) IJNME 98:625 and Farhat, Chapman, Avery (2015)
IJNME 102:1077. On training states ``q_s`` (projected snapshots) the exact reduced force is
the sum of the element contributions ``g_e(q_s) = V_e^T f_e(u_e(q_s))``; ECSW looks for a few
elements with non-negative weights that reproduce it::

    min ||A w - b||  s.t. w >= 0,    A = [g_e(q_s)]_(s, e),  b = [sum_e g_e(q_s)]_s

(the rows of each state scaled by ``1 / |b_s|``, so that small motions count as much as large
ones), stopped as soon as the relative residual ``|A w - b| / |b|`` is at most ``tol``.
Non-negative weights keep the reduced force the gradient of a positive weighted energy (energy
conservation and the symmetry of the tangent, the method's name).

The fit is the Lawson-Hanson active-set NNLS stopped at the tolerance, as ECSW's papers do
(:func:`greedy_nnls`): an element enters when its column has the largest correlation with the
residual, and the weights of the elements in are refitted by SciPy's NNLS (as the skinning
cubature's fit, :mod:`..wsc.nnls`), elements whose weight drops to zero leaving. Solving the
full NNLS first (SciPy, to its exact fit with one element per row) took 69 s CPU on the
neo-Hookean liver (600 rows, 10995 elements) to keep 141 of its 600 elements. Every fourth
training state is held out of the fit; the rule's force error on them is reported.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.optimize import nnls

from ..wsc.cubature import cell_centroids
from ..wsc.handles import furthest_point_sampling
from .forces import ReducedForces

__all__ = ["ecsw_rule", "greedy_nnls", "MAX_ENTRIES"]

#: the largest NNLS matrix (rows x candidate elements) formed; past it the candidates are a
#: furthest-point sample of the element centroids
MAX_ENTRIES = 3e7


def _contributions(full: ReducedForces, q, uc):
    """``(G (r, m), b (r,))``: the element contributions to the reduced force and their sum."""
    G = full.contributions(q, uc).T
    return G, G.sum(axis=1)


def greedy_nnls(A, b, tol: float, max_elements: int) -> tuple[np.ndarray, np.ndarray, float]:
    """``(columns, weights > 0, relative residual)``: the active-set NNLS stopped once
    ``|A w - b| <= tol |b|`` (module docstring), at most ``max_elements`` columns."""
    bn = max(float(np.linalg.norm(b)), 1e-300)
    cols, w, r = np.zeros(0, dtype=np.int64), np.zeros(0), b.copy()
    for _ in range(3 * max_elements):  # an element leaves only when its weight drops to zero: no cycling
        if np.linalg.norm(r) <= tol * bn or len(cols) >= max_elements:
            break
        g = A.T @ r
        g[cols] = -np.inf
        j = int(np.argmax(g))
        if not g[j] > 0:  # no column decreases the residual: the NNLS optimum
            break
        cols = np.append(cols, j)
        w, _ = nnls(A[:, cols], b, maxiter=50 * len(cols))
        cols, w = cols[w > 0], w[w > 0]
        r = b - A[:, cols] @ w
    return cols, w, float(np.linalg.norm(r) / bn)


def ecsw_rule(full: ReducedForces, states, tol: float, points=None, cells=None, seed: int = 0):
    """Elements and weights of the ECSW rule (module docstring).

    Parameters
    ----------
    full : ReducedForces
        Every element with weight 1 (the exact reduced force).
    states : list of (q (r,), uc (n_c,) or None)
        Training states (projected snapshots); those with a zero force are skipped.
    tol : float
        Largest relative residual of the fit on the training states (> 0).
    points, cells : arrays, optional
        Mesh points and cells, for the furthest-point candidates of a large problem.

    Returns
    -------
    (elements (k,) int array: positions in ``full``'s elements, weights (k,), info dict)

    Raises
    ------
    ValueError
        Fewer than two training states with a force, or a fit that cannot reach ``tol`` (the
        NNLS optimum, or one element per row of the fit, leaves a larger residual).
    """
    tic = time.perf_counter()
    data = [_contributions(full, q, uc) for q, uc in states]
    norms = np.array([np.linalg.norm(b) for _, b in data])
    use = [k for k in range(len(data)) if norms[k] > 1e-12 * max(norms.max(initial=0.0), 1e-300)]
    if len(use) < 2:
        raise ValueError(f"pod_galerkin hyper='ecsw': {len(use)} training state(s) with a force; needs at least 2")
    held = use[3::4] if len(use) >= 4 else []
    train = [k for k in use if k not in held]
    rows = len(train) * full.r
    cand = np.arange(full.m)
    if rows * full.m > MAX_ENTRIES and points is not None:
        count = max(int(MAX_ENTRIES // rows), 4 * full.r)
        cand = np.sort(furthest_point_sampling(cell_centroids(points, cells[full.cells]), min(count, full.m),
                                               seed).indices)
    A = np.vstack([data[k][0][:, cand] / norms[k] for k in train])
    b = np.concatenate([data[k][1] / norms[k] for k in train])
    cols, w, residual = greedy_nnls(A, b, tol, min(len(cand), A.shape[0]))
    if not residual <= tol:
        raise ValueError(f"pod_galerkin hyper='ecsw': the NNLS fit over {len(cand)} elements stops at a relative "
                         f"residual {residual:.3g} > ecsw_tol = {tol:g} ({len(cols)} elements); raise ecsw_tol")
    errors = []
    for k in held:
        G, bs = data[k]
        errors.append(float(np.linalg.norm(G[:, cand[cols]] @ w - bs) / norms[k]))
    info = {"elements": int(len(cols)), "candidates": int(len(cand)), "training_states": len(train),
            "heldout_states": len(held), "train_residual": residual,
            "heldout_force_error": max(errors) if errors else float("nan"), "tol": float(tol),
            "offline_s": time.perf_counter() - tic}
    return cand[cols], w, info
