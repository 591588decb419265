"""The parameter contract (issue 27) around its named check: for every registered method and every
``Scene.at`` parameter, evaluating at a changed parameter either changes the result, flags it, or
is refused when the spec loads. The per-method check is ``parameters_are_honoured`` of the
shipped battery (:mod:`tissuebench.testing.parameters`), run over every method by
``tests/rom/test_rom_contract.py``; here the rules of the spec's loader it relies on."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from tissuebench.rom import METHODS
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.evaluation import build_evaluation
from tissuebench.studies.spec import check_pair, load_spec
from tissuebench.studies.training import case_scene
from tissuebench.testing.parameters import run_entry


def _entry(case, evaluation):
    return {"id": "c", "variant": None, "resolution": "ci", "backend": "skfem", **copy.deepcopy(case),
            "evaluation": evaluation}


def _write_spec(path, entry, method, options):
    import json

    def toml_value(v):
        if isinstance(v, dict):
            return "{ " + ", ".join(f"{k} = {toml_value(x)}" for k, x in v.items()) + " }"
        if isinstance(v, list):
            return "[" + ", ".join(toml_value(x) for x in v) + "]"
        return json.dumps(v)

    lines = ["[sweep]", 'name = "contract"', "[[case]]"]
    lines += [f"{k} = {toml_value(v)}" for k, v in entry.items() if v is not None and k != "backend"]
    lines += ["[[method]]", f'name = "{method}"', f"options = {toml_value(options)}"]
    path.write_text("\n".join(lines) + "\n")
    return path


def _run(entry, method, options):
    """(fields, statuses) of ``method`` driven through ``entry``'s evaluation, as the check runs it."""
    return run_entry(METHODS[method], entry, options)


def test_load_factor_is_refused_at_spec_load(tmp_path):
    """``mu.load_factor`` is not a scene parameter: refused when the spec loads, wherever it is given."""
    case = {"name": "cornea_pinch", "training": {"kind": "path", "every": 2}}
    for where in ({"mu": {"load_factor": 2.0}}, {"evaluation": {"kind": "map", "mus": [{"load_factor": 2.0}]}}):
        entry = {**_entry(case, {"kind": "path"}), **where}
        with pytest.raises(ValueError, match="load_factor"):
            load_spec(_write_spec(tmp_path / "s.toml", entry, "pod_linear", {}))
    dyn = {"name": "frame_2dof", "training": {"kind": "trajectory", "runs": [{"load_factor": 0.5}]}}
    with pytest.raises(ValueError, match="load_factor"):
        load_spec(_write_spec(tmp_path / "d.toml", _entry(dyn, {"kind": "trajectory"}), "nearest", {}))


def test_load_scale_reaches_the_model_as_its_load_factor(tmp_path):
    """``load_scale`` at evaluation: the model steps at ``load_scale x`` the reference's load factor
    (a linear model outside its training envelope: flagged, and equal to the reference)."""
    entry = _entry({"name": "cornea_pinch", "training": {"kind": "path", "every": 2}},
                   {"kind": "map", "mus": [{"load_scale": 1.25}]})
    case = CaseEntry.from_dict(entry)
    scene = case_scene(case)
    ev = build_evaluation(case, scene)
    assert ev.points[0].mu == {"load_factor": 1.25 * float(scene.analysis.get("max_load_factor", 1.0))}
    fields, statuses = _run(entry, "pod_linear", {"n_modes": 3})
    assert statuses == ["extrapolation"]


def test_load_scale_is_refused_where_supports_prescribe_a_displacement(tmp_path):
    """The cube is stretched by a prescribed displacement that load_scale does not scale."""
    entry = _entry({"name": "cube_tension_twist", "variant": "tension", "training": {"kind": "path"}},
                   {"kind": "map", "mus": [{"load_scale": 2.0}]})
    with pytest.raises(ValueError, match="load_scale scales the loads but not the displacement"):
        load_spec(_write_spec(tmp_path / "s.toml", entry, "pod_linear", {}))


def test_analysis_parameters_of_the_other_analysis_are_refused():
    static = case_scene(CaseEntry.from_dict(_entry({"name": "cornea_pinch", "training": {"kind": "path"}}, {})))
    for key, value in (("t_end", 2.0), ("dt", 0.1), ("integrator", "hht")):
        with pytest.raises(ValueError, match=f"mu.{key}"):
            static.at({key: value})
    dynamic = case_scene(CaseEntry.from_dict(_entry({"name": "frame_2dof", "training": {"kind": "trajectory"}}, {})))
    for key, value in (("max_load_factor", 2.0), ("load_steps", 3)):
        with pytest.raises(ValueError, match=f"mu.{key}"):
            dynamic.at({key: value})


def test_linear_fe_follows_load_scale_exactly():
    """linear_fe on a linear trajectory at half the load amplitude: half the training's response
    (the check only asks for a change or a flag)."""
    base = _entry({"name": "wave_block", "variant": "linear", "training": {"kind": "trajectory"}},
                  {"kind": "trajectory", "t_end": 0.05})
    base_fields, statuses = _run(base, "linear_fe", {})
    assert all(s in ("ok", "initial") for s in statuses), statuses[:3]
    fields, statuses = _run({**base, "evaluation": {"kind": "trajectory", "t_end": 0.05, "load_scale": 0.5}},
                            "linear_fe", {})
    assert all(s in ("ok", "initial") for s in statuses), statuses[:3]
    for u, v in zip(fields, base_fields):
        np.testing.assert_allclose(u, 0.5 * v, rtol=1e-9, atol=1e-12 * np.abs(v).max())


@pytest.mark.parametrize("evaluation, method, refused", [
    ({"kind": "map", "mus": [{"nu": 0.3}]}, "pod_linear", "evaluation changes 'nu'"),
    ({"kind": "map", "mus": [{"position": 0.2}]}, "pod_linear", "does not read a position"),
    ({"kind": "map", "mus": [{"load_scale": 0.5}]}, "pod_linear", None),
    ({"kind": "map", "mus": [{}]}, "pod_linear", None),
])
def test_check_pair_refuses_what_the_spec_loader_refuses(tmp_path, evaluation, method, refused):
    """The battery asks ``check_pair`` whether an evaluation is refused at spec load: it agrees with
    ``load_spec`` on both sides of the rule."""
    entry = _entry({"name": "cornea_pinch", "training": {"kind": "path", "every": 2}}, evaluation)
    table = {k: v for k, v in entry.items() if v is not None and k != "backend"}
    spec = _write_spec(tmp_path / "s.toml", entry, method, {})
    if refused is None:
        assert check_pair(table, method).id == "c" and load_spec(spec).cases[0].id == "c"
        return
    with pytest.raises(ValueError, match=refused):
        check_pair(table, method)
    with pytest.raises(ValueError, match=refused):
        load_spec(spec)
