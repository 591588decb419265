"""``tissuebench fit`` (issue 53): train to a requirement.

The indicator by hand on small linear problems (the residual of the exact state is zero, of a
perturbed one the stiffness times the perturbation; a motion's residual vanishes on its scheme's
own trajectory), the candidates (never a point the evaluation measures or the training learnt),
the stopping rule on both sides of every clause and of the "helps" threshold, the path
training's ``runs`` the fit adds, the manifest and the resume after a kill, and fits end to end on
a small catalogue scene: one that meets an achievable requirement (its answer spec measured again
by ``tissuebench sweep`` gives the same unit and error) and one that reports why none can.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.cli import main
from tissuebench.reference import cached_solve
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.fit import Target, loop
from tissuebench.studies.fit.axes import DENSE_FRACTIONS
from tissuebench.studies.fit.candidates import amplitude_candidates, gap_middles, path_candidates, run_steps
from tissuebench.studies.fit.indicator import (central_residuals, newmark_parameters, newmark_residuals,
                                               path_residuals, rank_correlation, static_residual)
from tissuebench.studies.evaluation import build_evaluation
from tissuebench.studies.fit.axes import PositionAxis
from tissuebench.studies.fit.specs import Family, family_case, held_out, scene_plan
from tissuebench.studies.fit.manifest import check_settings, new_manifest, read_manifest, write_manifest
from tissuebench.studies.limits import check_path_runs
from tissuebench.studies.results import read_units
from tissuebench.studies.training import build_training, case_scene, training_references

from _mesh_scene import scene_file, write_block


# ----------------------------------------------------------------------------- the indicator
class _LinearBackend:
    """``f_int(u) = K u``, ``f_ext(u, lam) = lam f``: a linear problem small enough to check by hand."""

    def __init__(self, K, f):
        self.K, self.f = np.asarray(K, float), np.asarray(f, float)
        self.ndof = len(f)

    def internal_force(self, u):
        return self.K @ u

    def external_force(self, u, lam):
        return lam * self.f


def _spd(n, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.normal(size=(n, n))
    return A @ A.T + n * np.eye(n)


def test_static_residual_is_zero_at_the_exact_state_and_k_times_a_perturbation_elsewhere():
    K, f = _spd(6), np.random.default_rng(1).normal(size=6)
    free, fixed = np.arange(4), np.array([4, 5])
    be, lam = _LinearBackend(K, f), 0.7
    u = np.zeros(6)
    u[fixed] = [0.1, -0.2]  # a prescribed displacement: the residual lives on the free dofs only
    u[free] = np.linalg.solve(K[np.ix_(free, free)], lam * f[free] - K[np.ix_(free, fixed)] @ u[fixed])
    exact = static_residual(be, u, lam, free)
    assert np.linalg.norm(exact) <= 1e-12 * np.linalg.norm(lam * f)
    delta = np.zeros(6)
    delta[free] = [1e-3, -2e-3, 0.5e-3, 0.0]
    perturbed = static_residual(be, u + delta, lam, free)
    np.testing.assert_allclose(perturbed, K[np.ix_(free, free)] @ delta[free], rtol=1e-10, atol=1e-14)
    assert np.linalg.norm(perturbed) > 1e3 * np.linalg.norm(exact)
    res, ext = path_residuals(be, [u, u + delta, None], [lam, lam, lam], free)
    assert res[0] <= 1e-12 * ext[0] and res[1] == pytest.approx(np.linalg.norm(perturbed)) and res[2] == np.inf
    np.testing.assert_allclose(ext, np.linalg.norm(lam * f[free]))


def _chain(n=4):
    K = sp.diags([2.0 * np.ones(n), -np.ones(n - 1), -np.ones(n - 1)], [0, -1, 1]) * 50.0
    M = sp.diags(np.linspace(1.0, 2.0, n))
    f = np.zeros(n)
    f[-1] = 1.0
    return SecondOrderSystem.linear_system(M, K, lambda t: f * np.sin(3.0 * t)), K


@pytest.mark.parametrize("alpha", [0.0, -0.1])
def test_newmark_residual_vanishes_on_the_schemes_own_trajectory_and_not_off_it(alpha):
    system, K = _chain()
    dt, t_end = 0.01, 0.5
    res = integrate(system, None, None, dt, t_end, method="hht", alpha=alpha)
    U, times = res.u, res.t
    params = newmark_parameters("hht", {"alpha": alpha})
    assert params == (alpha, (1 - alpha) ** 2 / 4, 0.5 - alpha)
    r, ext = newmark_residuals(system, U, times, np.zeros(4), params)
    assert r.max() <= 1e-9 * ext.max()
    # one step moved by delta: its residual is (M / (beta dt^2) + (1 + alpha) (K + gamma / (beta dt) C)) delta
    k, delta = 10, np.array([0.0, 1e-4, 0.0, -2e-4])
    V = U.copy()
    V[k] += delta
    r2, _ = newmark_residuals(system, V, times, np.zeros(4), params)
    _, beta, _ = params
    expected = system.M_ff @ delta / (beta * dt * dt) + (1 + alpha) * (K @ delta)
    assert r2[k - 1] == pytest.approx(np.linalg.norm(expected), rel=1e-6)
    assert np.all(r2[:k - 1] <= 1e-9 * ext.max())  # the steps before it are untouched
    V[k + 3] = np.nan  # a failed step: its residual and the later ones are infinite
    r3, _ = newmark_residuals(system, V, times, np.zeros(4), params)
    assert np.all(np.isinf(r3[k + 2:])) and np.isfinite(r3[:k + 2]).all()


def test_central_residual_vanishes_on_the_central_difference_trajectory():
    system, _ = _chain()
    dt = 1e-3  # below the chain's stability limit
    res = integrate(system, None, None, dt, 0.2, method="central_difference")
    r, ext = central_residuals(system, res.u, res.t)
    assert newmark_parameters("central_difference") is None
    assert r.max() <= 1e-9 * ext.max()


def test_rank_correlation_of_the_indicator_with_the_error():
    assert rank_correlation([1, 2, 3, 4], [0.1, 0.2, 0.3, 0.4])[0] == pytest.approx(1.0)
    assert rank_correlation([4, 3, 2, 1], [0.1, 0.2, 0.3, 0.4])[0] == pytest.approx(-1.0)
    assert rank_correlation([1, np.inf, 3], [0.1, 0.9, 0.3])[0] == pytest.approx(1.0)  # a failed step ranks last
    rho, n = rank_correlation([1, 2, np.nan, 4], [0.1, 0.2, 0.3, np.nan])
    assert np.isnan(rho) and n == 2  # fewer than 3 pairs: no correlation claimed


# ----------------------------------------------------------------------------- the candidates
def test_candidates_are_the_middles_of_the_gaps_never_a_point_used():
    np.testing.assert_allclose(gap_middles([0.5], 0.0, 1.0), [0.25, 0.75])
    trained, measured = [0.5, 1.0], [0.25, 0.75]
    c = path_candidates(trained, measured, 1.0)
    np.testing.assert_allclose(c, [0.125, 0.375, 0.625, 0.875])
    assert not set(c) & set(trained + measured)
    # a reference added at a candidate splits its gap: the next candidates refine there
    c2 = path_candidates(trained + [0.875], measured, 1.0)
    np.testing.assert_allclose(c2, [0.125, 0.375, 0.625, 0.8125, 0.9375])
    np.testing.assert_allclose(amplitude_candidates([0.5, 1.0], [0.75], 0.5), [0.625, 0.875])
    # the dense check's thirds are never a dyadic middle, however far the greedy refines
    used = [0.5, 0.75, 1.0]
    for _ in range(6):
        cands = amplitude_candidates(used, [], 0.5)
        used += list(cands)
    thirds = [0.5 + f * 0.5 for f in DENSE_FRACTIONS]
    assert min(abs(t - u) for t in thirds for u in used) > 1e-4


def test_a_gap_narrower_than_min_gap_gets_no_candidate_and_an_empty_range_is_refused():
    assert len(gap_middles([0.5, 0.5 + 2e-3], 0.0, 1.0, min_gap=1e-3)) == 3  # the 2e-3 gap: a candidate
    assert len(gap_middles([0.5, 0.5 + 0.5e-3], 0.0, 1.0, min_gap=1e-3)) == 2  # the 0.5e-3 gap: none
    with pytest.raises(ValueError, match=r"candidate range \[1.0, 1.0\]"):
        gap_middles([], 1.0, 1.0)


def test_a_run_takes_increments_no_larger_than_the_paths():
    assert run_steps(0.3, 0.1) == 3 and run_steps(0.31, 0.1) == 4 and run_steps(1e-4, 0.1) == 1


# ----------------------------------------------------------------------------- the stopping rule
def _row(error, p99, status="ok", seen=False):
    return {"unit_status": status, "seen": seen, "error": error, "haptic_p99_s": p99}


def test_the_requirement_holds_on_its_boundary_and_fails_just_past_it():
    t = Target.of([("rate", ">=", 1000.0), ("error", "<=", 0.02)])
    assert t.meets(_row(0.02, 1e-3))  # both on the boundary: inclusive
    assert not t.meets(_row(0.0201, 1e-3)) and t.missed(_row(0.0201, 1e-3)) == ["error<=2%: 2.01%"]
    assert not t.meets(_row(0.02, 1.001e-3)) and t.meets_error(_row(0.02, 1.001e-3))
    assert not t.meets(_row(0.01, 1e-4, status="failed")) and not t.meets(_row(0.01, 1e-4, seen=True))
    strict = Target.of([("error", "<", 0.02), ("latency", "<", 1e-3)])
    assert not strict.meets(_row(0.02, 0.5e-3)) and strict.meets(_row(0.0199, 0.5e-3))
    assert not strict.meets(_row(0.01, 1e-3)) and strict.meets(_row(0.01, 0.999e-3))
    with pytest.raises(ValueError, match="clause rate op = '<='"):
        Target.of([("rate", "<=", 1000.0)])
    with pytest.raises(ValueError, match="a quantity given twice"):
        Target.of([("error", "<=", 0.1), ("error", "<", 0.2)])


def _point(error, p99=1e-4, status="ok", action="add"):
    return {"status": status, "seen": False, "error": error, "p99_s": p99, "action": action}


def test_references_are_added_while_they_help_and_the_model_grows_when_they_no_longer_do():
    t = Target.of([("rate", ">=", 1000.0), ("error", "<=", 0.01)])
    # one reference that did not help (0.10 -> 0.095): one more before "training no longer helps"
    once = {"curve": [_point(0.10, action="start")], "refs_added": 1, "last_action": "add"}
    assert loop.decide(once, _point(0.095), t, 4, True, True)[0] == "add"
    # two in a row, each lowering the error by less than MIN_GAIN (10 %): 9.9 % is not enough, 10.1 % is
    state = {"curve": [_point(0.10, action="start"), _point(0.095)], "refs_added": 2, "last_action": "add"}
    assert loop.decide(state, _point(0.0899 * 0.95 / 0.9), t, 4, True, True)[0] == "grow"  # 0.0949: -0.1 %
    assert loop.decide(state, _point(0.095 * 0.899), t, 4, True, True)[0] == "add"  # 10.1 % lower: it helps
    assert loop.decide(state, _point(0.095 * 0.901), t, 4, True, True)[0] == "grow"  # 9.9 % lower: no longer
    action, why = loop.decide(state, _point(0.095 * 0.901), t, 4, True, False)
    assert action == "stop" and why.startswith("training no longer helps (2 references: 10 % -> 8.56 %)")
    assert loop.decide(state, _point(0.01), t, 4, True, True)[0] == "met"
    assert loop.decide(state, {**_point(None, status="failed"), "message": "boom"}, t, 4, True, True) == (
        "stop", "its unit failed: boom")
    assert loop.decide(state, _point(0.05, p99=2e-3), t, 4, True, True)[0] == "stop"  # a rate miss: no training helps
    grown = {**state, "last_action": "grow"}
    assert loop.decide(grown, _point(0.095 * 0.899, action="grow"), t, 4, True, True)[0] == "add"
    action, why = loop.decide(grown, _point(0.095 * 0.901, action="grow"), t, 4, True, True)
    assert action == "stop" and "neither more training nor a larger or refined model" in why
    spent = {**once, "refs_added": 4}
    assert loop.decide(spent, _point(0.05), t, 4, True, True)[0] == "grow"
    assert loop.decide(spent, _point(0.05), t, 4, True, False) == ("stop", "the budget of 4 references is spent")
    assert loop.decide({**once, "refs_added": 3}, _point(0.05), t, 4, True, False)[0] == "add"
    assert loop.decide({**once, "refs_added": 3}, _point(0.05), t, 4, False, False)[0] == "stop"


def test_a_rate_missed_only_by_the_machines_load_does_not_stop_the_training():
    t = Target.of([("rate", ">=", 1000.0), ("error", "<=", 0.01)])
    busy = {**_point(0.05, p99=1.5e-3, action="start"), "load_average": 4.0, "n_cpus": 2}  # load factor 2
    idle = {**busy, "load_average": 2.0}  # load factor 1: the p99 is the step's own
    assert loop.load_factor(busy) == 2.0 and loop.load_factor(idle) == 1.0 and loop.load_factor(_point(0.1)) == 1.0
    assert loop.speed_ok(t, busy) and not loop.speed_ok(t, idle)
    assert not t.meets(_as_row(busy))  # the requirement itself reads the p99 as timed
    state = {"curve": [], "refs_added": 0, "last_action": "start"}
    assert loop.decide(state, busy, t, 4, True, True)[0] == "add"
    action, why = loop.decide(state, idle, t, 4, True, True)
    assert action == "stop" and "even with its p99 divided by the machine's load factor (1)" in why


def _as_row(p):
    return {"unit_status": p["status"], "seen": p["seen"], "error": p["error"], "haptic_p99_s": p["p99_s"]}


def test_the_model_grows_along_its_grid_then_by_half_up_to_a_bound():
    fam = Family("pod_interp", {}, {"n_modes": [3, 5]}, {}, "n_modes")
    assert loop.next_size(fam, 3) == 5 and loop.next_size(fam, 5) == 8 and loop.next_size(fam, 13) == 20
    assert loop.next_size(fam, 14) is None  # 21 > 4 x 5
    assert loop.next_size(Family("nearest", {}, {}, {}), None) is None


def test_a_scenes_moving_load_is_a_family_of_its_own_whose_held_out_positions_never_move():
    plan = scene_plan("cornea_pinch", methods=["podi", "pod_interp"])
    assert sorted(f.id for f in plan.families) == ["pod_interp", "pod_interp.positions", "podi.positions"]
    base = plan.base_cases["positions"]
    scene = case_scene(CaseEntry(id="c", name="cornea_pinch", training=base["training"],
                                 evaluation={"kind": "positions", "held_out": 2}))
    lattice = base["training"]["positions"]
    assert lattice == [-1.2, 0.0, 1.2]
    # the evaluation's own rule, frozen into a list: the same positions
    ev = build_evaluation(CaseEntry(id="c", name="cornea_pinch", training={"kind": "positions", "positions": 3,
                                                                           "load_steps": 4},
                                    evaluation={"kind": "positions", "held_out": 2}), scene)
    assert ev.info["lattice"] == lattice
    assert sorted({p.group for p in ev.points}) == pytest.approx(held_out(lattice, 2)) and held_out(lattice, 2) == [
        -0.9, 0.6]
    case = family_case(plan, "podi.positions", [{"position": 0.3}])
    assert case["training"]["positions"] == [-1.2, 0.0, 0.3, 1.2] and case["evaluation"]["held_out"] == [-0.9, 0.6]
    assert held_out(case["training"]["positions"], case["evaluation"]["held_out"]) == [-0.9, 0.6]
    axis = PositionAxis(plan.scene, base, "skfem")
    np.testing.assert_allclose(axis.candidates(case["training"]["positions"], [-0.9, 0.6]),
                               [-1.05, -0.45, 0.15, 0.45, 0.9])
    assert axis.dense_evaluations(base)[0][1]["held_out"] == pytest.approx([-0.8, -0.4, 0.4, 0.8])
    with pytest.raises(ValueError, match="--methods = 'pod_galerkin': not a family of this fit"):
        scene_plan("cornea_pinch", methods=["pod_galerkin"])


# ----------------------------------------------------------------------------- path training runs
def _block_case(tmp_path, runs):
    write_block(tmp_path)
    p = scene_file(tmp_path)
    p.write_text(p.read_text().replace("load_steps = 2", "load_steps = 4"))
    return CaseEntry(id="c", name=str(p), training={"kind": "path", "every": 2, "runs": runs},
                     evaluation={"kind": "path", "held_out": True})


def test_a_path_training_run_adds_the_last_state_of_its_own_path(tmp_path):
    case = _block_case(tmp_path, [{"max_load_factor": 0.375, "load_steps": 2}])
    scene = case_scene(case)
    training = build_training(case, scene)
    lams = training.parameter_values("load_factor")
    np.testing.assert_allclose(lams, [0.0, 0.375, 0.5, 1.0])  # in load-factor order among the path's states
    run = scene.at({"max_load_factor": 0.375, "load_steps": 2})
    ref, _ = cached_solve(run, "skfem")
    np.testing.assert_allclose(training.snapshots[:, 1], ref.displacement[-1].ravel())
    assert run.content_hash() in {s.content_hash() for s in training_references(case, scene)}
    # without runs: the path's own states only
    plain = build_training(_block_case(tmp_path, []), scene)
    np.testing.assert_allclose(plain.parameter_values("load_factor"), [0.0, 0.5, 1.0])


def test_a_path_training_run_sets_the_load_path_only(tmp_path):
    scene = case_scene(_block_case(tmp_path, []))
    check_path_runs("training.runs", [{"max_load_factor": 0.3, "load_steps": 2}], scene)
    with pytest.raises(ValueError, match=r"training.runs\[0\].nu = 0.3: a run of a path training sets only"):
        check_path_runs("training.runs", [{"nu": 0.3}], scene)
    with pytest.raises(ValueError, match=r"training.runs\[0\].max_load_factor = 0: expected a finite number > 0"):
        check_path_runs("training.runs", [{"max_load_factor": 0}], scene)
    with pytest.raises(ValueError, match=r"training.runs\[1\].load_steps = 0"):
        check_path_runs("training.runs", [{"max_load_factor": 0.2}, {"max_load_factor": 0.2, "load_steps": 0}], scene)


# ----------------------------------------------------------------------------- manifest and resume
SETTINGS = {"scene": "cube_tension_twist", "variant": None, "resolution": "ci", "backend": "skfem",
            "require": "error<=1%", "methods": ["pod_interp"], "budget_references": 4, "budget_minutes": 60.0}


def test_the_manifest_refuses_another_fits_settings_and_a_foreign_file(tmp_path):
    m = new_manifest(SETTINGS)
    write_manifest(tmp_path, m)
    assert read_manifest(tmp_path)["settings"] == SETTINGS
    check_settings(m, {**SETTINGS, "budget_references": 9}, tmp_path)  # a budget may change on resume
    with pytest.raises(ValueError, match="holds a fit with require = 'error<=1%', not 'error<=2%'"):
        check_settings(m, {**SETTINGS, "require": "error<=2%"}, tmp_path)
    grow = {"options": {"n_modes": 45}, "option": "n_modes", "value": 45}
    m["families"] = {"pod_galerkin": {"next": {"action": "grow", "alternatives": [grow]}}}
    write_manifest(tmp_path, m)
    assert read_manifest(tmp_path)["families"]["pod_galerkin"]["next"]["alternatives"] == [grow]
    for damaged in ([{**grow, "options": "n_modes=45"}], [{**grow, "value": None}], [], {"n_modes": 45}):
        m["families"]["pod_galerkin"]["next"]["alternatives"] = damaged
        write_manifest(tmp_path, m)
        with pytest.raises(ValueError, match="families.pod_galerkin.next.alternatives = .*the manifest is damaged"):
            read_manifest(tmp_path)
    (tmp_path / "fit.json").write_text(json.dumps({"kind": "something else"}))
    with pytest.raises(ValueError, match="not the manifest of a tissuebench fit"):
        read_manifest(tmp_path)
    assert read_manifest(tmp_path / "nothing") is None


ACHIEVABLE = ["fit", "cube_tension_twist", "--require", "rate>=1kHz, error<=0.01%", "--methods", "pod_interp",
              "--quiet"]


def test_a_killed_fit_resumes_where_it_stopped(tmp_path, monkeypatch):
    out = tmp_path / "fit"
    real, calls = loop.run_sweep, []

    def killed_in_round_1(spec, folder, *args, **kwargs):
        calls.append(folder.name)
        if folder.name == "round-1":
            raise KeyboardInterrupt  # killed while the round's sweep runs
        return real(spec, folder, *args, **kwargs)

    monkeypatch.setattr(loop, "run_sweep", killed_in_round_1)
    assert main(ACHIEVABLE + ["--out", str(out)]) == 130
    m = read_manifest(out)
    assert [r["status"] for r in m["rounds"]] == ["done", "running"]
    assert m["families"]["pod_interp"]["refs_added"] == 1
    round0 = {p.name: p.stat().st_mtime_ns for p in (out / "rounds" / "round-0").rglob("*.parquet")}
    monkeypatch.setattr(loop, "run_sweep", lambda *a, **k: (calls.append(a[1].name), real(*a, **k))[1])
    assert main(ACHIEVABLE + ["--out", str(out)]) == 0
    m = read_manifest(out)
    assert calls[:2] == ["round-0", "round-1"] and calls[2] == "round-1"  # round 0 is never run again
    assert {p.name: p.stat().st_mtime_ns for p in (out / "rounds" / "round-0").rglob("*.parquet")} == round0
    assert m["state"] == "met" and all(r["status"] == "done" for r in m["rounds"])
    assert [p["references"] for p in m["families"]["pod_interp"]["curve"]] == list(range(len(m["rounds"])))


def test_a_family_whose_model_fails_outside_its_unit_stops_and_the_fit_goes_on(tmp_path, monkeypatch):
    """A lead model that raises when the fit rebuilds it for the indicator (wsc's Cholesky on the
    liver in motion ended the whole fit) stops its family, saying why; the others go on."""
    real = loop._Fit.lead_model

    def failing(self, entry, method, options):
        if method == "nearest":
            raise np.linalg.LinAlgError("979-th leading minor of the array is not positive definite")
        return real(self, entry, method, options)

    monkeypatch.setattr(loop._Fit, "lead_model", failing)
    out = tmp_path / "fit"
    assert main(ACHIEVABLE[:5] + ["pod_interp,nearest", "--quiet", "--out", str(out)]) == 0
    m = read_manifest(out)
    assert m["families"]["nearest"]["status"] == "stopped"
    assert m["families"]["nearest"]["why"] == ("the indicator could not be computed on its lead model: LinAlgError: "
                                               "979-th leading minor of the array is not positive definite")
    assert m["families"]["pod_interp"]["status"] == "met"


# ----------------------------------------------------------------------------- end to end
def test_a_fit_meets_an_achievable_requirement_and_its_spec_measures_the_same_unit(tmp_path):
    out = tmp_path / "fit"
    assert main(ACHIEVABLE + ["--out", str(out)]) == 0
    m = read_manifest(out)
    answer = m["answer"]
    assert answer["reproduces"] and answer["why"] == "the same unit key as the fit's measurement"
    assert answer["point"]["references"] >= 1 and answer["point"]["error"] <= 1e-4  # the protocol alone: 0.018 %
    assert m["families"]["pod_interp"]["curve"][0]["error"] > 1e-4
    assert answer["added_references"] == answer["point"]["references"]
    dense = m["dense"][answer["point"]["unit_key"]]
    assert dense["status"] == "ok" and 0.5 < dense["ratio"] < 2.0
    checks = m["families"]["pod_interp"]["checks"]
    assert checks and all(c["pairs"] >= 10 and c["rho"] > 0.5 for c in checks)
    assert (out / "learning_curves.png").stat().st_size > 0
    assert "## The answer" in (out / "fit.md").read_text()
    again = tmp_path / "again"
    assert main(["sweep", str(out / "answer.spec.toml"), "--out", str(again), "--quiet"]) == 0
    row = read_units(again).iloc[0]
    assert row["unit_key"] == answer["point"]["unit_key"]
    assert row["claimed_error"] == pytest.approx(answer["point"]["error"], rel=1e-9)


def test_a_fit_says_why_no_unit_can_meet_a_requirement(tmp_path, capsys):
    out = tmp_path / "fit"
    code = main(["fit", "cube_tension_twist", "--require", "rate>=1kHz, error<=0.1%", "--methods", "nearest",
                 "--quiet", "--out", str(out)])
    assert code == 1
    m = read_manifest(out)
    assert m["state"] == "not_met" and m["answer"] is None
    st = m["families"]["nearest"]
    assert st["status"] == "stopped" and st["why"].startswith("training no longer helps")
    assert m["best_per_clause"]["error"]["family"] == "nearest" and m["best_per_clause"]["speed"] is None
    assert "flat" in st["heading"]["words"]
    said = capsys.readouterr().out
    assert "fit: no unit meets rate>=1kHz, error<=0.1% (not_met)" in said
    assert "## No unit meets the requirement" in (out / "fit.md").read_text()


@pytest.mark.slow
def test_a_fit_adds_stored_positions_where_the_moving_loads_model_errs_most(tmp_path):
    """About 20 s: PODI on the cornea learns from 3 stored positions (7.6 % against the
    mean-dilatation reference of issue 54; 6.35 % against the locking Q1); the positions the fit adds
    bring it under 4 % on the held-out positions (2 added: 3.8 %), and near it at the dense check's
    thirds (3.6 %). Its best is 2.9 % (4 added; more raise it again): the 2 % this test asked of the
    locking Q1 is out of PODI's reach on the cornea that does not lock."""
    out = tmp_path / "fit"
    assert main(["fit", "cornea_pinch", "--require", "error<=4%", "--methods", "podi", "--quiet", "--out",
                 str(out)]) == 0
    m = read_manifest(out)
    st = m["families"]["podi.positions"]
    assert st["axis"] == "position" and st["status"] == "met" and 1 <= st["refs_added"] <= 4
    assert st["curve"][0]["error"] > 0.04 >= st["curve"][-1]["error"]
    assert all(-1.2 < a["value"] < 1.2 and a["value"] not in (-0.9, 0.6) for a in st["added"])
    assert m["dense"][m["answer"]["point"]["unit_key"]]["error"] <= 0.05 and m["answer"]["reproduces"]


def test_the_fit_command_refuses_bad_options_before_any_work(tmp_path, capsys):
    base = ["fit", "cube_tension_twist", "--out", str(tmp_path / "f")]
    assert main(base + ["--require", "rate>=1kHz", "--budget-references", "-1"]) == 2
    assert "--budget-references = -1: expected an integer >= 0" in capsys.readouterr().err
    assert main(base + ["--require", "rate>=1kHz", "--budget-minutes", "0"]) == 2
    assert "--budget-minutes = 0.0" in capsys.readouterr().err
    assert main(base + ["--require", "speed>=1kHz"]) == 2
    assert "unknown quantity 'speed'" in capsys.readouterr().err
    assert main(base + ["--require", "error<=1%", "--methods", "pod_galerkin"]) == 2
    assert "--methods = 'pod_galerkin': not a family of this fit" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()
