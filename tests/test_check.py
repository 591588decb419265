"""The regression gate ``tissuebench check``: it holds on its own results, and it fails when a
method gets less accurate or slower (injected), or when a unit goes missing."""
from __future__ import annotations

import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from tissuebench.cli import main
from tissuebench.reports.check import BaselineError, check, load_baseline, update_baseline
from tissuebench.rom.anm_pod import AnmPodModel
from tissuebench.studies.spec import load_spec
from tissuebench.studies.sweep import run_sweep

SPEC = """
[sweep]
name = "gate"
[protocol]
latency_steps = 400
warmup = 40
reference_samples = 1
[[case]]
name = "cornea_pinch"
training = { kind = "path", every = 2 }
evaluation = { kind = "path", beyond = [2.0] }
[[method]]
name = "anm_pod"
options = { eps = 1e-6, max_segments = 1 }
list = [{ n_modes = 4, order = 6 }]
[[method]]
name = "pod_interp"
grid = { n_modes = [4] }
"""
HEADER = """# gate test baseline: a comment that --update-baseline must keep
[defaults]
error_rtol = 0.25
error_atol = 1e-9
latency_tolerance = 4   # the 12x slowdown below must trip it; identical runs differ by up to 2.3x
reference_latency_tolerance = 4
latency_floor = 0.0   # the steps here are microseconds: no floor, or the slowdown would hide under it
"""


@pytest.fixture(scope="module")
def gated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gate")
    spec = folder / "gate.toml"
    spec.write_text(SPEC)
    out = folder / "base"
    run_sweep(load_spec(spec), out, progress=False)
    baseline = folder / "baseline.toml"
    baseline.write_text(HEADER)
    assert update_baseline(out, baseline) == 2
    return spec, out, baseline


def test_a_run_holds_against_its_own_baseline(gated, capsys):
    spec, out, baseline = gated
    assert main(["check", str(out), "--baseline", str(baseline)]) == 0
    assert "2 units hold" in capsys.readouterr().out
    text = baseline.read_text()
    assert text.startswith("# gate test baseline") and "latency_tolerance = 4   # the 12x slowdown" in text
    _, units = load_baseline(baseline)
    assert {u["method"] for u in units} == {"anm_pod", "pod_interp"}
    assert all(u["latency_per_calibration"] > 0 and u["latency_per_reference"] > 0 for u in units)


def _slow_step(monkeypatch, factor=12.0):
    """Every ANM-POD step takes ``factor`` times its own duration (busy wait, not sleep)."""
    original = AnmPodModel.step

    def slowed(self, mu):
        t0 = time.perf_counter()
        res = original(self, mu)
        spent = time.perf_counter() - t0
        while time.perf_counter() - t0 < factor * spent:
            pass
        return res
    monkeypatch.setattr(AnmPodModel, "step", slowed)


def test_an_injected_12x_slowdown_fails_the_gate(gated, tmp_path, monkeypatch, capsys):
    spec, _, baseline = gated
    _slow_step(monkeypatch)
    out = tmp_path / "slow"
    run_sweep(load_spec(spec), out, progress=False)
    junit = tmp_path / "gate.xml"
    assert main(["check", str(out), "--baseline", str(baseline), "--junit", str(junit)]) == 1
    text = capsys.readouterr().out
    assert "regressions" in text and "latency_per_calibration" in text and "anm_pod" in text
    assert "pod_interp" not in [line.split()[1] for line in text.splitlines()[1:] if line.strip()]
    suite = ET.parse(junit).getroot()
    assert suite.get("failures") == "1" and suite.get("tests") == "2"


def _scaled_baseline(baseline, tmp_path, factor, floor):
    """The baseline with every latency ratio scaled by ``factor`` and ``latency_floor = floor``."""
    import tomlkit
    doc = tomlkit.parse(baseline.read_text())
    doc["defaults"]["latency_floor"] = floor
    for u in doc["unit"]:
        u["latency_per_calibration"] = u["latency_per_calibration"] * factor
        u["latency_per_reference"] = u["latency_per_reference"] * factor
    edited = tmp_path / f"scaled-{factor}-{floor}.toml"
    edited.write_text(tomlkit.dumps(doc))
    return edited


def test_the_latency_floor_spares_microsecond_noise_only(gated, tmp_path):
    """A run 6x slower than its baseline (the baseline scaled down by 6) fails without a floor;
    with a floor above the units' steps it holds; with a floor below them it fails again, and so
    it does when the floor raises the baseline but not past the step over the tolerance (4)."""
    _, out, baseline = gated
    steps = [u["latency_per_calibration"] for u in load_baseline(baseline)[1]]
    slower = lambda floor: check(out, _scaled_baseline(baseline, tmp_path, 1 / 6, floor))  # noqa: E731
    assert {f.metric for f in slower(0.0).regressions} == {"latency_per_calibration", "latency_per_reference"}
    assert slower(2 * max(steps)).ok
    below = slower(min(steps) / 10)
    assert {f.metric for f in below.regressions} == {"latency_per_calibration", "latency_per_reference"}
    assert not any("floor" in f.tolerance for f in below.regressions)
    # a floor that raises the baseline but stays under the step / tolerance still catches it
    raised = slower(min(steps) / 5)  # above the scaled baseline (1/6), below the step / tolerance (1/4)
    fastest = min(load_baseline(baseline)[1], key=lambda u: u["latency_per_calibration"])["method"]
    assert {f.metric for f in raised.per_unit[next(k for k in raised.per_unit if k[1] == fastest)]
            if "floor" in f.tolerance} == {"latency_per_calibration", "latency_per_reference"}


def test_a_less_accurate_method_fails_the_gate(gated, tmp_path, monkeypatch):
    spec, _, baseline = gated
    original = AnmPodModel.reconstruct

    def perturbed(self, result):
        u = original(self, result)
        return u * 1.02  # a 2 % error injected in every reconstructed field
    monkeypatch.setattr(AnmPodModel, "reconstruct", perturbed)
    out = tmp_path / "worse"
    run_sweep(load_spec(spec), out, progress=False)
    result = check(out, baseline)
    assert not result.ok
    # the error finding, exactly once; this run's latency against the baseline's depends on the
    # machine's load at that moment (microsecond steps, no floor here), so it is not asserted
    errors = [f for f in result.regressions if f.metric == "error"]
    assert len(errors) == 1 and errors[0].now == pytest.approx(0.02, rel=1e-3)


def test_a_missing_unit_is_a_regression(gated, tmp_path):
    spec, out, baseline = gated
    text = baseline.read_text().replace('method = "pod_interp"', 'method = "podi"', 1)
    edited = tmp_path / "edited.toml"
    edited.write_text(text)
    result = check(out, edited)
    assert [(f.method, f.metric) for f in result.regressions] == [("podi", "unit")]
    assert [k[1] for k in result.new_units] == ["pod_interp"]


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("error_rtol = 0.25", 'error_rtol = "a"'), "defaults.error_rtol = 'a': expected a number"),
    (lambda t: t.replace("[defaults]", "[defaults]\nspeed = 1"), "defaults.speed: unknown key"),
    (lambda t: t.replace("flagged_steps = ", "flagged_stepz = ", 1), r"unit\[0\].flagged_steps: missing"),
    (lambda t: t + "\n[[unit]]\ncase = 5\n", r"unit\[2\].case"),
    (lambda t: t + "\n[oops\n", "not valid TOML"),
])
def test_a_bad_baseline_exits_2_naming_the_key(gated, tmp_path, capsys, edit, message):
    spec, out, baseline = gated
    bad = tmp_path / "bad.toml"
    bad.write_text(edit(baseline.read_text()))
    with pytest.raises(BaselineError, match=message):
        load_baseline(bad)
    assert main(["check", str(out), "--baseline", str(bad)]) == 2
    assert "tissuebench: error:" in capsys.readouterr().err


def test_flagged_steps_may_not_grow(gated, tmp_path):
    spec, out, baseline = gated
    text = baseline.read_text()
    # a baseline without the extrapolated steps the results now have
    edited = tmp_path / "fewer.toml"
    import re

    edited.write_text(re.sub(r"flagged_steps = \d+", "flagged_steps = 0", text))
    units = {u["method"]: u for u in load_baseline(baseline)[1]}
    result = check(out, edited)
    expected = sorted(m for m, u in units.items() if u["flagged_steps"] > 0)
    assert expected == ["anm_pod", "pod_interp"]  # the 2x point past the path is flagged by both
    assert sorted(f.method for f in result.regressions if f.metric == "flagged_steps") == expected
    assert np.all([f.now > 0 for f in result.regressions])
