"""Latency statistics and the basic error measures shared by every study.

Latency: each online step is timed on its own (:mod:`.protocol`) and reported as median
and 99th percentile (never a mean: one page fault must not move the figure). A p99 is decided
by the few slowest samples, ranked above it: :func:`p99_tail` of them (2 of 200 steps: one
late step moves it); :data:`TAIL_SAMPLES` is how many a verdict should rest on, so the
protocol times :data:`TAIL_STEPS` steps by default.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LatencyStats", "latency_stats", "relative_l2", "max_displacement", "p99_tail", "TAIL_SAMPLES",
           "TAIL_STEPS"]

#: samples ranked above the p99 that a verdict on it should rest on, and the steps that gives
TAIL_SAMPLES = 20
TAIL_STEPS = 100 * TAIL_SAMPLES


def p99_tail(n) -> int:
    """The samples of ``n`` ranked above their 99th percentile, which decide it: numpy's p99
    (linear interpolation) lies between the sorted samples ``i`` and ``i + 1``, ``i = floor(0.99
    (n - 1))``, so ``n - 1 - i`` of them are beyond it (2 of 200, 20 of 2000; 0 when ``n < 2``)."""
    n = int(n)
    return 0 if n < 2 else n - 1 - (99 * (n - 1)) // 100


@dataclass(frozen=True)
class LatencyStats:
    """Per-call wall times [s]: median, 99th percentile, min, max and the count."""

    median: float
    p99: float
    min: float
    max: float
    n: int

    @property
    def tail(self) -> int:
        """The samples beyond the p99 (:func:`p99_tail`)."""
        return p99_tail(self.n)

    def as_dict(self, prefix: str = "") -> dict:
        return {f"{prefix}median_s": self.median, f"{prefix}p99_s": self.p99, f"{prefix}min_s": self.min,
                f"{prefix}max_s": self.max, f"{prefix}n": self.n}


def latency_stats(samples) -> LatencyStats:
    """:class:`LatencyStats` of wall times ``samples`` [s] (a non-empty 1D sequence)."""
    s = np.asarray(samples, dtype=float)
    if s.ndim != 1 or s.size == 0 or not np.all(np.isfinite(s)):
        raise ValueError(f"latency samples must be a non-empty finite 1D sequence, got shape {s.shape}")
    return LatencyStats(float(np.median(s)), float(np.percentile(s, 99)), float(s.min()), float(s.max()), s.size)


def relative_l2(u, u_ref) -> float:
    """||u - u_ref|| / ||u_ref|| over all nodal displacement components (NaN-free inputs); ``inf``
    against a zero ``u_ref``: a relative error has no scale there, and is never reported as 0."""
    u, u_ref = np.asarray(u, float).ravel(), np.asarray(u_ref, float).ravel()
    if u.shape != u_ref.shape:
        raise ValueError(f"relative_l2: shapes differ: {u.shape} vs {u_ref.shape}")
    den = np.linalg.norm(u_ref)
    return float(np.linalg.norm(u - u_ref) / den) if den > 0 else np.inf


def max_displacement(u) -> float:
    """Largest nodal displacement magnitude of a node-major (n_nodes * 3,) vector."""
    return float(np.linalg.norm(np.asarray(u, float).reshape(-1, 3), axis=1).max())
