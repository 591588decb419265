"""A relative error against a zero reference is never 0 % (issue 37, item 1): a scene whose load
did no work had a zero reference everywhere, every model "matched" it, and the report recommended
them with "error 0 %, margin 1.8e+308x"."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from tissuebench.studies.metrics import ZERO_REFERENCE, output_rows, point_rows, summarise_points
from tissuebench.studies.timing import relative_l2


def _run(references, fields, monitors=None, outputs=None):
    n = len(references)
    evaluation = SimpleNamespace(kind="path", x_name="load_factor", points=[
        SimpleNamespace(reference=r, x=k + 1.0, group=None, mu={"load_factor": k + 1.0}, beyond=False,
                        monitors=(monitors or [{}] * n)[k]) for k, r in enumerate(references)])
    driven = SimpleNamespace(results=[SimpleNamespace(status="ok", message="")] * n, fields=fields,
                             outputs=outputs or [{}] * n)
    points = pd.DataFrame(point_rows(evaluation, driven))
    out = pd.DataFrame(output_rows(evaluation, driven), columns=["point", "x", "monitor", "reference", "rom",
                                                                 "rel_error"])
    return points, out, summarise_points(points, out, evaluation, fields)


def test_a_model_matching_a_zero_reference_everywhere_has_an_infinite_error_said_in_the_message():
    zero = np.zeros(6)
    points, out, row = _run([zero, zero], [zero, zero], [{"tip": 0.0}] * 2, [{"tip": 0.0}] * 2)
    assert np.isinf(points["rel_l2"]).all() and np.isinf(points["rel_max_displacement"]).all()
    assert (points["message"] == ZERO_REFERENCE).all()
    assert row["max_rel_l2"] == np.inf and row["max_rel_l2_in_envelope"] == np.inf and row["rmse_rel"] == np.inf
    assert np.isinf(out["rel_error"]).all() and row["max_monitor_rel_error"] == np.inf
    assert row["validity_1pct"] == 0.0


def test_a_zero_reference_point_is_measured_against_the_evaluations_largest_reference():
    """The other side: one reference is zero (a trajectory at rest before its load starts), the others
    are not; the error there is relative to the largest (0.5 / 2), not the absolute norm of the field."""
    ref = np.array([2.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    u0 = np.array([0.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    points, out, row = _run([np.zeros(6), ref], [u0, ref], [{"tip": 0.0}, {"tip": 4.0}],
                            [{"tip": 1.0}, {"tip": 4.0}])
    assert points["rel_l2"].tolist() == pytest.approx([0.25, 0.0])
    assert points["rel_max_displacement"].tolist() == pytest.approx([0.25, 0.0])
    assert (points["message"] == "").all()
    assert out["rel_error"].tolist() == pytest.approx([0.25, 0.0])
    assert row["max_rel_l2"] == pytest.approx(0.25)
    exact = _run([np.zeros(6), ref], [np.zeros(6), ref])[2]
    assert exact["max_rel_l2"] == 0.0 and exact["rmse_rel"] == 0.0


def test_relative_l2_against_a_zero_field_is_inf():
    assert relative_l2(np.zeros(3), np.zeros(3)) == np.inf
    assert relative_l2(np.ones(3), np.zeros(3)) == np.inf
    assert relative_l2(np.ones(3), np.ones(3)) == 0.0
