"""The error metrics and the validity radius against hand-computed values on tiny arrays (issue 41).

Each test states the number a user reads in a results table and checks it to round-off, so a
one-line slip in :mod:`tissuebench.studies.metrics` or :mod:`tissuebench.studies.timing` (a
sign, a factor, ``<`` for ``<=``, a dropped term) fails here. Every rule is tested on both
sides of its boundary.
"""
from __future__ import annotations

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from tissuebench.studies.evaluation import Evaluation, EvaluationPoint
from tissuebench.studies.metrics import (SEEN_RTOL, TOLERANCES, ZERO_REFERENCE, claimed_mask, claimed_range,
                                         output_rows, pareto_front, peak_normalise, point_rows, seen_points,
                                         summarise_points, validity_radius)
from tissuebench.studies.timing import LatencyStats, latency_stats, max_displacement, relative_l2


def _evaluation(refs, kind="path", monitors=None, xs=None, beyond=None, groups=None, mus=None):
    n = len(refs)
    points = [EvaluationPoint(mu=(mus or [{}] * n)[k], reference=None if r is None else np.asarray(r, float),
                              monitors=(monitors or [{}] * n)[k], x=float((xs or range(n))[k]),
                              group=(groups or [None] * n)[k], beyond=(beyond or [False] * n)[k])
              for k, r in enumerate(refs)]
    return Evaluation(kind=kind, x_name="load factor", points=points)


def _driven(fields, statuses=None, messages=None, outputs=None):
    n = len(fields)
    statuses = statuses or ["ok"] * n
    results = [None if s is None else SimpleNamespace(status=s, message=(messages or [""] * n)[k])
               for k, s in enumerate(statuses)]
    return SimpleNamespace(results=results, fields=[None if u is None else np.asarray(u, float) for u in fields],
                           outputs=outputs or [{}] * n)


# ---------------------------------------------------------------- point errors
def test_rel_l2_and_max_displacement_error_of_one_node_by_hand():
    # ref (3, 4, 0): |ref| = 5; u - ref = (0, 0, 1): rel_l2 = 1/5; |u| = sqrt(26)
    row, = point_rows(_evaluation([[3, 4, 0]]), _driven([[3, 4, 1]]))
    assert row["rel_l2"] == pytest.approx(0.2, rel=1e-14)
    assert row["rel_max_displacement"] == pytest.approx((math.sqrt(26) - 5) / 5, rel=1e-14)
    assert row["status"] == "ok" and row["has_reference"] is True and row["seen"] is False
    assert row["beyond"] is False and row["message"] == "" and row["point"] == 0 and row["x"] == 0.0
    assert math.isnan(row["group"]) and row["mu"] == ""


def test_max_displacement_error_takes_the_largest_node_not_the_largest_component():
    # node-major (2 nodes x 3): ref's largest node is |(3, 4, 0)| = 5 (largest component 4);
    # u's is |(0, 0, 6)| = 6: (6 - 5) / 5 = 0.2 (by components it would be (6 - 4) / 4)
    ref = [3, 4, 0, 0, 0, 1]
    u = [3, 4, 0, 0, 0, 6]
    row, = point_rows(_evaluation([ref]), _driven([u]))
    assert row["rel_max_displacement"] == pytest.approx(0.2, rel=1e-14)
    assert row["rel_l2"] == pytest.approx(5 / math.sqrt(26), rel=1e-14)


def test_a_vector_not_of_three_components_uses_the_largest_absolute_entry():
    # ref (1, -2): |ref| = sqrt(5); u (1, -3): |u - ref| = 1; max |ref| 2, max |u| 3
    row, = point_rows(_evaluation([[1, -2]]), _driven([[1, -3]]))
    assert row["rel_l2"] == pytest.approx(1 / math.sqrt(5), rel=1e-14)
    assert row["rel_max_displacement"] == pytest.approx(0.5, rel=1e-14)
    row, = point_rows(_evaluation([[1, -2, 2, 0]]), _driven([[1, -3, 2, 0]]))
    assert row["rel_max_displacement"] == pytest.approx(0.5, rel=1e-14)  # 4 entries: not nodes of 3


def test_a_small_reference_is_still_relative():
    # |ref| = 0.5 < 1: relative errors, not absolute ones
    row, = point_rows(_evaluation([[0.3, 0.4, 0]]), _driven([[0.3, 0.4, 0.1]]))
    assert row["rel_l2"] == pytest.approx(0.2, rel=1e-14)
    assert row["rel_max_displacement"] == pytest.approx((math.sqrt(0.26) - 0.5) / 0.5, rel=1e-12)


def test_a_point_object_without_beyond_is_not_beyond():
    ev = _evaluation([[1, 0, 0]])
    p = ev.points[0]
    ev.points[0] = SimpleNamespace(mu=p.mu, reference=p.reference, monitors={}, x=p.x, group=None)
    assert point_rows(ev, _driven([[1, 0, 0]]))[0]["beyond"] is False


def test_a_zero_reference_is_measured_against_the_largest_reference_of_the_evaluation():
    # point 0: ref 2 nodes (3, 4, 0), (0, 0, 12): |ref| = 13, largest node 12; point 1: ref zero,
    # u = (0, 0, 0.3), (0, 0.4, 0): |u| = 0.5 -> 0.5 / 13 (l2 scale), largest node 0.4 -> 0.4 / 12 (its own scale)
    ev = _evaluation([[3, 4, 0, 0, 0, 12], [0, 0, 0, 0, 0, 0]])
    rows = point_rows(ev, _driven([[3, 4, 0, 0, 0, 12], [0, 0, 0.3, 0, 0.4, 0]]))
    assert rows[1]["rel_l2"] == pytest.approx(0.5 / 13, rel=1e-14)
    assert rows[1]["rel_max_displacement"] == pytest.approx(0.4 / 12, rel=1e-14)
    assert rows[0]["rel_l2"] == 0.0 and rows[1]["message"] == ""
    # not node-major (size 2): the largest component is the scale, |0 - 3| / 2 both ways
    rows = point_rows(_evaluation([[2, 0], [0, 0]]), _driven([[2, 0], [0, -3]]))
    assert rows[1]["rel_l2"] == pytest.approx(1.5) and rows[1]["rel_max_displacement"] == pytest.approx(1.5)


def test_every_reference_zero_is_an_infinite_error_said_in_the_message():
    row, = point_rows(_evaluation([[0, 0, 0]]), _driven([[0, 3, 4]]))
    assert row["rel_l2"] == np.inf and row["rel_max_displacement"] == np.inf
    assert row["message"] == ZERO_REFERENCE
    row, = point_rows(_evaluation([[0, 0, 0]]), _driven([[0, 0, 0]], messages=["slow"]))
    assert row["rel_l2"] == np.inf and row["message"] == "slow; " + ZERO_REFERENCE


def test_a_failed_step_is_inf_and_a_point_without_reference_is_nan():
    ev = _evaluation([[1, 0, 0], None, [1, 0, 0], [1, 0, 0], [1, 0, 0], [1, 0, 0]])
    big = 1e150
    rows = point_rows(ev, _driven([None, [1, 0, 0], [np.nan, 0, 0], [2 * big, 0, 0], [big, 0, 0], [-2 * big, 0, 0]],
                                  statuses=["failed", "ok", "ok", "ok", "ok", "ok"]))
    assert rows[0]["rel_l2"] == math.inf and rows[0]["rel_max_displacement"] == math.inf
    assert math.isnan(rows[1]["rel_l2"]) and math.isnan(rows[1]["rel_max_displacement"])
    assert rows[1]["has_reference"] is False
    assert rows[2]["rel_l2"] == math.inf and rows[2]["rel_max_displacement"] == math.inf  # non-finite field
    assert rows[3]["rel_l2"] == math.inf and rows[3]["rel_max_displacement"] == math.inf  # a blow-up, > 1e150
    # exactly 1e150 is still a number: its error is computed, not inf
    assert rows[4]["rel_l2"] == pytest.approx(big) and rows[4]["rel_max_displacement"] == pytest.approx(big)
    assert rows[5]["rel_l2"] == math.inf  # the magnitude counts, not the signed value
    # the peak-normalised and absolute errors (issue 52) on the same sides: inf where rel_l2 is, NaN without
    # a reference, 1e150 still a number (the scale: |ref| = 1)
    assert [rows[k]["abs_error"] for k in (0, 2, 3, 5)] == [math.inf] * 4
    assert [rows[k]["peak_rel"] for k in (0, 2, 3, 5)] == [math.inf] * 4
    assert math.isnan(rows[1]["abs_error"]) and math.isnan(rows[1]["peak_rel"])
    assert rows[4]["abs_error"] == pytest.approx(big) and rows[4]["peak_rel"] == pytest.approx(big)


def test_statuses_initial_not_reached_and_the_message():
    ev = _evaluation([[1, 0, 0]] * 3, kind="trajectory")
    rows = point_rows(ev, _driven([[1, 0, 0], None, [1, 0, 0]], statuses=[None, None, "extrapolation"],
                                  messages=["", "", "x" * 400]), seen=[True, True, True])
    assert [r["status"] for r in rows] == ["initial", "not_reached", "extrapolation"]
    assert math.isnan(rows[0]["rel_l2"]) and math.isnan(rows[0]["rel_max_displacement"])  # the initial state
    assert rows[0]["seen"] is False and rows[1]["seen"] is True and rows[2]["seen"] is True
    assert rows[1]["rel_l2"] == math.inf and rows[1]["message"] == ""
    assert rows[2]["message"] == "x" * 300 and rows[2]["rel_l2"] == 0.0
    # on a path (not a trajectory) a first point that never ran is not_reached, and has an error
    row = point_rows(_evaluation([[1, 0, 0]]), _driven([None], statuses=[None]))[0]
    assert row["status"] == "not_reached" and row["rel_l2"] == math.inf
    # a trajectory's later point without a result is not_reached too, not initial
    rows = point_rows(ev, _driven([[1, 0, 0], None, None], statuses=["ok", None, None]))
    assert [r["status"] for r in rows] == ["ok", "not_reached", "not_reached"]


def test_row_fields_x_group_mu_beyond():
    ev = _evaluation([[1, 0, 0], [2, 0, 0]], xs=[0.25, 0.5], groups=[None, 3.0], beyond=[False, True],
                     mus=[{"b": 0.5, "a": 1 / 3}, {}])
    rows = point_rows(ev, _driven([[1, 0, 0], [2, 0, 0]]), seen=[False, True])
    assert rows[0]["mu"] == "a=0.333333, b=0.5"
    assert rows[0]["x"] == 0.25 and math.isnan(rows[0]["group"]) and rows[1]["group"] == 3.0
    assert rows[0]["beyond"] is False and rows[1]["beyond"] is True
    assert rows[0]["seen"] is False and rows[1]["seen"] is True and rows[1]["point"] == 1


def test_monitor_errors_relative_and_absolute_at_zero():
    ev = _evaluation([[1, 0, 0], [1, 0, 0]], monitors=[{"force": 4.0, "zero": 0.0, "rest": 0.0},
                                                       {"force": -2.0, "zero": 0.0, "rest": -0.5}])
    out = output_rows(ev, _driven([[1, 0, 0]] * 2, outputs=[{"force": 5.0, "zero": -0.25, "rest": -0.25, "other": 1.0},
                                                            {"force": -1.0, "rest": -0.75}]))
    assert [(r["point"], r["monitor"]) for r in out] == [(0, "force"), (0, "zero"), (0, "rest"), (1, "force"),
                                                         (1, "rest")]
    assert out[0]["rel_error"] == pytest.approx(0.25) and out[0]["reference"] == 4.0 and out[0]["rom"] == 5.0
    assert out[1]["rel_error"] == np.inf  # every reference of the monitor is 0: no relative error
    assert out[2]["rel_error"] == pytest.approx(0.25 / 0.5)  # its reference is 0: against the monitor's largest
    assert out[3]["rel_error"] == pytest.approx(0.5) and out[3]["x"] == 1.0
    assert out[4]["rel_error"] == pytest.approx(0.5)


# ---------------------------------------------------------------- seen points
def test_seen_at_the_tolerance_on_both_sides():
    rng = np.random.default_rng(0)
    S = rng.normal(size=(6, 3))
    r = S[:, 1]
    d = rng.normal(size=6)
    d /= np.linalg.norm(d)
    n = np.linalg.norm(r)
    S *= 100.0  # |r|^2 far from 1: the tolerance is relative to it
    r = S[:, 1]
    n = np.linalg.norm(r)
    refs = [S[:, 0], r + 0.5 * SEEN_RTOL * n * d, r + 2 * SEEN_RTOL * n * d, r + 1e-3 * n * d, None,
            np.zeros(6), np.ones(5)]
    seen = seen_points(_evaluation(refs), np.column_stack([S, np.zeros(6)]))
    assert seen == [True, True, False, False, False, False, False]


def test_nothing_is_seen_without_snapshots_or_references():
    ev = _evaluation([[1.0, 2.0], [3.0, 4.0]])
    assert seen_points(ev, None) == [False, False]
    assert seen_points(ev, np.zeros((2, 0))) == [False, False]
    assert seen_points(_evaluation([None, None]), np.eye(2)) == [False, False]
    assert seen_points(ev, np.array([[1.0], [2.0]])) == [True, False]


def test_seen_against_float32_snapshots():
    # snapshots stored in single precision: the reference that is a snapshot is seen, one 2e-6 off is not
    rng = np.random.default_rng(2)
    S = rng.normal(size=(50, 8)).astype(np.float32) * np.float32(1000)
    exact = [S[:, k].astype(float) for k in range(8)]
    off = [e * (1 + 2 * SEEN_RTOL) for e in exact]
    assert seen_points(_evaluation(exact + off), S) == [True] * 8 + [False] * 8


def test_seen_over_more_points_than_one_chunk():
    rng = np.random.default_rng(1)
    S = rng.normal(size=(4, 3))
    refs = [S[:, k % 3] for k in range(600)]
    refs[300] = S[:, 0] + 1.0
    seen = seen_points(_evaluation(refs), S)
    assert seen == [k != 300 for k in range(600)]


# ---------------------------------------------------------------- validity radius
@pytest.mark.parametrize("tol", TOLERANCES)
def test_validity_radius_at_the_tolerance_on_both_sides(tol):
    x = [0.4, 0.1, 0.3, 0.2]
    just_over = tol * (1 + 1e-12)
    assert validity_radius(x, [0.0, 0.0, 0.0, tol], tol) == 0.4  # == tol holds
    assert validity_radius(x, [0.0, 0.0, just_over, tol], tol) == 0.2  # unsorted x; the first bad at 0.3
    assert validity_radius(x, [just_over, 0.0, 0.0, 0.0], tol) == 0.3
    assert validity_radius(x, [0.0, just_over, 0.0, 0.0], tol) == 0.0  # the first fails


def test_validity_radius_ignores_nan_and_stops_at_a_tie():
    assert math.isnan(validity_radius([0.1, 0.2], [np.nan, np.nan], 0.01))
    assert validity_radius([0.1, 0.2, 0.3], [0.0, np.nan, 0.0], 0.01) == 0.3
    assert validity_radius([0.1, 0.2, 0.3], [0.0, 0.0, np.nan], 0.01) == 0.2
    assert validity_radius([0.1, 0.2, 0.3], [np.nan, 0.0, 0.02], 0.01) == 0.2
    # two points at one abscissa, one bad: that abscissa is not valid
    assert validity_radius([0.1, 0.2, 0.2, 0.3], [0.0, 0.0, 0.5, 0.0], 0.01) == 0.1
    assert validity_radius([0.2, 0.1, 0.2, 0.3], [0.0, 0.0, 0.5, 0.0], 0.01) == 0.1
    assert validity_radius([0.1, 0.2, 0.3], [0.0, math.inf, 0.0], 0.01) == 0.1  # a failed step is bad
    assert validity_radius(np.array([0.3, 0.1, 0.2]), np.array([0.0, 0.0, 0.0]), 0.01) == 0.3


# ---------------------------------------------------------------- a unit's summary
def _summary_case():
    # five points: ok, ok (seen), extrapolation, beyond the path, and the initial state of nothing
    refs = [[3, 4, 0], [0, 0, 2], [1, 0, 0], [0, 2, 0], None]
    fields = [[3, 4, 0.1], [0, 0, 2], [1, 0, 0.5], [0, 2, 2], [0, 0, 0]]
    ev = _evaluation(refs, xs=[0.1, 0.2, 0.3, 0.4, 0.5], beyond=[False, False, False, True, False],
                     monitors=[{"f": 2.0}, {}, {}, {}, {}])
    driven = _driven(fields, statuses=["ok", "ok", "extrapolation", "ok", "not_reached"],
                     outputs=[{"f": 2.5}, {}, {}, {}, {}])
    points = pd.DataFrame(point_rows(ev, driven, seen=[False, True, False, False, False]))
    outputs = pd.DataFrame(output_rows(ev, driven))
    return points, outputs, ev, driven


def test_unit_summary_by_hand():
    points, outputs, ev, driven = _summary_case()
    row = summarise_points(points, outputs, ev, driven.fields)
    # rel_l2 of the three points with a reference inside the path: 0.1/5, 0, 0.5/1
    assert row["max_rel_l2"] == pytest.approx(0.5) and row["mean_rel_l2"] == pytest.approx(0.52 / 3)
    assert row["max_rel_l2_in_envelope"] == pytest.approx(0.02)  # the extrapolated point left out
    # sqrt((0.01 + 0 + 0.25) / (25 + 4 + 1)): the beyond point and the point without reference left out
    assert row["rmse_rel"] == pytest.approx(math.sqrt(0.26 / 30), rel=1e-14)
    assert row["max_monitor_rel_error"] == pytest.approx(0.25)
    assert (row["n_points"], row["n_reference_points"], row["n_seen"], row["n_beyond_reference"]) == (5, 3, 1, 1)
    assert row["seen"] is False and row["x_name"] == "load factor"
    assert (row["n_ok"], row["n_extrapolation"], row["n_beyond_validity"], row["n_failed"],
            row["n_not_reached"]) == (3, 1, 0, 0, 1)
    # validity over every point with a reference (the beyond one too): 0.02 fails 1 % at the first
    # point; 5 % holds up to 0.2, where the 0.5 of x = 0.3 fails it
    assert row["validity_1pct"] == 0.0 and row["validity_5pct"] == 0.2
    assert row["validity_range"] == ""  # no extrapolation key: a plain evaluation, every point
    # the worst step's error over the peak reference (0.5 / 5) and the largest nodal error (0.5)
    assert row["peak_rel_l2"] == pytest.approx(0.1) and row["max_abs_error"] == pytest.approx(0.5)


def test_peak_and_absolute_errors_of_references_smaller_than_one():
    ev = _evaluation([[0.3, 0.4, 0.0], [0.0, 0.0, 0.2]])  # |u| 0.5 and 0.2
    fields = [[0.3, 0.4, 0.1], [0.0, 0.0, 0.2]]
    points = pd.DataFrame(point_rows(ev, _driven(fields)))
    row = summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])
    assert row["peak_rel_l2"] == pytest.approx(0.2) and row["max_abs_error"] == pytest.approx(0.1)
    # the headline's scale below 1 is still a scale (0.1 / 0.5), not an absolute error
    assert row["claimed_error"] == pytest.approx(0.2) and points["peak_rel"].tolist() == pytest.approx([0.2, 0.0])


def test_every_reference_zero_makes_the_history_errors_inf():
    ev = _evaluation([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    fields = [[0.1, 0.0, 0.0], [0.0, 0.0, 0.0]]
    points = pd.DataFrame(point_rows(ev, _driven(fields)))
    row = summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])
    assert row["rmse_rel"] == math.inf and row["peak_rel_l2"] == math.inf
    assert row["max_abs_error"] == pytest.approx(0.1)


def test_unit_summary_seen_when_every_reference_point_is_seen_and_a_failure_is_inf():
    points, outputs, ev, driven = _summary_case()
    points["seen"] = True
    assert summarise_points(points, outputs, ev, driven.fields)["seen"] is True
    fields = list(driven.fields)
    fields[2] = None
    points = pd.DataFrame(point_rows(ev, _driven([None if f is None else f for f in fields],
                                                 statuses=["ok", "ok", "failed", "ok", "not_reached"])))
    row = summarise_points(points, pd.DataFrame(), ev, fields)
    assert row["rmse_rel"] == math.inf and row["max_rel_l2"] == math.inf
    assert row["max_rel_l2_in_envelope"] == math.inf  # a failure on its own range is never accurate
    assert row["peak_rel_l2"] == math.inf and row["max_abs_error"] == math.inf
    assert math.isnan(row["max_monitor_rel_error"]) and row["n_failed"] == 1 and row["n_seen"] == 0


def test_unit_summary_of_rows_without_beyond_and_seen_columns():
    # older stores: no beyond column (nothing is past the path) and no seen column
    points, outputs, ev, driven = _summary_case()
    row = summarise_points(points.drop(columns=["beyond", "seen"]), outputs, ev, driven.fields)
    assert (row["n_reference_points"], row["n_beyond_reference"], row["n_seen"]) == (4, 0, 0)
    assert row["max_rel_l2"] == pytest.approx(1.0) and row["mean_rel_l2"] == pytest.approx(1.52 / 4)
    assert row["rmse_rel"] == pytest.approx(math.sqrt(4.26 / 34), rel=1e-14)


def test_a_trajectory_initial_state_with_a_reference_is_not_a_reference_point():
    # the initial state (point 0) has a reference but is not an error point; the rmse sums the later ones
    ev = _evaluation([[5, 0, 0], [0.1, 0, 0], [0.2, 0, 0]], kind="trajectory")
    fields = [[5, 0, 0], [0.1, 0, 0.01], [0.2, 0, 0.01]]
    points = pd.DataFrame(point_rows(ev, _driven(fields, statuses=[None, "ok", "ok"])))
    row = summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])
    assert row["n_reference_points"] == 2 and row["max_rel_l2"] == pytest.approx(0.1)
    # den = 0.01 + 0.04 < 1: still relative
    assert row["rmse_rel"] == pytest.approx(math.sqrt(0.0002 / 0.05), rel=1e-12)


def test_a_finite_blow_up_is_inf_without_a_warning():
    ev = _evaluation([[1, 0, 0], [1, 0, 0]])
    fields = [np.array([1.0, 0, 0]), np.array([1e200, 0, 0])]  # finite, its square overflows
    points = pd.DataFrame(point_rows(ev, _driven(fields)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        row = summarise_points(points, pd.DataFrame(), ev, fields)
    assert row["rmse_rel"] == math.inf and row["max_rel_l2"] == math.inf  # > 1e150: a blow-up


def test_unit_summary_without_a_reference_is_nan_not_zero():
    ev = _evaluation([None, None])
    points = pd.DataFrame(point_rows(ev, _driven([[1.0], [2.0]])))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no mean of an empty array
        row = summarise_points(points.drop(columns=["beyond", "seen"]), pd.DataFrame(), ev, [None, None])
    for k in ("max_rel_l2", "mean_rel_l2", "max_rel_l2_in_envelope", "rmse_rel", "validity_1pct"):
        assert math.isnan(row[k]), k
    assert row["n_seen"] == 0 and row["seen"] is False and row["n_reference_points"] == 0


def test_rmse_is_over_the_history_not_the_mean_of_the_points():
    ev = _evaluation([[1, 0, 0], [10, 0, 0]])
    fields = [[2, 0, 0], [10, 0, 0]]  # errors 1 and 0, |ref|^2 1 and 100
    points = pd.DataFrame(point_rows(ev, _driven(fields)))
    row = summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])
    assert row["rmse_rel"] == pytest.approx(math.sqrt(1 / 101), rel=1e-14)
    assert row["mean_rel_l2"] == pytest.approx(0.5)


def test_in_envelope_without_any_inside_point_is_nan():
    ev = _evaluation([[1, 0, 0]])
    points = pd.DataFrame(point_rows(ev, _driven([[2, 0, 0]], statuses=["beyond_validity"])))
    row = summarise_points(points, pd.DataFrame(), ev, [np.array([2.0, 0, 0])])
    assert math.isnan(row["max_rel_l2_in_envelope"]) and row["max_rel_l2"] == 1.0 and row["n_beyond_validity"] == 1


# ---------------------------------------------------------------- the range a unit claims (issue 44)
def _range_points(statuses, beyond):
    return pd.DataFrame({"x": [0.1, 0.2, 0.3], "status": statuses, "beyond": beyond}, index=[7, 8, 9])


@pytest.mark.parametrize("flag", ["extrapolation", "beyond_validity"])
def test_the_claimed_range_is_the_training_range_unless_extrapolation_is_asked(flag):
    points = _range_points(["ok", flag, "ok"], [False, False, True])
    mask, what = claimed_range(points, SimpleNamespace(info={"extrapolation": False}))
    assert what == "training" and mask.to_dict() == {7: True, 8: False, 9: False}
    mask, what = claimed_range(points, SimpleNamespace(info={"extrapolation": True}))
    assert what == "extrapolation" and mask.to_dict() == {7: True, 8: True, 9: True}
    for evaluation in (SimpleNamespace(info={}), SimpleNamespace(info=None), SimpleNamespace()):
        mask, what = claimed_range(points, evaluation)  # not a path: every point, no range named
        assert what == "" and mask.to_dict() == {7: True, 8: True, 9: True}
    # a store without the beyond column: nothing is past the top, the flagged point still left out
    mask, _ = claimed_range(points.drop(columns="beyond"), SimpleNamespace(info={"extrapolation": False}))
    assert mask.to_dict() == {7: True, 8: False, 9: True}


def _radius_row(statuses, beyond, fields, extrapolation):
    ev = _evaluation([[1, 0, 0]] * 3, xs=[0.1, 0.2, 0.3], beyond=beyond)
    ev.info["extrapolation"] = extrapolation
    points = pd.DataFrame(point_rows(ev, _driven(fields, statuses=statuses)))
    return summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])


def test_valid_to_stops_at_the_training_range_unless_extrapolation_is_asked():
    exact = [[1, 0, 0]] * 3
    # the point past the top is exact: "valid to" reaches it only when extrapolation is asked
    row = _radius_row(["ok"] * 3, [False, False, True], exact, False)
    assert (row["validity_1pct"], row["validity_5pct"], row["validity_range"]) == (0.2, 0.2, "training")
    row = _radius_row(["ok"] * 3, [False, False, True], exact, True)
    assert (row["validity_1pct"], row["validity_5pct"], row["validity_range"]) == (0.3, 0.3, "extrapolation")
    # a flagged point 50 % off inside the path: out of the training range, in with extrapolation
    off = [[1, 0, 0], [1.5, 0, 0], [1, 0, 0]]
    row = _radius_row(["ok", "extrapolation", "ok"], [False] * 3, off, False)
    assert row["validity_5pct"] == 0.3 and row["validity_range"] == "training"
    row = _radius_row(["ok", "extrapolation", "ok"], [False] * 3, off, True)
    assert row["validity_5pct"] == 0.1


# ---------------------------------------------------------------- the claimed (headline) error (issue 52)
def _headline_case(extrapolation):
    """A path: near rest (1/1000 of the first state: the model 100 % off state-relatively, 0.01
    absolute), a held-out state (|ref| 5, error 0.1), a step the model flags (|ref| 10, error 0.5)
    and a point past the top (|ref| 20, error 1)."""
    refs = [[0.01, 0, 0], [3, 4, 0], [0, 0, 10], [0, 20, 0]]
    fields = [[0.02, 0, 0], [3, 4, 0.1], [0, 0, 10.5], [0, 20, 1]]
    ev = _evaluation(refs, xs=[0.001, 0.5, 0.75, 1.5], beyond=[False, False, False, True])
    ev.info["extrapolation"] = extrapolation
    points = pd.DataFrame(point_rows(ev, _driven(fields, statuses=["ok", "ok", "extrapolation", "extrapolation"])))
    return points, summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])


def test_the_headline_is_peak_normalised_over_the_training_range_by_hand():
    points, row = _headline_case(False)
    # the largest reference of the claimed range is 5: neither the flagged step's 10 nor the 20 past the top
    assert points["peak_rel"].tolist() == pytest.approx([0.01 / 5, 0.1 / 5, 0.5 / 5, 1 / 5], rel=1e-14)
    assert points["abs_error"].tolist() == pytest.approx([0.01, 0.1, 0.5, 1.0], rel=1e-14)
    assert points["rel_l2"].tolist() == pytest.approx([1.0, 0.02, 0.05, 0.05], rel=1e-14)
    assert row["claimed_error"] == pytest.approx(0.02, rel=1e-14)  # the held-out state's 0.1 / 5
    # beside it, unchanged: the state-relative worst (near rest), the run's peak (0.5 / 10), the absolute
    assert row["max_rel_l2"] == pytest.approx(1.0) and row["peak_rel_l2"] == pytest.approx(0.05)
    assert row["max_abs_error"] == pytest.approx(0.5)
    # "valid to" reads the peak-normalised error: 0.2 % at 0.001, 2 % at 0.5 (state-relative: 0 at both)
    assert (row["validity_1pct"], row["validity_5pct"], row["validity_range"]) == (0.001, 0.5, "training")


def test_the_headline_with_extrapolation_asked_is_over_every_point():
    points, row = _headline_case(True)
    # the claimed range is every point: the largest reference is the 20 past the top
    assert points["peak_rel"].tolist() == pytest.approx([0.0005, 0.005, 0.025, 0.05], rel=1e-14)
    assert row["claimed_error"] == pytest.approx(0.05, rel=1e-14)
    # 2.5 % at the flagged 0.75 fails 1 %; 5 % at 1.5 holds 5 % (equality holds)
    assert (row["validity_1pct"], row["validity_5pct"], row["validity_range"]) == (0.5, 1.5, "extrapolation")


def test_the_headline_scale_counts_a_failed_step_and_skips_the_initial_state():
    # a trajectory: the initial state (|ref| 100) is no error point and no scale; a failed step's
    # reference (|ref| 10) is the largest of the run: its error is inf, the others' are over 10
    ev = _evaluation([[100, 0, 0], [0, 2, 0], [0, 0, 10]], kind="trajectory")
    fields = [[100, 0, 0], [0, 2, 0.5], None]
    points = pd.DataFrame(point_rows(ev, _driven(fields, statuses=[None, "ok", "failed"])))
    assert math.isnan(points["peak_rel"][0]) and math.isnan(points["abs_error"][0])
    assert points["peak_rel"][1] == pytest.approx(0.05, rel=1e-14) and points["abs_error"][1] == pytest.approx(0.5)
    assert points["peak_rel"][2] == math.inf and points["abs_error"][2] == math.inf
    row = summarise_points(points, pd.DataFrame(), ev, [None if f is None else np.asarray(f, float) for f in fields])
    assert row["claimed_error"] == math.inf and row["validity_range"] == ""
    # the other side: the step succeeds, exactly; the worst is 0.5 over the failed step's 10
    fields[2] = [0, 0, 10]
    points = pd.DataFrame(point_rows(ev, _driven(fields, statuses=[None, "ok", "ok"])))
    row = summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])
    assert row["claimed_error"] == pytest.approx(0.05, rel=1e-14) and points["peak_rel"][2] == 0.0
    assert row["claimed_error"] == pytest.approx(row["peak_rel_l2"], rel=1e-14)  # a motion: the same number


def test_a_zero_claimed_range_is_inf_whatever_lies_past_it():
    # every reference of the training range is zero: no peak-normalised error exists (inf), even where
    # the model matches it, and a reference past the top does not lend its scale
    ev = _evaluation([[0, 0, 0], [0, 0, 0], [0, 5, 0]], beyond=[False, False, True])
    ev.info["extrapolation"] = False
    fields = [[0, 0, 0], [0, 0, 0.1], [0, 5, 0]]
    points = pd.DataFrame(point_rows(ev, _driven(fields)))
    assert points["peak_rel"].tolist() == [math.inf] * 3
    row = summarise_points(points, pd.DataFrame(), ev, [np.asarray(f, float) for f in fields])
    assert row["claimed_error"] == math.inf and row["validity_1pct"] == 0.0
    # the other side: extrapolation asked, the 5 past the top is the scale
    ev.info["extrapolation"] = True
    points = pd.DataFrame(point_rows(ev, _driven(fields)))
    assert points["peak_rel"].tolist() == pytest.approx([0.0, 0.02, 0.0])


def test_no_reference_in_the_claimed_range_makes_the_scale_zero():
    # the claimed range has points, none with a reference: the point past the top has nothing to be
    # normalised by (inf); the points without reference stay NaN
    ev = _evaluation([None, [0, 5, 0]], beyond=[False, True])
    ev.info["extrapolation"] = False
    peaks = peak_normalise(point_rows(ev, _driven([[0, 0, 0], [0, 5, 1]])), [math.nan, 1.0], [0.0, 5.0], ev)
    assert math.isnan(peaks[0]) and peaks[1] == math.inf
    assert point_rows(_evaluation([]), _driven([])) == [] and peak_normalise([], [], [], ev) == []
    # the other side: a reference below 1 beside the point without one is the scale (0.1 / 0.5)
    ev = _evaluation([None, [0, 0.5, 0]])
    ev.info["extrapolation"] = False
    peaks = [r["peak_rel"] for r in point_rows(ev, _driven([[0, 0, 0], [0, 0.5, 0.1]]))]
    assert math.isnan(peaks[0]) and peaks[1] == pytest.approx(0.2, rel=1e-14)


def test_without_a_reference_or_peak_rel_column_the_headline_is_nan():
    ev = _evaluation([None, None])
    points = pd.DataFrame(point_rows(ev, _driven([[1.0], [2.0]])))
    assert points["peak_rel"].isna().all() and points["abs_error"].isna().all()
    assert math.isnan(summarise_points(points, pd.DataFrame(), ev, [None, None])["claimed_error"])
    # rows without peak_rel (a store's before issue 52): no headline, the radii read rel_l2
    points, _ = _headline_case(False)
    ev = _evaluation([[0.01, 0, 0], [3, 4, 0], [0, 0, 10], [0, 20, 0]], xs=[0.001, 0.5, 0.75, 1.5],
                     beyond=[False, False, False, True])
    ev.info["extrapolation"] = False
    row = summarise_points(points.drop(columns="peak_rel"), pd.DataFrame(), ev, [None] * 4)
    assert math.isnan(row["claimed_error"]) and row["validity_1pct"] == 0.0 and row["validity_5pct"] == 0.0


@pytest.mark.parametrize("what, expected", [("training", [True, False, False, False]),
                                            ("extrapolation", [True] * 4), ("", [True] * 4)])
def test_the_claimed_mask_of_stored_rows(what, expected):
    points = pd.DataFrame({"status": ["ok", "extrapolation", "beyond_validity", "ok"],
                           "beyond": [False, False, False, True]}, index=[3, 4, 5, 6])
    assert claimed_mask(points, what).tolist() == expected
    assert claimed_mask(points, what).index.tolist() == [3, 4, 5, 6]
    # a store without the beyond column: nothing is past the top
    assert claimed_mask(points.drop(columns="beyond"), what).tolist() == (
        [True, False, False, True] if what == "training" else [True] * 4)


# ---------------------------------------------------------------- Pareto front
def test_pareto_front_by_hand():
    units = pd.DataFrame([
        {"case": "a", "unit_status": "ok", "max_rel_l2": 0.1, "haptic_median_s": 1.0},   # front
        {"case": "a", "unit_status": "ok", "max_rel_l2": 0.1, "haptic_median_s": 1.0},   # a tie: front too
        {"case": "a", "unit_status": "ok", "max_rel_l2": 0.1, "haptic_median_s": 2.0},   # slower, as accurate
        {"case": "a", "unit_status": "ok", "max_rel_l2": 0.2, "haptic_median_s": 1.0},   # less accurate, as fast
        {"case": "a", "unit_status": "ok", "max_rel_l2": 0.05, "haptic_median_s": 3.0},  # front
        {"case": "a", "unit_status": "failed", "max_rel_l2": 0.0, "haptic_median_s": 0.1},  # never on it
        {"case": "a", "unit_status": "ok", "max_rel_l2": np.nan, "haptic_median_s": 0.1},
        {"case": "a", "unit_status": "ok", "max_rel_l2": 0.0, "haptic_median_s": np.inf},
        {"case": "b", "unit_status": "ok", "max_rel_l2": 0.3, "haptic_median_s": 5.0},   # alone in its case
    ])
    out = pareto_front(units)
    assert out["pareto"].tolist() == [True, True, False, False, True, False, False, False, True]
    assert "pareto" not in units  # a copy
    other = pareto_front(units.rename(columns={"max_rel_l2": "e", "haptic_median_s": "t"}), error="e", latency="t")
    assert other["pareto"].tolist() == out["pareto"].tolist()


# ---------------------------------------------------------------- latency statistics
def test_latency_stats_by_hand():
    s = latency_stats([4.0, 1.0, 100.0, 2.0, 3.0])
    # 99th percentile, linear: rank 0.99 * 4 = 3.96 between 4 and 100
    assert s == LatencyStats(3.0, pytest.approx(4 + 0.96 * 96), 1.0, 100.0, 5)
    assert s.as_dict("h_") == {"h_median_s": 3.0, "h_p99_s": s.p99, "h_min_s": 1.0, "h_max_s": 100.0, "h_n": 5}
    assert set(s.as_dict()) == {"median_s", "p99_s", "min_s", "max_s", "n"}
    assert latency_stats([2.0]) == LatencyStats(2.0, 2.0, 2.0, 2.0, 1)


@pytest.mark.parametrize("bad", [[], [[1.0, 2.0]], [1.0, np.nan], [1.0, np.inf]])
def test_latency_stats_refuses_what_is_not_a_finite_sample(bad):
    with pytest.raises(ValueError, match=r"latency samples must be a non-empty finite 1D sequence, got shape"):
        latency_stats(bad)


def test_relative_l2_and_max_displacement_by_hand():
    assert relative_l2([3, 4, 1], [3, 4, 0]) == pytest.approx(0.2, rel=1e-14)
    assert relative_l2([[3, 4], [1, 0]], [[3, 4], [0, 0]]) == pytest.approx(0.2, rel=1e-14)  # flattened
    assert relative_l2([0, 3, 4], [0, 0, 0]) == np.inf  # a zero field: no relative error
    assert relative_l2([0.3, 0.4, 0.1], [0.3, 0.4, 0.0]) == pytest.approx(0.2, rel=1e-14)  # |ref| < 1: relative
    with pytest.raises(ValueError, match=r"relative_l2: shapes differ: \(3,\) vs \(2,\)"):
        relative_l2([1, 2, 3], [1, 2])
    assert max_displacement([3, 4, 0, 0, 0, 4.5]) == 5.0
    assert max_displacement([0, 0, -6, 3, 4, 0]) == 6.0


def test_relative_l2_of_two_zero_fields_is_inf_not_nan():
    assert relative_l2([0.0, 0.0], [0.0, 0.0]) == np.inf


def test_p99_tail_counts_the_samples_beyond_the_p99():
    from tissuebench.studies.timing import p99_tail
    assert [p99_tail(n) for n in (0, 1, 2, 3, 100, 101, 200, 2000)] == [0, 0, 1, 1, 1, 1, 2, 20]
