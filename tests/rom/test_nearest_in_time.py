"""``nearest`` on a trajectory is the state stored at the nearest (time, load) of the training runs
(issue 44: it looked up the nearest load factor alone, so after a probe's release every step
returned the rest state at time 0, 100 % off for the rest of the run, every step ok)."""
from __future__ import annotations

import numpy as np

from tissuebench.cases.scene import CATALOGUE_DIR
from tissuebench.rom import make_method
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.evaluation import build_evaluation
from tissuebench.studies.protocol import drive
from tissuebench.studies.training import build_training, case_scene

_RELEASE = 'history = { type = "ramp_hold_release", t_ramp = 0.5, t_hold = 0.5, t_release = 0.5 }'


def _frame_case(tmp_path, evaluation):
    """The two-storey frame of the catalogue, its top slab pushed and released (free vibration from
    t = 1.5 s to 3 s, undamped)."""
    text = (CATALOGUE_DIR / "frame_2dof.toml").read_text(encoding="utf-8")
    step, horizon = 'history = { type = "step", t0 = 0.0 }', "t_end = 5.0"
    assert step in text and horizon in text
    path = tmp_path / "frame_release.toml"
    path.write_text(text.replace(step, _RELEASE).replace(horizon, "t_end = 3.0"), encoding="utf-8")
    return CaseEntry.from_dict({"id": "frame", "name": str(path), "variant": None, "resolution": "ci",
                                "backend": "skfem", "training": {"kind": "trajectory"}, "evaluation": evaluation})


def test_nearest_plays_back_a_released_probe(tmp_path):
    case = _frame_case(tmp_path, {"kind": "trajectory"})
    scene = case_scene(case)
    training = build_training(case, scene)
    model = make_method("nearest").build(training)
    ev = build_evaluation(case, scene)
    driven = drive(model, ev, ev.history or training.history)
    released = [k for k, p in enumerate(ev.points) if p.mu["time"] > 1.5 + 1e-9]
    assert len(released) >= 0.45 * len(ev.points)  # half the run is the free vibration after the release
    assert all(np.linalg.norm(ev.points[k].reference) > 0 for k in released)  # the frame still moves
    for k, (p, res, u) in enumerate(zip(ev.points, driven.results, driven.fields)):
        if k == 0:
            continue
        assert res.status == "ok"
        # the training run is the evaluation's: played back, the nearest stored state is the reference
        np.testing.assert_allclose(u, p.reference, rtol=0, atol=1e-12 * np.abs(p.reference).max() + 1e-300)


def test_nearest_flags_a_time_past_the_training_runs(tmp_path):
    case = _frame_case(tmp_path, {"kind": "trajectory"})
    training = build_training(case)
    model = make_method("nearest").build(training)
    assert model.step({"time": 2.5, "load_factor": 0.0}).status == "ok"
    far = model.step({"time": 4.5, "load_factor": 0.0})
    assert far.status == "extrapolation" and "time" in far.message
