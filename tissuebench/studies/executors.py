"""Where units run: ``serial`` (default, in this process), ``processes`` (a local pool) or
``dask`` (dask.distributed: an existing scheduler with ``scheduler="tcp://host:port"``,
else a LocalCluster on loopback).

Every executor runs :func:`~.units.run_unit` on plain-data units, one unit at a time per
worker process (threads_per_worker = 1), and yields ``(unit, outcome)`` as units finish;
the caller alone writes the store, so its contents do not depend on the executor.
Dask workers of an existing cluster need tissuebench importable (the same version).

A worker process that dies (SIGKILL, the out-of-memory killer, a crash in native code)
does not end the sweep. Dask resubmits the lost task itself. The ``processes`` pool breaks
as a whole when one worker dies, losing every unit in flight: they are run again in a
fresh pool, one at a time (so the unit that kills its worker is known); a unit whose worker
dies while it runs alone is stored as failed, saying so, and the sweep goes on.
"""
from __future__ import annotations

import multiprocessing
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from .units import failed_outcome, run_unit

__all__ = ["EXECUTORS", "execute", "check_executor"]

EXECUTORS = ("serial", "processes", "dask")


def check_executor(name: str, workers: int | None = None, scheduler: str | None = None) -> None:
    """ValueError naming a bad executor, worker count or scheduler address (before any work)."""
    if name not in EXECUTORS:
        raise ValueError(f"executor = {name!r}: valid: {list(EXECUTORS)}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers = {workers!r}: expected a positive integer")
    if scheduler is not None and name != "dask":
        raise ValueError(f"scheduler = {scheduler!r} needs executor 'dask' (got {name!r})")
    if scheduler is not None and not (isinstance(scheduler, str) and "://" in scheduler):
        raise ValueError(f"scheduler = {scheduler!r}: expected an address such as tcp://127.0.0.1:8786")


def execute(units, name: str = "serial", workers: int | None = None, scheduler: str | None = None, run=run_unit):
    """Yield ``(unit, UnitOutcome)`` for every unit, in completion order (``run``: the function
    a worker applies to a unit, :func:`~.units.run_unit`; a module-level function)."""
    check_executor(name, workers, scheduler)
    if name == "serial":
        for u in units:
            yield u, run(u)
    elif name == "processes":
        yield from _processes(units, workers or 2, run)
    else:
        yield from _dask(units, workers or 2, scheduler, run)


def _pool(workers):
    # spawn: a fresh interpreter per worker (no forked BLAS / NGSolve thread state)
    return ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"))


def _processes(units, workers, run):
    """At most ``workers`` units in flight; after a worker died, the units it took down run
    again one at a time (module docstring)."""
    queue, suspects = list(units)[::-1], []
    while queue or suspects:
        pool = _pool(workers)
        in_flight = {}
        try:
            while queue or suspects or in_flight:
                alone = bool(suspects)
                while not in_flight and suspects:  # a suspect runs alone: its own death is its own
                    u = suspects.pop()
                    in_flight[pool.submit(run, u)] = (u, time.perf_counter())
                while not alone and queue and len(in_flight) < workers:
                    u = queue.pop()
                    in_flight[pool.submit(run, u)] = (u, time.perf_counter())
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                for fut in done:
                    u, t0 = in_flight.pop(fut)
                    try:
                        outcome = fut.result()
                    except BrokenProcessPool:
                        if alone:
                            yield u, failed_outcome(u, "the worker process running this unit died (killed by a "
                                                       "signal, out of memory, or a crash in native code); the "
                                                       "sweep went on", time.perf_counter() - t0)
                        else:
                            suspects.append(u)
                        continue
                    yield u, outcome
                if any(isinstance(f.exception(), BrokenProcessPool) for f in done if f.done()):
                    # the pool is gone: what is still in flight died with it; run it again
                    suspects += [u for u, _ in in_flight.values()]
                    in_flight.clear()
                    break
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


def _dask(units, workers, scheduler, run):
    try:
        from distributed import Client, LocalCluster, as_completed as dask_completed
    except ImportError as exc:  # pragma: no cover - dask is a dependency
        raise ValueError(f"executor 'dask' needs dask[distributed]: {exc}") from None
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
        client = Client(cluster)
    else:
        try:
            client = Client(scheduler, timeout="10s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"scheduler = {scheduler!r} cannot be reached: {exc}") from None
    try:
        futures = {client.submit(run, u, key=f"unit-{u.key[:32]}", pure=False): u for u in units}
        for fut in dask_completed(futures):
            yield futures[fut], fut.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
