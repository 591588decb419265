"""Where units run: ``serial`` (default, in this process), ``processes`` (a local pool) or
``dask`` (dask.distributed: an existing scheduler with ``scheduler="tcp://host:port"``,
else a LocalCluster on loopback).

Every executor runs :func:`~.units.run_unit` on plain-data units, one unit at a time per
worker process (threads_per_worker = 1), and yields ``(unit, outcome)`` as units finish;
the caller alone writes the store, so its contents do not depend on the executor.
Dask workers of an existing cluster need tissuebench importable (the same version).
``workers`` sizes the local pools only, at most :data:`WORKERS_PER_CORE` per core
(:func:`check_executor`); a LocalCluster whose workers do not all run within
:func:`start_timeout_s` is an error (:func:`_local_cluster`), never a sweep waiting for ever.

The reference cache a unit uses travels with it (``cache``: a folder or an fsspec URL,
:mod:`.reference.location`), never read from a worker's environment by accident: on a cluster
of several machines it must be a location every worker reaches (``s3://...``, a shared
folder). On dask, the reference runs a unit declares (:func:`~.units.unit_references`) are
tasks of their own, one per content hash, submitted before the units, and each unit takes the
results of its references' tasks as arguments, so it starts once they are in the cache; a
reference a unit did not declare is computed by the unit under a cluster-wide lock
(:func:`~.reference.cache.cached_solve`): never twice at once.

A worker process that dies (SIGKILL, the out-of-memory killer, a crash in native code)
does not end the sweep. Dask resubmits the lost task itself (a unit whose workers died
``distributed.scheduler.allowed-failures`` + 1 times is stored as failed, saying so). A unit whose
result could not be gathered (lost with its worker after it ended, or cancelled) is submitted
again, at most :data:`RESUBMITS` times (:func:`_dask_units`). The ``processes`` pool breaks
as a whole when one worker dies, losing every unit in flight: they are run again in a
fresh pool, one at a time (so the unit that kills its worker is known); a unit whose worker
dies while it runs alone is stored as failed, saying so, and the sweep goes on. A ``SystemExit``
(or a ``KeyboardInterrupt`` no signal sent) that a unit's code raises is its stored failure in
every executor (:func:`_in_cache`): no worker dies of it and no other unit is lost.
"""
from __future__ import annotations

import contextlib
import functools
import logging
import multiprocessing
import os
import re
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from ..exits import EXIT_TYPES, exit_text, raised_by_code, user_signals
from ..reference.cache import cache_url, cached_solve
from ..reference.location import CACHE_ENV, check_cache_url, using_cache
from .units import failed_outcome, run_unit, unit_references

__all__ = ["EXECUTORS", "WORKERS_PER_CORE", "execute", "check_executor", "check_scheduler", "max_workers"]

EXECUTORS = ("serial", "processes", "dask")
logger = logging.getLogger(__name__)


WORKERS_PER_CORE = 4  # a unit is single-threaded: more workers than this per core only share the cores
#: how long a sweep waits for a ``--scheduler`` to answer before it says it cannot be reached
SCHEDULER_CONNECT_TIMEOUT_S = 10.0
# tcp://HOST:PORT, HOST a name, an IPv4 address or a bracketed IPv6 address (what dask's tcp comm parses)
_SCHEDULER = re.compile(r"tcp://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9](?:[A-Za-z0-9._-]*[A-Za-z0-9])?):([0-9]{1,5})")


def max_workers() -> int:
    """The most worker processes a local executor (``processes``, dask's LocalCluster) starts:
    :data:`WORKERS_PER_CORE` per core this process may run on."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return WORKERS_PER_CORE * max(1, cores)


def check_scheduler(scheduler) -> str:
    """``scheduler`` when it is a dask scheduler address this executor connects to,
    ``tcp://HOST:PORT`` (port 1-65535); else ValueError naming it."""
    m = _SCHEDULER.fullmatch(scheduler) if isinstance(scheduler, str) else None
    if m is None or not 1 <= int(m.group(2)) <= 65535:
        raise ValueError(f"scheduler = {scheduler!r}: expected the address of a running dask scheduler, "
                         "tcp://HOST:PORT (e.g. tcp://127.0.0.1:8786)")
    return scheduler


def check_executor(name: str, workers: int | None = None, scheduler: str | None = None) -> None:
    """ValueError naming a bad executor, worker count or scheduler address (before any work).

    ``workers`` sizes a local pool (``processes``, a dask LocalCluster): at most
    :func:`max_workers`; it is refused where it would do nothing (``serial``, which runs units in
    this process, and a ``scheduler``'s cluster, whose workers ``dask worker`` started)."""
    if name not in EXECUTORS:
        raise ValueError(f"executor = {name!r}: valid: {list(EXECUTORS)}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise ValueError(f"workers = {workers!r}: expected a positive integer")
    if workers is not None and name == "serial":
        raise ValueError(f"workers = {workers}: executor 'serial' runs the units one at a time in this process and "
                         "starts no worker; give --executor processes or dask, or leave --workers out")
    if workers is not None and scheduler is not None:
        raise ValueError(f"workers = {workers}: the cluster at scheduler = {scheduler!r} has the workers `dask worker` "
                         "started there; --workers sizes a local cluster only (leave it out)")
    if workers is not None and workers > max_workers():
        raise ValueError(f"workers = {workers}: at most {max_workers()} on this machine ({WORKERS_PER_CORE} per core "
                         f"this process may run on): each worker is a process running one single-threaded unit, "
                         "more only share the cores (a cluster: --executor dask --scheduler)")
    if scheduler is not None and name != "dask":
        raise ValueError(f"scheduler = {scheduler!r} needs executor 'dask' (got {name!r})")
    if scheduler is not None:
        check_scheduler(scheduler)


def execute(units, name: str = "serial", workers: int | None = None, scheduler: str | None = None, run=run_unit,
            cache=None):
    """Yield ``(unit, UnitOutcome)`` for every unit, in completion order (``run``: the function
    a worker applies to a unit, :func:`~.units.run_unit`; a module-level function). ``cache``:
    the reference cache the units use (module docstring); None: this process's
    (:func:`~.reference.location.cache_url`), except on an existing dask cluster, whose workers
    then use each their own."""
    check_executor(name, workers, scheduler)
    if cache is not None:
        cache = check_cache_url(cache)
    elif name != "dask" or scheduler is None:
        cache = check_cache_url(cache_url(), CACHE_ENV)
    in_cache = functools.partial(_in_cache, run, cache)
    if name == "serial":
        for u in units:
            yield u, in_cache(u)
    elif name == "processes":
        yield from _processes(units, workers or 2, in_cache)
    else:
        yield from _dask(units, workers or 2, scheduler, run, cache)


def _in_cache(run, cache, unit, *references):
    """``run(unit)`` with the reference cache at ``cache``; ``references``: what the unit's
    reference tasks returned (their runs are in the cache: the arguments only order the tasks).

    In every executor and worker, the user's SIGINT is recorded meanwhile
    (:func:`~tissuebench.exits.user_signals`), so that a ``SystemExit`` or ``KeyboardInterrupt``
    raised by code, not sent by the user, that ``run`` lets through (:func:`~.units.run_unit`
    catches the method's own) fails this unit only: from a ``processes`` worker it would come back
    as the unit's result and end the sweep."""
    with using_cache(cache), user_signals():
        try:
            return run(unit)
        except EXIT_TYPES as exc:
            if not raised_by_code(exc):
                raise  # the user's Ctrl-C: the sweep stops, resumably
            return failed_outcome(unit, f"{exit_text(exc, 'the code running this unit')}; the sweep went on")


def reference_task(scene, backend: str, cache) -> str:
    """Compute the reference run of ``scene`` into ``cache`` unless it is there: ``"hit"``,
    ``"solved"``, or ``"failed: ..."``. Never raises: a unit that needs a reference that could not
    be computed meets the error itself, and stores it as its failure."""
    try:
        with using_cache(cache):
            return "hit" if cached_solve(scene, backend)[1] else "solved"
    except Exception as exc:  # noqa: BLE001 - see the docstring
        return f"failed: {type(exc).__name__}: {exc}"


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
                if not in_flight and suspects:  # a suspect runs alone: its own death is its own
                    _submit(pool, run, suspects, in_flight)
                while not alone and queue and len(in_flight) < workers and _submit(pool, run, queue, in_flight):
                    pass
                if not in_flight:  # the pool broke before anything could run on it: a new pool
                    break
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


def _submit(pool, run, waiting: list, in_flight: dict) -> bool:
    """Submit the last unit of ``waiting`` to ``pool``; False, with the unit left waiting, when the
    pool broke before it could take it (a worker died since the last wait returned: a race
    between one unit's death and another's end, which raised out of the sweep under load)."""
    try:
        future = pool.submit(run, waiting[-1])
    except BrokenProcessPool:
        return False
    in_flight[future] = (waiting.pop(), time.perf_counter())
    return True


def _dask(units, workers, scheduler, run, cache):
    try:
        from distributed import Client, LocalCluster, as_completed as dask_completed
    except ImportError as exc:  # pragma: no cover - dask is a dependency
        raise ValueError(f"executor 'dask' needs dask[distributed]: {exc}") from None
    cluster = None
    if scheduler is None:
        cluster, client = _local_cluster(LocalCluster, Client, workers)
    else:
        try:
            client = Client(scheduler, timeout=f"{SCHEDULER_CONNECT_TIMEOUT_S}s")
        except (OSError, TimeoutError) as exc:
            raise ValueError(f"scheduler = {scheduler!r} cannot be reached: {exc}") from None
    try:
        yield from _dask_units(client, units, run, cache, dask_completed)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def start_timeout_s(workers: int) -> float:
    """How long a LocalCluster of ``workers`` workers may take to start [s]: a spawned worker
    imports dask and numpy (seconds on a loaded machine), so a minute plus 15 s per worker."""
    return 60.0 + 15.0 * workers


def _local_cluster(LocalCluster, Client, workers: int):
    """``(cluster, client)`` of a LocalCluster on loopback whose ``workers`` workers all run; a
    cluster that cannot start them within :func:`start_timeout_s` (a process limit, a worker that
    dies on start) is closed and a ValueError says so (the sweep is then marked failed)."""
    cluster = client = None
    try:
        cluster = LocalCluster(n_workers=0, threads_per_worker=1, processes=True, host="127.0.0.1",
                               dashboard_address=None)
        client = Client(cluster)
        cluster.scale(workers)
        client.wait_for_workers(workers, timeout=start_timeout_s(workers))
    except Exception as exc:  # noqa: BLE001 - whatever stopped it, the sweep cannot run on it
        running = 0
        with contextlib.suppress(Exception):
            running = len(client.scheduler_info().get("workers", {}))
        for closing in (client, cluster):
            with contextlib.suppress(Exception):
                if closing is not None:
                    closing.close()
        raise ValueError(f"executor 'dask': a LocalCluster of workers = {workers} could not start ({running} of "
                         f"{workers} workers running; {start_timeout_s(workers):.0f} s allowed): "
                         f"{type(exc).__name__}: {exc}") from None
    return cluster, client


RESUBMITS = 2  # a unit whose result was lost (not its run) is submitted again at most this often


def _dask_units(client, units, run, cache, dask_completed):
    """Submit every reference task, then every unit depending on its references; yield
    ``(unit, outcome)`` as units end. A unit whose task errs
    (``KilledWorker``: its workers died ``allowed-failures`` + 1 times while running it) is stored
    failed; one whose result was lost or cancelled (its worker died after it ended, the
    connection dropped) is submitted again, at most :data:`RESUBMITS` times, then stored failed."""
    references, futures, needs = {}, {}, {}
    declared = [(u, unit_references(u)) for u in units]
    for u, refs in declared:  # every reference first: submitted earlier, they run first
        for key, scene in refs.items():
            if key not in references:
                references[key] = client.submit(reference_task, scene, u.case.backend, cache,
                                                key=f"reference-{key}", pure=False)

    def submit(u, key):  # a unit waits for its references' tasks: their futures are its arguments
        fut = client.submit(_in_cache, run, cache, u, *needs[u.key], key=key, pure=False)
        futures[fut] = u
        return fut

    for u, refs in declared:
        needs[u.key] = [references[k] for k in refs]
        submit(u, f"unit-{u.key}")
    tries = {}
    # as_completed without results: with them, a gather that fails inside its tracking coroutine
    # drops the future and the iteration waits forever (seen in the kill soak, seed 5)
    done = dask_completed(list(futures))
    for fut in done:
        u = futures.pop(fut)
        try:
            outcome = fut.result()
        except Exception as exc:  # noqa: BLE001 - the unit never raises: read the task's end below
            outcome = exc
        if not isinstance(outcome, BaseException):
            yield u, outcome
            continue
        if fut.status == "error":  # the unit itself never raises: KilledWorker, its own or a reference's
            dead = [r.key for r in needs[u.key] if r.status == "error"]
            whose = f"its reference task {dead[0]}" if dead else "this unit"
            why = f"the dask workers running {whose} died ({type(outcome).__name__}: {outcome})"
        else:
            why = f"its result was lost ({fut.status}: {type(outcome).__name__}: {outcome})"
            tries[u.key] = tries.get(u.key, 0) + 1
            if tries[u.key] <= RESUBMITS:
                logger.warning("%s: %s; submitted again (%d of %d)", u.label, why, tries[u.key], RESUBMITS)
                done.add(submit(u, f"unit-{u.key}-again-{tries[u.key]}"))
                continue
        yield u, failed_outcome(u, f"{why}; the sweep went on")
