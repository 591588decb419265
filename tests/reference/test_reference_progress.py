"""Long reference runs inside a sweep show what they compute, and a stored position whose
reference stalls is solved again with a finer path before the case fails (issue 27)."""
from __future__ import annotations

import dataclasses
import warnings

import pytest

from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies import training as training_module
from tissuebench.reference import cache as cache_module
from tissuebench.reference.runner import progress_bar
from tissuebench.studies.training import POSITION_RETRIES, build_training, case_scene


def test_a_time_past_the_end_does_not_make_tqdm_warn(capsys):
    bar, update = progress_bar("t", "dynamic")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # tqdm's "clamping frac to range [0, 1]" is a TqdmWarning
        update(0.25 + 1e-15, 0.25)  # k dt > t_end by round-off
        bar.close()
    assert bar.n == bar.total == 0.25


def test_a_reference_computed_in_a_sweep_shows_which_and_how_far(tmp_path, monkeypatch, capsys):
    from tissuebench.cases import load

    monkeypatch.setenv(cache_module.PROGRESS_ENV, "1")
    scene = load("cornea_pinch").at({"load_steps": 3})
    cache_module.cached_solve(scene, "skfem", cache=tmp_path)
    err = capsys.readouterr().err
    assert "reference cornea_pinch (load_steps=3) skfem" in err and "load factor" in err and "<" in err
    cache_module.cached_solve(scene, "skfem", cache=tmp_path)  # a cache hit: nothing to show
    assert "reference cornea_pinch" not in capsys.readouterr().err


CASE = CaseEntry(id="p", name="cornea_pinch", variant=None, resolution="ci", backend="skfem",
                 training={"kind": "positions", "positions": 3, "max_load_factor": 1.0, "load_steps": 2})


def _stalling(stall_at: float, steps_that_stall):
    """cached_solve, but the reference at position ``stall_at`` with load steps in
    ``steps_that_stall`` is reported as stalled (as a point load on a coarse path can)."""
    real = cache_module.cached_solve
    calls = []

    def solve(scene, backend="skfem", *a, **k):
        ref, hit = real(scene, backend, *a, **k)
        pos, steps = scene.mu.get("position"), scene.analysis.get("load_steps")
        calls.append((pos, steps))
        if pos is not None and abs(pos - stall_at) < 1e-12 and steps in steps_that_stall:
            ref = dataclasses.replace(ref, status="stalled", message="Newton stopped converging at load factor "
                                      "0.952; last converged load factor 0.9 of 1")
        return ref, hit
    return solve, calls


def test_a_stalled_position_is_retried_with_a_finer_path(monkeypatch):
    scene = case_scene(CASE)
    lo, hi = scene.parameters["position"]["range"]
    mid = 0.5 * (lo + hi)
    solve, calls = _stalling(mid, {2})
    monkeypatch.setattr(training_module, "cached_solve", solve)
    tr = build_training(CASE, scene)
    [(s, steps)] = tr.info["retried_positions"].items()
    assert s == pytest.approx(mid) and steps == 2 * POSITION_RETRIES[0]
    assert sorted(tr.groups) == pytest.approx([lo, mid, hi])
    assert len(tr.groups[float(list(tr.groups)[1])].parameters) == 4  # the finer path's states


def test_a_position_that_stalls_at_every_retry_fails_the_case_naming_it(monkeypatch):
    scene = case_scene(CASE)
    lo, hi = scene.parameters["position"]["range"]
    mid = 0.5 * (lo + hi)
    solve, calls = _stalling(mid, {2} | {2 * f for f in POSITION_RETRIES})
    monkeypatch.setattr(training_module, "cached_solve", solve)
    with pytest.raises(RuntimeError, match=f"1 stored position.*position {mid:g}: Newton stopped converging at load "
                                           "factor 0.952"):
        build_training(CASE, scene)
    solved = sorted({round(p, 9) for p, _ in calls})
    assert solved == pytest.approx([lo, mid, hi])  # the others still ran
    assert [s for p, s in calls if abs(p - mid) < 1e-12] == [2, 4, 8]
