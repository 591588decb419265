"""Executors survive a worker process that dies (issue 26, item 7: a SIGKILLed worker of the
``processes`` pool gave a BrokenProcessPool traceback), tested with real SIGKILLs."""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from _kill_scenarios import units as _units
from _workers import sleepy
from tissuebench.studies.executors import WORKERS_PER_CORE, check_executor, execute, max_workers


def _scenario(name: str, timeout: float = 240) -> dict:
    """Run ``_kill_scenarios.NAME`` in a fresh interpreter (see that module) and return what it
    printed; its process ending otherwise (killed by a signal, a crash) fails the test, naming how,
    with its stderr (faulthandler's tracebacks included)."""
    tests = Path(__file__).resolve().parents[1]
    path = [str(tests), str(tests.parent), os.environ.get("PYTHONPATH", "")]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in path if p)}
    proc = subprocess.run([sys.executable, "-X", "faulthandler", "-c",
                           f"import json, _kill_scenarios as s; print(json.dumps(s.{name}()))"],
                          capture_output=True, text=True, env=env, timeout=timeout)
    how = f"signal {signal.Signals(-proc.returncode).name}" if proc.returncode < 0 else f"exit {proc.returncode}"
    assert proc.returncode == 0, f"the sweep's process ended with {how}:\n{proc.stderr[-4000:]}"
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_7_a_unit_that_kills_its_worker_is_stored_failed_and_the_others_finish():
    run = _scenario("unit_that_kills_its_worker")
    keys, done = run["keys"], run["rows"]
    assert sorted(done) == sorted(keys)  # every unit once, none lost
    dead = done[keys[1]]
    assert dead["unit_status"] == "failed" and "worker process running this unit died" in dead["message"]
    assert dead["case"] == "c" and dead["method"] == "nearest"  # a full row: the store writes it
    assert all(done[k]["unit_status"] == "ok" for k in keys if k != keys[1])
    assert run["seconds"] < 120


@pytest.mark.slow  # ~10 s; the default run keeps the unit that kills its own worker (the same recovery)
def test_7_a_worker_killed_from_outside_loses_no_unit():
    """SIGKILL of a busy worker (not the unit's doing): its unit and the pool's other units in
    flight run again, all finish ok."""
    run = _scenario("worker_killed_from_outside")
    done = run["rows"]
    assert run["killed"], "no worker was killed: nothing was tested"
    assert sorted(done) == sorted(run["keys"])
    assert all(r["unit_status"] == "ok" for r in done.values()), done
    assert str(run["killed"][0]) not in {r["message"] for r in done.values()}


def test_a_scenario_process_that_dies_fails_its_test_naming_the_signal():
    """The harness of the tests above can fail: a scenario process killed by a signal is an
    assertion naming the signal, not a pass (nor a crash of the test runner's worker)."""
    with pytest.raises(AssertionError, match="ended with signal SIGKILL"):
        _scenario("the_process_itself_killed")


def test_minor_an_unreachable_scheduler_marks_the_sweep_failed(tmp_path, monkeypatch):
    from tissuebench.cli import main
    from tissuebench.studies import executors

    monkeypatch.setattr(executors, "SCHEDULER_CONNECT_TIMEOUT_S", 1.0)  # refused at once; dask retries until then
    from tissuebench.studies.sweep_manifest import read_sweep_manifest

    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "s"\n[protocol]\nlatency_steps = 5\n[[case]]\nname = "cornea_pinch"\n'
                    '[[method]]\nname = "nearest"\n')
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--quiet", "--executor", "dask", "--scheduler",
                 "tcp://127.0.0.1:9"]) == 2
    assert read_sweep_manifest(out)["state"] == "failed" and not (out / ".lock").exists()


@pytest.mark.parametrize("name", ["serial", "processes"])
def test_execute_yields_every_unit_once(name):
    units = _units({"sleep": 0.0}, {"sleep": 0.0}, {"sleep": 0.0})
    workers = None if name == "serial" else 2  # serial starts no worker: --workers is refused there
    assert sorted(u.key for u, _ in execute(units, name, workers, run=sleepy)) == sorted(u.key for u in units)


@pytest.mark.slow  # ~8 s: a Dask cluster; the default run kills a process worker (test_7_...)
def test_a_unit_that_kills_every_dask_worker_it_runs_on_is_stored_failed_and_the_others_finish():
    """Dask runs a task whose worker died on another worker, up to ``allowed-failures`` times; past
    that (0 here: the first death) the unit is a failed row saying so, not the end of the sweep.
    (Dask counts a death against every task assigned to that worker: here one task per worker at a
    time, no reference task to wait for, and the one that dies waits 3 s, so that the others are
    done by then.)"""
    run = _scenario("unit_that_kills_every_dask_worker")
    keys, done = run["keys"], run["rows"]
    assert sorted(done) == sorted(keys)
    dead = done[keys[1]]
    assert dead["unit_status"] == "failed" and "dask workers running this unit died" in dead["message"], dead
    assert dead["case"] == "c" and all(done[k]["unit_status"] == "ok" for k in (keys[0], keys[2]))


class _Future:
    def __init__(self, key, status, value):
        self.key, self.status, self.value = key, status, value

    def result(self):
        if isinstance(self.value, BaseException):
            raise self.value
        return self.value


class _Client:
    """A dask client whose unit tasks end as ``plan`` says, task after task: ``lost`` /
    ``cancelled`` (the result gone after the unit ended), ``error`` (KilledWorker), else finished."""

    def __init__(self, plan):
        self.plan, self.submitted = plan, []

    def submit(self, fn, *args, key, pure):
        self.submitted.append(key)
        if key.startswith("reference-"):
            return _Future(key, "error" if self.plan.get("reference") else "finished", "hit")
        unit = args[2]
        fates = self.plan.get(unit.key, [])
        fate = fates.pop(0) if fates else "finished"
        value = {"lost": RuntimeError("lost"), "error": KeyError("KilledWorker: 4 deaths"),
                 "cancelled": RuntimeError("cancelled")}.get(fate, f"outcome of {unit.key[-2:]}")
        return _Future(key, fate, value)


class _Completed:
    """``distributed.as_completed``'s interface: futures as they end, and add()."""

    def __init__(self, futures):
        self.queue = list(futures)

    def add(self, fut):
        self.queue.append(fut)

    def __iter__(self):
        while self.queue:
            yield self.queue.pop(0)


def test_a_lost_dask_result_is_submitted_again_and_a_killed_worker_unit_is_stored_failed(monkeypatch):
    """The executor's reading of a unit task's end (CI saw a unit lost with its worker after it
    had finished): lost or cancelled -> submitted again, at most RESUBMITS times; KilledWorker ->
    stored failed at once; each unit yielded once."""
    from tissuebench.studies import executors

    monkeypatch.setattr(executors, "failed_outcome", lambda u, why: ("failed", why))
    units = _units({}, {}, {}, {})
    lost_once, killed, lost_always = units[0].key, units[1].key, units[2].key
    client = _Client({lost_once: ["lost"], killed: ["error"], lost_always: ["cancelled"] * 5})
    done = list(executors._dask_units(client, units, sleepy, None, _Completed))
    assert sorted(u.key for u, _ in done) == sorted(u.key for u in units)
    by_key = {u.key: o for u, o in done}
    assert by_key[lost_once] == "outcome of 00" and by_key[units[3].key] == "outcome of 03"
    assert by_key[killed][0] == "failed" and "workers running this unit died (KeyError" in by_key[killed][1]
    assert by_key[lost_always][0] == "failed" and "result was lost (cancelled" in by_key[lost_always][1]
    again = [k for k in client.submitted if "-again-" in k]
    assert sorted(again) == sorted([f"unit-{lost_once}-again-1"] +
                                   [f"unit-{lost_always}-again-{n}" for n in (1, 2)])


def test_a_unit_whose_reference_task_died_names_the_reference(monkeypatch):
    """Units depend on their reference tasks: when a reference's workers died (KilledWorker), the
    units are errored by dask without having run, and their message says whose task died."""
    from tissuebench.studies import executors

    monkeypatch.setattr(executors, "failed_outcome", lambda u, why: ("failed", why))
    monkeypatch.setattr(executors, "unit_references", lambda u: {"abc": None})
    units = _units({})
    client = _Client({"reference": True, units[0].key: ["error"]})
    (_, outcome), = executors._dask_units(client, units, sleepy, None, _Completed)
    assert outcome[0] == "failed" and "running its reference task reference-abc died" in outcome[1]


class _RacingPool:
    """A real pool whose ``submit`` raises BrokenProcessPool at the calls listed in ``broken_at``
    (counted over every pool of the test), as a real pool does when one of its workers died between
    the executor's last wait and its next submit."""

    calls = 0

    def __init__(self, pool, broken_at):
        self.pool, self.broken_at = pool, broken_at

    def submit(self, fn, *args):
        from concurrent.futures.process import BrokenProcessPool

        type(self).calls += 1
        if type(self).calls in self.broken_at:
            raise BrokenProcessPool("a child process terminated abruptly (simulated race)")
        return self.pool.submit(fn, *args)

    def shutdown(self, **kwargs):
        self.pool.shutdown(**kwargs)


@pytest.mark.parametrize("broken_at", [{1}, {3}])  # a fresh pool broken; one broken under a unit in flight
def test_a_pool_that_broke_between_wait_and_submit_loses_no_unit_and_raises_nothing(monkeypatch, broken_at):
    """The race of a worker's death with another unit's end: ``submit`` on the broken pool raises
    BrokenProcessPool. Before, that propagated out of the sweep; now the unit waits for the next
    pool, and every unit runs once, ok."""
    import tissuebench.studies.executors as executors

    _RacingPool.calls = 0
    real_pool = executors._pool
    monkeypatch.setattr(executors, "_pool", lambda workers: _RacingPool(real_pool(workers), broken_at))
    units = _units(*[{"sleep": 0.05, "n": i} for i in range(4)])
    done = [(u.key, o.row["unit_status"]) for u, o in execute(units, "processes", 2, run=sleepy)]
    assert sorted(done) == sorted((u.key, "ok") for u in units)
    assert _RacingPool.calls >= len(units) + len(broken_at)


# ------------------------------------------------------------------------ issue 37: workers and schedulers
_TOO_MANY = max_workers() + 1


@pytest.mark.parametrize("kwargs, message", [
    # a flag that did nothing, silently
    (dict(name="serial", workers=5), "workers = 5: executor 'serial' runs the units one at a time in this process"),
    (dict(name="serial", workers=1), "workers = 1: executor 'serial'"),
    (dict(name="dask", workers=2, scheduler="tcp://127.0.0.1:8786"), "workers = 2: the cluster at scheduler = "),
    # every unit at once: 2 GB on 2 cores, or a LocalCluster that never started
    (dict(name="processes", workers=_TOO_MANY), f"workers = {_TOO_MANY}: at most {max_workers()} on this machine"),
    (dict(name="dask", workers=1_000_000), f"workers = 1000000: at most {max_workers()}"),
    # "not enough values to unpack" from deep inside distributed
    (dict(name="dask", scheduler="inproc://x"), "scheduler = 'inproc://x': expected the address of a running dask"),
    (dict(name="dask", scheduler="tcp://host"), "scheduler = 'tcp://host': expected"),
    (dict(name="dask", scheduler="tcp://host:0"), "scheduler = 'tcp://host:0': expected"),
    (dict(name="dask", scheduler="tcp://host:65536"), "scheduler = 'tcp://host:65536': expected"),
    (dict(name="dask", scheduler="tcp://:8786"), "scheduler = 'tcp://:8786': expected"),
    (dict(name="dask", scheduler="tcp://h:8786/x"), "scheduler = 'tcp://h:8786/x': expected"),
    (dict(name="dask", scheduler="tls://h:8786"), "scheduler = 'tls://h:8786': expected"),
    (dict(name="dask", scheduler="127.0.0.1:8786"), "scheduler = '127.0.0.1:8786': expected"),
])
def test_bad_workers_and_schedulers_are_refused_naming_them(kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        check_executor(**kwargs)


def test_the_bound_and_the_scheduler_addresses_that_are_accepted():
    assert max_workers() == WORKERS_PER_CORE * len(os.sched_getaffinity(0))
    check_executor("processes", max_workers())
    check_executor("dask", max_workers())
    check_executor("serial")
    for address in ("tcp://127.0.0.1:8786", "tcp://[::1]:8786", "tcp://node-3.cluster.local:1", "tcp://h:65535"):
        check_executor("dask", None, address)


def test_workers_with_the_serial_executor_exits_2_before_any_work(tmp_path, capsys):
    from tissuebench.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "s"\n[protocol]\nlatency_steps = 5\n[[case]]\nname = "cornea_pinch"\n'
                    '[[method]]\nname = "nearest"\n')
    assert main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--quiet", "--workers", "5"]) == 2
    assert "workers = 5: executor 'serial'" in capsys.readouterr().err and not (tmp_path / "out").exists()


def test_a_local_cluster_that_cannot_start_fails_and_marks_the_sweep_failed(tmp_path, capsys, monkeypatch):
    """A LocalCluster whose workers do not start (a process limit; 10**6 workers) left the sweep
    waiting, and ``_sweep.json`` "running" once killed: now an error within the start timeout."""
    from tissuebench.cli import main
    from tissuebench.studies import executors
    from tissuebench.studies.sweep_manifest import read_sweep_manifest

    monkeypatch.setattr(executors, "start_timeout_s", lambda workers: 1e-6)  # no process starts in 1 us
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "s"\n[protocol]\nlatency_steps = 5\n[[case]]\nname = "cornea_pinch"\n'
                    '[[method]]\nname = "nearest"\n')
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--quiet", "--executor", "dask", "--workers", "1"]) == 2
    err = capsys.readouterr().err
    assert "executor 'dask': a LocalCluster of workers = 1 could not start (0 of 1 workers running" in err, err
    assert read_sweep_manifest(out)["state"] == "failed" and not (out / ".lock").exists()
