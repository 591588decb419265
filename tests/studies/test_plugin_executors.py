"""A method from another package runs in every process tissuebench starts (issue 38): the example
plugin (examples/bring_your_own_method), declared by an installed distribution's entry point
(its dist-info on PYTHONPATH: the real discovery), run by the ``processes`` pool and by a Dask
LocalCluster; each worker finds it by its entry point."""
from __future__ import annotations

import os

import pytest

from _gate_repo import EXAMPLE
from _gate_spec import HELD_OUT, cornea_spec
from _plugin_dist import Installed, forget_modules, on_path, write_dist
from _workers import run_saying_where
from tissuebench.studies.executors import execute
from tissuebench.studies.spec import expand_units, load_spec

SPEC = cornea_spec("plugin-executors", [("pod_polyreg", "list = [{ n_modes = 2, degree = 2 }]")],
                   evaluation=HELD_OUT)


@pytest.fixture
def podreg(tmp_path, monkeypatch):
    """The example installed as a distribution would be: its dist-info (entry point
    pod_polyreg = podreg.method:PodPolyReg) and its source folder on the path of every process."""
    inst = Installed(tmp_path / "site", monkeypatch)
    write_dist(inst.root, "tissuebench-podreg", "0.1.0", {"pod_polyreg": "podreg.method:PodPolyReg"}, {},
               top_level=["podreg"])
    on_path(monkeypatch, EXAMPLE / "src")
    yield inst
    inst.undo()
    forget_modules("podreg")


@pytest.mark.parametrize("executor", [pytest.param("processes", marks=pytest.mark.slow), "dask"])  # ~9 s each
def test_a_plugin_method_runs_on_the_parallel_executors(podreg, tmp_path, executor):
    spec = tmp_path / "s.toml"
    spec.write_text(SPEC)
    [unit] = expand_units(load_spec(spec))
    assert (unit.method, unit.source) == ("pod_polyreg", "podreg.method:PodPolyReg")
    [(done, outcome)] = list(execute([unit], executor, 1, run=run_saying_where))
    row = outcome.row
    assert done.key == unit.key and row["unit_status"] == "ok", row.get("message")
    assert row["_pid"] != os.getpid() and row["_how"] == "entry point"  # a worker, by the entry point
    assert (row["method_distribution"], row["method_version"]) == ("tissuebench-podreg", "0.1.0")
    assert 0 < row["max_rel_l2"] < 0.02  # the cornea's path between and below its training states (1.1 %: near rest)


def test_the_ab_probes_entry_builds_a_plugin_by_its_class_path(podreg):
    """The A/B units carry a plugin method as "module:Class" (plain data): the probe's entry into
    either side's code (gate.latency.prepare_unit) builds it from there."""
    from tissuebench.gate.latency import prepare_unit

    case = {"id": "c", "name": "cornea_pinch", "variant": None, "resolution": "ci", "backend": "skfem",
            "training": {"kind": "path", "every": 2}, "evaluation": {"kind": "path", "held_out": True}}
    prepared = prepare_unit(case, "podreg.method:PodPolyReg", {"n_modes": 2, "degree": 2}, steps=5)
    assert type(prepared.model).__module__ == "podreg.method" and len(prepared.sequence) >= 5
