"""One history per scene, refused alike by every command; a variant replaces a load's history
(issue 44: gravity held constant with a probe on ``ramp_hold_release`` passed ``scene check`` and
``methods``, then ``run`` failed with "loads have different histories; use load_histories()"; a
dynamic version of a static scene needed a second file)."""
from __future__ import annotations

import pytest

from tissuebench.cases.scene import load
from tissuebench.cli import main

from _box_scene import box_scene

_BLOCK = box_scene("probed_block", "a soft block held at its base, weighed down by gravity and pressed by a probe",
                   (0.04, 0.04, 0.02), (2, 2, 1), 5000.0, 0.45, clamp="z", clamp_name="base")
#: what the scene adds to the block: its two loads, its analysis, a monitor, its variants
_SCENE = """[[load]]
name = "gravity"
type = "body"
value = [0.0, 0.0, -9810.0]
{gravity_history}
[[load]]
name = "probe"
type = "point"
region = {{ nearest = [0.02, 0.02, 0.02], count = 1 }}
value = [0.0, 0.0, -0.05]
{probe_history}
[analysis]
{analysis}
[[monitor]]
name = "top_uz"
quantity = "displacement"
point = [0.02, 0.02, 0.02]
component = "z"
{variants}
"""
_DYNAMIC = 'type = "dynamic"\nintegrator = "backward_euler"\ndt = 0.01\nt_end = 0.05'
_STATIC = 'type = "static"\nload_steps = 2'
_RELEASE = 'history = { type = "ramp_hold_release", t_ramp = 0.01, t_hold = 0.01, t_release = 0.01 }'


def _write(tmp_path, gravity_history="", probe_history="", analysis=_DYNAMIC, variants=""):
    path = tmp_path / "probed.toml"
    path.write_text(_BLOCK + _SCENE.format(gravity_history=gravity_history, probe_history=probe_history,
                                           analysis=analysis, variants=variants), encoding="utf-8")
    return path


_DIFFERENT = ("load[1].history = {'type': 'ramp_hold_release', 't_ramp': 0.01, 't_hold': 0.01, 't_release': 0.01} "
              "('probe'): differs from load[0].history = {'type': 'constant'} ('gravity'); loads have different "
              "histories")


@pytest.mark.parametrize("analysis", [_DYNAMIC, _STATIC], ids=["dynamic", "static"])
def test_loads_with_different_histories_are_refused_when_the_scene_loads(tmp_path, analysis):
    path = _write(tmp_path, 'history = { type = "constant" }', _RELEASE, analysis)
    with pytest.raises(ValueError) as caught:
        load(path)
    assert _DIFFERENT in str(caught.value) and "give them the same history" in str(caught.value)


def test_scene_check_methods_and_run_refuse_them_with_one_message(tmp_path, capsys):
    path = _write(tmp_path, 'history = { type = "constant" }', _RELEASE)
    said = []
    for argv in (["scene", "check", str(path), "--out", "-"], ["methods", str(path)],
                 ["run", str(path), "--out", str(tmp_path / "run"), "--quiet"]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert _DIFFERENT in err, (argv, err)
        said.append(err.strip())
    assert len(set(said)) == 1  # the same line, whichever command a user tries first
    assert not (tmp_path / "run").exists()


def test_one_history_written_two_ways_is_one_history(tmp_path):
    path = _write(tmp_path, 'history = { type = "ramp", t1 = 1.0 }', 'history = { type = "ramp", t0 = 0.0, t1 = 1.0 }',
                  _STATIC)
    assert load(path).history(0.5) == 0.5


_VARIANT = """
[variants.dynamic]
description = "the probe pressed and released, gravity with it"
analysis = {{ type = "dynamic", integrator = "backward_euler", dt = 0.01, t_end = 0.05 }}
[variants.dynamic.histories]
{histories}
"""


def test_a_variant_replaces_the_history_of_named_loads(tmp_path):
    rhr = "{ type = \"ramp_hold_release\", t_ramp = 0.01, t_hold = 0.01, t_release = 0.01 }"
    path = _write(tmp_path, analysis=_STATIC, variants=_VARIANT.format(histories=f"probe = {rhr}\ngravity = {rhr}"))
    static, dynamic = load(path), load(path, variant="dynamic")
    assert static.analysis["type"] == "static" and static.history.spec["type"] == "ramp"
    assert dynamic.analysis["type"] == "dynamic"
    assert [ld["history"]["type"] for ld in dynamic.loads] == ["ramp_hold_release"] * 2
    assert dynamic.history(0.015) == 1.0 and dynamic.history(0.03) == 0.0
    assert main(["scene", "check", str(path), "--variant", "dynamic", "--out", "-"]) == 0


def test_a_variant_naming_no_load_or_leaving_histories_apart_is_refused(tmp_path):
    rhr = "{ type = \"ramp_hold_release\", t_ramp = 0.01, t_hold = 0.01, t_release = 0.01 }"
    path = _write(tmp_path, analysis=_STATIC, variants=_VARIANT.format(histories=f"tool = {rhr}"))
    with pytest.raises(ValueError, match=r"variants\.dynamic\.histories\.tool = .*no load is named 'tool'; named "
                                         r"loads: \['gravity', 'probe'\]"):
        load(path, variant="dynamic")
    path = _write(tmp_path, analysis=_STATIC, variants=_VARIANT.format(histories=f"probe = {rhr}"))
    with pytest.raises(ValueError, match="loads have different histories"):
        load(path, variant="dynamic")
    bad = _write(tmp_path, analysis=_STATIC, variants=_VARIANT.format(histories='probe = { type = "bogus" }'))
    with pytest.raises(ValueError, match=r"load\[1\]\.history\.type = 'bogus': unknown history"):
        load(bad, variant="dynamic")
