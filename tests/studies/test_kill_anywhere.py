"""Kill anywhere: ``tissuebench run`` and ``sweep`` under SIGKILL and Ctrl-C (issue 16).

SIGKILL at a random moment (seeded; half of the moments inside the final write, where
the hidden temporary folder exists) must leave either no result folder or a complete one,
and the next run into the same place must work and remove what the killed one left.
Ctrl-C (SIGINT to the whole process group, as a terminal sends it, so the child renderer
gets it too) must stop with exit 130 and one line on stderr, no traceback, nothing left.
A sweep stopped by Ctrl-C keeps its finished units, releases its lock and says how to resume.
The figures (kills, folders left behind, reruns that worked) are printed at the end and
appended to ``$TISSUEBENCH_KILL_REPORT`` when it is set.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
FILES = {"results.parquet", "fields.npz", "deformed.vtu", "deformed.png", "monitors.png", "manifest.json"}
FIGURES = Counter()


@pytest.fixture(scope="module", autouse=True)
def kill_report():
    yield
    if FIGURES:
        text = ("kill-anywhere: " + ", ".join(f"{k} {v}" for k, v in sorted(FIGURES.items())))
        print("\n" + text)
        if os.environ.get("TISSUEBENCH_KILL_REPORT"):
            with open(os.environ["TISSUEBENCH_KILL_REPORT"], "a") as fh:
                fh.write(text + "\n")


def _start(args, quiet=True):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYVISTA_OFF_SCREEN": "true"}
    cmd = [sys.executable, "-m", "tissuebench.cli", *args] + (["--quiet"] if quiet else [])
    # a session of its own: the signal goes to the process group, as a terminal's Ctrl-C does; SIGINT
    # back to its default in the child, since a suite started as a background job of a script inherits
    # it ignored (and Python then installs no KeyboardInterrupt handler): a foreground run's Ctrl-C
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for(predicate, proc, timeout=600):
    deadline = time.monotonic() + timeout
    while not predicate():
        if proc.poll() is not None:
            return False
        assert time.monotonic() < deadline, "the run made no progress"
        time.sleep(0.005)
    return True


def _writing(out):
    return lambda: any(p.name.startswith(f".{out.name}.tmp-") for p in out.parent.iterdir())


def _complete(out) -> bool:
    return FILES <= {p.name for p in out.iterdir()} and json.loads((out / "manifest.json").read_text())["ok"]


@pytest.fixture(scope="module")
def run_seconds(tmp_path_factory):
    """Wall time of one uninterrupted run (the window the random kills fall in)."""
    out = tmp_path_factory.mktemp("uninterrupted") / "res"
    t0 = time.monotonic()
    proc = _start(["run", "cornea_pinch", "--out", str(out)])
    proc.communicate()
    assert proc.returncode == 0 and _complete(out)
    return time.monotonic() - t0


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5, 6])
def test_sigkill_of_run_at_a_random_moment_leaves_no_half_written_folder(tmp_path, seed, run_seconds):
    rng = np.random.default_rng(seed)
    out = tmp_path / "res"
    proc = _start(["run", "cornea_pinch", "--out", str(out)])
    if seed % 2:  # inside the final write: the hidden temporary folder exists
        _wait_for(_writing(out), proc)
        time.sleep(rng.uniform(0.0, 1.5))
    else:
        time.sleep(rng.uniform(0.2, 1.0) * run_seconds)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate()
    FIGURES["SIGKILLs of run"] += 1
    assert not out.exists() or _complete(out), "a half-written result folder"
    FIGURES["hidden folders the kill left (for the rerun to clean)"] += sum(
        p.name.startswith(".res.") for p in tmp_path.iterdir())
    again = _start(["run", "cornea_pinch", "--out", str(out), "--force"])
    _, err = again.communicate()
    assert again.returncode == 0, err.decode()
    FIGURES["reruns OK"] += 1
    left = sorted(p.name for p in tmp_path.iterdir() if p.name != "res")
    FIGURES["folders left behind"] += len(left)
    assert left == [] and _complete(out)


def _one_line(err: bytes) -> str:
    lines = [ln for ln in err.decode().replace("\r", "\n").splitlines() if ln.strip()]
    assert "Traceback" not in err.decode(), err.decode()
    return lines[-1]


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow), pytest.param(3, marks=pytest.mark.slow)])
def test_ctrl_c_while_writing_and_plotting_stops_cleanly_with_one_line(tmp_path, seed):
    rng = np.random.default_rng(seed)
    out = tmp_path / "res"
    proc = _start(["run", "cornea_pinch", "--out", str(out)])
    assert _wait_for(_writing(out), proc), "the run ended before writing"
    time.sleep(rng.uniform(0.0, 1.0))
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate()
    FIGURES["SIGINTs of run"] += 1
    if proc.returncode == 0:
        pytest.skip("the run finished before the signal")
    assert proc.returncode == 130, err.decode()
    assert _one_line(err).startswith(f"tissuebench: interrupted; nothing was written to {out}")
    assert len(err.decode().strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_ctrl_c_during_the_solve_stops_cleanly_with_one_line(tmp_path):
    out = tmp_path / "res"
    proc = _start(["run", "cornea_pinch", "--out", str(out)], quiet=False)
    proc.stderr.read(1)  # the progress bar started: the solve runs
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate()
    FIGURES["SIGINTs of run"] += 1
    assert proc.returncode == 130
    assert _one_line(err).startswith("tissuebench: interrupted; nothing was written")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow
def test_ctrl_c_of_a_sweep_keeps_finished_units_releases_the_lock_and_says_how_to_resume(tmp_path):
    from test_sweep import write_spec

    from tissuebench.studies.results import ResultsStore
    from tissuebench.studies.spec import load_spec
    from tissuebench.studies.sweep import run_sweep

    spec = write_spec(tmp_path)
    out = tmp_path / "out"
    proc = _start(["sweep", str(spec), "--out", str(out)])
    assert _wait_for(lambda: len(list(out.glob("case=*/method=*/*.parquet"))) >= 1, proc)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate()
    FIGURES["SIGINTs of sweep"] += 1
    line = _one_line(err)
    assert proc.returncode == 130 and "Resume with: tissuebench sweep" in line and "--resume" in line
    assert not (out / ".lock").exists()
    finished = {p.stem: p.read_bytes() for p in out.glob("case=*/method=*/*.parquet")}
    assert set(ResultsStore(out).finished()) == set(finished) and finished
    summary = run_sweep(load_spec(spec), out, resume=True, progress=False)
    assert sorted(summary.skipped) == sorted(finished) and len(summary.skipped) + len(summary.computed) == 7
    for key, data in finished.items():
        assert next(out.glob(f"case=*/method=*/{key}.parquet")).read_bytes() == data
    FIGURES["sweep resumes OK"] += 1
