"""Ranges nobody checked (issue 50, item 5), refused when the spec loads, before any reference is
solved, naming the key and the value: a trajectory evaluation's ``load_scale = 1e308`` failed
after the references with a NaN from inside the dynamics, ``load_scale = 0`` was stored "ok"
with error inf, ``t_end`` below the scene's ``dt`` failed with "zero-size array". Each rule is
checked on both sides of its boundary (the scene's sine, unresolved by ``dt``, is in
tests/cases/test_history_resolution.py)."""
from __future__ import annotations

import re

import pytest

from tissuebench.cli import main
from tissuebench.studies.limits import MAX_LOAD_SCALE
from tissuebench.studies.spec import load_spec

# the clamped beam (a line model: loads in milliseconds) at dt = 0.05 s; nearest applies to it
SPEC = """
[sweep]
name = "ranges"
[[case]]
name = "clamped_beam"
mu = {{ dt = 0.05{mu} }}
training = {{ kind = "trajectory"{training} }}
evaluation = {{ kind = "trajectory", {evaluation} }}
[[method]]
name = "nearest"
"""


def spec(tmp_path, evaluation="load_scale = 0.75", training="", mu=""):
    path = tmp_path / "spec.toml"
    path.write_text(SPEC.format(evaluation=evaluation, training=training, mu=mu))
    return path


def evaluation_of(path) -> dict:
    return load_spec(path).cases[0].evaluation


# ------------------------------------------------------------------------------------ load_scale = 0
def test_a_zero_load_scale_is_refused_naming_the_key_and_why(tmp_path):
    with pytest.raises(ValueError, match=r"case\[0\].evaluation.load_scale = 0: must not be 0 \(a zero load has no "
                                         r"relative error"):
        load_spec(spec(tmp_path, "load_scale = 0"))


@pytest.mark.parametrize("scale", [1e-3, 1e-9, -0.75])
def test_a_small_or_a_reversed_load_scale_is_accepted(tmp_path, scale):
    assert evaluation_of(spec(tmp_path, f"load_scale = {scale!r}"))["load_scale"] == scale


def test_a_zero_load_scale_of_a_training_run_or_of_the_case_is_refused_too(tmp_path):
    with pytest.raises(ValueError, match=r"case\[0\].training.runs\[1\].load_scale = 0.0: must not be 0"):
        load_spec(spec(tmp_path, training=", runs = [{ load_scale = 0.5 }, { load_scale = 0.0 }]"))
    with pytest.raises(ValueError, match=r"case\[0\].mu.load_scale = 0: must not be 0"):
        load_spec(spec(tmp_path, mu=", load_scale = 0"))
    assert load_spec(spec(tmp_path, training=", runs = [{ load_scale = 0.5 }]", mu=", load_scale = 2.0")).cases


# ------------------------------------------------------------------------------------ the overflow bound
@pytest.mark.parametrize("scale", ["1e308", "1e306", "-1e7", "1000000.0000001"])
def test_a_load_scale_past_the_bound_is_refused_naming_the_key_the_value_and_the_bound(tmp_path, scale):
    shown = re.escape(repr(float(scale)))
    with pytest.raises(ValueError, match=rf"case\[0\].evaluation.load_scale = {shown}: expected at most 1e\+06 in "
                                         r"magnitude \(MAX_LOAD_SCALE .*overflow the float range"):
        load_spec(spec(tmp_path, f"load_scale = {scale}"))


@pytest.mark.parametrize("scale", ["1000000.0", "-1000000.0", "200.0"])
def test_a_load_scale_up_to_the_bound_is_accepted(tmp_path, scale):
    assert abs(float(scale)) <= MAX_LOAD_SCALE
    assert evaluation_of(spec(tmp_path, f"load_scale = {scale}"))["load_scale"] == float(scale)


def test_a_load_scale_that_is_no_number_is_refused_naming_it(tmp_path):
    with pytest.raises(ValueError, match=r"case\[0\].evaluation.load_scale = 'x': expected a finite number"):
        load_spec(spec(tmp_path, 'load_scale = "x"'))


# ------------------------------------------------------------------------------------ t_end >= dt
def test_a_t_end_below_the_scene_dt_is_refused_naming_both(tmp_path):
    with pytest.raises(ValueError, match=r"case\[0\].evaluation.t_end = 0.01: below the scene's time step dt = 0.05 s: "
                                         r"a trajectory needs at least one step \(t_end >= dt\)"):
        load_spec(spec(tmp_path, "t_end = 0.01"))


@pytest.mark.parametrize("t_end", [0.05, 0.075])
def test_a_t_end_of_one_step_or_more_is_accepted(tmp_path, t_end):
    assert evaluation_of(spec(tmp_path, f"t_end = {t_end!r}"))["t_end"] == t_end


def test_a_case_mu_t_end_below_its_dt_is_refused_by_the_scene_naming_mu_t_end(tmp_path):
    with pytest.raises(ValueError, match=r"mu.t_end = 0.01: t_end = 0.01 is below dt = 0.05: a dynamic run needs at "
                                         r"least one time step"):
        load_spec(spec(tmp_path, mu=", t_end = 0.01"))
    assert load_spec(spec(tmp_path, mu=", t_end = 0.05")).cases[0].mu["t_end"] == 0.05


# ------------------------------------------------------------------------------------ up front, by the CLI
@pytest.mark.parametrize("evaluation, message", [
    ("load_scale = 0", "evaluation.load_scale = 0: must not be 0"),
    ("load_scale = 1e308", "evaluation.load_scale = 1e+308: expected at most 1e+06"),
    ("t_end = 0.01", "evaluation.t_end = 0.01: below the scene's time step dt = 0.05 s")])
def test_the_sweep_refuses_before_any_work(tmp_path, capsys, monkeypatch, evaluation, message):
    import tissuebench.studies.sweep as sweep

    monkeypatch.setattr(sweep, "run_sweep", lambda *a, **k: pytest.fail("the sweep started"))
    out = tmp_path / "out"
    assert main(["sweep", str(spec(tmp_path, evaluation)), "--out", str(out), "--quiet"]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
