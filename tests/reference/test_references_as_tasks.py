"""References as tasks on the dask executor (issue 30): a reference needed by several units of a
sweep is computed once per content hash, whether the units declare it (it runs as its own task
they wait for) or not (computed inside a unit under a cluster-wide lock named by its key).

The solve is counted in the worker processes themselves (a worker plugin logs each solve,
``_workers.RunLog``) and the cache is a ``file://`` folder they share. Each solve is held 1 s,
so two workers that both miss the cache overlap: without the tasks and the lock (the code
before issue 30) the path's reference was solved by both workers' first units, 2 times
(measured: see the issue's closing note)."""
from __future__ import annotations

import threading
import time
import uuid
from pathlib import Path

import pytest

from _gate_spec import BEYOND, cornea_spec
from _workers import RunLog

import tissuebench.reference.cache as cache_module
from tissuebench.studies.executors import execute
from tissuebench.studies.path_range import range_scenes
from tissuebench.reference import reference_key
from tissuebench.studies.results import read_units
from tissuebench.studies.spec import expand_units, load_spec
from tissuebench.studies.sweep import run_sweep
from tissuebench.studies.training import case_scene
from tissuebench.studies.units import unit_references

distributed = pytest.importorskip("distributed")

FIVE = cornea_spec(
    "five", ["nearest", ("pod_interp", 'grid = { n_modes = [2, 4], interpolation = ["linear", "rbf"] }')],
    latency_steps=5, warmup=1, evaluation=BEYOND)


@pytest.fixture()
def spec(tmp_path):
    p = tmp_path / "five.toml"
    p.write_text(FIVE)
    return load_spec(p)


@pytest.fixture()
def counted(monkeypatch):
    """Every solve the cache starts, by reference key, held 1 s (module docstring)."""
    solves, lock, real = [], threading.Lock(), cache_module.solve

    def solve(scene, backend="skfem", **kw):
        with lock:
            solves.append(reference_key(scene, backend, kw.get("linear_solver", "auto")))
        time.sleep(1.0)
        return real(scene, backend=backend, **kw)

    monkeypatch.setattr(cache_module, "solve", solve)
    return solves


def test_the_declared_references_are_the_ones_the_units_read(spec):
    units = expand_units(spec)
    scene = case_scene(units[0].case)
    assert len(units) == 5
    # the path and its range (issue 44: the finer path between the training states, the short one
    # near rest, one increment from rest to 1/64 and 1/1024 of the first training state) are declared
    # (their keys, on the case's backend); the continuation past the top is not
    ranges = [run for _, run in range_scenes(scene, 2)]
    assert len(ranges) == 4
    declared = [reference_key(s, "skfem") for s in [scene, *ranges]]
    assert all(list(unit_references(u)) == declared for u in units)


@pytest.mark.slow  # ~11 s (two worker processes); the default run keeps the cache-argument test of this file
def test_a_reference_five_units_need_is_computed_once_on_two_workers(spec, tmp_path):
    """Two worker processes (threads of one process running units side by side segfaulted once in
    native code, README command 2 beside another run), a shared ``file://`` cache; every solve
    is logged by the workers (``_workers.RunLog``) and held 1 s so that misses overlap."""
    url = f"file://{tmp_path}/cache"
    log = tmp_path / "runs.log"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cl, \
            distributed.Client(cl) as client:
        client.register_plugin(RunLog(str(log), hold_s=1.0))
        summary = run_sweep(spec, tmp_path / "out", executor="dask", scheduler=cl.scheduler_address, progress=False,
                            cache=url)
    assert len(summary.computed) == 5 and not summary.failed, read_units(tmp_path / "out")["message"].tolist()
    counted = [key for what, key, _ in (ln.split() for ln in log.read_text().splitlines()) if what == "solve"]
    # six references: the path and its range's four (declared: tasks) and its continuation past the
    # top (not declared: computed by the first unit to need it under the lock, read by the other four)
    assert len(counted) == 6 and len(set(counted)) == 6, counted
    assert sorted(p.name for p in (tmp_path / "cache" / "references").iterdir()) == sorted(set(counted))


@pytest.mark.slow  # ~9 s: a process pool
def test_serial_and_processes_keep_their_cache_argument(spec, tmp_path, counted):
    """The cache a sweep is given reaches the units of every executor (not the environment's)."""
    url = f"memory://tb-{uuid.uuid4().hex[:8]}/serial"
    outcomes = list(execute(expand_units(spec)[:2], "serial", cache=url))
    assert all(o.row["unit_status"] == "ok" for _, o in outcomes)
    assert len(counted) == 6  # path, its range's four and continuation, once each, into the memory cache
    import fsspec

    assert len(fsspec.filesystem("memory").ls(f"/{url.split('://', 1)[1]}/references", detail=False)) == 6


def _ci_cases():
    spec = load_spec(Path(__file__).resolve().parents[2] / "tissuebench" / "studies" / "presets" / "ci.toml")
    cases = {u.case.id: u.case for u in expand_units(spec)}  # every case of the preset, once
    # the trained dynamic case (~14 s of reference runs) with the slow tests: cube-tension-dynamic
    # keeps the trajectory kinds in the default run
    return [pytest.param(c, id=i, marks=[pytest.mark.slow] if i == "cube-tension-dynamic-trained" else [])
            for i, c in cases.items() if c.training_kind != "operators" or c.evaluation_kind == "map"]


@pytest.mark.parametrize("case", _ci_cases())
def test_each_kind_declares_the_references_its_builders_read(case, monkeypatch):
    """What :func:`unit_references` declares for every case of the ci preset with references is
    read by the builders (a declared reference nobody reads would be computed for nothing), and
    what they read beyond it is the continuation past a path's top (``beyond``), the one reference
    not declared by design."""
    import tissuebench.studies.evaluation as evaluation
    import tissuebench.studies.path_range as path_range
    import tissuebench.studies.training as training
    from tissuebench.studies.units import WorkUnit

    read, real = {}, cache_module.cached_solve

    def recording(scene, backend="skfem", **kw):
        read[reference_key(scene, backend)] = scene
        return real(scene, backend, **kw)

    monkeypatch.setattr(training, "cached_solve", recording)
    monkeypatch.setattr(evaluation, "cached_solve", recording)
    monkeypatch.setattr(path_range, "cached_solve", recording)
    declared = unit_references(WorkUnit(case, "nearest", {}, {}, {}, "0" * 64))
    scene = case_scene(case)
    training.build_training(case, scene)
    if case.evaluation_kind not in evaluation.NEEDS_MODEL:
        evaluation.build_evaluation(case, scene)
    assert declared and set(declared) <= set(read)
    extra = [s for k, s in read.items() if k not in declared]
    assert len(extra) == (1 if case.evaluation.get("beyond") else 0), [s.mu for s in extra]
