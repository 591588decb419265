"""Executors survive a worker process that dies (issue 26, item 7: a SIGKILLed worker of the
``processes`` pool gave a BrokenProcessPool traceback), tested with real SIGKILLs."""
from __future__ import annotations

import dataclasses
import multiprocessing
import os
import signal
import threading
import time

import pytest

from _workers import sleepy
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.executors import execute
from tissuebench.studies.units import WorkUnit, unit_references


def _units(*options):
    case = CaseEntry(id="c", name="cornea_pinch", resolution="ci", backend="skfem", training={"kind": "path"},
                     evaluation={"kind": "path"})
    return [WorkUnit(case, "nearest", o, {}, {"name": "t", "hash": "0" * 64}, f"{i:064x}")
            for i, o in enumerate(options)]


def test_7_a_unit_that_kills_its_worker_is_stored_failed_and_the_others_finish():
    units = _units({"sleep": 0.3}, {"die": True}, {"sleep": 0.3}, {"sleep": 0.1}, {"sleep": 0.1})
    t0 = time.perf_counter()
    done = {u.key: o.row for u, o in execute(units, "processes", 2, run=sleepy)}
    assert sorted(done) == sorted(u.key for u in units)  # every unit once, none lost
    dead = done[units[1].key]
    assert dead["unit_status"] == "failed" and "worker process running this unit died" in dead["message"]
    assert dead["case"] == "c" and dead["method"] == "nearest"  # a full row: the store writes it
    assert all(done[u.key]["unit_status"] == "ok" for u in units if u is not units[1])
    assert time.perf_counter() - t0 < 120


def test_7_a_worker_killed_from_outside_loses_no_unit():
    """SIGKILL of a busy worker (not the unit's doing): its unit and the pool's other units in
    flight run again, all finish ok."""
    units = _units(*[{"sleep": 1.5, "n": i} for i in range(4)])
    killed = []

    def kill_one():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            children = multiprocessing.active_children()
            busy = [p for p in children if p.pid and p.is_alive()]
            if len(busy) >= 2:
                time.sleep(0.5)  # both workers inside their first unit
                os.kill(busy[0].pid, signal.SIGKILL)
                killed.append(busy[0].pid)
                return
            time.sleep(0.05)

    threading.Thread(target=kill_one, daemon=True).start()
    done = {u.key: o.row for u, o in execute(units, "processes", 2, run=sleepy)}
    assert killed, "no worker was killed: nothing was tested"
    assert sorted(done) == sorted(u.key for u in units)
    assert all(r["unit_status"] == "ok" for r in done.values()), done
    assert str(killed[0]) not in {r["message"] for r in done.values()}


def test_minor_an_unreachable_scheduler_marks_the_sweep_failed(tmp_path):
    from tissuebench.cli import main
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
    assert sorted(u.key for u, _ in execute(units, name, 2, run=sleepy)) == sorted(u.key for u in units)


def test_a_unit_that_kills_every_dask_worker_it_runs_on_is_stored_failed_and_the_others_finish():
    """Dask runs a task whose worker died on another worker, up to ``allowed-failures`` times; past
    that (0 here: the first death) the unit is a failed row saying so, not the end of the sweep.
    (Dask counts a death against every task assigned to that worker: here one task per worker at a
    time, no reference task to wait for, and the one that dies waits 3 s, so that the others are
    done by then.)"""
    import dask

    operators = {"training": {"kind": "operators"}, "evaluation": {"kind": "cut_lengths"}}  # no reference declared
    units = [dataclasses.replace(u, case=dataclasses.replace(u.case, **operators))
             for u in _units({"sleep": 0.1}, {"die": True, "sleep": 3.0}, {"sleep": 0.1})]
    assert not any(unit_references(u) for u in units)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0, "distributed.scheduler.worker-saturation": 1.0}):
        done = {u.key: o.row for u, o in execute(units, "dask", 2, run=sleepy)}
    assert sorted(done) == sorted(u.key for u in units)
    dead = done[units[1].key]
    assert dead["unit_status"] == "failed" and "dask workers running this unit died" in dead["message"], dead
    assert dead["case"] == "c" and all(done[u.key]["unit_status"] == "ok" for u in (units[0], units[2]))


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
    BrokenProcessPool. Before, that propagated out of the sweep (likely what failed
    test_7_a_unit_that_kills_its_worker once in a default run at load 7, whose traceback was not
    kept); now the unit waits for the next pool, and every unit runs once, ok."""
    import tissuebench.studies.executors as executors

    _RacingPool.calls = 0
    real_pool = executors._pool
    monkeypatch.setattr(executors, "_pool", lambda workers: _RacingPool(real_pool(workers), broken_at))
    units = _units(*[{"sleep": 0.05, "n": i} for i in range(4)])
    done = [(u.key, o.row["unit_status"]) for u, o in execute(units, "processes", 2, run=sleepy)]
    assert sorted(done) == sorted((u.key, "ok") for u in units)
    assert _RacingPool.calls >= len(units) + len(broken_at)
