"""Where a fit may add a reference: candidate parameters over the range a family claims.

A family's training and its evaluation pin parameters on one axis (:mod:`.axes`): the load
factor of a path, the amplitude (``load_scale``) of a motion. The candidates are the middles of
the gaps between every parameter already **used** (trained on, or measured at by the held-out
evaluation) and the ends of the range: a candidate is never a point the evaluation measures
(the headline error stays on references the training never used, whatever the greedy adds) nor
a state already learnt, and each reference added splits its gap, so the candidates refine where
the greedy has been (the dyadic refinement of a reduced-basis greedy's training set, built
lazily). A gap narrower than ``min_gap`` times the range has no candidate (no reference is
added closer to another than that).

The dense check (:mod:`.dense`) measures at thirds of the range, which no dyadic middle ever is.
"""
from __future__ import annotations

import numpy as np

__all__ = ["gap_middles", "path_candidates", "amplitude_candidates", "MIN_GAP", "run_steps"]

#: a gap narrower than this fraction of the range gets no candidate
MIN_GAP = 1e-3


def gap_middles(used, lo: float, hi: float, min_gap: float = MIN_GAP) -> np.ndarray:
    """The middle of every gap between consecutive distinct values of ``used`` and the ends
    ``lo``, ``hi`` (values outside ``[lo, hi]`` ignored), in increasing order; gaps narrower than
    ``min_gap * (hi - lo)`` skipped. ValueError when ``hi <= lo``."""
    lo, hi = float(lo), float(hi)
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        raise ValueError(f"candidate range [{lo!r}, {hi!r}]: expected finite ends with lo < hi")
    tol = 1e-9 * (hi - lo)
    values = np.asarray([float(v) for v in used], float)
    values = values[(values >= lo - tol) & (values <= hi + tol)]
    grid = np.unique(np.concatenate([[lo, hi], np.clip(values, lo, hi)]))
    keep = [grid[0]]
    for v in grid[1:]:  # values within round-off of each other are one value
        if v - keep[-1] > tol:
            keep.append(v)
    grid = np.asarray(keep)
    gaps = np.diff(grid)
    # 12 significant digits: a spec reads 0.725, not 0.7250000000000001 (a middle is at least min_gap / 2
    # from either end of its gap, far above the rounding)
    mids = np.array([float(f"{m:.12g}") for m in 0.5 * (grid[:-1] + grid[1:])])
    return mids[gaps > min_gap * (hi - lo)]


def path_candidates(trained, measured, top: float, min_gap: float = MIN_GAP) -> np.ndarray:
    """Candidate load factors of a path family: the middles between rest (0), the load factors
    ``trained`` and ``measured`` (the held-out evaluation's) and the path's ``top``."""
    return gap_middles(list(trained) + list(measured), 0.0, top, min_gap)


def amplitude_candidates(trained, measured, lo: float, hi: float = 1.0, min_gap: float = MIN_GAP) -> np.ndarray:
    """Candidate amplitudes (``load_scale``) of a motion family over ``[lo, hi]``: the middles
    between the amplitudes ``trained`` and ``measured``."""
    return gap_middles(list(trained) + list(measured), lo, hi, min_gap)


def run_steps(load_factor: float, increment: float) -> int:
    """Increments of a run from rest to ``load_factor`` no larger than the path's ``increment``
    (where its Newton converged): at least 1."""
    if not increment > 0:
        return 1
    return max(1, int(np.ceil(load_factor / increment - 1e-9)))
