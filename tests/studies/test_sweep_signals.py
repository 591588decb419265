"""A real Ctrl-C or SIGTERM stops a running sweep cleanly and resumably (issue 50, items 1 and 7).

SIGTERM (``timeout 5 tissuebench sweep ...``, a batch system's stop) used to kill the sweep with
its ``_sweep.json`` saying "running" and its lock left; it now stops it as Ctrl-C does: the
manifest says "interrupted", the lock is released, one line says how to resume, exit 128 + 15.
And the signal arrives while a plugin method's code runs, so this is also the other side of
test_plugin_exits.py: a KeyboardInterrupt the user *sent* is not taken for one the method raised
(the unit is not stored as failed; the sweep stops).

Not timing sensitive: the plugin's step writes a file when it starts and then waits for another
to go away; the signal is sent once the first exists, so it always lands inside the step."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from _gate_spec import cornea_spec
from _plugin_dist import Installed, toy_source, write_dist
from tissuebench.studies.results import ResultsStore, read_units
from tissuebench.studies.spec import load_spec
from tissuebench.studies.sweep import run_sweep
from tissuebench.studies.sweep_manifest import read_sweep_manifest

SPEC = cornea_spec("signals", ["nearest", "toy_wait"])
_STEP = "        mu = check_parameters(mu,"
#: the step: say it started, then wait while the file $TB_TEST_WAIT exists
WAIT = ("        import os, pathlib, time\n"
        "        pathlib.Path(os.environ['TB_TEST_WAIT'] + '.started').touch()\n"
        "        while os.path.exists(os.environ['TB_TEST_WAIT']):\n"
        "            time.sleep(0.01)\n")


@pytest.fixture
def waiting(tmp_path, monkeypatch):
    inst = Installed(tmp_path / "site", monkeypatch)
    source = toy_source("toy_wait").replace(_STEP, WAIT + _STEP)
    write_dist(inst.root, "tb-wait", "0.1", {"toy_wait": "toywait:Toy"}, {"toywait": source})
    gate = tmp_path / "wait"
    gate.touch()
    monkeypatch.setenv("TB_TEST_WAIT", str(gate))
    yield gate
    inst.undo()


def _start(spec, out):
    """``tissuebench sweep`` in a session of its own (a signal to its process group, as a terminal's
    Ctrl-C and ``timeout`` send them), SIGINT at its default (a suite run as a background job
    inherits it ignored)."""
    cmd = [sys.executable, "-m", "tissuebench.cli", "sweep", str(spec), "--out", str(out), "--quiet"]
    return subprocess.Popen(cmd, env=dict(os.environ), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _wait_for(path, proc, timeout=300):
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < deadline, "the plugin's step never started"
        time.sleep(0.02)


@pytest.mark.parametrize("signum, code, said", [(signal.SIGINT, 130, "interrupted;"),
                                                (signal.SIGTERM, 143, "interrupted (SIGTERM);")],
                         ids=["SIGINT", "SIGTERM"])
def test_a_signal_stops_a_running_sweep_interrupted_unlocked_and_resumable(waiting, tmp_path, signum, code, said):
    spec, out = tmp_path / "spec.toml", tmp_path / "out"
    spec.write_text(SPEC)
    proc = _start(spec, out)
    _wait_for(waiting.with_name(waiting.name + ".started"), proc)  # inside toy_wait's step, after nearest
    os.killpg(proc.pid, signum)
    _, err = proc.communicate(timeout=120)
    lines = err.decode().strip().splitlines()
    assert proc.returncode == code, err.decode()
    assert lines[-1].startswith(f"tissuebench: {said} finished units are stored in {out}. Resume with: "
                                f"tissuebench sweep {spec} --out {out} --resume"), lines
    assert read_sweep_manifest(out)["state"] == "interrupted"  # was "running" after SIGTERM
    assert not (out / ".lock").exists()
    # the user's signal is not the method's failure: toy_wait is not stored, nearest is
    assert [method for _, method, _ in ResultsStore(out).finished().values()] == ["nearest"]
    waiting.unlink()  # toy_wait's step goes through now
    summary = run_sweep(load_spec(spec), out, resume=True, progress=False)
    assert (len(summary.skipped), len(summary.computed), summary.failed) == (1, 1, [])
    assert read_sweep_manifest(out)["state"] == "finished"
    assert sorted(read_units(out)["unit_status"]) == ["ok", "ok"]
