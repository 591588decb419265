"""Handle (and sample-element) selection by furthest-point sampling (wsc paper §2.3).

Furthest-point sampling (FPS) picks points one at a time, each the point furthest
(Euclidean distance) from all points picked so far, so the picks are approximately
equidistant over the body. It starts from a seeded random point, hence is deterministic
for a seed. ``sources`` (e.g. the nodes of a Dirichlet set, which get their own boundary
handle) count as already picked: the free handles then keep away from them.

The sampling also returns the covering radius ``R`` (every point lies within ``R`` of a
pick or a source) and the smallest separation of the picks (``>= R`` by construction):
the skinning and cubature RBF supports are multiples of ``R``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

__all__ = ["Sampling", "furthest_point_sampling", "resolve_count"]


@dataclass(frozen=True)
class Sampling:
    """Outcome of :func:`furthest_point_sampling`.

    Attributes
    ----------
    indices : (k,) int array
        Picked points, in the order picked.
    covering_radius : float
        ``max_i min_j |x_i - x_pick_j|`` over all points (sources included as picks).
    separation : float
        Smallest distance between two picks (inf for k = 1).
    """

    indices: np.ndarray
    covering_radius: float
    separation: float


def resolve_count(value, n_total: int, name: str) -> int:
    """A count from an integer ``value`` or a fraction ``0 < value < 1`` of ``n_total``.

    Raises ValueError naming ``name`` for a count below 1 or above ``n_total``.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be an integer count or a fraction in (0, 1), got {value!r}")
    if isinstance(value, (float, np.floating)) and not float(value).is_integer():
        if not 0.0 < value < 1.0:
            raise ValueError(f"{name} = {value!r}: a fraction must lie in (0, 1)")
        count = int(round(value * n_total))
    else:
        count = int(value)
    if count < 1:
        raise ValueError(f"{name} = {value!r} gives {count} (of {n_total}); at least 1 is needed")
    if count > n_total:
        raise ValueError(f"{name} = {value!r}: more than the {n_total} available")
    return count


def furthest_point_sampling(points, count: int, seed: int = 0, sources=None, sources_as_picks: bool = True) \
        -> Sampling:
    """Pick ``count`` of ``points`` (n, 3) by furthest-point sampling.

    Parameters
    ----------
    points : (n, 3) array
        Candidate points [length unit of the mesh].
    count : int
        Number of picks, 1 <= count <= number of candidates not in ``sources``.
    seed : int
        Seed of the first pick (a uniformly random candidate).
    sources : sequence of (m_i,) int arrays, optional
        Point sets whose points are never picked; with ``sources_as_picks`` they also count
        as already picked (the picks keep away from them).

    Returns
    -------
    Sampling
    """
    X = np.asarray(points, dtype=float)
    if X.ndim != 2 or X.shape[1] != 3 or not np.all(np.isfinite(X)):
        raise ValueError(f"points must be a finite (n, 3) array, got shape {X.shape}")
    dist = np.full(len(X), np.inf)  # distance to the nearest pick (squared in the loop below)
    blocked = np.zeros(len(X), dtype=bool)
    for src in sources or ():
        src = np.asarray(src, dtype=np.int64)
        if src.size:
            if sources_as_picks:
                dist = np.minimum(dist, cKDTree(X[src]).query(X)[0])
            blocked[src] = True
    available = int((~blocked).sum())
    if not 1 <= int(count) <= available:
        raise ValueError(f"furthest_point_sampling: count = {count} but {available} points are available "
                         f"({len(X)} in all, {len(X) - available} in the sources)")
    rng = np.random.default_rng(seed)
    picks = np.empty(int(count), dtype=np.int64)
    picks[0] = rng.choice(np.flatnonzero(~blocked))
    separation = np.inf
    dist = dist ** 2
    dist[blocked] = -np.inf  # never picked (their own distances are not needed)
    for k in range(int(count)):
        if k:
            picks[k] = int(np.argmax(dist))
        D = X - X[picks[k]]
        np.minimum(dist, np.einsum("ij,ij->i", D, D), out=dist, where=~blocked)
    if len(picks) > 1:
        separation = float(cKDTree(X[picks]).query(X[picks], k=2)[0][:, 1].min())
    # covering radius over the pickable points (a blocked one is covered by its own set)
    covering = float(np.sqrt(max(dist.max(), 0.0)))
    return Sampling(picks, covering, separation)
