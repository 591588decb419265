"""A unit evaluated where it was trained is marked ``seen`` and never recommended (issue 27: the
nearest stored snapshot "met" 500 Hz / 2 % with 0 % error on the trajectory it replayed)."""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tissuebench.reports.recommend import SEEN_REASON, parse_requirement, rank_units
from tissuebench.reports.report_sections import recommendation
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.evaluation import Evaluation, EvaluationPoint, build_evaluation
from tissuebench.studies.metrics import seen_points
from tissuebench.studies.results import read_points, read_units
from tissuebench.studies.spec import PRESETS_DIR, load_spec
from tissuebench.studies.sweep import run_sweep
from tissuebench.studies.training import build_training, case_scene


def test_seen_points_are_the_training_snapshots():
    rng = np.random.default_rng(0)
    S = rng.standard_normal((30, 5))
    points = [EvaluationPoint({}, S[:, 2] * (1 + 1e-9), {}, 0.0),  # a training state to round-off
              EvaluationPoint({}, S[:, 2] + 1e-3 * S[:, 0], {}, 1.0),  # near, not the same
              EvaluationPoint({}, None, {}, 2.0),  # no reference (beyond the path)
              EvaluationPoint({}, np.zeros(30), {}, 3.0)]  # a zero field is never "seen"
    ev = Evaluation("path", "load_factor", points)
    assert seen_points(ev, S) == [True, False, False, False]
    assert seen_points(ev, None) == [False] * 4  # operators: nothing was seen


def test_path_every_other_state_is_half_seen():
    case = CaseEntry(id="c", name="cornea_pinch", variant=None, resolution="ci", backend="skfem",
                     training={"kind": "path", "every": 2}, evaluation={"kind": "path"})
    scene = case_scene(case)
    training, ev = build_training(case, scene), build_evaluation(case, scene)
    seen = seen_points(ev, training.snapshots)
    lams = [p.mu["load_factor"] for p in ev.points]
    trained = {p["load_factor"] for p in training.parameters}
    assert seen == [lam in trained for lam in lams] and 0 < sum(seen) < len(seen)


SPEC = """
[sweep]
name = "seen"
[protocol]
latency_steps = 20
warmup = 2
reference_samples = 1
[[case]]
id = "frame-replayed"
name = "frame_2dof"
training = {{ kind = "trajectory" }}
evaluation = {{ kind = "trajectory" }}
[[case]]
id = "frame-held-out"
name = "frame_2dof"
training = {{ kind = "trajectory" }}
evaluation = {{ kind = "trajectory", {held_out} }}
[[method]]
name = "nearest"
"""


@pytest.mark.parametrize("held_out", ["load_scale = 0.75", "t_end = 7.5, from_time = 5.1"])
def test_a_replayed_trajectory_is_seen_and_never_recommended(tmp_path, held_out):
    spec = tmp_path / "seen.toml"
    spec.write_text(SPEC.format(held_out=held_out))
    run_sweep(load_spec(spec), tmp_path / "out", progress=False)
    units = read_units(tmp_path / "out").set_index("case")
    replayed, held = units.loc["frame-replayed"], units.loc["frame-held-out"]
    assert replayed["seen"] and replayed["n_seen"] == replayed["n_reference_points"] > 0
    assert not held["seen"] and held["n_seen"] == 0
    points = read_points(tmp_path / "out")
    assert points.loc[points["case"] == "frame-replayed", "seen"].sum() == replayed["n_seen"]
    # the recommendation: even a requirement the replayed unit meets with margin leaves it out
    easy = parse_requirement("rate>=1Hz, error<=100%")
    rec = recommendation(units.reset_index().query("case == 'frame-replayed'"), easy, "max_rel_l2")
    assert rec["meets"] == 0 and "Not considered: 1 unit" in rec["excluded"]
    ranked = rank_units(units.reset_index(), easy, "max_rel_l2")
    assert not ranked.loc[ranked["case"] == "frame-replayed", "meets"].any()
    assert (ranked.loc[ranked["case"] == "frame-replayed", "misses"] == SEEN_REASON).all()
    if held["max_rel_l2"] <= 1.0:
        assert ranked.loc[ranked["case"] == "frame-held-out", "meets"].all()


def test_the_report_greys_seen_units(tmp_path):
    """The HTML ranking table shows a seen unit greyed with the reason; the recommendation names it."""
    from tissuebench.reports.html import write_report

    spec = tmp_path / "seen.toml"
    spec.write_text(SPEC.format(held_out="load_scale = 0.75"))
    run_sweep(load_spec(spec), tmp_path / "out", progress=False)
    html = Path(write_report(tmp_path / "out", tmp_path / "r.html", "rate>=1Hz, error<=100%")).read_text()
    assert '<td class="seen">seen</td>' in html and SEEN_REASON in html
    assert "Not considered: 1 unit(s) evaluated only on their training data" in html


def _trajectory_cases():
    for path in sorted(PRESETS_DIR.glob("*.toml")):
        for c in tomllib.loads(path.read_text()).get("case", []):
            if c.get("training", {}).get("kind") == "trajectory":
                yield path.stem, c


@pytest.mark.parametrize("preset, case", list(_trajectory_cases()),
                         ids=[f"{p}-{c.get('id', c['name'])}" for p, c in _trajectory_cases()])
def test_every_preset_trajectory_case_is_held_out(preset, case):
    """Every shipped preset's case that learns from a trajectory is measured on another one: a
    different load amplitude, or a window after the training's horizon (or a longer horizon)."""
    ev = case.get("evaluation", {})
    assert ev.get("load_scale", 1.0) != 1.0 or "from_time" in ev or "t_end" in ev, (preset, case)


def test_units_that_see_part_of_their_points_say_how_many():
    units = pd.DataFrame([{"case": "c", "label": "u", "unit_status": "ok", "max_rel_l2": 0.01,
                           "haptic_p99_s": 1e-5, "haptic_median_s": 1e-5, "seen": False, "n_seen": 7,
                           "n_reference_points": 14, "message": ""}])
    rec = recommendation(units, parse_requirement("rate>=1kHz, error<=2%"), "max_rel_l2")
    assert rec["meets"] == 1 and "(7 of 14 evaluation points seen in training)" in rec["lines"][0]
