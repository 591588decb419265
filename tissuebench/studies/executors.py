"""Where units run: ``serial`` (default, in this process), ``processes`` (a local pool) or
``dask`` (dask.distributed: an existing scheduler with ``scheduler="tcp://host:port"``,
else a LocalCluster on loopback).

Every executor runs :func:`~.units.run_unit` on plain-data units, one unit at a time per
worker process (threads_per_worker = 1), and yields ``(unit, outcome)`` as units finish;
the caller alone writes the store, so its contents do not depend on the executor.
Dask workers of an existing cluster need tissuebench importable (the same version).
"""
from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed

from .units import run_unit

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


def execute(units, name: str = "serial", workers: int | None = None, scheduler: str | None = None):
    """Yield ``(unit, UnitOutcome)`` for every unit, in completion order."""
    check_executor(name, workers, scheduler)
    if name == "serial":
        for u in units:
            yield u, run_unit(u)
    elif name == "processes":
        yield from _processes(units, workers or 2)
    else:
        yield from _dask(units, workers or 2, scheduler)


def _processes(units, workers):
    # spawn: a fresh interpreter per worker (no forked BLAS / NGSolve thread state)
    with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = {pool.submit(run_unit, u): u for u in units}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()


def _dask(units, workers, scheduler):
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
        futures = {client.submit(run_unit, u, key=f"unit-{u.key[:32]}", pure=False): u for u in units}
        for fut in dask_completed(futures):
            yield futures[fut], fut.result()
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
