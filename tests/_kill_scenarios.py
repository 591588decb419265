"""Sweeps whose workers are SIGKILLed, each run by ``tests/studies/test_executors.py`` in an
interpreter of its own (``python -X faulthandler -m _kill_scenarios NAME``), as a user's
``tissuebench sweep --executor ...`` runs: what a real SIGKILL does to a process pool is then
seen in the exit status and the stderr of that process, not as a crash of the test runner's worker
(CI lost an xdist worker running the processes case once, with no traceback kept).

Each scenario prints one JSON object: ``rows`` (unit key -> the fields the tests read) and what
else its test asserts.
"""
from __future__ import annotations

import dataclasses
import json
import multiprocessing
import os
import signal
import sys
import threading
import time

from _workers import sleepy
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.executors import execute
from tissuebench.studies.units import WorkUnit, unit_references


def units(*options):
    case = CaseEntry(id="c", name="cornea_pinch", resolution="ci", backend="skfem", training={"kind": "path"},
                     evaluation={"kind": "path"})
    return [WorkUnit(case, "nearest", o, {}, {"name": "t", "hash": "0" * 64}, f"{i:064x}")
            for i, o in enumerate(options)]


def _rows(done):
    return {u.key: {k: o.row.get(k) for k in ("unit_status", "message", "case", "method")} for u, o in done}


def unit_that_kills_its_worker() -> dict:
    todo = units({"sleep": 0.3}, {"die": True}, {"sleep": 0.3}, {"sleep": 0.1}, {"sleep": 0.1})
    t0 = time.perf_counter()
    rows = _rows(execute(todo, "processes", 2, run=sleepy))
    return {"keys": [u.key for u in todo], "rows": rows, "seconds": time.perf_counter() - t0}


def worker_killed_from_outside() -> dict:
    """SIGKILL of a busy worker of the pool (not the unit's doing) once both workers are inside
    their first unit."""
    todo = units(*[{"sleep": 1.5, "n": i} for i in range(4)])
    killed = []

    def kill_one():
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            busy = [p for p in multiprocessing.active_children() if p.pid and p.is_alive()]
            if len(busy) >= 2:
                time.sleep(0.5)  # both workers inside their first unit
                os.kill(busy[0].pid, signal.SIGKILL)
                killed.append(busy[0].pid)
                return
            time.sleep(0.05)

    threading.Thread(target=kill_one, daemon=True).start()
    rows = _rows(execute(todo, "processes", 2, run=sleepy))
    return {"keys": [u.key for u in todo], "rows": rows, "killed": killed}


def unit_that_kills_every_dask_worker() -> dict:
    """Dask, ``allowed-failures`` 0: the unit whose worker died once is a failed row."""
    import dask

    operators = {"training": {"kind": "operators"}, "evaluation": {"kind": "cut_lengths"}}  # no reference declared
    todo = [dataclasses.replace(u, case=dataclasses.replace(u.case, **operators))
            for u in units({"sleep": 0.1}, {"die": True, "sleep": 3.0}, {"sleep": 0.1})]
    assert not any(unit_references(u) for u in todo)
    with dask.config.set({"distributed.scheduler.allowed-failures": 0, "distributed.scheduler.worker-saturation": 1.0}):
        rows = _rows(execute(todo, "dask", 2, run=sleepy))
    return {"keys": [u.key for u in todo], "rows": rows}


def the_process_itself_killed() -> dict:
    """The negative control of the tests' harness: the scenario's own process SIGKILLed."""
    os.kill(os.getpid(), signal.SIGKILL)
    return {}


SCENARIOS = {f.__name__: f for f in (unit_that_kills_its_worker, worker_killed_from_outside,
                                     unit_that_kills_every_dask_worker, the_process_itself_killed)}

if __name__ == "__main__":
    print(json.dumps(SCENARIOS[sys.argv[1]]()))
