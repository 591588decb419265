"""The rank floor of a point-load family: the least error that any space of N modes can reach.

The exact responses ``u_j = K^{-1} f(s_j)`` at the ``n_s`` parameter nodes, each scaled to
unit Euclidean norm, form ``Û`` (n_free, n_s) with singular values ``σ_1 >= σ_2 >= ...``.
For any N-dimensional space V (PGD modes, a POD basis, anything) and any approximation
taken from it (the srb Galerkin solve, the prb coefficients, an l2 projection), the
relative errors ``e_j = |u_j - v_j| / |u_j|`` satisfy (Eckart-Young)

    sqrt(mean_j e_j^2)  >=  sqrt(sum_{i>N} σ_i^2 / n_s)  =: rms_rel_l2

so no N-mode model meets a bound below ``rms_rel_l2`` at every parameter node (its worst
node is at least as far off). ``max_rel_l2_svd`` is the worst node of the l2 projection on
the leading N singular vectors: what an SVD-optimal basis gives, to compare a vademecum
against. The errors are Euclidean on the free dofs, as the sweep's ``rel_l2``.

This needs the ``n_s`` full solves that the PGD itself avoids: it is a verification figure
(stored in the model's ``info`` after the build, not part of the offline time), computed
only for ``n_s <= max_parameters``.
"""
from __future__ import annotations

import numpy as np

from ...refsolvers.sparse_direct import factorized
from .family import PointLoadFamily

__all__ = ["rank_floor", "snapshot_floor"]


def snapshot_floor(U: np.ndarray, n_modes: int) -> dict:
    """Eckart-Young floor of the columns of ``U`` (n, m), each scaled to unit norm: no space of
    ``n_modes`` dimensions approximates them with an RMS relative error below ``rms_rel_l2``;
    ``max_rel_l2_svd`` is the worst column of the projection on the leading singular vectors.
    Zero columns (nothing to approximate) are counted apart."""
    if isinstance(n_modes, bool) or not isinstance(n_modes, (int, np.integer)) or n_modes < 1:
        raise ValueError(f"snapshot_floor: n_modes must be an integer >= 1, got {n_modes!r}")
    U = np.asarray(U, float)
    if U.ndim != 2 or not np.all(np.isfinite(U)):
        raise ValueError(f"snapshot_floor: U must be a finite 2D array (n, m), got shape {U.shape}")
    norms = np.linalg.norm(U, axis=0)
    live = norms > 0  # a load on a clamped boundary node moves nothing: every model is exact there
    Un = U[:, live] / norms[live]
    Q, s, _ = np.linalg.svd(Un, full_matrices=False)
    V = Q[:, :n_modes]
    e = np.linalg.norm(Un - V @ (V.T @ Un), axis=0)
    return {"n_modes": int(n_modes), "n_parameters": int(live.sum()), "n_zero_responses": int((~live).sum()),
            "rms_rel_l2": float(np.sqrt(np.sum(s[n_modes:] ** 2) / max(int(live.sum()), 1))),
            "max_rel_l2_svd": float(e.max()) if e.size else 0.0}


def rank_floor(family: PointLoadFamily, n_modes: int, max_parameters: int = 400) -> dict:
    """Rank-``n_modes`` floor of ``family`` (module docstring).

    Returns
    -------
    dict
        ``n_modes``, ``n_parameters`` (with a nonzero response), ``n_zero_responses``,
        ``rms_rel_l2`` (lower bound, dimensionless), ``max_rel_l2_svd``, ``norm``; or
        ``skipped`` (the reason) when the family has more than ``max_parameters`` parameter nodes.
    """
    if isinstance(n_modes, bool) or not isinstance(n_modes, (int, np.integer)) or n_modes < 1:
        raise ValueError(f"rank_floor: n_modes must be an integer >= 1, got {n_modes!r}")
    n_s = family.n_parameters
    if n_s > max_parameters:
        return {"n_modes": int(n_modes), "n_parameters": n_s,
                "skipped": f"{n_s} parameter nodes > max_parameters = {max_parameters} (as many full solves)"}
    U = factorized(family.K)(family.loads.toarray())
    return {**snapshot_floor(U, n_modes),
            "norm": "Euclidean on the free dofs, every response scaled to 1; mean over the parameter nodes"}
