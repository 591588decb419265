"""Each rule of the gate (:mod:`tissuebench.gate.checks`) at its boundary, on both sides:
just inside holds, just outside is flagged, with the finding's exact values and wording (issue 41).

The checks run here on hand-made unit rows, in memory: no sweep, no worker process (the A/B's
timing is replaced by given samples; its statistics are :mod:`tissuebench.gate.stats`').
"""
from __future__ import annotations

import math

import pandas as pd
import pytest

from tissuebench.gate import checks
from tissuebench.gate.baseline import DEFAULTS, unit_identity
from tissuebench.gate.base import ABSettings, CheckResult, Finding
from tissuebench.reports.recommend import parse_requirement

KEY = ("cube", "pod", '{"n":2}')
KEY2 = ("cube", "pod", '{"n":4}')


def _row(error=0.01, status="ok", message="", calib=0.5, median=2e-4, ref_step=1e-2, p99=3e-4, label="pod",
         **flagged):
    return {"label": label, "error": error, "unit_status": status, "message": message, "haptic_per_calibration": calib,
            "haptic_median_s": median, "haptic_p99_s": p99, "reference_step_s": ref_step, "max_rel_l2": error,
            **{c: flagged.get(c, 0) for c in checks._FLAGGED}}


def _unit(key=KEY, error=0.01, calib=0.5, flagged=0, **overrides):
    return {"case": key[0], "method": key[1], "options": key[2], "error": error, "latency_per_calibration": calib,
            "latency_per_reference": 0.02, "flagged_steps": flagged, "_identity": unit_identity(*key), **overrides}


# ---------------------------------------------------------------- the values gated
def test_unit_values_by_hand():
    v = checks.unit_values(_row(error=0.25, calib=0.75, median=3e-4, ref_step=1.5e-2, n_failed=1,
                                n_extrapolation=2, n_beyond_validity=4, n_not_reached=8))
    assert v == {"error": 0.25, "latency_per_calibration": 0.75, "latency_per_reference": pytest.approx(0.02),
                 "flagged_steps": 15}
    assert math.isnan(checks.unit_values(_row(ref_step=0.0))["latency_per_reference"])
    assert checks.unit_values(_row(ref_step=0.5, median=0.25))["latency_per_reference"] == 0.5  # a step < 1 s


def test_tolerances_take_the_unit_override_else_the_default():
    t = checks.tolerances({"error_rtol": 0.5, "case": "x"}, DEFAULTS)
    assert t == {**DEFAULTS, "error_rtol": 0.5}
    assert checks.tolerances(None, DEFAULTS) == DEFAULTS


# ---------------------------------------------------------------- the error rule
@pytest.mark.parametrize("was, now, changed", [
    (1.0, 1.0 + 0.999e-3, False), (1.0, 1.0 + 1.001e-3, True),      # relative: 1e-3 of the baseline's
    (1.0, 1.0 - 0.999e-3, False), (1.0, 1.0 - 1.001e-3, True),
    (2.0, 2.0 + 1.999e-3, False), (2.0, 2.0 + 2.001e-3, True),      # relative to the baseline's, not to 1
    (0.0, 0.999e-9, False), (0.0, 1.001e-9, True),                  # absolute near zero
    (0.0, 1e-9, False), (1.0, 1.5, False), (1.0, 1.75, True),       # exactly at the bound holds (rtol 0.5 below)
    (1e-7, 1e-7 + 0.999e-9, False), (1e-7, 1e-7 + 1.001e-9, True),  # atol above rtol * was
    (math.inf, math.inf, False), (math.inf, 1.0, True), (1.0, math.inf, True), (1.0, math.nan, True),
])
def test_the_error_rule_at_its_boundary(was, now, changed):
    tol = {**DEFAULTS, "error_rtol": 0.5 if (was, now) in ((1.0, 1.5), (1.0, 1.75)) else 1e-3, "error_atol": 1e-9}
    assert checks._error_changed(was, now, tol) is changed


def test_a_baseline_error_of_inf_still_gates_the_error():
    # a unit that finished with a failed step has error inf in the baseline; a relative tolerance
    # of inf * 1e-3 let any later error through unflagged, so that unit was never gated again
    out = CheckResult()
    checks.errors_against_baseline(out, {KEY: _row(error=0.5)}, [_unit(KEY, error=math.inf)], DEFAULTS)
    assert [(f.metric, f.baseline, f.now) for f in out.regressions] == [("error", math.inf, 0.5)]


def test_the_error_rule_with_zero_tolerances_flags_any_change_only():
    tol = {**DEFAULTS, "error_rtol": 0.0, "error_atol": 0.0}
    assert checks._error_changed(0.5, 0.5, tol) is False
    assert checks._error_changed(0.5, math.nextafter(0.5, 1), tol) is True


def test_error_and_flagged_findings_with_their_wording():
    out = CheckResult()
    tol = {**DEFAULTS, "error_rtol": 0.01, "error_atol": 1e-6}
    checks._value_findings(out, KEY, {"error": 1.0, "flagged_steps": 2}, {"error": 1.02, "flagged_steps": 3}, tol,
                           "REF", False)
    assert out.regressions == [
        Finding(*KEY, "error", 1.0, 1.02, "changed against REF by more than 0.01 relative / 1e-06: if intended, "
                                           "update the baseline in the same commit (check --update-baseline)"),
        Finding(*KEY, "flagged_steps", 2, 3, "failed/extrapolated/beyond-validity steps may not grow (REF)")]
    assert out.per_unit[KEY] == out.regressions and out.notes == []


def test_flagged_steps_may_stay_or_shrink():
    out = CheckResult()
    checks._value_findings(out, KEY, {"error": 1.0, "flagged_steps": 2}, {"error": 1.0, "flagged_steps": 2}, DEFAULTS,
                           "REF", False)
    checks._value_findings(out, KEY2, {"error": 1.0, "flagged_steps": 2}, {"error": 1.0, "flagged_steps": 1},
                           DEFAULTS, "REF", False)
    assert out.regressions == [] and out.per_unit == {KEY: [], KEY2: []}


def test_a_declared_change_is_a_note_not_a_finding():
    out = CheckResult()
    checks._value_findings(out, KEY, {"error": 1.0, "flagged_steps": 0}, {"error": 2.0, "flagged_steps": 5}, DEFAULTS,
                           "REF", True)
    assert out.regressions == [] and out.per_unit == {KEY: []}
    assert out.notes == ['cube pod {"n":2}: error 1 -> 2, declared by the baseline update of this commit']


# ---------------------------------------------------------------- against the baseline file
def test_errors_against_the_baseline_every_outcome():
    k3, k4 = ("cube", "pod", '{"n":8}'), ("bar", "anm", "{}")
    units = [_unit(k3), _unit(KEY2, error=0.01), _unit(KEY, error=0.01)]  # the missing and the failed one first
    rows = {KEY: _row(error=0.01 * (1 + 0.5e-3)), KEY2: _row(status="failed", message="m" * 200),
            k4: _row(status="failed"), ("a", "b", "{}"): _row()}
    out = CheckResult()
    checks.errors_against_baseline(out, rows, units, DEFAULTS)
    assert out.errors_against == "baseline" and out.compared == 2
    assert [(f.case, f.method, f.options, f.metric, f.tolerance) for f in out.regressions] == [
        (*k3, "unit", "missing from the results"), (*KEY2, "unit_status", f"failed: {'m' * 120}")]
    assert [f.baseline for f in out.regressions] == [1.0, 1.0] and all(math.isnan(f.now) for f in out.regressions)
    assert set(out.per_unit) == {KEY, KEY2, k3}
    assert out.per_unit[KEY] == [] and len(out.per_unit[KEY2]) == 1
    assert out.new_units == [("a", "b", "{}"), k4] and out.new_failed == {k4}


def test_errors_against_the_baseline_flags_a_change_with_the_unit_tolerance():
    units = [_unit(KEY, error=1.0, error_rtol=0.1)]
    out = CheckResult()
    checks.errors_against_baseline(out, {KEY: _row(error=1.09)}, units, DEFAULTS)
    assert out.regressions == []
    checks.errors_against_baseline(out, {KEY: _row(error=1.11)}, units, DEFAULTS)
    assert [(f.metric, f.baseline, f.now) for f in out.regressions] == [("error", 1.0, 1.11)]
    assert out.regressions[0].tolerance == ("changed against the baseline by more than 0.1 relative / 1e-09: "
                                            "if intended, update the baseline in the same commit "
                                            "(check --update-baseline)")


def test_no_unit_compared_is_an_error_not_a_pass():
    with pytest.raises(ValueError, match=r"^check: no unit of the baseline is in the results \(0 compared\): "
                                         r"wrong results folder or baseline\?$"):
        checks.errors_against_baseline(CheckResult(), {KEY2: _row()}, [_unit(KEY)], DEFAULTS)


# ---------------------------------------------------------------- against REF
def test_errors_against_ref_every_branch():
    k_new, k_base, k_fail_both, k_fail_here, k_missing, k_ref_failed = (
        ("n", "m", "{}"), ("b", "m", "{}"), ("f", "m", "{}"), ("h", "m", "{}"), ("x", "m", "{}"), ("r", "m", "{}"))
    rows = {KEY: _row(error=1.0 + 2e-3), KEY2: _row(error=5.0), k_new: _row(), k_base: _row(error=2.0),
            k_fail_both: _row(status="failed", message="boom"), k_fail_here: _row(status="failed", message="bad"),
            k_ref_failed: _row(error=3.0)}
    ref_rows = {KEY: _row(error=1.0), KEY2: _row(error=1.0), k_fail_both: _row(status="failed"),
                k_fail_here: _row(), k_ref_failed: _row(status="failed")}
    units = [_unit(k_base, error=2.5), _unit(k_missing), _unit(k_ref_failed, error=3.0)]
    out = CheckResult()
    checks.errors_against_ref(out, rows, ref_rows, units, DEFAULTS, {KEY2}, "main")
    assert out.errors_against == "ref"
    assert out.compared == 5  # KEY, KEY2, k_base, k_fail_here, k_ref_failed
    got = [(f.case, f.metric, f.baseline, f.now, f.tolerance) for f in out.regressions]
    assert got == [
        ("cube", "error", 1.0, 1.0 + 2e-3, "changed against main by more than 0.001 relative / 1e-09: if intended, "
                                           "update the baseline in the same commit (check --update-baseline)"),
        ("b", "error", 2.5, 2.0, "changed against the baseline by more than 0.001 relative / 1e-09: if intended, "
                                 "update the baseline in the same commit (check --update-baseline)"),
        ("h", "unit_status", 1.0, got[2][3], "failed: bad"),
        ("x", "unit", 1.0, got[3][3], "in the baseline, missing from the results")]
    assert math.isnan(got[2][3]) and math.isnan(got[3][3])
    assert set(out.per_unit) == {KEY, KEY2, k_base, k_fail_here, k_missing, k_ref_failed}
    assert out.notes == ['cube pod {"n":4}: error 1 -> 5, declared by the baseline update of this commit',
                         "b m {}: main has no such unit: compared with the baseline file",
                         "f m {}: fails here and on main (not a regression)",
                         "r m {}: main failed on it: compared with the baseline file"]
    assert out.new_units == sorted([KEY, KEY2, k_new, k_fail_both, k_fail_here]) and \
        out.new_failed == {k_fail_both, k_fail_here}
    assert k_fail_both not in out.per_unit and k_new not in out.per_unit  # new: not compared with anything


def test_a_unit_failing_here_that_only_the_baseline_knows_is_a_regression():
    out = CheckResult()
    checks.errors_against_ref(out, {KEY: _row(status="failed", message="x" * 300)}, {}, [_unit(KEY)], DEFAULTS,
                              set(), "main")
    assert out.compared == 1 and [f.tolerance for f in out.regressions] == [f"failed: {'x' * 120}"]


def test_errors_against_ref_uses_the_baseline_unit_tolerance_and_refuses_nothing_compared():
    out = CheckResult()
    checks.errors_against_ref(out, {KEY: _row(error=1.05)}, {KEY: _row(error=1.0)}, [_unit(KEY, error_rtol=0.1)],
                              DEFAULTS, set(), "main")
    assert out.regressions == []
    with pytest.raises(ValueError, match=r"^check: no unit could be compared with v1 or the baseline \(0 compared\)$"):
        checks.errors_against_ref(CheckResult(), {KEY: _row()}, {}, [], DEFAULTS, set(), "v1")


# ---------------------------------------------------------------- latency, file mode
def _file_note(why, above, seen, tol, shown=""):
    return (f"{why}latency not gated (the A/B of --against REF gates it): the baseline file's ratios (haptic median "
            "/ calibration kernel) move 2-3x between runs of identical code for microsecond steps. For information: "
            f"{above} of {seen} units above x{tol:g} of the file's ratio" + (f" ({shown})" if shown else ""))


def test_file_latency_at_its_limit_on_both_sides_is_information_only():
    # issue 39: file-mode latency never fails identical code; what is above the limit is said, not gated
    base = 0.5
    units = [_unit(KEY, calib=base), _unit(KEY2, calib=base), _unit(("c", "m", "{}"), calib=base),
             _unit(("d", "m", "{}"), calib=base)]
    limit = base * 1.3
    rows = {("c", "m", "{}"): _row(status="failed", calib=100.0), KEY: _row(calib=limit),
            KEY2: _row(calib=math.nextafter(limit, 2))}
    units = units[3:] + units[:3]  # the unit without a row first
    out = CheckResult()
    checks.latency_from_file(out, rows, units, DEFAULTS, "why: ")
    assert out.latency_mode == "file" and out.regressions == [] and out.per_unit == {}
    now = math.nextafter(limit, 2)
    assert out.notes == [_file_note("why: ", 1, 2, 1.3, f"cube pod {KEY2[2]}: 0.5 -> {now:.4g} (limit {limit:.4g})")]


def test_file_latency_raises_a_small_baseline_to_the_floor_first():
    defaults = {**DEFAULTS, "latency_floor": 0.1, "file_latency_tolerance": 2.0}
    units = [_unit(KEY, calib=0.01), _unit(KEY2, calib=0.5)]
    out = CheckResult()
    checks.latency_from_file(out, {KEY: _row(calib=0.2), KEY2: _row(calib=1.0)}, units, defaults, "")
    assert out.notes == [_file_note("", 0, 2, 2.0)]  # 0.2 <= max(0.01, 0.1) * 2; 1.0 <= 0.5 * 2
    checks.latency_from_file(out, {KEY: _row(calib=0.21), KEY2: _row(calib=1.01)}, units, defaults, "")
    assert out.notes[1] == _file_note("", 2, 2, 2.0, f"cube pod {KEY[2]}: 0.01 -> 0.21 (limit 0.2); "
                                                     f"cube pod {KEY2[2]}: 0.5 -> 1.01 (limit 1)")
    assert out.regressions == []


def test_file_latency_with_a_unit_tolerance_and_a_nan_now():
    units = [_unit(KEY, calib=1.0, file_latency_tolerance=3.0), _unit(KEY2, calib=1.0)]
    out = CheckResult()
    checks.latency_from_file(out, {KEY: _row(calib=2.9), KEY2: _row(calib=math.nan)}, units, DEFAULTS, "")
    assert out.notes == [_file_note("", 1, 2, 1.3, f"cube pod {KEY2[2]}: 1 -> nan (limit 1.3)")]  # NaN is not <=


def test_file_latency_lists_five_units_then_counts():
    keys = [("cube", "pod", f'{{"n":{i}}}') for i in range(7)]
    out = CheckResult()
    checks.latency_from_file(out, {k: _row(calib=9.0) for k in keys}, [_unit(k, calib=1.0) for k in keys],
                             DEFAULTS, "")
    assert out.notes[0].endswith("; 2 more)") and out.notes[0].count(" -> 9 ") == 5


# ---------------------------------------------------------------- latency, A/B (samples given)
def _samples(uid, ref_s, head_s, rounds=3, blocks=3):
    rows = [{"uid": uid, "side": side, "round": r, "block": b, "haptic_s": s}
            for side, s in (("ref", ref_s), ("head", head_s)) for r in range(rounds) for b in range(blocks)]
    return pd.DataFrame(rows)


def test_latency_ab_turns_verdicts_and_failures_into_findings(monkeypatch):
    k3 = ("c", "m", "{}")
    ok_rows = {KEY: _row(), KEY2: _row(), k3: _row(), ("d", "n", "{}"): _row()}
    seen = {}

    def ab_units(results_dir, table, workdir=None):
        seen["table"], seen["dir"] = table, results_dir
        return [type("U", (), {"uid": f"u{i}"})() for i in range(len(table))]

    def run_ab(ab, ref_root, head_root, decide, min_rounds, max_rounds, blocks, budget_s, inject=None, log=None,
               workdir=None):
        seen["args"] = (ref_root, head_root, min_rounds, max_rounds, blocks, budget_s, inject)
        seen["ab"], seen["log"] = ab, log
        seen["decide"] = decide
        samples = pd.concat([_samples("u0", 1e-3, 2e-3), _samples("u1", 1e-3, 1e-3)])
        return samples, {"u2": {"head": "h" * 200}, "u3": {"ref": "r" * 200}}

    monkeypatch.setattr(checks, "ab_units", ab_units)
    monkeypatch.setattr(checks, "run_ab", run_ab)
    logs = []
    units = [_unit(KEY, latency_tolerance=5.0)]  # KEY: 2x, within its own threshold sqrt(5)
    settings = ABSettings(min_rounds=2, max_rounds=5, blocks=4, budget_s=60.0, inject={KEY2: 1.5})
    out = CheckResult()
    samples = checks.latency_ab(out, "res", ok_rows, units, DEFAULTS, "R", "H", "main", settings, logs.append)
    assert list(seen["table"]["case"]) == ["cube", "cube", "c", "d"]
    assert list(seen["table"]["options"]) == [KEY[2], KEY2[2], "{}", "{}"]
    assert list(seen["table"]["method"]) == ["pod", "pod", "m", "n"] and seen["dir"] == "res"
    assert [u.uid for u in seen["ab"]] == ["u0", "u1", "u2", "u3"] and seen["log"] == logs.append
    assert seen["args"] == ("R", "H", 2, 5, 4, 60.0, {"u1": 1.5})
    assert logs == ["A/B latency: 4 units, main against this code, 2-5 rounds of 4 blocks"]
    assert out.latency_mode == "ab" and set(out.ab) == {KEY, KEY2}
    assert out.ab[KEY].verdict == "holds" and out.ab[KEY].threshold == pytest.approx(math.sqrt(5.0))
    assert out.ab[KEY2].verdict == "holds"
    assert [(f.options, f.metric, f.tolerance) for f in out.regressions] == [("{}", "latency_ab", f"fails under A/B: "
                                                                                                  f"{'h' * 120}")]
    assert out.regressions[0].case == "c" and math.isnan(out.regressions[0].baseline)
    assert math.isnan(out.regressions[0].now) and set(out.per_unit) == {KEY, KEY2, k3}
    assert out.notes == [f"d n {{}}: latency not compared: main's code cannot run it ({'r' * 120})"]
    assert list(samples["case"]) == ["cube"] * 36 and set(samples["options"]) == {KEY[2], KEY2[2]}
    assert set(samples["method"]) == {"pod"}
    assert seen["decide"](samples) == {"u0", "u1"}  # the per-unit tolerances: both decided


def test_latency_ab_flags_a_slowdown_beyond_the_default_tolerance(monkeypatch):
    monkeypatch.setattr(checks, "ab_units", lambda d, t, w=None: [type("U", (), {"uid": "u0"})()])
    monkeypatch.setattr(checks, "run_ab", lambda *a, **k: (_samples("u0", 1e-3, 2e-3), {}))
    out = CheckResult()
    checks.latency_ab(out, "res", {KEY: _row()}, [_unit(KEY)], DEFAULTS, "R", "H", "main", ABSettings(), print)
    v = out.ab[KEY]
    assert v.verdict == "slower" and v.ratio == pytest.approx(2.0)
    assert out.regressions == [Finding(*KEY, "latency_ab", 1.0, v.ratio, f"slower: {v.text()}")]
    assert set(out.per_unit) == {KEY}
    # the floor: a 1 ms increase under a 2 ms floor holds
    out = CheckResult()
    checks.latency_ab(out, "res", {KEY: _row()}, [_unit(KEY, latency_floor_s=2e-3)], DEFAULTS, "R", "H", "main",
                      ABSettings(), print)
    assert out.regressions == [] and out.ab[KEY].held_by_floor is True


def test_latency_ab_that_compared_nothing_is_an_error(monkeypatch):
    monkeypatch.setattr(checks, "ab_units", lambda d, t, w=None: [type("U", (), {"uid": "u0"})()])
    monkeypatch.setattr(checks, "run_ab", lambda *a, **k: (_samples("u0", 1e-3, 1e-3).iloc[:0], {"u0": {"ref": "x"}}))
    with pytest.raises(ValueError, match=r"^--against v2: the A/B compared no unit \(v2's code could run none of "
                                         r"them\)$"):
        checks.latency_ab(CheckResult(), "res", {KEY: _row()}, [], DEFAULTS, "R", "H", "v2", ABSettings(), print)


# ---------------------------------------------------------------- requirements
def test_a_requirement_met_at_its_boundary_and_missed_just_beyond():
    req = parse_requirement("rate>=1kHz, error<=1%")
    rows = {("zed", "m", "{}"): _row(error=0.001, p99=1e-4, label="z"),
            KEY: _row(error=0.01, p99=1e-3, label="pod n=2"), ("bar", "m", "{}"): _row(error=0.0101, p99=1e-3),
            ("bar", "n", "{}"): _row(error=0.001, p99=1.01e-3)}
    out = CheckResult()
    checks.requirement_met(out, rows, req, "max_rel_l2")
    assert out.notes == ["cube: pod n=2 meets 'rate>=1kHz, error<=1%' (margin 1)",
                         "zed: z meets 'rate>=1kHz, error<=1%' (margin 10)"]  # by case, sorted
    assert len(out.regressions) == 1
    f = out.regressions[0]
    assert (f.case, f.method, f.options, f.metric) == ("bar", "*", "*", "requirement") and math.isnan(f.baseline)
    assert f.now == pytest.approx(1 / 1.01)
    assert f.tolerance.startswith("no unit meets 'rate>=1kHz, error<=1%'; closest ")
    assert list(out.per_unit) == [("bar", "*", "*"), ("cube", "*", "*"), ("zed", "*", "*")]
