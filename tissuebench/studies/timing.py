"""Latency statistics and the basic error measures shared by every study.

Latency: each online step is timed on its own (:mod:`.protocol`) and reported as median
and 99th percentile (never a mean: one page fault must not move the figure).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LatencyStats", "latency_stats", "relative_l2", "max_displacement"]


@dataclass(frozen=True)
class LatencyStats:
    """Per-call wall times [s]: median, 99th percentile, min, max and the count."""

    median: float
    p99: float
    min: float
    max: float
    n: int

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
