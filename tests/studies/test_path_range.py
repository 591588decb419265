"""Issue 44: the error of a unit is its worst over the range it claims. A path evaluation is
measured between the training states (their quarter points and middle) and near rest, from
finer reference runs; "valid to" stops at the training range unless extrapolation is asked.

On a breast-like organ the held-out states (0.2, 0.6 .. 1.8 N) gave 4.51 % while the field error
was 8.41 % at 0.1 N, and "valid to 2.4 N at 5 %" counted steps flagged ``extrapolation``."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from tissuebench.reference import reference_key
from tissuebench.rom import make_method
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.evaluation import build_evaluation, evaluation_references
from tissuebench.studies.metrics import point_rows, seen_points, summarise_points
from tissuebench.studies.protocol import drive
from tissuebench.studies.spec import load_spec
from tissuebench.studies.training import build_training, case_scene


def _case(**evaluation):
    return CaseEntry(id="c", name="cornea_pinch", variant=None, resolution="ci", backend="skfem",
                     training={"kind": "path", "every": 2}, evaluation={"kind": "path", **evaluation})


def _near(values, x):
    return any(abs(v - x) < 1e-9 for v in values)


def test_a_held_out_path_is_measured_over_the_range_the_training_claims():
    case = _case(held_out=True)
    scene = case_scene(case)
    ev = build_evaluation(case, scene)
    lams = [p.x for p in ev.points]
    trained = [0.0, 0.2, 0.4, 0.6, 0.8, 1.0]  # every other state of the 10-increment path
    assert lams == sorted(lams) and not any(_near(lams, t) for t in trained)
    for a, b in zip(trained[:-1], trained[1:]):  # the quarter points and the middle of every interval
        assert all(_near(lams, a + f * (b - a)) for f in (0.25, 0.5, 0.75)), (a, b, lams)
    # near rest, where the limit of the error at rest is: 1/8, 1/16, 1/64 and 1/1024 of the first training state
    assert all(_near(lams, 0.2 / d) for d in (8, 16, 64, 1024)) and min(lams) == pytest.approx(0.2 / 1024)
    assert all(p.reference is not None and np.linalg.norm(p.reference) > 0 for p in ev.points)
    assert ev.info["range_points"] == 14 and ev.info["extrapolation"] is False
    # the finer runs are declared from the case entry (the dask executor solves them as tasks)
    keys = {reference_key(s, "skfem") for s in evaluation_references(case, scene)}
    assert len(keys) == 5 and reference_key(scene, "skfem") in keys


def test_refine_1_keeps_the_path_states_only():
    from tissuebench.studies.path_range import range_scenes

    case = _case(held_out=True, refine=1)
    scene = case_scene(case)
    assert [round(p.x, 9) for p in build_evaluation(case, scene).points] == [0.1, 0.3, 0.5, 0.7, 0.9]
    assert range_scenes(scene, 2, 1) == [] and len(evaluation_references(case, scene)) == 1
    # training every = 4: the path's own states are the quarter points, only near rest is added
    assert [role for role, _ in range_scenes(scene, 4, 4)] == ["near_rest", "rest_64", "rest_1024"]


def test_the_error_of_a_unit_is_its_worst_over_the_range():
    """Linear interpolation between rest and the first training state misses the tangent at
    rest: its worst error is near rest, where the path's own states had no point."""
    case = _case(held_out=True)
    scene = case_scene(case)
    training, ev = build_training(case, scene), build_evaluation(case, scene)
    model = make_method("pod_interp", n_modes=4, interpolation="linear").build(training)
    driven = drive(model, ev)
    points = pd.DataFrame(point_rows(ev, driven, seen_points(ev, training.snapshots)))
    row = summarise_points(points, pd.DataFrame(columns=["rel_error"]), ev, driven.fields)
    worst = points.loc[points["rel_l2"].idxmax()]
    assert row["max_rel_l2_in_envelope"] == points["rel_l2"].max() and row["n_seen"] == 0
    assert worst["x"] < 0.1  # below the first held-out state of the path (0.1)
    at_path_states = points.loc[[_near([0.1, 0.3, 0.5, 0.7, 0.9], x) for x in points["x"]], "rel_l2"]
    assert row["max_rel_l2_in_envelope"] > 1.5 * at_path_states.max()


def _summary(info):
    x = [0.25, 0.5, 0.75, 1.0, 1.25, 1.5]
    status = ["ok"] * 4 + ["extrapolation"] * 2
    points = pd.DataFrame({"x": x, "status": status, "rel_l2": [0.01, 0.02, 0.01, 0.03, 0.04, 0.2],
                           "has_reference": True, "seen": False, "beyond": [False] * 4 + [True] * 2})
    ref = np.ones(3)
    evaluation = SimpleNamespace(points=[SimpleNamespace(reference=ref) for _ in x], x_name="load_factor", info=info)
    return summarise_points(points, pd.DataFrame(), evaluation, [ref] * len(x))


def test_valid_to_stops_at_the_training_range_unless_extrapolation_is_asked():
    within = _summary({"extrapolation": False})
    assert within["validity_5pct"] == 1.0 and within["validity_range"] == "training"
    assert within["validity_1pct"] == 0.25  # 2 % at 0.5: both sides of the tolerance
    asked = _summary({"extrapolation": True})
    assert asked["validity_5pct"] == 1.25 and asked["validity_range"] == "extrapolation"
    other = _summary({})  # a kind without a training range along its abscissa: every point
    assert other["validity_5pct"] == 1.25 and other["validity_range"] == ""


SPEC = """
[sweep]
name = "range"
[[case]]
name = "cornea_pinch"
training = {{ kind = "path", every = 2 }}
evaluation = {{ kind = "path", {evaluation} }}
[[method]]
name = "nearest"
"""


@pytest.mark.parametrize("evaluation, message", [
    ("refine = 0", r"evaluation.refine = 0: expected an integer from 1 to 64"),
    ("refine = 2.5", r"evaluation.refine = 2.5: expected an integer"),
    ("refine = 64", None),
    ("refine = 65", r"evaluation.refine = 65"),
    ('extrapolation = "yes"', r"evaluation.extrapolation = 'yes': expected true or false"),
    ("extrapolation = true", None),
])
def test_refine_and_extrapolation_are_checked_at_spec_load(tmp_path, evaluation, message):
    path = tmp_path / "spec.toml"
    path.write_text(SPEC.format(evaluation=evaluation))
    if message is None:
        load_spec(path)
        return
    with pytest.raises(ValueError, match=message):
        load_spec(path)
