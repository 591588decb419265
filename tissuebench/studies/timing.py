"""Latency protocol and error metrics shared by every study.

Latency: each online step is timed on its own with ``time.perf_counter`` after a
warm-up, and reported as median and 99th percentile (never a mean: one page fault must
not move the figure); the reconstruction of the full field is timed separately. The
reference is timed in the same process and run so that the speed-up ratio survives a
noisy machine (SPEC "Measurements").
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

__all__ = ["LatencyStats", "latency_stats", "time_online_steps", "relative_l2", "max_displacement"]


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


def time_online_steps(model, mus, warmup: int = 20, repeats: int = 1, reconstruct: bool = True):
    """Time ``model.step(mu)`` for every ``mu`` (``repeats`` passes after ``warmup`` steps).

    Returns
    -------
    step : LatencyStats
        Time of ``step`` alone.
    step_and_reconstruct : LatencyStats or None
        Time of ``step`` followed by ``reconstruct`` (None with ``reconstruct=False``).
    results : list of StepResult
        The results of the last pass, one per ``mu``.
    """
    mus = list(mus)
    if not mus:
        raise ValueError("time_online_steps: no parameters given")
    for k in range(int(warmup)):
        res = model.step(mus[k % len(mus)])
        if reconstruct and res.q is not None:
            model.reconstruct(res)
    steps, both, results = [], [], []
    for _ in range(int(repeats)):
        model.reset()
        results = []
        for mu in mus:
            t0 = time.perf_counter()
            res = model.step(mu)
            t1 = time.perf_counter()
            steps.append(t1 - t0)
            if reconstruct and res.q is not None:
                model.reconstruct(res)
                both.append(time.perf_counter() - t0)
            results.append(res)
    return latency_stats(steps), (latency_stats(both) if both else None), results


def relative_l2(u, u_ref) -> float:
    """||u - u_ref|| / ||u_ref|| over all nodal displacement components (NaN-free inputs)."""
    u, u_ref = np.asarray(u, float).ravel(), np.asarray(u_ref, float).ravel()
    if u.shape != u_ref.shape:
        raise ValueError(f"relative_l2: shapes differ: {u.shape} vs {u_ref.shape}")
    den = np.linalg.norm(u_ref)
    return float(np.linalg.norm(u - u_ref) / den) if den > 0 else float(np.linalg.norm(u))


def max_displacement(u) -> float:
    """Largest nodal displacement magnitude of a node-major (n_nodes * 3,) vector."""
    return float(np.linalg.norm(np.asarray(u, float).reshape(-1, 3), axis=1).max())
