"""The A/B verdicts (:mod:`tissuebench.gate.stats`) by hand: block medians, the lower-quartile
ratio, the bootstrap interval, and each verdict at its boundary on both sides (issue 41). The
power of the whole A/B is test_check_ab.py's; these run on given samples, in milliseconds."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from tissuebench.gate import stats as ab_stats
from tissuebench.gate.stats import ABVerdict, block_medians, decided_units, ratio_interval, verdicts


def _samples(uid, side, grid, steps=(1.0,)):
    """One row per step: block (r, b) of ``grid`` has steps ``value * s`` for s in ``steps``."""
    return [{"uid": uid, "side": side, "round": r, "block": b, "haptic_s": v * s}
            for r, row in enumerate(grid) for b, v in enumerate(row) for s in steps]


def _frame(*parts):
    return pd.DataFrame([row for p in parts for row in p])


def test_block_medians_by_hand():
    df = _frame(_samples("u", "ref", [[1.0, 2.0]], steps=(1.0, 3.0, 2.0)), _samples("u", "head", [[5.0]]))
    med = block_medians(df)
    assert list(med.columns) == ["uid", "side", "round", "block", "median_s"]
    assert med["median_s"].tolist() == [5.0, 2.0, 4.0]  # head first (sorted), then ref's blocks: median of 1, 3, 2


def test_grid_pads_a_short_round_by_repeating_it():
    obs = pd.DataFrame({"round": [0, 0, 0, 1, 1], "median_s": [1.0, 2.0, 3.0, 4.0, 5.0]})
    assert ab_stats._grid(obs).tolist() == [[1.0, 2.0, 3.0], [4.0, 5.0, 4.0]]


def test_ratio_of_lower_quartiles_and_a_degenerate_interval():
    # every block alike within a side: the interval is the ratio itself
    ref = block_medians(_frame(_samples("u", "ref", [[2.0] * 4] * 3)))
    head = block_medians(_frame(_samples("u", "head", [[3.0] * 4] * 3)))
    assert ratio_interval(ref, head) == (pytest.approx(1.5), pytest.approx(1.5), pytest.approx(1.5))


def test_the_statistic_is_the_lower_quartile_not_the_median():
    # ref blocks 1, 2, 3, 4, 5 -> lower quartile 2 (median 3); head 2, 4, 6, 8, 100 -> 4 (median 6)
    ref = block_medians(_frame(_samples("u", "ref", [[1.0, 2.0, 3.0, 4.0, 5.0]])))
    head = block_medians(_frame(_samples("u", "head", [[2.0, 4.0, 6.0, 8.0, 100.0]])))
    ratio, lo, hi = ratio_interval(ref, head)
    assert ratio == pytest.approx(2.0)
    assert lo <= ratio <= hi and lo < hi


def test_the_interval_is_seeded_and_narrows_with_the_confidence():
    rng = np.random.default_rng(3)
    ref = block_medians(_frame(_samples("u", "ref", 1.0 + 0.2 * rng.random((4, 5)))))
    head = block_medians(_frame(_samples("u", "head", 1.3 + 0.2 * rng.random((4, 5)))))
    r95 = ratio_interval(ref, head)
    assert ratio_interval(ref, head, seed=0) == r95 and ratio_interval(ref, head, seed=1) != r95
    r50 = ratio_interval(ref, head, confidence=0.5)
    assert r95[1] < r50[1] <= r50[0] <= r50[2] < r95[2]
    # the bootstrap's lower end is the 2.5 % quantile of log-ratios: below 1.3 / 1.2, above 1.3 / 1.2 ** -1 bounds
    assert 1.0 < r95[1] < r95[0] < r95[2] < 1.5 / 1.0
    r_few = ratio_interval(ref, head, n_boot=50)
    assert r_few[0] == r95[0] and r_few[1:] != r95[1:]


def test_bootstrap_resamples_rounds_then_blocks_with_the_lower_quartile():
    grid = np.array([[1.0, 2.0], [3.0, 4.0]])

    class Fixed:  # draws: rows (0, 0); then blocks (1, 1) and (0, 1)
        def integers(self, low, high, size):
            return np.zeros(size, int) if size == (1, 2) else np.array([[[1, 1], [0, 1]]])

    assert ab_stats._boot_medians(grid, Fixed(), 1).tolist() == [np.quantile([2.0, 2.0, 1.0, 2.0], 0.25)]


def _verdict(ref_grid, head_grid, **kw):
    df = _frame(_samples("u", "ref", ref_grid), _samples("u", "head", head_grid))
    return verdicts(df, **kw).get("u")


@pytest.mark.parametrize("factor, verdict, decided", [
    (2.0 * (1 + 1e-9), "slower", True),  # just above sqrt(4) = 2: decided slower
    (2.0, "holds", False),               # at the threshold: undecided, the estimate is not above it
    (1.999, "holds", True),
    (0.5, "holds", True),                # at 1 / threshold: not faster
    (0.5 * (1 - 1e-9), "faster", True),
])
def test_each_verdict_at_its_threshold(factor, verdict, decided):
    v = _verdict([[1.0] * 3] * 2, [[factor] * 3] * 2, tolerance=4.0)
    assert (v.verdict, v.decided) == (verdict, decided)
    assert v.threshold == 2.0 and v.ratio == pytest.approx(factor) and v.regressed is (verdict == "slower")
    assert (v.rounds, v.blocks, v.ref_median_s, v.head_median_s) == (2, 3, 1.0, pytest.approx(factor))


def test_the_floor_holds_a_slower_ratio_below_the_least_increase():
    # levels 10 us and 20 us: +10 us
    v = _verdict([[1e-5] * 3] * 2, [[2e-5] * 3] * 2, floor_s=1e-5)
    assert v.verdict == "slower" and not v.held_by_floor  # the increase equals the floor: counts
    v = _verdict([[1e-5] * 3] * 2, [[2e-5] * 3] * 2, floor_s=1.0001e-5)
    assert v.verdict == "holds" and v.held_by_floor and v.floor_s == 1.0001e-5 and not v.regressed
    assert v.text().endswith(" (below the floor: +10 us < 10 us)")
    v = _verdict([[1e-5] * 3] * 2, [[2e-5] * 3] * 2, floor_s={"other": 1.0})  # another unit's floor
    assert v.verdict == "slower" and v.floor_s == 0.0


def test_per_unit_tolerances_default_to_1_3():
    v = _verdict([[1.0] * 3] * 2, [[1.2] * 3] * 2, tolerance={"other": 9.0})
    assert v.threshold == pytest.approx(math.sqrt(1.3)) and v.verdict == "slower"
    v = _verdict([[1.0] * 3] * 2, [[1.2] * 3] * 2, tolerance={"u": 1.5})
    assert v.threshold == pytest.approx(math.sqrt(1.5)) and v.verdict == "holds"


def _undecided(head_rounds):
    ref = [[1.0] * 3] * 4
    df = _frame(_samples("u", "ref", ref), _samples("u", "head", head_rounds))
    return df


def test_an_undecided_unit_is_judged_by_its_estimate_and_its_interval():
    # head: one fast round, three slow ones: estimate 2.5 above the threshold, interval reaching 1
    df = _undecided([[1.0] * 3] + [[3.0] * 3] * 3)
    v = verdicts(df)["u"]
    assert not v.decided and v.ratio == pytest.approx(2.5) and v.low == pytest.approx(1.0)
    assert v.verdict == "slower" and v.text().endswith(" (undecided: judged by the estimate and the interval)")
    assert verdicts(df, final=False) == {} and decided_units()(df) == set()
    # an interval reaching into the faster region (low < 1 / threshold): holds, however high the estimate
    v = verdicts(_undecided([[0.8] * 3] + [[3.0] * 3] * 3))["u"]
    assert not v.decided and v.ratio > v.threshold and v.low < 1 / v.threshold and v.verdict == "holds"
    # undecided and the estimate below 1 / threshold: faster
    v = verdicts(_undecided([[0.1] * 3] * 3 + [[1.5] * 3]))["u"]
    assert not v.decided and v.ratio < 1 / v.threshold and v.verdict == "faster"


def test_units_without_both_sides_and_empty_samples():
    df = _frame(_samples("a", "ref", [[1.0]]), _samples("b", "head", [[1.0]]), _samples("c", "ref", [[1.0] * 2]),
                _samples("c", "head", [[3.0] * 2]))
    assert list(verdicts(df)) == ["c"] and decided_units(1.3)(df) == {"c"}
    assert verdicts(df.iloc[:0]) == {}


def test_the_text_of_a_verdict():
    v = ABVerdict("u", 1.23456, 1.1, 1.4, 1e-5, 1.23456e-5, 3, 4, 1.14, "slower", True)
    assert v.text() == "HEAD/REF 1.235 [1.100, 1.400] (12.35 vs 10 us, 3 rounds x 4 blocks)"
    assert v.floor_s == 0.0 and v.held_by_floor is False


def test_units_come_back_sorted_and_an_undecided_one_does_not_hide_the_next():
    straddling = _samples("a", "head", [[1.0] * 3] + [[3.0] * 3] * 3)  # undecided (see above)
    df = _frame(_samples("b", "ref", [[1.0] * 3] * 2), _samples("b", "head", [[2.0] * 3] * 2),
                _samples("a", "ref", [[1.0] * 3] * 4), straddling)
    assert list(verdicts(df)) == ["a", "b"]
    assert set(verdicts(df, final=False)) == {"b"}


def test_decided_units_uses_its_tolerance_and_defaults_to_1_3():
    # head's rounds at 1.3 and 1.8: the interval ~[1.3, 1.8] is clear of sqrt(1.3) = 1.14, not of sqrt(2.3) = 1.52
    df = _frame(_samples("u", "ref", [[1.0] * 3] * 4), _samples("u", "head", [[1.3] * 3, [1.8] * 3] * 2))
    assert decided_units()(df) == {"u"} and decided_units(1.3)(df) == {"u"}
    assert decided_units(2.3)(df) == set() and decided_units({"u": 2.3})(df) == set()


def test_the_text_in_microseconds_to_its_last_digit():
    # values just below a rounding boundary: a factor off by 1e-6 rounds the other way
    v = ABVerdict("u", 1.0, 1.0, 1.0, 2.0004999e-3, 1.2344999e-2, 1, 1, 1.14, "holds", True)
    assert v.text() == "HEAD/REF 1.000 [1.000, 1.000] (1.234e+04 vs 2000 us, 1 rounds x 1 blocks)"
    v = ABVerdict("u", 1.2, 1.0, 1.5, 1e-5, 1e-5 + 1.0349995e-6, 3, 2, 1.14, "holds", False, 1.2349999e-5, True)
    assert v.text() == ("HEAD/REF 1.200 [1.000, 1.500] (11.03 vs 10 us, 3 rounds x 2 blocks) (undecided: judged by "
                        "the estimate and the interval) (below the floor: +1.03 us < 12.3 us)")


def test_bootstrap_draws_every_block_and_every_round():
    boot = ab_stats._boot_medians(np.array([[1.0, 2.0]]), np.random.default_rng(0), 200)
    assert boot.min() == 1.0 and boot.max() == 2.0  # both blocks drawn (block 0 too)
    boot = ab_stats._boot_medians(np.array([[1.0], [2.0]]), np.random.default_rng(0), 200)
    assert boot.min() == 1.0 and boot.max() == 2.0  # both rounds drawn


def test_the_interval_is_the_central_percentile_interval_of_the_log_ratios():
    rng = np.random.default_rng(5)
    ref = block_medians(_frame(_samples("u", "ref", 1.0 + 0.3 * rng.random((4, 3)))))
    head = block_medians(_frame(_samples("u", "head", 1.2 + 0.3 * rng.random((4, 3)))))
    draws = np.random.default_rng(9)
    boot = np.log(ab_stats._boot_medians(ab_stats._grid(head), draws, 500)) - \
        np.log(ab_stats._boot_medians(ab_stats._grid(ref), draws, 500))
    _, lo, hi = ratio_interval(ref, head, confidence=0.9, n_boot=500, seed=9)
    assert (lo, hi) == (pytest.approx(math.exp(np.quantile(boot, 0.05)), rel=1e-12),
                        pytest.approx(math.exp(np.quantile(boot, 0.95)), rel=1e-12))


def test_an_undecided_interval_ending_exactly_at_one_over_the_threshold_holds():
    # tolerance 4: threshold 2, faster region below 0.5; head's rounds 0.5, 4, 4, 4: estimate
    # 3.125, the interval's low end exactly 0.5 (a quarter of the bootstrap draws give 0.5)
    v = _verdict([[1.0] * 3] * 4, [[0.5] * 3] + [[4.0] * 3] * 3, tolerance=4.0)
    assert not v.decided and v.ratio == pytest.approx(3.125) and v.low == 0.5 and v.verdict == "holds"
    assert v.uid == "u" and type(v.blocks) is int and type(v.rounds) is int
