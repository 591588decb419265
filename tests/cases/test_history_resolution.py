"""A sine load its time step cannot sample is refused when the scene loads (issue 50, item 5): a
dynamic bar under a 1e12 Hz sine at dt = 0.05 passed ``scene check``, then the reference's Newton
failed below round-off with no explanation (the steps sampled round-off noise of ``2 pi f t``).
Nyquist is the rule: ``frequency x dt < 1/2``; refused naming the history's key, its value and the
time step (``analysis.dt``, an ``analysis.dt_sweep`` entry, a ``mu.dt``), by the loader, so that
``scene check``, ``run`` and every sweep refuse it alike. A dynamic run shorter than one step
(``mu.t_end < dt``) is refused by ``Scene.at`` as well."""
from __future__ import annotations

import re

import pytest

from tissuebench.cases.histories import MAX_CYCLES_PER_STEP, check_history_resolution
from tissuebench.cases.scene import CATALOGUE_DIR, load
from tissuebench.cli import main

from _box_scene import box_scene

BAR = box_scene("bar_sine", "a bar clamped at x = 0, its tip shaken by a sine", (1.0, 0.1, 0.1), (4, 1, 1), 1000.0,
                0.3) + """[[load]]
type = "point"
value = [0.0, -1.0, 0.0]
region = { plane = "x", value = 1.0, tol = 1e-9 }
history = { type = "sine", frequency = FREQUENCY }
[analysis]
type = "dynamic"
dt = 0.05
t_end = 0.5
integrator = "newmark"
"""


def bar(tmp_path, frequency: str):
    path = tmp_path / "bar.toml"
    path.write_text(BAR.replace("FREQUENCY", frequency))
    return path


def beam(tmp_path, frequency: str, dt_sweep=True):
    """The catalogue's clamped beam (dt = 0.005, dt_sweep up to 0.05) with another frequency."""
    text = (CATALOGUE_DIR / "clamped_beam.toml").read_text()
    assert "frequency = 1.0 }" in text and "dt_sweep = [0.05," in text
    text = text.replace("frequency = 1.0 }", f"frequency = {frequency} }}")
    if not dt_sweep:
        text = re.sub(r"\ndt_sweep = .*\n", "\n", text)
    path = tmp_path / "beam.toml"
    path.write_text(text)
    return path


def test_the_probe_a_1e12_hz_sine_at_dt_0_05_is_refused_naming_the_key_the_value_and_dt(tmp_path):
    with pytest.raises(ValueError, match=r"load\[0\].history.frequency = 1000000000000.0: its period 1e-12 s is not "
                                         r"resolved by the time step analysis.dt = 0.05 s .*Nyquist.*expected a "
                                         r"frequency below 1 / \(2 dt\) = 10 "):
        load(bar(tmp_path, "1e12"))


@pytest.mark.parametrize("frequency", ["10.0", "10.000001", "1e300"])
def test_a_sine_of_two_steps_a_period_or_fewer_is_refused(tmp_path, frequency):
    """At exactly 2 steps a period (f = 1 / (2 dt) = 10 Hz) a phase-0 sine is 0 at every step."""
    with pytest.raises(ValueError, match=rf"load\[0\].history.frequency = {re.escape(repr(float(frequency)))}: .*"
                                         r"analysis.dt = 0.05 s"):
        load(bar(tmp_path, frequency))


@pytest.mark.parametrize("frequency", ["9.99", "1.0"])
def test_a_sine_of_more_than_two_steps_a_period_loads(tmp_path, frequency):
    assert load(bar(tmp_path, frequency)).loads[0]["history"]["frequency"] == float(frequency)


def test_scene_check_exits_2_with_the_message_on_the_unresolved_sine_and_0_on_a_resolved_one(tmp_path, capsys):
    assert main(["scene", "check", str(bar(tmp_path, "1e12")), "--out", "-"]) == 2
    err = capsys.readouterr().err
    assert "load[0].history.frequency = 1000000000000.0" in err and "analysis.dt = 0.05 s" in err
    assert main(["scene", "check", str(bar(tmp_path, "2.0")), "--out", "-"]) == 0
    assert "valid" in capsys.readouterr().out


def test_every_time_step_of_the_dt_sweep_must_resolve_it(tmp_path):
    # f = 10 Hz: 20 steps a period at dt = 0.005, 2 at the dt_sweep's 0.05
    with pytest.raises(ValueError, match=r"load\[0\].history.frequency = 10.0: .*time step analysis.dt_sweep\[0\] = "
                                         r"0.05 s"):
        load(beam(tmp_path, "10.0"))
    assert load(beam(tmp_path, "9.99")).loads[0]["history"]["frequency"] == 9.99
    # without the dt_sweep, the analysis' own dt = 0.005: its boundary is 100 Hz
    with pytest.raises(ValueError, match=r"frequency = 100.0: .*time step analysis.dt = 0.005 s"):
        load(beam(tmp_path, "100.0", dt_sweep=False))
    assert load(beam(tmp_path, "99.9", dt_sweep=False)).loads[0]["history"]["frequency"] == 99.9


def test_a_mu_dt_that_does_not_resolve_the_scene_sine_is_refused_naming_mu_dt():
    scene = load("clamped_beam")  # 1 Hz
    with pytest.raises(ValueError, match=r"load\[0\].history.frequency = 1.0: its period 1 s is not resolved by the "
                                         r"time step mu.dt = 0.5 s"):
        scene.at({"dt": 0.5})
    assert scene.at({"dt": 0.25}).analysis["dt"] == 0.25


def test_a_mu_t_end_below_dt_is_refused_by_the_scene(tmp_path):
    scene = load("clamped_beam")  # dt = 0.005
    with pytest.raises(ValueError, match=r"clamped_beam: mu.t_end = 0.001: t_end = 0.001 is below dt = 0.005: a "
                                         r"dynamic run needs at least one time step"):
        scene.at({"t_end": 0.001})
    with pytest.raises(ValueError, match=r"mu.dt = 0.01: t_end = 0.005 is below dt = 0.01"):
        scene.at({"t_end": 0.005}).at({"dt": 0.01})  # a run of one step, then its dt grown past it
    with pytest.raises(ValueError, match=r"mu.t_end = 0.05: t_end = 0.05 is below dt = 0.1"):
        scene.at({"t_end": 0.05, "dt": 0.1})
    assert scene.at({"t_end": 0.005}).analysis["t_end"] == 0.005


def test_only_a_sine_has_a_period_to_resolve():
    """A ramp or a release shorter than dt is a step, which the integrators take as such."""
    for spec in ({"type": "ramp", "t1": 1e-9}, {"type": "step"}, {"type": "constant"},
                 {"type": "ramp_hold_release", "t_ramp": 1e-6, "t_release": 1e-6},
                 {"type": "tabulated", "t": [0.0, 1e-9], "values": [0.0, 1.0]}):
        check_history_resolution("load[0].history", spec, 0.05)
    assert MAX_CYCLES_PER_STEP == 0.5
    check_history_resolution("h", {"type": "sine", "frequency": 0.49}, 1.0)
    with pytest.raises(ValueError, match=r"h.frequency = 0.5: its period 2 is not resolved by the time step dt = 1 "):
        check_history_resolution("h", {"type": "sine", "frequency": 0.5}, 1.0, "dt")
