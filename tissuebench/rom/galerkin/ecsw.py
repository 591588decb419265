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
residual, and the weights are then the NNLS optimum over the elements in, elements whose weight
drops to zero leaving. It is warm-started: the elements in, their weights and an economic QR of
their columns carry over from one element to the next (SciPy's ``qr_insert`` / ``qr_delete``
update the QR), and Lawson-Hanson's inner loop (least squares on the elements in, stepping back
to the boundary while a weight is <= 0) moves the weights. An element costs two products with
``A`` (``A.T r`` and the residual) and O(rows x elements in) per element entering or leaving,
where refitting the elements in from scratch with SciPy's NNLS at every element cost O(rows x
elements in ** 2), the whole fit the cube of the elements kept (on a 5k-node organ with 102
modes it had run 25 min at its 1350th iteration). On a seeded random problem of ECSW's shape
(6000 rows, 3000 candidates, b the sum of the columns, 725 elements to reach tol 1e-3, one
thread) the warm start took 21 s against 600 s for the refits (28x), for the same elements and
weights equal to 5e-12 relative. Solving the full NNLS first (SciPy, to its exact fit with one
element per row) took 69 s CPU on the neo-Hookean liver (600 rows, 10995 elements) to keep 141
of its 600 elements. Every fourth training state is held out of the fit; the rule's force error
on them is reported.
"""
from __future__ import annotations

import time

import numpy as np
from scipy.linalg import qr_delete, qr_insert, solve_triangular

from ..wsc.cubature import cell_centroids
from ..wsc.handles import furthest_point_sampling
from .forces import ReducedForces

__all__ = ["ecsw_rule", "greedy_nnls", "MAX_ENTRIES"]

#: the largest NNLS matrix (rows x candidate elements) formed; past it the candidates are a
#: furthest-point sample of the element centroids
MAX_ENTRIES = 3e7

#: the smallest reciprocal condition number of the fitted columns' QR with a column entering; past
#: it the column is numerically in their span and cannot enter
_RCOND = 1e-10


def _contributions(full: ReducedForces, q, uc):
    """``(G (r, m), b (r,))``: the element contributions to the reduced force and their sum."""
    G = full.contributions(q, uc).T
    return G, G.sum(axis=1)


def greedy_nnls(A, b, tol: float, max_elements: int) -> tuple[np.ndarray, np.ndarray, float]:
    """``(columns, weights > 0, relative residual)``: the active-set NNLS stopped once
    ``|A w - b| <= tol |b|`` (module docstring), at most ``max_elements`` columns.

    Lawson-Hanson warm-started: the columns in and their weights carry over from one iteration to
    the next, with an economic QR of ``A[:, columns]`` that SciPy's ``qr_insert`` / ``qr_delete``
    update as a column enters or leaves; an iteration costs ``A.T @ r``, the residual (a product
    with ``A``) and O(rows x k) per column entering or leaving. Its weights are the NNLS optimum
    over the columns in before it and the one entering, as a refit of those from scratch gives: the
    inner loop steps back to the boundary while a least-squares weight is <= 0, the columns at zero
    leaving, and one that left re-enters while its correlation with the residual is positive. A
    column numerically in the span of those in (``qr_insert`` refuses it at ``_RCOND``, or as many
    columns as rows are in), or whose least-squares weight on entering is not positive, is out for
    the rest of the fit (for the rest of the iteration if it was re-entering)."""
    A = np.asarray(A, dtype=float)
    b = np.asarray(b, dtype=float)
    rows, n = A.shape
    bn = max(float(np.linalg.norm(b)), 1e-300)
    cols: list[int] = []                          # the columns in, in the QR's order
    w = np.zeros(0)                               # their weights, > 0 between iterations
    Q, R = np.zeros((rows, 0)), np.zeros((0, 0))  # A[:, cols] = Q R
    excluded = np.zeros(n, dtype=bool)
    r = b.copy()

    def residual():  # b - A[:, cols] w, as a product with all of A: cheaper than gathering the columns
        full = np.zeros(n)
        full[cols] = w
        return b - A @ full

    def leave(positions):
        nonlocal Q, R, w
        for p in sorted(positions, reverse=True):
            Q, R = qr_delete(Q, R, p, which="col")
            del cols[p]
            Q, R = Q[:, :len(cols)], R[:len(cols)]  # from a square Q SciPy returns the full QR
        w = np.delete(w, positions)

    def enter(j, left: set) -> bool:
        """Column j in and the weights refitted (Lawson-Hanson's inner loop), the columns leaving
        added to ``left``; False, nothing changed, if j cannot enter (in the span, or its
        least-squares weight <= 0)."""
        nonlocal Q, R, w
        if len(cols) >= rows:  # as many columns as rows: any other is in their span
            return False
        try:
            Q, R = qr_insert(Q, R, A[:, j], len(cols), which="col", rcond=_RCOND)
        except np.linalg.LinAlgError:
            return False
        cols.append(j)
        w = np.append(w, 0.0)
        z = solve_triangular(R, Q.T @ b)
        if not z[-1] > 0:
            leave([len(cols) - 1])
            return False
        while not np.all(z > 0):
            low = np.flatnonzero(z <= 0)
            steps = w[low] / (w[low] - z[low])
            alpha = float(steps.min())
            w = w + alpha * (z - w)
            w[low[steps <= alpha]] = 0.0
            out = np.flatnonzero(w <= 0)
            left.update(cols[p] for p in out)
            leave(out)
            z = solve_triangular(R, Q.T @ b) if cols else np.zeros(0)
        w = z
        return True

    g, entered = None, 0
    while entered < 3 * max_elements:  # bounded (a refused column is out for good): no cycling
        if np.linalg.norm(r) <= tol * bn or len(cols) >= max_elements or n == 0:
            break
        if g is None:  # the correlations with the residual (unchanged after a column was refused)
            g = A.T @ r
            g[cols] = -np.inf
            g[excluded] = -np.inf
        j = int(np.argmax(g))
        if not g[j] > 0:  # no column decreases the residual: the NNLS optimum
            break
        left: set[int] = set()
        if not enter(j, left):
            excluded[j], g[j] = True, -np.inf
            continue
        entered += 1
        refused: set[int] = set()
        for _ in range(3 * len(cols) + 3 * len(left)):  # the NNLS optimum over this iteration's columns
            back = sorted(left - refused - set(cols))
            if not back:
                break
            gb = A[:, back].T @ residual()
            k = int(np.argmax(gb))
            if not gb[k] > 0:
                break
            if not enter(back[k], left):
                refused.add(back[k])
        r, g = residual(), None
    return np.array(cols, dtype=np.int64), w, float(np.linalg.norm(r) / bn)


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
