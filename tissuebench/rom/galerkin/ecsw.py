"""ECSW: energy-conserving sampling and weighting of the reduced internal force.

Farhat, Avery, Chapman, Cortial (2014) IJNME 98:625 and Farhat, Chapman, Avery (2015)
IJNME 102:1077. On training states ``q_s`` (projected snapshots) the exact reduced force is
the sum of the element contributions ``g_e(q_s) = V_e^T f_e(u_e(q_s))``; ECSW looks for a few
elements with non-negative weights that reproduce it::

    min ||A w - b||  s.t. w >= 0,    A = [g_e(q_s)]_(s, e),  b = [sum_e g_e(q_s)]_s

(the rows of each state scaled by ``1 / |b_s|``, so that small motions count as much as large
ones), keeping the smallest number of elements whose relative residual ``|A w - b| / |b|`` is at
most ``tol``. Non-negative weights keep the reduced force the gradient of a positive weighted
energy (energy conservation and the symmetry of the tangent, the method's name).

The NNLS is SciPy's Lawson-Hanson, as the skinning-cubature's fit (:mod:`..wsc.nnls`, whose
:func:`~..wsc.nnls.refit_heaviest` this module shares): the full solution first, then the
smallest count of its heaviest elements, refitted, that meets ``tol`` (by bisection on the
count). Every fourth training state is held out of the fit; the rule's force error on them is
reported.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.optimize import nnls

from ..wsc.cubature import cell_centroids
from ..wsc.handles import furthest_point_sampling
from ..wsc.nnls import refit_heaviest
from .forces import ReducedForces

__all__ = ["ecsw_rule", "MAX_ENTRIES"]

#: the largest NNLS matrix (rows x candidate elements) formed; past it the candidates are a
#: furthest-point sample of the element centroids
MAX_ENTRIES = 3e7


def _contributions(full: ReducedForces, q, uc):
    """``(G (r, m), b (r,))``: the element contributions to the reduced force and their sum."""
    _, fe = full.kernel.energies_and_forces(full.local(q, uc))
    G = np.einsum("eir,ei->re", full.V_loc, fe)
    return G, G.sum(axis=1)


def _residual(A, b, cols, w):
    return float(np.linalg.norm(A[:, cols] @ w - b) / max(np.linalg.norm(b), 1e-300))


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
        Fewer than two training states with a force, or a full NNLS solution whose residual
        exceeds ``tol`` (the basis and the states cannot be fitted that closely).
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
    w_full, _ = nnls(A, b, maxiter=20 * len(cand))
    nnz = int(np.sum(w_full > 0))
    res_full = _residual(A, b, np.flatnonzero(w_full > 0), w_full[w_full > 0])
    if not res_full <= tol:
        raise ValueError(f"pod_galerkin hyper='ecsw': the NNLS fit over {len(cand)} elements leaves a relative "
                         f"residual {res_full:.3g} > ecsw_tol = {tol:g}; raise ecsw_tol")
    lo, hi = 1, nnz  # the count meeting tol: bisection (hi always meets it)
    best = refit_heaviest(A, b, w_full, hi)
    while lo < hi:
        mid = (lo + hi) // 2
        cols, w = refit_heaviest(A, b, w_full, mid)
        if len(cols) and _residual(A, b, cols, w) <= tol:
            hi, best = mid, (cols, w)
        else:
            lo = mid + 1
    cols, w = best
    errors = []
    for k in held:
        G, bs = data[k]
        errors.append(float(np.linalg.norm(G[:, cand[cols]] @ w - bs) / norms[k]))
    info = {"elements": int(len(cols)), "candidates": int(len(cand)), "training_states": len(train),
            "heldout_states": len(held), "train_residual": _residual(A, b, cols, w),
            "full_nnls_elements": nnz, "full_nnls_residual": res_full,
            "heldout_force_error": max(errors) if errors else float("nan"), "tol": float(tol),
            "offline_s": time.perf_counter() - tic}
    return cand[cols], w, info
