"""``sweep --scene FILE --all-methods`` (issue 27): the spec of a user's scene, held out by default,
the reference continued past the path (the validity radius in the scene's units), and the whole
path of a new user on a gmsh-built organ: check -> methods -> sweep -> report."""
from __future__ import annotations

import importlib.util
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from tissuebench.cases import load
from tissuebench.cli import main
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.evaluation import beyond_scene, build_evaluation
from tissuebench.studies.metrics import validity_radius
from tissuebench.studies.results import read_points, read_units
from tissuebench.studies.scene_spec import scene_spec_text
from tissuebench.studies.spec import load_spec
from tissuebench.studies.training import build_training, case_scene

from _mesh_scene import scene_file, write_block

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "bring_your_own_organ"


def _case(scene_path, evaluation, training=None):
    return CaseEntry(id="c", name=str(scene_path), variant=None, resolution="ci", backend="skfem",
                     training=training or {"kind": "path", "every": 2}, evaluation=evaluation)


def test_held_out_path_states_are_the_ones_the_training_left_out(tmp_path):
    write_block(tmp_path)
    p = scene_file(tmp_path)
    p.write_text(p.read_text().replace("load_steps = 2", "load_steps = 6"))
    case = _case(p, {"kind": "path", "held_out": True})
    scene = case_scene(case)
    trained = {q["load_factor"] for q in build_training(case, scene).parameters}
    held = [q.mu["load_factor"] for q in build_evaluation(case, scene).points]
    assert held == sorted(held) and not set(held) & trained  # the range's points too (issue 44)
    assert [x for x in held if any(abs(x - k / 6) < 1e-9 for k in range(7))] == pytest.approx([1 / 6, 3 / 6, 5 / 6])


def test_held_out_needs_a_thinned_training(tmp_path):
    write_block(tmp_path)
    spec = tmp_path / "s.toml"
    spec.write_text(f'[[case]]\nname = "{scene_file(tmp_path)}"\ntraining = {{ kind = "path" }}\n'
                    'evaluation = { kind = "path", held_out = true }\n[[method]]\nname = "nearest"\n')
    with pytest.raises(ValueError, match="evaluation.held_out = True: the states a path training left out"):
        load_spec(spec)


def test_the_reference_is_continued_past_the_path(tmp_path):
    """beyond = [2]: the path is continued with its own increment; every converged state past the
    top is a point with a reference, the load factor 1 is the scene's 0.1 N (x_scale, x_unit)."""
    write_block(tmp_path)
    case = _case(scene_file(tmp_path), {"kind": "path", "held_out": True, "beyond": [2.0]})
    scene = case_scene(case)
    ev = build_evaluation(case, scene)
    past = [q.x for q in ev.points if q.reference is not None and q.beyond]
    assert past == pytest.approx([1.5, 2.0]) and ev.info["reference_limit"] == pytest.approx(2.0)
    # the range the training claims (issue 44): the held-out state, the quarter points of the
    # training interval [0, 1] and near rest (1/8, 1/16, 1/64, 1/1024 of it), from the finer reference runs
    within = [q.x for q in ev.points if q.reference is not None and not q.beyond]
    assert within == pytest.approx([1 / 1024, 1 / 64, 1 / 16, 1 / 8, 0.25, 0.5, 0.75])
    assert ev.info["x_scale"] == pytest.approx(0.1) and ev.info["x_unit"] == "N"
    # the continued run's first states are the path's: one reference
    path = load(scene.path)
    ext = beyond_scene(path, 2.0)
    assert ext.analysis["load_steps"] == 4 and ext.analysis["max_load_factor"] == pytest.approx(2.0)


def test_where_the_continued_reference_stops_is_recorded(tmp_path):
    """Past the path, the continued reference of an SVK block stalls (inverted elements under the
    point load): where, is recorded; the points past it carry no reference."""
    write_block(tmp_path)
    p = scene_file(tmp_path)
    p.write_text(p.read_text().replace("[0.0, -0.1, 0.0]", "[0.0, -0.5, 0.0]").replace("neo_hookean", "svk"))
    case = _case(p, {"kind": "path", "held_out": True, "beyond": [4.0]})
    ev = build_evaluation(case, case_scene(case))
    limit = ev.info["reference_limit"]
    assert 1.0 < limit < 4.0 and ev.info["reference_beyond_status"] == "stalled"  # measured: 1.6
    assert "Newton stopped converging" in ev.info["reference_beyond_message"]
    without = [q for q in ev.points if q.reference is None]
    assert [q.x for q in without] == [pytest.approx(4.0)]
    assert max(q.x for q in ev.points if q.reference is not None) == pytest.approx(limit)


def test_validity_radius_reaches_past_the_training_range():
    x = np.array([0.5, 1.5, 2.0, 3.0])
    assert validity_radius(x, [0.001, 0.004, 0.02, np.nan], 0.01) == 1.5


def test_the_spec_of_a_static_scene(tmp_path):
    write_block(tmp_path)
    scene = load(scene_file(tmp_path))
    text, left_out = scene_spec_text(scene, "scene.toml")
    raw = tomllib.loads(text)
    # the headline, peak-normalised over the training range (issue 52): not the state-relative worst,
    # which the near-rest point at 1/1024 of the first training state sets
    assert raw["sweep"]["error_metric"] == "claimed_error"
    # the practitioner baselines (issue 28) run once, on the path: no vademecum applies here whose
    # contact nodes they could be measured at
    [case] = raw["case"]
    assert case["training"] == {"kind": "path", "every": 2}
    assert case["evaluation"] == {"kind": "path", "held_out": True, "beyond": [1.25, 1.5, 2.0]}
    methods = {m["name"]: m["cases"] for m in raw["method"]}
    assert set(methods) == {"nearest", "pod_interp", "pod_linear", "pod_newton", "linear_fe", "corotational_fe",
                            "coarse_fe"}
    assert all(methods[m] == ["path"] for m in ("linear_fe", "corotational_fe", "coarse_fe"))
    why = dict(left_out)
    assert "'neo_hookean' is not polynomial" in why["anm_pod"] and "needs a dynamic scene" in why["wsc"]
    assert "[parameters.position]" in why["podi"]


@pytest.mark.parametrize("case, variant, held, runs", [
    ("liver_dynamic", None, {"kind": "trajectory", "load_scale": 0.75}, [{"load_scale": 0.5}]),
    ("liver_dynamic", "neo_hookean", {"kind": "trajectory", "load_scale": 0.75}, [{"load_scale": 0.5}]),
    ("cube_tension_twist", "tension_dynamic", {"kind": "trajectory", "t_end": 1.5, "from_time": 1.005}, None),
])
def test_the_spec_of_a_dynamic_scene_is_held_out(case, variant, held, runs):
    """Another amplitude, between the two the training runs cover (issue 42), or (a support
    prescribes a displacement load_scale would not scale) a window after the training's horizon;
    POD-Galerkin among the methods offered (issue 42)."""
    text, _ = scene_spec_text(load(case, variant=variant), case, variant)
    raw = tomllib.loads(text)
    # a motion is ranked and reported by its peak-normalised error, not the RMSE over the history (issue 52)
    assert raw["sweep"]["error_metric"] == "peak_rel_l2"
    assert all(c["evaluation"] == pytest.approx(held) for c in raw["case"])
    trajectory = next(c for c in raw["case"] if c["id"] == "trajectory")
    assert trajectory["training"].get("runs") == runs
    methods = {m["name"]: m["cases"] for m in raw["method"]}
    assert set(methods) >= {"wsc", "nearest", "linear_fe", "pod_galerkin"} and methods["linear_fe"] == ["trajectory"]
    assert methods["pod_galerkin"] == ["trajectory"]
    grid = next(m["grid"] for m in raw["method"] if m["name"] == "pod_galerkin")
    assert set(grid["hyper"]) == {"ecsw", "none"}


def test_the_baselines_join_the_contact_nodes_only_beside_a_vademecum():
    """A practitioner baseline runs once (its first case), and at the contact nodes only where a
    point-load vademecum (pgd) is measured there: the nodes are the vademecum's."""
    from tissuebench.studies.scene_spec import _baselines_once

    cases = [{"id": "path", "evaluation": {"kind": "path"}},
             {"id": "operators", "evaluation": {"kind": "contact_nodes", "count": 3}}]
    alone = _baselines_once([("linear_fe", ["path", "operators"], {}, {}, {})], cases)
    assert alone == [("linear_fe", ["path"], {}, {}, {})]
    beside = _baselines_once([("pgd", ["operators"], {}, {}, {}), ("linear_fe", ["path", "operators"], {}, {}, {})],
                             cases)
    assert beside[1][1] == ["path", "operators"]
    dynamic = [{"id": "trajectory", "evaluation": {"kind": "trajectory"}},
               {"id": "operators", "evaluation": {"kind": "trajectory"}}]
    assert _baselines_once([("coarse_fe", ["trajectory", "operators"], {}, {}, {})], dynamic)[0][1] == ["trajectory"]


def _kidney(folder: Path, size: float, monkeypatch) -> Path:
    monkeypatch.syspath_prepend(str(EXAMPLE))  # make_kidney.py imports gmsh_body.py from its folder
    spec = importlib.util.spec_from_file_location("make_kidney", EXAMPLE / "make_kidney.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.kidney_mesh(str(folder / "kidney.msh"), size)
    (folder / "kidney.toml").write_text((EXAMPLE / "kidney.toml").read_text())
    return folder / "kidney.toml"


@pytest.mark.slow
def test_a_new_users_organ_from_mesh_file_to_report(tmp_path, capsys, monkeypatch):
    """Done-when of issue 27: a small organ generated with gmsh, its scene, then check -> methods ->
    sweep --all-methods -> report at ci size; the recommendation rests on no seen unit."""
    pytest.importorskip("gmsh")
    monkeypatch.chdir(tmp_path)
    scene = _kidney(tmp_path, size=12.0, monkeypatch=monkeypatch)  # ~200 nodes
    assert main(["scene", "check", str(scene)]) == 0
    assert (tmp_path / "scene.png").stat().st_size > 0
    assert main(["methods", str(scene)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"pod_linear\s+applies", out) and re.search(r"anm_pod\s+does not apply: material", out)
    assert main(["sweep", "--scene", str(scene), "--all-methods", "--out", str(tmp_path / "kidney"), "--quiet"]) == 0
    spec = tmp_path / "kidney.spec.toml"
    assert spec.is_file() and load_spec(spec).cases[0].evaluation["held_out"] is True
    units = read_units(tmp_path / "kidney")
    # 8 ROM units and the practitioner baselines on the path (issue 28): linear (condensed or not),
    # corotational, a 2x coarser mesh
    assert len(units) == 12 and (units["unit_status"] == "ok").all() and not units["seen"].any()
    assert (units["n_seen"] == 0).all()  # held out: no evaluation point is a training state
    points = read_points(tmp_path / "kidney")
    assert (points.loc[points["x"] > 1.0 + 1e-9, "has_reference"]).any()  # the continued reference
    assert main(["report", str(tmp_path / "kidney"), "--require", "rate>=500Hz, error<=5%"]) == 0
    html = (tmp_path / "kidney" / "_report" / "report.html").read_text()
    assert "valid to" in html and " N at 5 %" in html
    assert '<td class="seen">' not in html and "Not considered" not in html


def test_a_scene_named_in_a_spec_is_found_from_the_spec_folder(tmp_path, monkeypatch):
    """A relative scene path in a spec is the one beside the spec, not one at the same relative path
    from the working folder (the kidney measured for issue 27 first ran another folder's kidney)."""
    spec_dir, work = tmp_path / "study" / "out", tmp_path / "elsewhere" / "sub"
    for d in (spec_dir, work):
        d.mkdir(parents=True)
    mine = tmp_path / "study"
    write_block(mine)
    scene_file(mine)
    other = tmp_path / "elsewhere"
    write_block(other, size_mm=(80.0, 20.0, 20.0))
    scene_file(other)
    spec = spec_dir / "s.toml"
    spec.write_text('[[case]]\nname = "../scene.toml"\ntraining = { kind = "path", every = 2 }\n'
                    '[[method]]\nname = "nearest"\n')
    monkeypatch.chdir(work)  # ../scene.toml from here is the other block
    name = load_spec(spec).cases[0].name
    assert Path(name) == (mine / "scene.toml").resolve()
