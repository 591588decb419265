"""Gate your own repository (issue 39), end to end through the shipped CLI only: the example's
package (examples/bring_your_own_method) in a git repository of its own, installed editable into
a fresh venv, gated by its CI recipe (``ci/gate.sh``: sweep, then ``check --against`` the merge
base, JUnit) on three commits on top of a base: (a) a slower step, (b) an error regression, (c)
a comment. Expected: (a) flagged slower, (b) exit 1 naming the error, and the same commit with
the baseline file written by the command that failure prints passes (an intended change,
declared), (c) holds. And REF's processes run REF's copy of a package an editable install
serves through an import hook (setuptools' finder, a flat layout), or name the copy they were
handed instead.

Each gate runs REF's sweep and an A/B of both versions (about a minute or two here): slow."""
from __future__ import annotations

import os
import re
import subprocess
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from _gate_repo import EXAMPLE, commit, example_repo, git, init
from _gate_spec import HELD_OUT, cornea_spec
from _venv import chained_venv, tissuebench_command

SPEC = cornea_spec("podreg_gate", [("pod_polyreg", "options = { n_modes = 4, degree = 3 }")], latency_steps=200,
                   warmup=20, evaluation=HELD_OUT, sweep='resolution = "ci"')
STEP = ("        q = (lam / self._top) ** self._powers @ self._coeffs  # a new array each step: it belongs to the "
        "result\n")
# (a) the polynomial evaluated three times: the step about 1.5x slower (measured 1.5-1.7 by the gate here)
SLOWER = ("        x = lam / self._top\n        for _ in range(2):  # a leftover of profiling\n"
          "            x ** self._powers @ self._coeffs\n        q = x ** self._powers @ self._coeffs\n")
# (b) one degree fewer than asked: the reduced coordinates' fit is worse
FIT = "        V = np.vander(lams / top, self.degree + 1, increasing=True)[:, 1:]"
WORSE = "        V = np.vander(lams / top, self.degree, increasing=True)[:, 1:]"
COMMENT = "        # the reduced coordinates of the step: a polynomial in the scaled load factor\n"


def _edit(repo: Path, old: str, new: str) -> dict:
    path = repo / "src" / "podreg" / "method.py"
    text = path.read_text()
    assert text.count(old) == 1, old
    return {"src/podreg/method.py": text.replace(old, new)}


def _env(venv_python: Path, **extra) -> dict:
    return {**os.environ, "PATH": f"{venv_python.parent}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg",
            "PYTHONPATH": os.environ.get("TB_GATE_PYTHONPATH", ""), **extra}


@pytest.fixture(scope="module")
def user_repo(tmp_path_factory):
    """The user's repository: the example package at its top, its gate spec, a base commit and a
    branch per change; the package installed editable (src/ layout: a path in a .pth file)."""
    root = tmp_path_factory.mktemp("own")
    repo, base = example_repo(root, {"gate_spec.toml": SPEC})
    for branch, files in (("slower", _edit(repo, STEP, SLOWER)), ("worse", _edit(repo, FIT, WORSE)),
                          ("comment", _edit(repo, STEP, COMMENT + STEP))):
        git(repo, "checkout", "-q", "-b", branch, base)
        commit(repo, files, branch)
    git(repo, "checkout", "-q", "main")
    python = chained_venv(root / "venv")
    tissuebench_command(python)
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-build-isolation", "--no-deps", "-e", "."],
                   cwd=repo, check=True, capture_output=True)
    return repo, python, base


def _gate(repo: Path, python: Path, branch: str) -> tuple[subprocess.CompletedProcess, float]:
    git(repo, "checkout", "-q", branch)
    t0 = time.perf_counter()
    proc = subprocess.run(["bash", "ci/gate.sh", "main"], cwd=repo, capture_output=True, text=True,
                          env=_env(python, SPEC="gate_spec.toml"))
    took = time.perf_counter() - t0
    print(f"gate of {branch}: exit {proc.returncode} in {took:.0f} s\n{proc.stdout}")
    return proc, took


def _said_sides(out: str, repo: Path, base: str) -> None:
    assert f"project under test: {repo} (the repository of the package podreg of the sweep's plugin methods)" in out
    assert f"REF  {base} = {base[:12]} of {repo}: tissuebench-podreg 0.1.0 (podreg in src/)" in out
    assert f"HEAD the working tree of {repo} at " in out and f"(podreg from {repo / 'src'})" in out


@pytest.mark.slow
def test_a_slower_step_of_the_users_package_is_flagged(user_repo):
    repo, python, base = user_repo
    proc, _ = _gate(repo, python, "slower")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    _said_sides(proc.stdout, repo, base)
    assert re.search(r"A/B slower cornea_pinch pod_polyreg .*: HEAD/REF \d", proc.stdout), proc.stdout
    assert "check: 1 regressions in 1 units (errors against" in proc.stdout
    assert not re.search(r"pod_polyreg\s+error\s+was", proc.stdout)
    junit = ET.parse(repo / "out" / "tissuebench-gate" / "_junit.xml").getroot()
    assert junit.get("failures") == "1" and "latency_ab" in ET.tostring(junit, encoding="unicode")
    props = {p.get("name"): p.get("value") for p in junit.iter("property")}
    assert props["project"].startswith(str(repo)) and props["ref"].startswith(f"{base} = {base[:12]} of {repo}")
    assert props["head"].startswith(f"the working tree of {repo} at ")


@pytest.mark.slow
def test_an_error_regression_of_the_users_package_exits_1_naming_the_error_then_its_baseline_accepts_it(user_repo):
    """The recipe once could not land an intended change (its failure said "update the baseline"
    and it passed none): the command the failed gate prints writes ``ci/baseline.toml``, and the
    same commit with that file passes, the change noted as declared."""
    repo, python, base = user_repo
    proc, _ = _gate(repo, python, "worse")
    assert proc.returncode == 1, proc.stdout + proc.stderr
    _said_sides(proc.stdout, repo, base)
    assert re.search(r"cornea_pinch\s+pod_polyreg\s+error\s+was\s+\S+\s+now\s+\S+\s+\(changed against "
                     rf"{base} \({base[:12]}\) by more than", proc.stdout), proc.stdout
    said = ("gate:     tissuebench check out/tissuebench-gate --baseline ci/baseline.toml --update-baseline && "
            "git add ci/baseline.toml\n")
    assert "gate: if an error changed on purpose, record it in ci/baseline.toml and commit that file with the " \
           "change:\n" + said in proc.stdout
    # the intended change: the printed command, its file amended into the same commit
    git(repo, "checkout", "-q", "-b", "worse-accepted", "worse")
    accept = subprocess.run(["bash", "-c", said.split("gate:", 1)[1]], cwd=repo, capture_output=True, text=True,
                            env=_env(python))
    assert accept.returncode == 0, accept.stdout + accept.stderr
    git(repo, "commit", "-q", "--amend", "--no-edit")
    assert "ci/baseline.toml" in git(repo, "show", "--name-only", "--format=", "HEAD").split()
    proc, _ = _gate(repo, python, "worse-accepted")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert f"against {base[:7]} (merge base with main), baseline ci/baseline.toml" in proc.stdout
    assert re.search(r"note: cornea_pinch pod_polyreg \S+: error \S+ -> \S+, declared by the baseline update of this "
                     "commit", proc.stdout), proc.stdout
    assert f"check: 1 units hold (errors against {base}, latency A/B against {base})" in proc.stdout


@pytest.mark.slow
def test_a_comment_of_the_users_package_holds(user_repo):
    repo, python, base = user_repo
    proc, _ = _gate(repo, python, "comment")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    _said_sides(proc.stdout, repo, base)
    assert f"check: 1 units hold (errors against {base}, latency A/B against {base})" in proc.stdout
    assert "A/B holds  cornea_pinch pod_polyreg" in proc.stdout


FLAT = """[build-system]
requires = ["setuptools>=70.1"]
build-backend = "setuptools.build_meta"
[project]
name = "tissuebench-podreg"
version = "{version}"
dependencies = ["tissuebench"]
[tool.setuptools.packages.find]
include = ["podreg*"]
"""
POINT = '\n[project.entry-points."tissuebench.methods"]\npod_polyreg = "podreg.{module}:PodPolyReg"\n'


@pytest.mark.slow
def test_an_editable_finders_copy_is_not_taken_for_refs(tmp_path):
    """A flat layout installed editable gets setuptools' import hook (``__editable__..._finder``),
    which serves a module REF's package lacks from HEAD's work tree. HEAD moved the class to
    ``podreg/fast.py``: by its entry point (REF's, written beside REF's export) REF's processes
    run REF's ``podreg/method.py``, and the two are compared; named ``podreg.fast:PodPolyReg``
    without an entry point, REF's processes are handed HEAD's module by the hook, and the gate
    says so instead of comparing HEAD with itself."""
    repo = init(tmp_path / "flat")
    method = (EXAMPLE / "src" / "podreg" / "method.py").read_text()
    bare = commit(repo, {"pyproject.toml": FLAT.format(version="0.0.1"), "podreg/method.py": method,
                         "podreg/__init__.py": "from .method import PodPolyReg\n", "gate_spec.toml": SPEC})
    pointed = commit(repo, {"pyproject.toml": FLAT.format(version="0.1.0") + POINT.format(module="method")})
    commit(repo, {"pyproject.toml": FLAT.format(version="0.2.0") + POINT.format(module="fast"),
                  "podreg/method.py": None, "podreg/fast.py": method,
                  "podreg/__init__.py": "from .fast import PodPolyReg\n"}, "moved")
    python = chained_venv(tmp_path / "venv")
    tissuebench_command(python)
    env = _env(python)

    def run(*args):
        proc = subprocess.run(args, cwd=repo, capture_output=True, text=True, env=env)
        print(f"{' '.join(args)}: exit {proc.returncode}\n{proc.stdout}\n{proc.stderr[-2000:]}")
        return proc

    install = (str(python), "-m", "pip", "install", "-q", "--no-build-isolation", "--no-deps", "-e", ".")
    assert run(*install).returncode == 0
    assert list((tmp_path / "venv").glob("lib/*/site-packages/__editable___tissuebench_podreg_*_finder.py"))
    assert run("tissuebench", "sweep", "gate_spec.toml", "--out", "out/a", "--quiet").returncode == 0
    by_entry_point = run("tissuebench", "check", "out/a", "--against", pointed, "--ab-rounds", "2,3")
    out = by_entry_point.stdout
    assert by_entry_point.returncode == 0 and "check: 1 units hold (errors against" in out
    assert "tissuebench-podreg 0.1.0 (podreg in the top/)" in out and "tissuebench-podreg 0.2.0" in out
    assert "A/B holds  cornea_pinch pod_polyreg" in out and "not REF's code" not in by_entry_point.stderr
    # no entry point: the spec names the class where HEAD has it, a module REF lacks
    commit(repo, {"pyproject.toml": FLAT.format(version="0.3.0"),
                  "gate_spec.toml": SPEC.replace('"pod_polyreg"', '"podreg.fast:PodPolyReg"')})
    assert run(*install).returncode == 0
    assert run("tissuebench", "sweep", "gate_spec.toml", "--out", "out/b", "--quiet").returncode == 0
    by_source = run("tissuebench", "check", "out/b", "--against", bare)
    assert by_source.returncode == 2
    assert (f"REF's sweep did not run (REF cannot run any method of the spec: podreg.fast:PodPolyReg (not REF's "
            f"code: podreg.fast comes from {repo / 'podreg' / 'fast.py'}, not from ") in by_source.stderr
