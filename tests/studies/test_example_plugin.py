"""examples/bring_your_own_method as a user runs it (issue 38): the package installed into a fresh
venv (offline: ``pip install --no-build-isolation --no-deps -e``), then its README's steps through
the command line: ``tissuebench methods`` lists it with its distribution and version, a sweep of
two catalogue scenes beside pod_interp and anm_pod, the report, and the package's own tests of
tissuebench's contract checks."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from tissuebench.studies.results import read_units

from _venv import chained_venv as _venv

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "bring_your_own_method"


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
