"""``check --against REF`` refuses, before any REF work, what would make it pass vacuously or fail
at its end (issue 50, items 4 and 6), fast: REF's stage (``_with_ref``: the export, REF's sweep,
the A/B) is replaced by a recorder, so each test says whether the check got there.

* A ``--project`` that holds none of the sweep's methods (the plugin imported from a folder
  outside it, tissuebench's own methods from tissuebench) timed the same code on both sides and
  passed ("1 units hold"): refused, naming where each method's code comes from. The repository
  that holds the plugin passes, the shipped method said in a note.
* ``--junit nodir/x.xml`` was refused only after REF's sweep and the whole A/B; a ``_gate`` in
  RESULTS that is not a folder lost the A/B's files at the end. Both refused before REF's stage.
* ``ci/gate.sh`` passes its baseline file (``BASELINE``, default ``ci/baseline.toml``) when it
  exists, and prints the command that records an intended change in it (end to end:
  tests/studies/test_gate_own_repo.py, slow).
"""
from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

import tissuebench.gate as gate
from tissuebench.cli import main
from tissuebench.gate import HEAD_ROOT, check

from _gate_repo import readme_history, recipe_calls, recipe_env, recipe_repo
from _gate_spec import cornea_spec
from _plugin_dist import Installed, toy_source, write_dist

SPEC = cornea_spec("scope", ["tb_scope_plug", "nearest"])


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    """``(results, site)``: a sweep of a plugin method (distribution tb-scope 0.1, module
    ``tb_scope`` in ``site``, a git repository of two commits) beside a shipped one."""
    import tissuebench.reports.derived_figures as figures

    root = tmp_path_factory.mktemp("scope")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(figures, "draw_derived", lambda *args, **kwargs: [])  # seconds of matplotlib, not tested here
        installed = Installed(root / "site", mp)
        write_dist(installed.root, "tb-scope", "0.1", {"tb_scope_plug": "tb_scope:Toy"},
                   {"tb_scope": toy_source("tb_scope_plug")})
        readme_history(installed.root)
        spec = root / "scope.toml"
        spec.write_text(SPEC)
        assert main(["sweep", str(spec), "--out", str(root / "res"), "--quiet"]) == 0
        yield root / "res", installed.root
        installed.undo()


@pytest.fixture
def ref_stage(monkeypatch):
    """The calls that reached REF's stage (export, REF's sweep, A/B), which does nothing here."""
    calls = []
    monkeypatch.setattr(gate, "_with_ref", lambda out, proj, *args, **kwargs: calls.append(proj))
    return calls


def test_a_project_that_holds_none_of_the_methods_is_refused_saying_where_they_come_from(store, ref_stage, tmp_path,
                                                                                         capsys):
    results, site = store
    empty = readme_history(tmp_path / "empty")
    assert main(["check", str(results), "--against", "HEAD~1", "--project", str(empty)]) == 2
    out, err = capsys.readouterr()
    assert ref_stage == [] and "units hold" not in out  # before REF's export, sweep and A/B
    assert (f"tissuebench: error: --against HEAD~1: method 'tb_scope_plug' is imported from {site / 'tb_scope.py'} "
            f"(distribution tb-scope 0.1); method 'nearest' is tissuebench's own, imported from "
            f"{HEAD_ROOT / 'tissuebench'} (tissuebench {_version()}), which are not inside --project "
            f"{empty.resolve()}: REF's export of {empty.resolve()} at HEAD~1 would run the same code on both sides "
            "(every unit would hold whatever changed); give --project a path in the git repository holding the "
            "source of the code under test") in err


def test_the_repository_that_holds_the_plugin_passes_the_scope_check_the_shipped_method_noted(store, ref_stage):
    results, site = store
    result = check(results, None, against="HEAD~1", project=site, log=lambda m: None)
    assert [p.repo for p in ref_stage] == [site.resolve()]  # REF's stage reached
    assert [p.name for p in ref_stage[0].packages] == ["tb_scope"]
    assert result.notes == ["not code of the project under test, the same on both sides (their errors and steps are "
                            f"compared with themselves): method 'nearest' is tissuebench's own, imported from "
                            f"{HEAD_ROOT / 'tissuebench'} (tissuebench {_version()})"]
    # found without --project (the plugin's repository): the same
    ref_stage.clear()
    check(results, None, against="HEAD~1", log=lambda m: None)
    assert [p.repo for p in ref_stage] == [site.resolve()]


def _version() -> str:
    from tissuebench.gate.project import _installed_version

    return _installed_version("tissuebench")


def test_output_paths_are_refused_before_any_ref_work(store, ref_stage, tmp_path, capsys):
    results, site = store
    work = tmp_path / "copy"
    shutil.copytree(results, work)
    nodir = tmp_path / "nodir" / "x.xml"
    args = ["check", str(work), "--against", "HEAD~1", "--project", str(site)]
    assert main([*args, "--junit", str(nodir)]) == 2
    err = capsys.readouterr().err
    assert f"--junit {nodir}: the folder {nodir.parent} does not exist (create it first, e.g. mkdir -p " \
           f"{nodir.parent})" in err and err.count("\n") == 1
    (tmp_path / "afile").write_text("")
    assert main([*args, "--junit", str(tmp_path / "afile" / "x.xml")]) == 2
    assert f"'{tmp_path / 'afile'}' is not a folder" in capsys.readouterr().err
    (work / "_gate").write_text("not a folder")  # where the A/B's samples, verdicts and plot go
    assert main(args) == 2
    assert (f"results {work / '_gate' / 'ab_samples.parquet'}: '{work / '_gate'}' is not a folder (the A/B's "
            f"samples, verdicts and plot are written to {work / '_gate'}/ at the end of the check)"
            ) in capsys.readouterr().err
    (work / "_gate").unlink()
    (work / "_gate" / "ab_ratios.png").mkdir(parents=True)
    with pytest.raises(ValueError, match="ab_ratios.png: is a folder, not a regular file"):
        check(work, None, against="HEAD~1", project=site)
    assert ref_stage == []
    # the other side: a folder that exists, a _gate folder: the check goes on to REF's stage
    (work / "_gate" / "ab_ratios.png").rmdir()
    nodir.parent.mkdir()
    assert main([*args, "--junit", str(nodir)]) == 0 and len(ref_stage) == 1
    assert nodir.is_file()


def test_the_ci_recipe_passes_its_baseline_file_when_there_is_one_and_says_how_to_accept(tmp_path):
    """The example's CI recipe with tissuebench stood in (it records its arguments; its check exits
    $TB_CHECK_EXIT)."""
    repo, base, _ = recipe_repo(tmp_path)
    env, calls = recipe_env(tmp_path)

    def gate_sh(**extra):
        calls.unlink(missing_ok=True)
        proc = subprocess.run(["bash", "ci/gate.sh", "main"], cwd=repo, capture_output=True, text=True,
                              env={**env, **extra})
        return proc, recipe_calls(calls)[-1]

    proc, said = gate_sh()
    assert proc.returncode == 0 and "--baseline" not in said  # no file: none passed
    proc, said = gate_sh(TB_CHECK_EXIT="1")
    assert proc.returncode == 1
    assert ("gate: if an error changed on purpose, record it in ci/baseline.toml and commit that file with the change:"
            f"\ngate:     {env['TISSUEBENCH']} check out/tissuebench-gate --baseline ci/baseline.toml "
            "--update-baseline && git add ci/baseline.toml\n") in proc.stdout
    (repo / "ci" / "baseline.toml").write_text("")
    proc, said = gate_sh()
    assert proc.returncode == 0 and said == ["check", "out/tissuebench-gate", "--against", base, "--baseline",
                                             "ci/baseline.toml", "--latency-floor-s", "0", "--junit",
                                             "out/tissuebench-gate/_junit.xml"]
    assert "baseline ci/baseline.toml" in proc.stdout
    proc, said = gate_sh(BASELINE="gate/base.toml", TB_CHECK_EXIT="2")  # another file, absent; exit 2 kept
    assert proc.returncode == 2 and "--baseline" not in said and "record it" not in proc.stdout


def test_a_failed_check_names_the_command_that_records_an_intended_error_change(capsys):
    """The failure said "update the baseline in the same commit" and nothing more (issue 50, 9):
    it now gives the command, with the results and the baseline file of this check; an error
    regression only (a slower step is not accepted by a baseline file)."""
    import argparse

    from tissuebench.cli import _print_check
    from tissuebench.gate import CheckResult, Finding

    key = ("cornea_pinch", "pod_polyreg", "{}")

    def printed(metric, baseline):
        result = CheckResult(errors_against="ref", latency_mode="ab")
        result.add(key, Finding(*key, metric, 1.0, 1.5, "changed"))
        _print_check(result, argparse.Namespace(against="main", baseline=baseline, require=None,
                                                results=Path("out/my gate")))
        return capsys.readouterr().out

    assert ("check: if the change is intended, record it in the baseline and commit that file with the change: "
            "tissuebench check 'out/my gate' --baseline ci/baseline.toml --update-baseline\n"
            ) in printed("error", Path("ci/baseline.toml"))
    assert ("check: if the change is intended, record it in a baseline file of the repository, commit that file with "
            "the change and pass it to this check (--baseline FILE): tissuebench check 'out/my gate' --baseline FILE "
            "--update-baseline\n") in printed("flagged_steps", None)
    assert "if the change is intended" not in printed("latency_ab", Path("ci/baseline.toml"))


def test_the_scope_rule_on_both_sides_of_its_boundary(tmp_path):
    """Every method the project's: nothing said; some: a note per package outside it; none: refused,
    unless the project is tissuebench's (every method runs through its code). Without --project,
    the message says how the project was found."""
    from tissuebench.gate.project import Package, Project
    from tissuebench.gate.scope import check_scope, method_packages

    plug = ("tbp_plug", "tbp.m:P", "tbp-dist", "2.0")
    shipped = ("nearest", "", None, None)
    old_store = ("pod_interp", float("nan"), float("nan"), float("nan"))  # a store without the plugin columns
    assert method_packages([plug, shipped, old_store]) == {"tbp": (["tbp_plug"], "tbp-dist", "2.0"),
                                                           "tissuebench": (["nearest", "pod_interp"], None, None)}
    site = tmp_path / "site"
    (site / "tbp").mkdir(parents=True)
    holds = Project(tmp_path, "given by --project", (Package("tbp", "tbp-dist", "", site),),
                    {"tissuebench": HEAD_ROOT})
    assert check_scope([plug], holds, "HEAD~1") == []
    [note] = check_scope([plug, shipped, old_store], holds, "HEAD~1")
    assert note.endswith(f"methods 'nearest', 'pod_interp' are tissuebench's own, imported from "
                         f"{HEAD_ROOT / 'tissuebench'} (tissuebench {_version()})")
    lacks = Project(tmp_path, "the working directory's repository", (), {"tbp": site, "tissuebench": HEAD_ROOT})
    with pytest.raises(ValueError, match=re.escape(
            f"--against main: method 'tbp_plug' is imported from {site / 'tbp'} (distribution tbp-dist 2.0), which "
            f"is not inside the project under test {tmp_path} (the working directory's repository): REF's export of "
            f"{tmp_path} at main would run the same code on both sides")):
        check_scope([plug], lacks, "main")
    # tissuebench's own repository: its changes reach a plugin's method too (its base classes, the timing)
    tissuebench = Project(tmp_path, "given by --project", (Package("tissuebench", "tissuebench", "", HEAD_ROOT),),
                          {"tbp": site})
    assert check_scope([plug, shipped], tissuebench, "main") == [
        "not code of the project under test, the same package on both sides (the project's tissuebench differs): "
        f"method 'tbp_plug' is imported from {site / 'tbp'} (distribution tbp-dist 2.0)"]
    assert check_scope([shipped], tissuebench, "main") == []
    gone = Project(tmp_path, "given by --project", (), {"tbp": None})
    with pytest.raises(ValueError, match=re.escape("method 'tbp_plug' is of package tbp (this process cannot import "
                                                   "it), which is not inside --project")):
        check_scope([plug], gone, "main")
