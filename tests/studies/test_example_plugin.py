"""examples/bring_your_own_method as a user runs it (issue 38): the package installed into a fresh
venv (offline: ``pip install --no-build-isolation --no-deps -e``), then its README's steps through
the command line: ``tissuebench methods`` lists it with its distribution and version, a sweep of
two catalogue scenes beside pod_interp and anm_pod, the report, and the package's own tests of
tissuebench's contract checks."""
from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from tissuebench.studies.results import read_units

from _gate_repo import EXAMPLE, git, recipe_calls, recipe_env, recipe_repo
from _venv import chained_venv as _venv


def _run(python, *args, cwd):
    proc = subprocess.run([str(python), *args], cwd=cwd, capture_output=True, text=True,
                          env={**os.environ, "MPLBACKEND": "Agg", "PYTHONPATH": ""})
    assert proc.returncode == 0, f"{args}: exit {proc.returncode}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


@pytest.mark.slow
def test_the_example_plugin_installed_listed_swept_reported_and_checked(tmp_path):
    work = tmp_path / "bring_your_own_method"
    shutil.copytree(EXAMPLE, work, ignore=shutil.ignore_patterns("build", "*.egg-info", "out", "__pycache__"))
    python = _venv(tmp_path / "venv")
    _run(python, "-m", "pip", "install", "-q", "--no-build-isolation", "--no-deps", "-e", ".", cwd=work)
    listed = _run(python, "-m", "tissuebench.cli", "methods", cwd=work)
    assert "pod_polyreg" in listed and "[plugin tissuebench-podreg 0.1.0 (podreg.method:PodPolyReg)]" in listed
    _run(python, "-m", "tissuebench.cli", "sweep", "spec.toml", "--out", "out/sweep", "--quiet", cwd=work)
    units = read_units(work / "out" / "sweep")
    assert (units["unit_status"] == "ok").all(), units[units["unit_status"] != "ok"][["label", "message"]]
    counts = units.groupby(["case", "method"]).size().to_dict()
    assert counts == {("cornea_pinch", "anm_pod"): 4, ("cornea_pinch", "pod_interp"): 2,
                      ("cornea_pinch", "pod_polyreg"): 4, ("cube_tension_twist", "pod_interp"): 2,
                      ("cube_tension_twist", "pod_polyreg"): 4}
    ours = units[units["method"] == "pod_polyreg"]
    assert set(ours["method_version"]) == {"0.1.0"} and (ours["max_rel_l2"] < 1e-2).all()
    _run(python, "-m", "tissuebench.cli", "report", "out/sweep", cwd=work)
    assert "tissuebench-podreg 0.1.0" in (work / "out" / "sweep" / "_report" / "report.html").read_text()
    checked = _run(python, "-m", "pytest", "-q", "-p", "no:cacheprovider", cwd=work)
    assert "failed" not in checked and " passed" in checked, checked[-2000:]


# ------------------------------------------------------------------ issue 39: the example's CI recipe
def test_the_ci_recipe_checks_against_the_merge_base_and_writes_junit(tmp_path):
    """``ci/gate.sh``: sweep the spec, then ``check --against`` the merge base of HEAD and the base
    branch (the previous commit on the base branch itself), the floor for a microsecond step, JUnit
    beside the results; no merge base: exit 2 saying what to fetch. ``tissuebench`` stands in
    (``$TISSUEBENCH``) to record its arguments."""
    repo, base, head = recipe_repo(tmp_path)
    env, calls = recipe_env(tmp_path)

    def gate(*args):
        calls.unlink(missing_ok=True)
        proc = subprocess.run(["bash", "ci/gate.sh", *args], cwd=repo, capture_output=True, text=True, env=env)
        return proc, recipe_calls(calls)

    proc, said = gate("main")
    assert proc.returncode == 0, proc.stderr
    assert said == [["sweep", "spec.toml", "--out", "out/tissuebench-gate", "--quiet"],
                    ["check", "out/tissuebench-gate", "--against", base, "--latency-floor-s", "0", "--junit",
                     "out/tissuebench-gate/_junit.xml"]]
    assert f"against {base[:7]} (merge base with main)" in proc.stdout
    git(repo, "checkout", "-q", "main")
    git(repo, "merge", "-q", "--ff-only", "feature")
    proc, said = gate("main")  # on the base branch: its last commit against the previous one
    assert said[1][3] == base and head == git(repo, "rev-parse", "HEAD")
    env["LATENCY_FLOOR_S"], env["SPEC"] = "1e-6", "other.toml"
    proc, said = gate("main")
    assert said[0][1] == "other.toml" and said[1][5] == "1e-6"
    proc, said = gate("origin/nowhere")
    assert proc.returncode == 2 and said == [] and "gate: no merge base of HEAD and origin/nowhere" in proc.stderr


def test_the_ci_workflow_checks_out_the_history_runs_the_recipe_and_keeps_the_junit():
    import yaml

    flow = yaml.safe_load((EXAMPLE / ".github" / "workflows" / "tissuebench-gate.yml").read_text())
    steps = flow["jobs"]["gate"]["steps"]
    checkout = next(s for s in steps if str(s.get("uses", "")).startswith("actions/checkout"))
    assert checkout["with"]["fetch-depth"] == 0  # the merge base is in the history
    runs = [s["run"] for s in steps if "run" in s]
    assert any("pip install -e ." in r for r in runs) and any(r.startswith("bash ci/gate.sh") for r in runs)
    upload = next(s for s in steps if str(s.get("uses", "")).startswith("actions/upload-artifact"))
    assert upload["if"] == "always()" and "out/tissuebench-gate/_junit.xml" in upload["with"]["path"]
    assert set(flow[True]) == {"pull_request", "push"}  # YAML reads the key `on` as True
