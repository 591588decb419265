"""The locking indicator and the formulation a reference chooses (issue 43), both sides of each rule.

The scene is the nearly incompressible dome of the extremes preset (``presets/scenes/dome.toml``,
~270 vertices at ci): neo-Hookean E = 3 kPa pressed on its apex cap.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.cli import main
from tissuebench.reference import formulation as formulation_module
from tissuebench.reference.cache import reference_key
from tissuebench.reference.formulation import formulation_of, scene_backend
from tissuebench.reference.locking import LOCKING_BULK_TO_SHEAR, LOCKING_NU, bulk_to_shear, locking_indicator
from tissuebench.reference.plan import plan_for
from tissuebench.refsolvers.anp import AnpBackend

SCENES = Path(__file__).resolve().parents[2] / "tissuebench" / "studies" / "presets" / "scenes"


def _dome(tmp_path, nu, element=None, extra_analysis="", density=None):
    text = (SCENES / "dome.toml").read_text().replace("nu = 0.499", f"nu = {nu}")
    if element:
        text = text.replace("[mesh]\n", f'[mesh]\nelement = "{element}"\n', 1)
    if extra_analysis:
        text = text.replace("load_steps = 6\n", f"load_steps = 6\n{extra_analysis}\n", 1)
    if density:
        text = text.replace('name = "neo_hookean"\n', f'name = "neo_hookean"\ndensity = {density}\n', 1)
    path = tmp_path / "dome.toml"
    path.write_text(text)
    return path


def test_threshold_is_nu_045():
    assert bulk_to_shear({"E": 1.0, "nu": LOCKING_NU}) == pytest.approx(LOCKING_BULK_TO_SHEAR)
    assert LOCKING_BULK_TO_SHEAR == pytest.approx(29 / 3)


@pytest.mark.parametrize("nu", [0.4499, 0.45])
def test_indicator_both_sides_of_the_threshold(tmp_path, nu):
    scene = load(_dome(tmp_path, nu))
    ind = locking_indicator(scene)
    if nu < LOCKING_NU:
        assert not ind["computed"] and ind["why"] == "not nearly incompressible"
        form = formulation_of(scene)
        assert form.name == "displacement" and form.element == "P1" and not form.warning
    else:
        assert ind["computed"] and ind["headline"] == "apex_uz"
        assert ind["deviation"] < -0.02  # P1 4 % short of ANP already at nu = 0.45 on this coarse mesh
        assert ind["locks"] and formulation_of(scene).name == "anp"


def test_without_element_the_reference_does_not_lock(tmp_path):
    scene = load(_dome(tmp_path, 0.499))
    form = formulation_of(scene)
    assert form.name == "anp" and "P1 locks" in form.reason and not form.warning
    assert form.indicator["deviation"] < -0.3  # P1 at least 30 % short at nu = 0.499
    plan = plan_for(scene)
    assert plan.formulation == "anp"
    assert any("average nodal pressure" in item for item, _ in plan.reasons)
    assert isinstance(scene_backend(scene), AnpBackend)


def test_p1_asked_for_gets_the_warning_with_its_number(tmp_path, capsys):
    scene = load(_dome(tmp_path, 0.499, element="P1"))
    form = formulation_of(scene)
    assert form.name == "displacement" and form.element == "P1"
    dev = form.indicator["deviation"]
    assert form.warning.startswith("WARNING: P1 locks") and f"{100 * dev:+.1f} %" in form.warning
    assert main(["scene", "check", str(tmp_path / "dome.toml"), "--out", "-"]) == 0
    out = capsys.readouterr().out
    assert "WARNING: P1 locks" in out and f"{100 * dev:+.1f} %" in out
    # below the threshold the same scene asking for P1 gets no warning
    below = load(_dome(tmp_path, 0.44, element="P1"))
    assert formulation_of(below).warning == "" and formulation_of(below).indicator is None


@pytest.mark.parametrize("deviation, chosen", [(-0.019, "displacement"), (-0.021, "anp")])
def test_the_tolerance_both_sides(tmp_path, monkeypatch, deviation, chosen):
    """P1 'locks' when the indicator's deviation passes 2 %: the choice follows the verdict."""
    scene = load(_dome(tmp_path, 0.46))
    real = locking_indicator(scene)
    fake = {**real, "deviation": deviation, "energy_deviation": deviation, "locks": abs(deviation) > 0.02,
            "compared": {**real["compared"], "apex_uz": {**real["compared"]["apex_uz"], "deviation": deviation}}}
    monkeypatch.setattr(formulation_module, "locking_indicator", lambda *a, **k: fake)
    assert formulation_of(scene).name == chosen


def test_formulation_is_part_of_the_cache_key(tmp_path, monkeypatch):
    scene = load(_dome(tmp_path, 0.499))
    key = reference_key(scene)
    other = dataclasses.replace(formulation_of(scene), name="displacement")
    monkeypatch.setattr("tissuebench.reference.cache.formulation_of", lambda s: other)
    assert reference_key(scene) != key


@pytest.mark.parametrize("element, formulation, message", [
    ("P1", "mixed", "mesh.element must be 'P2'"),
    ("P2", "anp", "mesh.element must be 'P1'"),
    (None, "displacement\nincompressible = true", "only the mixed formulation imposes J = 1"),
    ("P2", "dynamic", "the mixed formulation is static only"),
])
def test_inconsistent_formulations_are_refused_at_load(tmp_path, element, formulation, message, capsys):
    """scene check, describe and run all load the scene: one refusal, naming the key."""
    extra = {"displacement\nincompressible = true": 'formulation = "displacement"\nincompressible = true',
             "dynamic": 'formulation = "mixed"'}.get(formulation, f'formulation = "{formulation}"')
    path = _dome(tmp_path, 0.499, element=element, extra_analysis=extra, density=1000.0)
    if formulation == "dynamic":
        path.write_text(path.read_text().replace('type = "static"\nload_steps = 6',
                                                 'type = "dynamic"\ndt = 0.01\nt_end = 0.03\nintegrator = "hht"'))
    with pytest.raises(ValueError, match=message):
        load(path)
    for argv in (["scene", "check", str(path), "--out", "-"], ["describe", str(path)]):
        assert main(argv) == 2
        assert message in capsys.readouterr().err


def test_mixed_takes_the_volumetric_modulus_unless_incompressible(tmp_path):
    mixed = formulation_of(load(_dome(tmp_path, 0.45, extra_analysis='formulation = "mixed"')))
    lam = 3000.0 * 0.45 / ((1 + 0.45) * (1 - 2 * 0.45))  # U = lambda/2 ln^2 J: U''(1) = lambda
    assert mixed.element == "P2" and mixed.bulk_modulus == pytest.approx(lam)
    incompressible = formulation_of(load(_dome(tmp_path, 0.45, extra_analysis='formulation = "mixed"\n'
                                                                              'incompressible = true')))
    assert incompressible.bulk_modulus is None and "J = 1" in incompressible.reason


def test_p2_scene_with_a_density_is_checked(tmp_path, capsys):
    """The row sums of a P2 mass are negative at the vertices; the HRZ diagonal is positive and
    keeps the total mass (scene check failed with 'M is not positive definite' before)."""
    path = _dome(tmp_path, 0.3, element="P2", density=1000.0)
    assert main(["scene", "check", str(path), "--out", "-"]) == 0
    assert "critical time step" in capsys.readouterr().out
    from tissuebench.refsolvers.backends import make_backend

    pb = load(path).to_problem()
    for name in ("skfem", pytest.param("ngsolve").values[0]):
        be = make_backend(name, pb)
        M, lumped = be.mass(), be.mass(lumped=True).diagonal()
        assert lumped.min() > 0 and lumped.sum() == pytest.approx(M.sum(), rel=1e-12)
        assert np.allclose(lumped / M.diagonal(), lumped[0] / M.diagonal()[0])  # a scaled diagonal


@pytest.mark.slow
def test_a_dynamic_scene_runs_on_the_non_locking_formulation(tmp_path):
    """ANP has P1's mass: the implicit integrators take it as they take P1."""
    from tissuebench.reference.runner import solve

    text = _dome(tmp_path, 0.499, density=1000.0).read_text().replace(
        'type = "static"\nload_steps = 6', 'type = "dynamic"\ndt = 0.01\nt_end = 0.03\nintegrator = "hht"')
    (tmp_path / "dyn.toml").write_text(text)
    scene = load(tmp_path / "dyn.toml")
    assert plan_for(scene).formulation == "anp"
    ref = solve(scene)
    assert ref.ok and ref.info["formulation"] == "anp" and ref.info["locking_indicator"]["locks"]
    assert len(ref.steps) == 4 and np.all(np.isfinite(ref.displacement))


def test_svk_keeps_p1_and_says_why(tmp_path):
    """SVK has no volumetric part to average: P1 stays, with the indicator's number and the reason
    (before: the formulation chose ANP and the run failed building it)."""
    path = _dome(tmp_path, 0.499)
    path.write_text(path.read_text().replace('name = "neo_hookean"', 'name = "svk"'))
    form = formulation_of(load(path))
    assert form.name == "displacement" and form.indicator["locks"]
    assert "no formulation that does not lock for material 'svk'" in form.warning
    assert "small-strain comparison with the linear material" in form.indicator["material_note"]
