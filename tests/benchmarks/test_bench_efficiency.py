"""The efficiency of every method's haptic step: its arithmetic floor over its median step.

``pytest -n 0 -m slow tests/benchmarks/test_bench_efficiency.py --benchmark-enable -s`` runs, for one unit
of every registered method (the first of its units in the ``ci`` preset; ``pgd_svk``, which
that preset does not carry, from ``pgd_cutting``'s ``cornea-svk`` case), the latency protocol
of the sweeps (:func:`tissuebench.studies.protocol.time_latency`: 2000 haptic steps, step +
outputs back to back, the model's floor :meth:`~tissuebench.rom.OnlineModel.floor_ops` timed
right after each) and records in ``extra_info``: the median and p99 step, the floor, the
efficiency ``floor / median`` (issue 32's target: >= 0.5), the calibration kernel (256 x 256
matmul) and the load average, so a figure says under which load it was taken. Nothing is
asserted on the timings (a shared machine makes them noisy; the gate and the report read
the sweep's columns; ``-s`` prints one line per method); the untimed run (``-m slow`` without
``--benchmark-enable``) steps each model a few times and checks the floor runs. Slow: every
unit builds its model.
"""
from __future__ import annotations

import os

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from tissuebench.rom import METHODS, make_method
from tissuebench.studies.evaluation import NEEDS_MODEL, build_evaluation
from tissuebench.studies.protocol import calibration_seconds, time_latency
from tissuebench.studies.spec import expand_units, load_spec
from tissuebench.studies.training import build_training, case_scene

pytestmark = [pytest.mark.benchmark, pytest.mark.slow]


def _units():
    chosen = {}
    for preset in ("ci", "pgd_cutting"):
        for unit in expand_units(load_spec(preset, resolution="ci")):
            chosen.setdefault(unit.method, unit)
    return [chosen[m] for m in sorted(chosen)]


UNITS = _units()


def test_every_method_has_a_unit():
    assert {u.method for u in UNITS} == set(METHODS)


def _model(unit):
    scene = case_scene(unit.case)
    training = build_training(unit.case, scene)
    needs_model = unit.case.evaluation_kind in NEEDS_MODEL
    evaluation = None if needs_model else build_evaluation(unit.case, scene)
    model = make_method(unit.method, **unit.options).build(training)
    if needs_model:
        evaluation = build_evaluation(unit.case, scene, model)
    if training.outputs:
        model.attach_outputs(training.outputs)
    history = training.history or (scene.history if evaluation.kind == "trajectory" else None)
    return model, evaluation, history


@pytest.mark.parametrize("unit", UNITS, ids=[f"{u.method}-{u.case.id}" for u in UNITS])
def test_efficiency(benchmark, unit):
    model, evaluation, history = _model(unit)
    slow = unit.method in ("pod_newton",)  # full assembly per iteration: tens of ms a step
    steps = 5 if benchmark.disabled else (50 if slow else 2000)
    with threadpool_limits(1, "blas"):
        lat = benchmark.pedantic(lambda: time_latency(model, evaluation, history, steps=steps,
                                                      warmup=2 if slow else 50), rounds=1, iterations=1)
        calibration = calibration_seconds()
    h, f = lat["haptic"], lat["floor"]
    efficiency = f.median / h.median
    benchmark.extra_info.update(method=unit.method, case=unit.case.id, options=unit.options,
                                median_us=h.median * 1e6, p99_us=h.p99 * 1e6, floor_us=f.median * 1e6,
                                efficiency=efficiency, calibration_ms=calibration * 1e3,
                                load_average=os.getloadavg()[0], steps=h.n)
    print(f"{unit.method:15s} {unit.case.id:24s} median {h.median * 1e6:10.2f} us  p99 {h.p99 * 1e6:10.2f} us  "
          f"floor {f.median * 1e6:9.2f} us  efficiency {efficiency:5.2f}  (calibration {calibration * 1e3:.3f} ms, "
          f"load {os.getloadavg()[0]:.2f})")
    assert h.n >= steps and f.n == h.n and np.isfinite(efficiency) and efficiency > 0
