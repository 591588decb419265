"""The error metrics of a motion (issue 42) on two-node fields worked by hand.

``peak_rel_l2 = max_k |e_k| / max_k |u_ref,k|`` (the worst step against the run's peak
displacement) and ``max_abs_error = max_k max_node |e|`` (the scene's length unit), beside the
relative RMSE and the per-step relative error they complement: a step of small motion with a
small absolute error is a large relative error, not a large peak-normalised one.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from tissuebench.studies.metrics import ABSOLUTE_ERROR_METRICS, nodal_error, summarise_points
from tissuebench.studies.schema import UNIT_COLUMNS
from tissuebench.studies.spec import ERROR_METRICS

REF = [np.array([3.0, 4.0, 0.0, 0.0, 0.0, 0.0]),  # |u| = 5
       np.array([0.0, 0.0, 0.0, 0.0, 0.0, 10.0])]  # |u| = 10: the peak


def _summary(fields, statuses=("ok", "ok")):
    points = pd.DataFrame({"x": [1.0, 2.0], "status": list(statuses), "rel_l2": [0.0, 0.0],
                           "has_reference": True, "seen": False, "beyond": False})
    evaluation = SimpleNamespace(points=[SimpleNamespace(reference=r) for r in REF], x_name="time")
    return summarise_points(points, pd.DataFrame(), evaluation, fields)


def test_peak_normalised_and_absolute_errors_by_hand():
    # step 1 off by (0, 0, 3 | 0, 0, 4): |e| = 5, nodal errors 3 and 4; step 2 exact
    row = _summary([REF[0] + np.array([0.0, 0.0, 3.0, 0.0, 0.0, 4.0]), REF[1].copy()])
    assert row["peak_rel_l2"] == pytest.approx(5.0 / 10.0)        # not 5 / 5: the peak is step 2's
    assert row["max_abs_error"] == pytest.approx(4.0)             # the node off by 4, not the field's 5
    assert row["rmse_rel"] == pytest.approx(np.sqrt(25.0 / 125.0))


def test_the_worst_step_sets_both_whichever_it_is():
    row = _summary([REF[0] + np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]),
                    REF[1] + np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0])])
    assert row["peak_rel_l2"] == pytest.approx(2.0 / 10.0) and row["max_abs_error"] == pytest.approx(2.0)


def test_a_failed_step_is_an_infinite_error_in_both():
    row = _summary([REF[0].copy(), None], statuses=("ok", "failed"))
    assert row["peak_rel_l2"] == np.inf and row["max_abs_error"] == np.inf


def test_the_initial_state_and_points_without_reference_are_left_out():
    points = pd.DataFrame({"x": [0.0, 1.0, 2.0], "status": ["initial", "ok", "ok"], "rel_l2": [np.nan, 0.0, 0.0],
                           "has_reference": [True, True, False], "seen": False, "beyond": False})
    rest = np.zeros(6)
    evaluation = SimpleNamespace(points=[SimpleNamespace(reference=rest), SimpleNamespace(reference=REF[0]),
                                         SimpleNamespace(reference=None)], x_name="time")
    row = summarise_points(points, pd.DataFrame(), evaluation, [rest + 100.0, REF[0] + 0.5, None])
    e = np.full(6, 0.5)
    assert row["peak_rel_l2"] == pytest.approx(np.linalg.norm(e) / 5.0)
    assert row["max_abs_error"] == pytest.approx(np.sqrt(3 * 0.25))


def test_nodal_error_takes_node_magnitudes_or_dof_values():
    assert nodal_error([1.0, 2.0, 2.0, 0.0, 0.0, 0.0], np.zeros(6)) == pytest.approx(3.0)
    assert nodal_error([1.0, -4.0], [0.0, 0.0]) == pytest.approx(4.0)  # a 1D model: per dof


def test_the_new_metrics_are_registered_stored_and_the_absolute_one_named():
    for name in ("peak_rel_l2", "max_abs_error"):
        assert name in ERROR_METRICS and name in UNIT_COLUMNS
    assert ABSOLUTE_ERROR_METRICS == ("max_abs_error",) and "length_unit" in UNIT_COLUMNS
