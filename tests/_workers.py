"""Module-level unit functions for the executor tests (spawned workers import them by name)."""
from __future__ import annotations

import os
import signal
import time

from distributed.diagnostics.plugin import WorkerPlugin

from tissuebench.studies.units import UnitOutcome, run_unit


def sleepy(unit) -> UnitOutcome:
    """Sleep ``options["sleep"]`` seconds and return an ok row; ``options["die"]`` SIGKILLs the
    worker process running it after the sleep (as the out-of-memory killer would)."""
    time.sleep(unit.options.get("sleep", 0.0))
    if unit.options.get("die"):
        os.kill(os.getpid(), signal.SIGKILL)
    return UnitOutcome({"unit_key": unit.key, "unit_status": "ok", "message": f"pid {os.getpid()}"})


def run_saying_where(unit) -> UnitOutcome:
    """:func:`~tissuebench.studies.units.run_unit`, its row told which process ran it (``_pid``) and
    how that process found the unit's method (``_how``: "entry point", "module:Class" or
    "shipped")."""
    from tissuebench.rom.plugins import PLUGINS

    outcome = run_unit(unit)
    record = PLUGINS.get(unit.method)
    outcome.row.update(_pid=os.getpid(), _how=record.how if record is not None else "shipped")
    return outcome


class RunLog(WorkerPlugin):
    """A dask worker plugin writing one line per unit task started and finished, and per reference
    solve, to the file ``path`` (``start|end|solve KEY PID``; appends of a line are atomic): what the
    kill soak counts, in every worker, restarted ones included (the scheduler hands the plugin to
    each worker that joins)."""

    name = "tissuebench-run-log"

    def __init__(self, path: str, hold_s: float = 0.0):
        self.path, self.hold_s = path, hold_s  # hold_s: each solve held that long (misses overlap)

    def _write(self, what: str, key: str) -> None:
        with open(self.path, "a") as fh:
            fh.write(f"{what} {key} {os.getpid()}\n")

    def setup(self, worker):
        import tissuebench.reference.cache as cache

        real = cache.solve
        if getattr(real, "logged", False):
            return

        def solve(scene, backend="skfem", **kw):
            self._write("solve", cache.reference_key(scene, backend, kw.get("linear_solver", "auto")))
            time.sleep(self.hold_s)
            return real(scene, backend=backend, **kw)

        solve.logged = True
        cache.solve = solve

    def teardown(self, worker):
        pass

    def transition(self, key, start, finish, **kwargs):
        key = key if isinstance(key, str) else str(key)
        if not key.startswith("unit-"):
            return
        if finish == "executing":
            self._write("start", key)
        elif start == "executing" and finish == "memory":
            self._write("end", key)
