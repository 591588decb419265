"""An intended slowdown declared in the baseline file, in the commit that makes it
(``latency_change``, ``latency_change_reason``): the A/B of that commit expects the declared
factor, the next commit gates the unit at the normal tolerance again.

Fast and synthetic, as tests/studies/test_check_ab.py: REF is a git repository of two commits of
the baseline file (tests/_gate_repo.py), REF's sweep and the A/B's samples are faked (block
medians of a 1 ms step, HEAD's a given factor of REF's), and the gate's own wiring
(:func:`tissuebench.gate._against_ref`: the declaration read against the file at REF, the A/B's
verdicts, the notes) runs as it does in ``check --against``."""
from __future__ import annotations

import argparse
import re
import xml.etree.ElementTree as ET
from types import SimpleNamespace

import pandas as pd
import pytest

import tissuebench.gate as gate
from _gate_repo import commit, init
from tissuebench.cli import _print_check
from tissuebench.gate import ABSettings, BaselineError, CheckResult, checks, load_baseline, update_baseline, \
    write_junit
from tissuebench.gate.baseline import DEFAULTS
from tissuebench.gate.latency import SAMPLE_COLUMNS
from tissuebench.gate.stats import verdicts

KEY = ("cornea_pinch", "pod_newton", '{"n_modes":4}')
REASON = "mean-dilatation hexahedra: assembly ~2x Q1's"
DECLARED = f'latency_change = 2.2  # the next reference\nlatency_change_reason = "{REASON}"\n'


def _entry(extra: str = "") -> str:
    return (f'[[unit]]\ncase = "{KEY[0]}"\nmethod = "{KEY[1]}"\noptions = \'{KEY[2]}\'\nerror = 0.01\n'
            f"latency_per_calibration = 0.01\nlatency_per_reference = 0.001\nflagged_steps = 0\n{extra}")


def _file(extra: str = "") -> str:
    return f"# the gate's baseline\n[defaults]\nlatency_tolerance = 1.3\n\n{_entry(extra)}"


def _row():
    """A stored unit row as :func:`tissuebench.gate.io.read_gate_results` gives it (a 1 ms step)."""
    return {"unit_status": "ok", "message": "", "unit_key": "u", "error": 0.01, "haptic_per_calibration": 0.01,
            "reference_step_s": 1.0, "haptic_median_s": 1e-3, "n_failed": 0, "n_extrapolation": 0,
            "n_beyond_validity": 0, "n_not_reached": 0}


def _samples(factor: float) -> pd.DataFrame:
    """Four rounds of one 1 ms block per side, +-2 % apart, HEAD's ``factor`` times REF's."""
    ref, head = [1.00, 1.02, 0.99, 1.01], [1.01, 0.99, 1.00, 1.02]
    rows = [("u", side, r, 0, k, 1e-3 * f * v) for side, f, values in (("ref", 1.0, ref), ("head", factor, head))
            for r, v in enumerate(values) for k in range(3)]
    return pd.DataFrame(rows, columns=SAMPLE_COLUMNS)


@pytest.fixture
def gate_at(tmp_path, monkeypatch):
    """``gate_at(at_ref, now, factor)``: the check of a commit whose baseline file is ``now``
    against REF whose file is ``at_ref``, HEAD's step ``factor`` times REF's; the CheckResult."""
    def run(at_ref: str, now: str, factor: float) -> CheckResult:
        repo = init(tmp_path / f"repo{len(list(tmp_path.iterdir()))}")
        sha = commit(repo, {"baseline.toml": at_ref}, "REF")
        (repo / "baseline.toml").write_text(now)  # this commit's file: the working tree, as CI sweeps it
        results = repo / "results"
        results.mkdir()
        (results / "_sweep.json").write_text('{"spec_text": "", "resolution": "ci"}')
        defaults, units = load_baseline(repo / "baseline.toml")
        rows = {KEY: _row()}
        decided = []

        def run_ab(ab, ref_root, head_root, decide, *args, **kwargs):
            samples = _samples(factor)
            decided.append(decide(samples))  # the A/B's stopping rule sees the declaration too
            return samples, {}

        monkeypatch.setattr(gate, "run_ref_sweep", lambda *a: (True, ""))
        monkeypatch.setattr(gate, "read_gate_results", lambda folder: ({KEY: _row()}, "error"))
        monkeypatch.setattr(checks, "ab_units", lambda results_dir, table, workdir: [SimpleNamespace(uid="u")])
        monkeypatch.setattr(checks, "run_ab", run_ab)
        out = CheckResult()
        gate._against_ref(out, results, rows, rows, units, defaults, repo / "baseline.toml", repo, sha, "HEAD~1",
                          (repo, repo), tmp_path, ABSettings(), lambda m: None)
        assert decided == [{"u"}] and out.errors_against == "ref" and out.latency_mode == "ab"
        return out
    return run


def _latency(out: CheckResult) -> list:
    return [f for f in out.regressions if f.metric == "latency_ab"]


# ------------------------------------------------------------------------ the commit that declares it
@pytest.mark.parametrize("factor", [1.0, 2.2, 2.4])
def test_a_declared_slowdown_within_its_factor_passes_noted_with_ratio_interval_and_reason(gate_at, factor, tmp_path,
                                                                                         capsys):
    """Declared x2.2 at latency_tolerance 1.3: judged slower above 2.2 x sqrt(1.3) = 2.51 (the
    geometric midpoint between the declared factor and 2.2 x 1.3, as 1.14 is for no declaration)."""
    out = gate_at(_file(), _file(DECLARED), factor)
    assert out.ok, [f.line() for f in out.regressions]
    v = out.ab[KEY]
    assert v.expected == 2.2 and v.threshold == pytest.approx(2.2 * 1.3 ** 0.5) and v.decided
    note = next(n for n in out.notes if "latency_change" in n)
    assert re.fullmatch(rf"{re.escape(' '.join(KEY))}: latency HEAD/REF {factor:.3f} \[\d\.\d{{3}}, \d\.\d{{3}}\] "
                        r"against HEAD~1 \(\w{12}\), declared latency_change = 2\.2 by the baseline update of this "
                        r"commit: " + re.escape(REASON), note), note
    assert out.declared[KEY] == [note.split(": ", 1)[1]]
    # the JUnit file: the unit's test case passes and says what was declared
    write_junit(out, tmp_path / "gate.xml")
    case = ET.parse(tmp_path / "gate.xml").getroot().find("testcase")
    assert case.find("failure") is None and case.find("system-out").text == f"declared: {out.declared[KEY][0]}"
    # the summary line
    _print_check(out, argparse.Namespace(against="HEAD~1", baseline="baseline.toml", require=None))
    printed = capsys.readouterr().out
    assert f"; 1 declared slowdown (pod_newton x{v.ratio:.3g}, declared x2.2))" in printed
    assert f"note: {note}" in printed and "(declared x2.2: slower above 2.51)" in printed


@pytest.mark.parametrize("factor", [2.6, 2.86, 4.0])
def test_a_slowdown_beyond_the_declared_one_fails_naming_declared_and_measured(gate_at, factor):
    out = gate_at(_file(), _file(DECLARED), factor)
    (f,) = _latency(out)
    assert (f.baseline, round(f.now, 3)) == (2.2, factor)
    assert f.tolerance.startswith(f"slower than declared: measured HEAD/REF {factor:.3f} [")
    assert f"declared latency_change = 2.2 ({REASON}) x latency_tolerance 1.3" in f.tolerance
    assert not any("latency_change" in n for n in out.notes) and KEY not in out.declared


def test_an_edited_declaration_counts_and_the_floor_counts_beyond_the_declared_step(gate_at):
    """Raising 2.2 to 3.0 is a declaration of this commit (2.6 then holds); the floor is the
    increase beyond the declared step: 2.6x of 1 ms is 0.4 ms beyond 2.2x, not held by 1e-5 s,
    held by 1e-3 s."""
    raised = DECLARED.replace("2.2", "3.0")
    assert gate_at(_file(DECLARED), _file(raised), 2.6).ok
    assert not gate_at(_file(DECLARED), _file(DECLARED.replace("2.2", "2.0")), 2.6).ok
    held = gate_at(_file(), _file(DECLARED + "latency_floor_s = 1e-3\n"), 2.6)
    assert held.ok and held.ab[KEY].held_by_floor
    assert "(below the floor: +399 us beyond the declared < 1e+03 us)" in held.ab[KEY].text()
    assert not gate_at(_file(), _file(DECLARED + "latency_floor_s = 1e-4\n"), 2.6).ok


# ------------------------------------------------------------------------ no declaration, or an old one
@pytest.mark.parametrize("factor, slower", [(1.0, False), (1.1, False), (1.2, True), (2.0, True)])
def test_an_undeclared_slowdown_is_gated_as_before(gate_at, factor, slower):
    out = gate_at(_file(), _file(), factor)
    assert [f.baseline for f in _latency(out)] == ([1.0] if slower else [])
    assert out.ab[KEY].expected == 1.0 and not out.declared and not out.declared_slowdowns


@pytest.mark.parametrize("factor, slower", [(1.1, False), (2.0, True)])
def test_a_declaration_unchanged_against_ref_is_ignored(gate_at, factor, slower):
    """The commit after the one that declared it: the entry equals REF's, the normal tolerance
    applies (a 2x slowdown fails as undeclared), the keys need not be removed."""
    out = gate_at(_file(DECLARED), _file(DECLARED), factor)
    assert out.ab[KEY].expected == 1.0 and not any("latency_change" in n for n in out.notes)
    assert [(f.baseline, f.tolerance.split(":")[0]) for f in _latency(out)] == ([(1.0, "slower")] if slower else [])


def test_what_a_commit_declares_is_its_file_against_the_file_at_ref(tmp_path):
    """``_declared``: an entry added with a declaration (no file at REF) declares both; an error
    edited alone declares no slowdown; a reason edited alone is an edit of the declaration."""
    repo = init(tmp_path / "repo")
    empty = commit(repo, {"other.txt": "x"}, "no baseline yet")
    plain = commit(repo, {"baseline.toml": _file()}, "baseline")
    declared = commit(repo, {"baseline.toml": _file(DECLARED)}, "declared")

    def what(sha, text):
        (repo / "baseline.toml").write_text(text)
        return gate._declared(repo, sha, repo / "baseline.toml", load_baseline(repo / "baseline.toml")[1])

    assert what(empty, _file(DECLARED)) == ({KEY}, {KEY: (2.2, REASON)})
    assert what(plain, _file(DECLARED)) == (set(), {KEY: (2.2, REASON)})
    assert what(declared, _file(DECLARED)) == (set(), {})
    assert what(declared, _file(DECLARED).replace("error = 0.01", "error = 0.02")) == ({KEY}, {})
    assert what(declared, _file(DECLARED.replace("~2x", "about 2x"))) == (set(), {KEY: (2.2, REASON.replace(
        "~2x", "about 2x"))})
    assert gate._declared(repo, declared, tmp_path / "outside.toml", []) == (set(), {})


def load_baseline_text(text: str) -> list:
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        (Path(tmp) / "b.toml").write_text(text)
        return load_baseline(Path(tmp) / "b.toml")[1]


# ------------------------------------------------------------------------ file mode: shown, nothing else
def test_without_ref_a_declaration_is_shown_and_changes_nothing():
    units = load_baseline_text(_file(DECLARED))
    rows = {KEY: {**_row(), "haptic_per_calibration": 0.05}}  # 5x the file's ratio
    out = CheckResult()
    checks.latency_from_file(out, rows, units, dict(DEFAULTS), "no --against: ")
    plain = CheckResult()
    checks.latency_from_file(plain, rows, load_baseline_text(_file()), dict(DEFAULTS), "no --against: ")
    assert out.ok and out.notes[1:] == plain.notes and not out.declared
    assert out.notes[0] == (f"{' '.join(KEY)}: the baseline declares latency_change = 2.2 ({REASON}): used only by "
                            "the A/B (--against REF) of the commit that adds or edits it")
    assert "1 of 1 units above x1.3" in out.notes[1]


# ------------------------------------------------------------------------ the file: checked, kept
@pytest.mark.parametrize("extra, message", [
    ("latency_change = 0.5\n", "latency_change = 0.5: must be > 1"),
    ("latency_change = 1.0\n", "latency_change = 1.0: must be > 1"),
    ('latency_change = "x"\n', "latency_change = 'x': expected a number"),
    ("latency_change = inf\n", "latency_change = inf: must be a finite number"),
    ("latency_change = 2.2\n", "latency_change_reason: missing, required with latency_change = 2.2"),
    ('latency_change = 2.2\nlatency_change_reason = ""\n', "latency_change_reason = '': expected a non-empty"),
    ('latency_change = 2.2\nlatency_change_reason = "  "\n', "latency_change_reason = '  ': expected a non-empty"),
    ("latency_change = 2.2\nlatency_change_reason = 3\n", "latency_change_reason = 3: expected a non-empty"),
    ('latency_change_reason = "faster"\n', "latency_change_reason = 'faster': needs latency_change"),
])
def test_a_bad_declaration_is_refused_naming_the_key_the_unit_and_the_value(tmp_path, extra, message):
    bad = tmp_path / "bad.toml"
    bad.write_text(_file(extra))
    with pytest.raises(BaselineError, match=re.escape(f"unit[0] ({' '.join(KEY)}).{message}")):
        load_baseline(bad)


@pytest.mark.parametrize("factor", ["1.0001", "2.2", "1000"])
def test_a_declaration_above_1_with_a_reason_is_read(tmp_path, factor):
    good = tmp_path / "good.toml"
    good.write_text(_file(f'latency_change = {factor}\nlatency_change_reason = "x"\n'))
    (unit,) = load_baseline(good)[1]
    assert (unit["latency_change"], unit["latency_change_reason"]) == (float(factor), "x")


def test_update_baseline_keeps_a_declaration_and_its_comments(tmp_path):
    path = tmp_path / "baseline.toml"
    path.write_text(_file(DECLARED))
    new = {"case": KEY[0], "method": KEY[1], "options": KEY[2], "error": 0.02, "latency_per_calibration": 0.02,
           "latency_per_reference": 0.002, "flagged_steps": 0}
    assert update_baseline({KEY: new}, path) == 1
    text = path.read_text()
    assert "latency_change = 2.2  # the next reference\n" in text and f'latency_change_reason = "{REASON}"' in text
    (unit,) = load_baseline(path)[1]
    assert (unit["error"], unit["latency_change"], unit["latency_change_reason"]) == (0.02, 2.2, REASON)


def test_the_stopping_rule_and_the_verdict_share_the_declared_factor():
    """:func:`.stats.verdicts` with ``expected``: 2x holds against a declared 2.2, is slower
    without; faster still means faster than REF."""
    s = _samples(2.0)
    assert verdicts(s, 1.3, expected={"u": 2.2})["u"].verdict == "holds"
    assert verdicts(s, 1.3)["u"].verdict == "slower"
    assert verdicts(_samples(0.8), 1.3, expected={"u": 2.2})["u"].verdict == "faster"
    assert verdicts(_samples(1.0), 1.3, expected={"u": 2.2})["u"].verdict == "holds"
