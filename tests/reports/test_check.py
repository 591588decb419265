"""The regression gate ``tissuebench check``: errors gated exactly, latency against the baseline
file (file mode), requirements, and no vacuous pass. The A/B mode is in test_check_ab.py."""
from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import xml.etree.ElementTree as ET

import pandas as pd
import pytest
import tomlkit

from tissuebench.cli import main
from tissuebench.gate import BaselineError, baseline_rows, check, load_baseline, update_baseline
from tissuebench.gate.scratch import clean_stale_scratch, ref_scratch
from tissuebench.studies.spec import load_spec
from tissuebench.studies.sweep import run_sweep

from _gate_spec import SPEC

HEADER = "# gate test baseline: a comment that --update-baseline must keep\n"


@pytest.fixture(scope="module")
def gated(tmp_path_factory):
    folder = tmp_path_factory.mktemp("gate")
    spec = folder / "gate.toml"
    spec.write_text(SPEC)
    out = folder / "base"
    run_sweep(load_spec(spec), out, progress=False)
    baseline = folder / "baseline.toml"
    baseline.write_text(HEADER)
    assert update_baseline(baseline_rows(out)[0], baseline) == 2
    return spec, out, baseline


def _copy_store(out, tmp_path, name="copy"):
    import shutil

    dest = tmp_path / name
    shutil.copytree(out, dest)
    return dest


def _edit_rows(store, method="*", **scale):
    """Multiply columns of the unit row files of ``method`` in ``store`` (``scale``: column ->
    factor or callable), written back with the store's own schema."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    for f in store.glob(f"case=*/method={method}/*.parquet"):
        table = pq.read_table(f)
        t = table.to_pandas()
        for col, how in scale.items():
            t[col] = how(t) if callable(how) else t[col] * how
        pq.write_table(pa.Table.from_pandas(t, schema=table.schema, preserve_index=False), f)


def test_a_run_holds_against_its_own_baseline_and_the_file_keeps_its_comments(gated, capsys):
    _, out, baseline = gated
    assert main(["check", str(out), "--baseline", str(baseline)]) == 0
    text = capsys.readouterr().out
    assert "2 units hold" in text and "latency not gated (no REF" in text
    assert baseline.read_text().startswith("# gate test baseline")
    defaults, units = load_baseline(baseline)
    assert defaults["error_rtol"] == 1e-3 and defaults["latency_tolerance"] == 1.3 and defaults["latency_floor"] == 0
    assert {u["method"] for u in units} == {"anm_pod", "pod_interp"}


@pytest.mark.parametrize("factor, above", [(1.2, 0), (2.0, 2)])
def test_file_mode_latency_is_information_never_a_regression(gated, tmp_path, capsys, factor, above):
    """A baseline file's latency ratios move 2-3x between runs of identical code for microsecond
    steps: a user's gate failed 5 of 9 runs of identical code on them (x1.3, the tolerance
    --update-baseline wrote). Without REF they are noted for information (the units above x1.3
    named), never a regression; the errors are still gated exactly."""
    _, out, baseline = gated
    moved = _copy_store(out, tmp_path)
    cols = ["haptic_median_s", "haptic_p99_s", "haptic_per_calibration", "reconstruct_median_s", "reconstruct_p99_s"]
    _edit_rows(moved, **{c: factor for c in cols})
    result = check(moved, baseline)
    assert result.ok and result.latency_mode == "file", [f.line() for f in result.regressions]
    note = next(n for n in result.notes if "latency not gated" in n)
    assert f"{above} of 2 units above x1.3 of the file's ratio" in note
    assert ("anm_pod" in note and "pod_interp" in note) == bool(above)
    assert main(["check", str(moved), "--baseline", str(baseline)]) == 0
    assert "latency not gated (no REF" in capsys.readouterr().out
    _edit_rows(moved, "pod_interp", max_rel_l2=1.01)  # errors are gated as before
    assert [(f.method, f.metric) for f in check(moved, baseline).regressions] == [("pod_interp", "error")]


def test_a_new_baseline_says_what_its_latency_keys_are_and_how_to_set_the_floor(gated, tmp_path):
    _, out, _ = gated
    fresh = tmp_path / "fresh.toml"
    update_baseline(baseline_rows(out)[0], fresh)
    text = fresh.read_text()
    floor_line = next(line for line in text.splitlines() if line.startswith("latency_floor_s"))
    assert "1e-05" in floor_line and "microsecond ROM: 0" in floor_line and "--latency-floor-s" in floor_line
    assert "information only, never gated" in next(ln for ln in text.splitlines() if ln.startswith("file_latency_tol"))
    assert load_baseline(fresh)[0]["latency_floor_s"] == 1e-5


def test_a_one_percent_error_change_on_one_unit_fails(gated, tmp_path):
    _, out, baseline = gated
    worse = _copy_store(out, tmp_path)
    assert all(pd.read_parquet(f)["max_rel_l2"].iloc[0] > 1e-6 for f in worse.glob("case=*/method=pod_interp/*"))
    _edit_rows(worse, "pod_interp", max_rel_l2=1.01)  # not anm_pod: exact here (1e-12, round-off)
    assert main(["check", str(worse), "--baseline", str(baseline)]) == 1
    result = check(worse, baseline)
    assert [(f.method, f.metric) for f in result.regressions] == [("pod_interp", "error")]
    assert "update the baseline in the same commit" in result.regressions[0].tolerance
    # an improvement is a change too: the baseline must stay exact
    better = _copy_store(out, tmp_path, "better")
    _edit_rows(better, "pod_interp", max_rel_l2=0.9)
    assert [(f.method, f.metric) for f in check(better, baseline).regressions] == [("pod_interp", "error")]


def test_flagged_steps_may_not_grow(gated, tmp_path):
    _, out, baseline = gated
    edited = tmp_path / "fewer.toml"
    edited.write_text(re.sub(r"flagged_steps = \d+", "flagged_steps = 0", baseline.read_text()))
    result = check(out, edited)
    assert sorted(f.method for f in result.regressions if f.metric == "flagged_steps") == ["anm_pod", "pod_interp"]


def test_a_missing_unit_is_a_regression_and_options_compare_parsed(gated, tmp_path):
    _, out, baseline = gated
    doc = tomlkit.parse(baseline.read_text())
    first = doc["unit"][0]
    first["options"] = json.dumps(dict(reversed(list(json.loads(first["options"]).items()))))  # other key order
    doc["unit"][1]["method"] = "podi"
    edited = tmp_path / "edited.toml"
    edited.write_text(tomlkit.dumps(doc))
    result = check(out, edited)
    assert [(f.method, f.metric) for f in result.regressions] == [("podi", "unit")]
    assert [k[1] for k in result.new_units] == ["pod_interp"]


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("error_rtol = 0.001", 'error_rtol = "a"'), "defaults.error_rtol = 'a': expected a number"),
    (lambda t: t.replace("error_rtol = 0.001", "error_rtol = -0.1"), "defaults.error_rtol = -0.1: must be >= 0"),
    (lambda t: t.replace("latency_tolerance = 1.3", "latency_tolerance = -2"), "latency_tolerance = -2: must be > 1"),
    (lambda t: t.replace("latency_tolerance = 1.3", "latency_tolerance = 1"), "latency_tolerance = 1: must be > 1"),
    (lambda t: t.replace("[defaults]", "[defaults]\nspeed = 1"), "defaults.speed: unknown key"),
    (lambda t: t.replace("flagged_steps = ", "flagged_stepz = ", 1), r"unit\[0\].flagged_steps: missing"),
    (lambda t: re.sub(r"flagged_steps = \d+", "flagged_steps = -1", t, count=1), r"flagged_steps = -1: must be >= 0"),
    (lambda t: re.sub(r"\nerror = [^\n]+", "\nerror = -0.5", t, count=1), r"unit\[0\].error = -0.5: must be >= 0"),
    (lambda t: t + "\n[[unit]]\ncase = 5\n", r"unit\[2\].case"),
    (lambda t: t + "\n[oops\n", "not valid TOML"),
    (lambda t: t[:t.index("[[unit]]")], "has no \\[\\[unit\\]\\]"),
    (lambda t: t + "\n" + t[t.index("[[unit]]"):], r"the same unit as unit\[0\]"),
    (lambda t: t.replace('options = "{', 'options = "not json{', 1), "not JSON"),
    # issue 37: an infinite baseline value or tolerance made the gate pass anything
    (lambda t: re.sub(r"\nerror = [^\n]+", "\nerror = inf", t, count=1), r"unit\[0\].error = inf: must be a finite"),
    (lambda t: re.sub(r"latency_per_calibration = [^\n]+", "latency_per_calibration = inf", t, count=1),
     r"unit\[0\].latency_per_calibration = inf: must be a finite"),
    (lambda t: t.replace("error_atol = 1e-09", "error_atol = inf"), r"defaults.error_atol = inf: must be a finite"),
])
def test_a_bad_baseline_exits_2_naming_the_key(gated, tmp_path, capsys, edit, message):
    _, out, baseline = gated
    bad = tmp_path / "bad.toml"
    bad.write_text(edit(baseline.read_text()))
    with pytest.raises(BaselineError, match=message):
        load_baseline(bad)
    assert main(["check", str(out), "--baseline", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "tissuebench: error:" in err and "Traceback" not in err


def test_no_vacuous_pass(gated, tmp_path, capsys):
    _, out, baseline = gated
    # a baseline whose units are all elsewhere: nothing compared
    other = tmp_path / "other.toml"
    other.write_text(baseline.read_text().replace('case = "cornea_pinch"', 'case = "liver"'))
    assert main(["check", str(out), "--baseline", str(other)]) == 2
    assert "0 compared" in capsys.readouterr().err
    # every unit failed: a regression, and no baseline is written from it
    failed = _copy_store(out, tmp_path, "failed")
    _edit_rows(failed, unit_status=lambda t: "failed")
    assert main(["check", str(failed), "--baseline", str(baseline)]) == 1
    assert "all 2 units of the sweep failed" in capsys.readouterr().out
    before = baseline.read_text()
    assert main(["check", str(failed), "--baseline", str(baseline), "--update-baseline"]) == 2
    assert baseline.read_text() == before
    assert main(["check", str(out)]) == 2  # nothing asked for


def test_a_unit_with_an_infinite_error_is_left_out_of_the_baseline_and_said(gated, tmp_path, capsys):
    """The other side of the finite rule: --update-baseline never writes what load_baseline refuses."""
    _, out, _ = gated
    store = _copy_store(out, tmp_path, "inf")
    _edit_rows(store, method="pod_interp", max_rel_l2=lambda t: float("inf"))
    kept, left = baseline_rows(store)
    assert [k[1] for k in kept] == ["anm_pod"]
    assert [(k[1], why[:9]) for k, why in left] == [("pod_interp", "error inf")]
    fresh = tmp_path / "fresh.toml"
    assert main(["check", str(store), "--baseline", str(fresh), "--update-baseline"]) == 0
    assert "pod_interp" in capsys.readouterr().out
    assert [u["method"] for u in load_baseline(fresh)[1]] == ["anm_pod"]


def test_update_baseline_is_atomic(gated, tmp_path, monkeypatch):
    _, out, baseline = gated
    target = tmp_path / "b.toml"
    target.write_text(baseline.read_text())
    before = target.read_text()

    def killed(src, dst):  # the process dies between writing the temporary file and the rename
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", killed)
    with pytest.raises(KeyboardInterrupt):
        update_baseline(baseline_rows(out)[0], target)
    assert target.read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["b.toml"]  # no temporary left beside it


def test_unwritable_outputs_exit_2(gated, tmp_path, capsys):
    """A --junit that cannot be a file is refused before the check runs (issue 37: before an
    A/B's minutes); tests/cli/test_file_safety.py has the devices, FIFOs and links."""
    _, out, baseline = gated
    folder = tmp_path / "adir"
    folder.mkdir()
    assert main(["check", str(out), "--baseline", str(baseline), "--junit", str(folder)]) == 2
    captured = capsys.readouterr()
    assert "units hold" not in captured.out and f"--junit {folder}: is a folder" in captured.err
    assert main(["check", str(out), "--baseline", str(folder), "--update-baseline"]) == 2
    assert "not a file" in capsys.readouterr().err


def test_junit_has_one_case_per_unit(gated, tmp_path):
    _, out, baseline = gated
    junit = tmp_path / "gate.xml"
    worse = _copy_store(out, tmp_path)
    _edit_rows(worse, n_failed=lambda t: t["n_failed"] + 1)
    assert main(["check", str(worse), "--baseline", str(baseline), "--junit", str(junit)]) == 1
    suite = ET.parse(junit).getroot()
    assert suite.get("tests") == "2" and suite.get("failures") == "2"


@pytest.mark.parametrize("manifest, message", [
    ("[1, 2]", "expected a JSON object"),
    ('{"error_metric": "nope"}', "error_metric = 'nope'"),
    ('{"error_metric": "n_dof"}', "error_metric = 'n_dof'"),
    ('{"error_metric": "max_rel', "not valid JSON"),
])
def test_a_tampered_manifest_exits_2_naming_the_file(gated, tmp_path, capsys, manifest, message):
    _, out, baseline = gated
    bad = _copy_store(out, tmp_path)
    (bad / "_sweep.json").write_text(manifest)
    assert main(["check", str(bad), "--baseline", str(baseline)]) == 2
    err = capsys.readouterr().err
    assert message in err and "_sweep.json" in err and "Traceback" not in err


def test_a_foreign_parquet_file_in_the_store_is_named(gated, tmp_path, capsys):
    _, out, baseline = gated
    bad = _copy_store(out, tmp_path)
    stray = bad / "case=cornea_pinch" / "method=anm_pod" / "stray.parquet"
    pd.DataFrame({"x": [1, 2]}).to_parquet(stray)
    assert main(["check", str(bad), "--baseline", str(baseline)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "Traceback" not in err


def test_require_fails_when_no_unit_of_a_case_meets_it(gated, capsys):
    _, out, _ = gated
    assert main(["check", str(out), "--require", "rate>=10Hz, error<=50%"]) == 0
    assert "meets 'rate>=10Hz, error<=50%'" in capsys.readouterr().out
    assert main(["check", str(out), "--require", "rate>=1000kHz"]) == 1  # a 1 us p99 step: nobody
    text = capsys.readouterr().out
    assert "requirement" in text and "no unit meets 'rate>=1000kHz'" in text
    assert main(["check", str(out), "--require", "speed>=1"]) == 2


def _git(cwd, *args):
    subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True)


def _repo(root, files: dict, commits: int = 1):
    """A git repository at ``root`` with ``files`` (path -> text) committed ``commits`` times."""
    root.mkdir(parents=True)
    _git(root, "init", "-q")
    _git(root, "config", "user.email", "t@t")
    _git(root, "config", "user.name", "t")
    for k in range(commits):
        for name, text in files.items():
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_text(text)
        (root / "round.txt").write_text(str(k))
        _git(root, "add", ".")
        _git(root, "commit", "-qm", f"c{k}")
    return root


def test_a_ref_git_cannot_resolve_exits_2_even_with_a_baseline(gated, tmp_path, capsys, monkeypatch):
    """A mistyped REF once fell back to the baseline file and passed (exit 0): the fallback is the
    shallow clone's only."""
    _, out, baseline = gated
    repo = _repo(tmp_path / "repo", {"tissuebench/__init__.py": ""}, commits=2)
    with pytest.raises(ValueError, match=rf"--against = 'HEAD~zz': not a commit of the repository {repo} .*; the "
                                         r"project under test: given by --project \(--project PATH for another\)"):
        check(out, baseline, against="HEAD~zz", project=repo)
    (tmp_path / "plain").mkdir()
    with pytest.raises(ValueError, match=rf"--project = '{tmp_path / 'plain'}': not inside a git checkout"):
        check(out, baseline, against="HEAD~1", project=tmp_path / "plain")
    with pytest.raises(ValueError, match="--against = '--output=x': expected a git ref"):
        check(out, baseline, against="--output=x", project=repo)
    assert main(["check", str(out), "--baseline", str(baseline), "--against", "HEAD~zz"]) == 2
    captured = capsys.readouterr()
    assert "tissuebench: error: --against = 'HEAD~zz': " in captured.err and captured.err.count("\n") == 1
    assert "hold" not in captured.out
    # no --project: the working directory's repository (the sweep runs tissuebench's methods only), named
    monkeypatch.chdir(repo)
    assert main(["check", str(out), "--baseline", str(baseline), "--against", "HEAD~zz"]) == 2
    assert (f"not a commit of the repository {repo} (a branch, tag or commit that git rev-parse resolves there, e.g. "
            "HEAD~1); the project under test: the working directory's repository") in capsys.readouterr().err


def test_the_options_of_the_project_under_test_are_checked_naming_them(gated, tmp_path, capsys):
    _, out, baseline = gated
    assert main(["check", str(out), "--baseline", str(baseline), "--project", str(tmp_path)]) == 2
    assert "--project = " in capsys.readouterr().err  # only with --against
    for bad in ("-1", "nan", "inf"):
        assert main(["check", str(out), "--baseline", str(baseline), "--latency-floor-s", bad]) == 2
        err = capsys.readouterr().err
        assert f"--latency-floor-s = {float(bad)!r}: expected seconds >= 0" in err and err.count("\n") == 1
    assert main(["check", str(out), "--baseline", str(baseline), "--latency-floor-s", "0"]) == 0


def test_the_verdict_line_says_when_the_floor_held_a_slower_ratio(capsys):
    """held_by_floor was recorded (ab_verdicts.parquet) but never printed: a 1.5x slowdown of a
    6 us step passed the 10 us floor and the terminal said only that every unit held."""
    import argparse

    from tissuebench.cli import _print_check
    from tissuebench.gate import CheckResult
    from tissuebench.gate.stats import ABVerdict

    result = CheckResult(latency_mode="ab", errors_against="ref")
    for method, held in (("pod_polyreg", True), ("pod_interp", False)):
        key = ("cornea_pinch", method, "{}")
        result.add(key)
        result.ab[key] = ABVerdict("u", 1.5 if held else 1.0, 1.4, 1.6, 6e-6, 9e-6 if held else 6e-6, 3, 3, 1.14,
                                   "holds", True, 1e-5, held)
    result.new_units = sorted(result.ab)
    args = argparse.Namespace(against="HEAD~1", baseline=None, require=None)
    _print_check(result, args)
    text = capsys.readouterr().out
    assert "check: 2 units hold (errors against HEAD~1, latency A/B against HEAD~1; 1 unit slower by ratio but held " \
           "by the latency floor (10 us: pod_polyreg; --latency-floor-s 0 gates microsecond steps))" in text
    assert "is not in the baseline" not in text  # no baseline given: nothing to add to one
    result.ab[("cornea_pinch", "pod_polyreg", "{}")] = result.ab[("cornea_pinch", "pod_interp", "{}")]
    _print_check(result, args)
    assert "floor" not in capsys.readouterr().out


def test_check_help_says_how_latency_is_gated_and_what_the_floor_is(capsys):
    with pytest.raises(SystemExit):
        main(["check", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "printed for information, never gated" in text and "--latency-floor-s 0" in text
    assert "latency_floor_s [s] (default 1e-5: 10 us" in text and "For a microsecond ROM" in text
    assert "--project PATH" in text and "plugin methods' package" in text


def test_only_a_shallow_clone_that_lacks_ref_falls_back_to_the_file(gated, tmp_path):
    _, out, baseline = gated
    repo = _repo(tmp_path / "repo", {"tissuebench/__init__.py": ""}, commits=2)
    shallow = tmp_path / "shallow"
    _git(tmp_path, "clone", "-q", "--depth", "1", f"file://{repo}", str(shallow))
    result = check(out, baseline, against="HEAD~1", project=shallow)
    assert result.ok and result.latency_mode == "file" and result.errors_against == "baseline"
    assert any(f"HEAD~1 is not in the history of {shallow}, a shallow clone: falling back to the baseline file" in n
               for n in result.notes), result.notes
    with pytest.raises(ValueError, match="no --baseline to fall back to"):
        check(out, None, against="HEAD~1", project=shallow)


def test_a_ref_whose_code_does_not_import_exits_2_saying_so(gated, tmp_path):
    """Such a REF once ran its sweep (exit 1, no results) and the gate noted that its results could
    not be read, then passed on the baseline file."""
    _, out, baseline = gated
    repo = _repo(tmp_path / "repo", {"tissuebench/__init__.py": "def broken(:\n    pass\n"})
    with pytest.raises(ValueError, match=r"--against HEAD: REF's code \([0-9a-f]{12}\) failed to import: "
                                         r"SyntaxError: .*; REF cannot run the sweep"):
        check(out, baseline, against="HEAD", project=repo, log=lambda m: None)


# REF's code for the kill test: its sweep says where it runs, then waits (the check is killed meanwhile)
SLEEPING_REF = {
    "tissuebench/__init__.py": "",
    "tissuebench/rom/__init__.py": "METHODS = {'anm_pod': None, 'pod_interp': None}\n",
    "tissuebench/studies/__init__.py": "",
    "tissuebench/studies/sweep.py": "",
    "tissuebench/cli.py": (
        "import os, time\n"
        "if __name__ == '__main__':\n"
        "    path = os.environ['TB_REF_SWEEP_PID']\n"
        "    with open(path + '.tmp', 'w') as fh:\n"
        "        fh.write(str(os.getpid()))\n"
        "    os.replace(path + '.tmp', path)\n"
        "    time.sleep(600)\n"),
}
CHECK = "import sys; from tissuebench.gate import check; check(sys.argv[1], None, against='HEAD', " \
        "project=sys.argv[2], log=lambda m: None)"


def _running(pid: int) -> bool:
    """Process ``pid`` exists and is not a zombie (an orphan's zombie waits for whoever adopts it)."""
    try:
        stat = open(f"/proc/{pid}/stat").read()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] not in "ZX"


def _wait_for(condition, seconds: float, what: str) -> None:
    """Poll ``condition`` until true; fail after ``seconds`` (a guard against a hang, not a timing)."""
    deadline = time.monotonic() + seconds
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.1)


@pytest.mark.slow  # a check process started and killed (about 5 s); the rules: test_check_ab.py
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the children die with the check on Linux only")
def test_a_killed_check_leaves_no_ref_sweep_running_and_the_next_removes_its_folder(gated, tmp_path):
    """SIGKILL of ``check --against`` while REF's sweep runs: the REF sweep dies with it (it once
    ran on, orphaned), and its scratch folder (once left for good, 2.6 MB a run) is removed by the
    next check, which leaves a live run's alone."""
    _, out, _ = gated
    repo = _repo(tmp_path / "repo", SLEEPING_REF)
    scratch, pid_file = tmp_path / "tmp", tmp_path / "ref-sweep.pid"
    scratch.mkdir()
    env = {**os.environ, "TMPDIR": str(scratch), "TB_REF_SWEEP_PID": str(pid_file)}
    with open(tmp_path / "check.err", "w") as err:
        proc = subprocess.Popen([sys.executable, "-c", CHECK, str(out), str(repo)], env=env, stderr=err)
    try:
        _wait_for(lambda: pid_file.exists() or proc.poll() is not None, 300, "REF's sweep never started")
        assert proc.poll() is None, (tmp_path / "check.err").read_text()
        ref_pid = int(pid_file.read_text())
        folders = list(scratch.glob("tissuebench-ref.*"))
        assert len(folders) == 1 and json.loads((folders[0] / "owner.json").read_text())["pid"] == proc.pid
        assert _running(ref_pid)
    finally:
        proc.kill()
        proc.wait()
    _wait_for(lambda: not _running(ref_pid), 120, "REF's sweep outlived the killed check")
    assert folders[0].is_dir()  # nothing runs at a SIGKILL: the next check cleans up
    said = []
    with ref_scratch(log=said.append, base=scratch) as live:  # the next check
        assert not folders[0].exists() and folders[0].name in said[0] and live.parent == scratch
        assert clean_stale_scratch(scratch) == [] and live.is_dir()  # a live check's folder is kept
    assert not live.exists()
