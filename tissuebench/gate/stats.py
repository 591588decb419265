"""Verdicts of an A/B latency comparison (:mod:`.latency`): HEAD/REF ratio of medians with
a bootstrap confidence interval, and the decision against a tolerance.

Observations are block medians (one per block of haptic steps, each block on a fresh copy
of the model, each round a fresh worker process per side). The statistic is the ratio of
the *lower quartiles* of HEAD's and REF's block medians: what moves a block median apart
from the code is one-sided (a memory layout that puts a microsecond step 1.6x slower, the
other core's load, a page fault), while a change of the code moves every block, so the
lower quartile is the code's speed with the least noise, and stays put unless most blocks
of a side are disturbed (timeit's reasoning for its minimum, made robust). Its
confidence interval is a two-stage (hierarchical) percentile bootstrap: rounds (worker
processes) are resampled, then blocks within each drawn round, because block medians of
one process share that process's state and are not independent samples of the code's
speed.

The decision is sized by ``tolerance`` (default 1.3: the slowdown the gate must catch). A
test "lower bound > tolerance" would flag an actual 1.3x slowdown in only ~5 % of runs (at
the boundary a one-sided 95 % bound exceeds the truth 5 % of the time), so the threshold is
the geometric midpoint between no change and the tolerance, ``sqrt(tolerance)`` (1.14 for
1.3), where the errors of both kinds are balanced. A unit is

* ``slower`` (a regression) when the interval lies above the threshold;
* ``holds`` when it lies below (``faster`` when it lies below ``1 / threshold``);
* undecided otherwise: the A/B runs more rounds; when it stops (``max_rounds`` or the time
  budget) an undecided unit is ``slower`` only when its point estimate is above the threshold
  *and* its interval stays clear of the ``faster`` region (lower end above ``1 / threshold``),
  and says it was undecided. Judging by the estimate alone flagged identical code: in CI (main
  17841ea against its parent, which differ in a test file only) units ended undecided with
  estimates 1.35 and 1.60 and intervals [0.747, 1.683] and [0.738, 1.696], readable as 25 %
  faster as well as 60 % slower. On the synthetic noise models of ``tests/studies/test_check_ab.py``
  the undecided 1.3x slowdowns have lower ends 0.82-0.94 (1 in 100 would be lost) and no
  identical run is flagged.

A side with a single observation (one block median: a unit that failed after its first block)
has no interval: it is said as such (``interval n/a (one sample)``, never ``[x, x]``), and the
unit is judged by its estimate alone (``slower`` above the threshold: a slowdown that cannot be
excluded fails the gate). The A/B itself always runs ``min_rounds`` >= 2 rounds
(:func:`.latency.run_ab`), so every unit it completes has two observations per side at least.

A unit may be *expected* slower (``expected``: the ``latency_change`` a commit declares in the
baseline file, :mod:`tissuebench.gate`): the same rule then judges the ratio divided by that factor
(threshold ``expected * sqrt(tolerance)``, the geometric midpoint between the declared factor and
``expected * tolerance``, the slowdown beyond it to catch), the floor counts the increase beyond
the declared one (HEAD minus ``expected`` x REF), and ``faster`` still means faster than REF.

A slowdown must also be one a user could see: ``floor_s`` (the gate's ``latency_floor_s``,
default 10 us, 1 % of a 1 kHz haptic step) is the least increase of the level, HEAD minus REF,
that counts. Microsecond steps move 1.6x between processes with the memory layout (pod_interp
on the cornea: 15.45 vs 9.62 us, identical code, interval [1.013, 1.680]); a ratio alone
cannot tell that from the code.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["ABVerdict", "block_medians", "ratio_interval", "verdicts", "decided_units"]

CONFIDENCE = 0.95
N_BOOT = 4000
LEVEL_QUANTILE = 0.25  # of the block medians: the statistic (module docstring)


@dataclass(frozen=True)
class ABVerdict:
    """The A/B outcome of one unit: ratio HEAD/REF of the haptic step level (lower quartile of
    block medians), its interval, the levels [s], the observations behind them and the verdict."""

    uid: str
    ratio: float
    low: float
    high: float
    ref_median_s: float  # the side's level: lower quartile of its block medians
    head_median_s: float
    rounds: int
    blocks: int
    threshold: float
    verdict: str  # slower | holds | faster
    decided: bool
    floor_s: float = 0.0  # the least level increase [s] that counts as slower
    held_by_floor: bool = False  # the ratio says slower; the increase is below floor_s
    expected: float = 1.0  # the declared HEAD/REF factor (latency_change) the ratio is judged against

    @property
    def regressed(self) -> bool:
        return self.verdict == "slower"

    @property
    def has_interval(self) -> bool:
        """False when a side has a single observation: no interval (:func:`ratio_interval`)."""
        return math.isfinite(self.low) and math.isfinite(self.high)

    def text(self) -> str:
        how = "" if self.decided else (" (undecided: judged by the estimate and the interval)" if self.has_interval
                                       else " (undecided: one sample on a side, judged by the estimate alone)")
        if self.held_by_floor:
            beyond = " beyond the declared" if self.expected != 1.0 else ""
            how += f" (below the floor: +{(self.head_median_s - self.expected * self.ref_median_s) * 1e6:.3g} us" \
                   f"{beyond} < {self.floor_s * 1e6:.3g} us)"
        if self.expected != 1.0:
            how += f" (declared x{self.expected:g}: slower above {self.threshold:.3g})"
        interval = f"[{self.low:.3f}, {self.high:.3f}]" if self.has_interval else "interval n/a (one sample)"
        return (f"HEAD/REF {self.ratio:.3f} {interval} ({self.head_median_s * 1e6:.4g} vs "
                f"{self.ref_median_s * 1e6:.4g} us, {self.rounds} rounds x {self.blocks} blocks){how}")


def block_medians(samples: pd.DataFrame) -> pd.DataFrame:
    """One row per (uid, side, round, block): the block's median haptic step [s]."""
    return samples.groupby(["uid", "side", "round", "block"], sort=True)["haptic_s"].median().rename(
        "median_s").reset_index()


def _grid(obs: pd.DataFrame) -> np.ndarray:
    """Block medians of one side as a (rounds, blocks) array (ragged rounds padded by resampling)."""
    groups = [g["median_s"].to_numpy(float) for _, g in obs.groupby("round", sort=True)]
    k = max(len(g) for g in groups)
    return np.vstack([np.resize(g, k) for g in groups])


def _boot_medians(grid: np.ndarray, rng, n_boot: int) -> np.ndarray:
    r, k = grid.shape
    rows = rng.integers(0, r, size=(n_boot, r))
    cols = rng.integers(0, k, size=(n_boot, r, k))
    return np.quantile(grid[rows[:, :, None], cols].reshape(n_boot, r * k), LEVEL_QUANTILE, axis=1)


def ratio_interval(ref: pd.DataFrame, head: pd.DataFrame, confidence: float = CONFIDENCE, n_boot: int | None = None,
                   seed: int = 0) -> tuple[float, float, float]:
    """``(ratio, low, high)`` of HEAD/REF lower quartiles of block medians (module docstring);
    ``low`` and ``high`` NaN when a side has a single block median: resampling one number gives
    it back (an interval [x, x] would claim a certainty that one sample does not have)."""
    a, b = _grid(ref), _grid(head)
    ratio = float(np.quantile(b, LEVEL_QUANTILE) / np.quantile(a, LEVEL_QUANTILE))
    if a.size < 2 or b.size < 2:
        return ratio, math.nan, math.nan
    n_boot = n_boot or N_BOOT
    rng = np.random.default_rng(seed)
    boot = np.log(_boot_medians(b, rng, n_boot)) - np.log(_boot_medians(a, rng, n_boot))
    q = (1 - confidence) / 2
    lo, hi = np.quantile(boot, [q, 1 - q])
    return ratio, float(math.exp(lo)), float(math.exp(hi))


def verdicts(samples: pd.DataFrame, tolerance: float | dict = 1.3, final: bool = True,
             floor_s: float | dict = 0.0, expected: dict | None = None) -> dict:
    """``{uid: ABVerdict}`` of every unit with samples on both sides; ``tolerance`` and
    ``floor_s`` [s] a number or ``{uid: number}``; ``expected``: ``{uid: declared factor}``
    (module docstring; 1 for a unit it lacks). With ``final=False`` undecided units are left
    out (the A/B goes on)."""
    out = {}
    if samples.empty:
        return out
    med = block_medians(samples)
    for uid, g in med.groupby("uid", sort=True):
        ref, head = g[g["side"] == "ref"], g[g["side"] == "head"]
        if ref.empty or head.empty:
            continue
        tol = tolerance.get(uid, 1.3) if isinstance(tolerance, dict) else tolerance
        floor = float(floor_s.get(uid, 0.0) if isinstance(floor_s, dict) else floor_s)
        base = math.sqrt(float(tol))
        exp = float((expected or {}).get(uid, 1.0))
        thr = exp * base  # judged on ratio / exp by the same rule: its threshold scaled back
        ratio, lo, hi = ratio_interval(ref, head)
        decided = lo > thr or hi < thr  # False without an interval (NaN)
        if not decided and not final:
            continue
        ref_level = float(np.quantile(ref["median_s"], LEVEL_QUANTILE))
        head_level = float(np.quantile(head["median_s"], LEVEL_QUANTILE))
        # undecided: the estimate, and an interval clear of faster; without one (one sample) the estimate
        # alone: a slowdown that cannot be excluded fails the gate
        by_ratio = lo > thr if decided else (ratio > thr and (math.isnan(lo) or lo > exp / base))
        slower = by_ratio and head_level - exp * ref_level >= floor
        # faster than REF, whatever was declared (a declared unit that did not slow down at all)
        verdict = "slower" if slower else ("faster" if (hi if decided else ratio) < 1 / base else "holds")
        rounds = int(head["round"].nunique())
        out[uid] = ABVerdict(uid, ratio, lo, hi, ref_level, head_level, rounds, len(head) // rounds, thr,
                             verdict, decided, floor, by_ratio and not slower, exp)
    return out


def decided_units(tolerance: float | dict = 1.3, expected: dict | None = None):
    """The ``decide`` callback of :func:`.latency.run_ab`: the uids whose interval is clear."""
    return lambda samples: set(verdicts(samples, tolerance, final=False, expected=expected))
