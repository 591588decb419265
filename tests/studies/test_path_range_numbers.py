"""The evaluation points of the range a path unit claims, by hand (issue 50, item 10: the mutation
testing of studies/path_range.py): the finer path and the near-rest runs declared for each
``every`` and ``refine``, the continuation past the top and its cap, and which states of those
runs become points (none at a path state, none twice, none past the top, in order), on plain
scenes and references without a solve. The real runs: tests/studies/test_path_range.py."""
from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from tissuebench.studies import path_range as pr


@dataclasses.dataclass(frozen=True)
class _Scene:
    """A scene whose ``at(mu)`` sets the analysis keys of ``mu``."""

    analysis: dict

    def at(self, mu):
        return dataclasses.replace(self, analysis={**self.analysis, **mu})


def _static(n=10, top=2.0):
    return _Scene({"type": "static", "load_steps": n, "max_load_factor": top})


def _runs(runs):
    return [(role, {k: s.analysis[k] for k in ("load_steps", "max_load_factor") if k in s.analysis},
             s.analysis["max_cuts"]) for role, s in runs]


def test_capped_keeps_the_analysis_caps_the_cuts_and_shares_the_built_mesh():
    scene = _static()
    object.__setattr__(scene, "built", "the mesh")  # a built scene's mesh lives in its __dict__
    capped = pr._capped(scene, {"load_steps": 20})
    assert capped.analysis == {"type": "static", "load_steps": 20, "max_load_factor": 2.0, "max_cuts": 2}
    assert capped.__dict__["built"] == "the mesh"
    assert "built" not in pr._capped(_static(), {"load_steps": 20}).__dict__  # nothing built: nothing shared


@pytest.mark.parametrize("every, refine, runs", [
    # a path of 10 increments to 2. Every other state trained, cut into 4: a path of twice the increments;
    # near rest at L / 8, L / 64, L / 1024 of the first trained state L = 0.4
    (2, 4, [("between", {"load_steps": 20, "max_load_factor": 2.0}),
            ("near_rest", {"load_steps": 2, "max_load_factor": 0.4 / 8}),
            ("rest_64", {"load_steps": 1, "max_load_factor": 0.4 / 64}),
            ("rest_1024", {"load_steps": 1, "max_load_factor": 0.4 / 1024})]),
    # every 3rd, counted back from the last (10, 7, 4, 1): the first trained state is 0.2; 4 / gcd(4, 3) = 4
    (3, 4, [("between", {"load_steps": 40, "max_load_factor": 2.0}),
            ("near_rest", {"load_steps": 2, "max_load_factor": 0.2 / 8}),
            ("rest_64", {"load_steps": 1, "max_load_factor": 0.2 / 64}),
            ("rest_1024", {"load_steps": 1, "max_load_factor": 0.2 / 1024})]),
    # the path's own states are the quarter points: no finer path
    (4, 4, [("near_rest", {"load_steps": 2, "max_load_factor": 0.4 / 8}),
            ("rest_64", {"load_steps": 1, "max_load_factor": 0.4 / 64}),
            ("rest_1024", {"load_steps": 1, "max_load_factor": 0.4 / 1024})]),
    # refine 2 of every state: halves, near rest at L / 4
    (1, 2, [("between", {"load_steps": 20, "max_load_factor": 2.0}),
            ("near_rest", {"load_steps": 2, "max_load_factor": 0.2 / 4}),
            ("rest_64", {"load_steps": 1, "max_load_factor": 0.2 / 64}),
            ("rest_1024", {"load_steps": 1, "max_load_factor": 0.2 / 1024})]),
])
def test_range_scenes_by_hand(every, refine, runs):
    got = _runs(pr.range_scenes(_static(), every, refine))
    assert [(role, {k: pytest.approx(v, rel=1e-15) for k, v in a.items()}, 2) for role, a in runs] == got


def test_range_scenes_of_a_path_with_default_analysis_and_none_for_refine_1_or_dynamics():
    # no load_steps / max_load_factor: one increment to 1; refine as a string of digits is read as an integer
    runs = _runs(pr.range_scenes(_Scene({"type": "static"}), 1, "4"))
    assert runs[0] == ("between", {"load_steps": 4}, 2) and runs[1][1]["max_load_factor"] == 1.0 / 8
    assert pr.range_scenes(_static(), 2, 1) == [] and pr.range_scenes(_static(), 2, 0) == []
    assert pr.range_scenes(_Scene({"type": "dynamic", "load_steps": 10}), 2, 4) == []
    assert pr.range_scenes(_Scene({"load_steps": 10}), 2, 4) == []  # no type: not a static path


@pytest.mark.parametrize("load_factor, steps", [
    (2.5, 13),  # the next increment (0.2) past 2.5
    (2.6, 13),  # 2.6 / 0.2 = 13.000000000000002: on the increment, not one more
    (10.0, 50),  # the cap: 4 times the path's 10 increments past its top
    (10.1, 50),
])
def test_beyond_scene_continues_with_the_paths_increment_up_to_its_cap(load_factor, steps):
    s = pr.beyond_scene(_static(), load_factor)
    assert s.analysis["load_steps"] == steps and s.analysis["max_cuts"] == 2
    assert s.analysis["max_load_factor"] == pytest.approx(steps * 0.2, rel=1e-15)
    default = pr.beyond_scene(_Scene({"type": "static"}), 2.5)  # one increment of 1 to the top 1
    assert default.analysis["load_steps"] == 3 and default.analysis["max_load_factor"] == 3.0


def test_interval_every_reads_a_path_trainings_every_only():
    assert pr.interval_every(SimpleNamespace(training_kind="path", training={"every": "3"})) == 3
    assert pr.interval_every(SimpleNamespace(training_kind="path", training={})) == 1
    assert pr.interval_every(SimpleNamespace(training_kind="trajectory", training={"every": 3})) == 1


class _Ref:
    """A reference run: ``factors`` its load factors from rest, the state at ``lam`` filled with ``lam``."""

    def __init__(self, factors, status="success", message=""):
        self.steps = list(factors)
        self.status, self.message = status, message
        self.displacement = np.array([np.full(2, lam) for lam in factors])

    def monitors_at(self, name, lam):
        assert name == "load_factor"
        return {"at": lam}


def _states(monkeypatch, refs, path_factors, every=2, refine=4):
    """``range_states`` of a 10-increment path with the runs' references ``refs`` (by role)."""
    solved = []

    def solve(run, backend):
        role = next(r for r, s in pr.range_scenes(_static(), every, refine) if s == run)
        solved.append((role, backend))
        return refs[role], None

    monkeypatch.setattr(pr, "cached_solve", solve)
    out, info = pr.range_states(_static(), "ngsolve", every, refine, path_factors)
    return out, info, solved


def test_range_states_takes_each_new_load_factor_once_in_order_up_to_the_top(monkeypatch):
    path = [0.2, 0.4, 0.6]  # the path's converged states (rest excluded): its top is 0.6
    refs = {"between": _Ref([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]),  # 0.7: past the top
            "near_rest": _Ref([0.0, 0.0125, 0.025]),
            "rest_64": _Ref([0.0, 0.2 + 1e-12]),  # at a path state within 1e-9 of the top: not new
            "rest_1024": _Ref([0.0, 0.0125 + 1e-12])}  # at a point already taken: not twice
    out, info, solved = _states(monkeypatch, refs, path)
    assert [lam for lam, _, _ in out] == [0.0125, 0.025, 0.1, 0.3, 0.5]
    for lam, u, _ in out:
        np.testing.assert_array_equal(u, [lam, lam])
    assert [m for _, _, m in out] == [{"at": lam} for lam in (0.0125, 0.025, 0.1, 0.3, 0.5)]
    assert solved == [(role, "ngsolve") for role in ("between", "near_rest", "rest_64", "rest_1024")]
    assert info == {"reference_between_status": "success", "reference_near_rest_status": "success",
                    "reference_rest_64_status": "success", "reference_rest_1024_status": "success",
                    "range_points": 5}


def test_range_states_keeps_what_a_stalled_run_reached_and_says_why(monkeypatch):
    long = "x" * 400
    refs = {"between": _Ref([0.0, 0.1, 0.2, 0.3], "stalled", long),
            "near_rest": _Ref([0.0], "failed", "diverged"),  # no state past rest: nothing, said
            "rest_64": _Ref([0.0, 0.6 + 5e-10]),  # the top, within its 1e-9 tolerance: a path state
            "rest_1024": _Ref([0.0, 0.6 + 1e-6])}  # past the top
    out, info, _ = _states(monkeypatch, refs, [0.2, 0.4, 0.6])
    assert [lam for lam, _, _ in out] == [0.1, 0.3]
    assert info["reference_between_status"] == "stalled" and info["reference_between_message"] == "x" * 300
    assert info["reference_near_rest_status"] == "failed" and info["reference_near_rest_message"] == "diverged"
    assert "reference_rest_64_message" not in info and info["range_points"] == 2
    assert info["reference_rest_64_status"] == info["reference_rest_1024_status"] == "success"  # read after it


def test_range_states_of_no_path_state_reads_nothing(monkeypatch):
    monkeypatch.setattr(pr, "cached_solve", lambda run, backend: pytest.fail("nothing to solve"))
    assert pr.range_states(_static(), "skfem", 2, 4, []) == ([], {})


def test_range_states_tolerance_is_relative_to_the_top(monkeypatch):
    """A path to 1e-6 (tolerance 1e-15): a state 1e-14 off a path state is a new point."""
    refs = {role: _Ref([0.0]) for role in ("between", "near_rest", "rest_64", "rest_1024")}
    refs["between"] = _Ref([0.0, 0.5e-6 + 1e-14, 1e-6 + 1e-16])
    out, info, _ = _states(monkeypatch, refs, [0.5e-6, 1e-6])
    assert [lam for lam, _, _ in out] == [0.5e-6 + 1e-14] and info["range_points"] == 1


def test_a_state_exactly_the_tolerance_from_a_path_state_or_a_point_is_taken(monkeypatch):
    """Ties on the tolerance (1e-9 of the top 1): |2e-9 - 1e-9| is 1e-9 exactly in floating point."""
    refs = {role: _Ref([0.0]) for role in ("near_rest", "rest_64", "rest_1024")}
    refs["between"] = _Ref([0.0, 2e-9, 0.5])
    out, _, _ = _states(monkeypatch, refs, [1e-9, 1.0])  # 2e-9 is the path state 1e-9's
    assert [lam for lam, _, _ in out] == [0.5]
    refs["between"] = _Ref([0.0, 1e-9, 2e-9, 0.25])
    out, _, _ = _states(monkeypatch, refs, [0.5, 1.0])  # 2e-9 is the point 1e-9's
    assert [lam for lam, _, _ in out] == [1e-9, 0.25]
