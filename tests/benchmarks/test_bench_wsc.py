"""Online step of the skinning-cubature ROM (``wsc``) on the cube bar in tension (dynamics).

Each round times ONE ``step`` (+ ``outputs``, the haptic step) of a model started from rest
and advanced by a few warm-up steps; rounds continue along the trajectory (the pull at
constant velocity of ``cube_tension_twist/tension_dynamic``, backward Euler, 5 ms).
Configurations: the paper's default (250 handles, 3000 cubature elements) and a small one
(20 handles, 400 elements) -- at ci the same fractions of the 208-vertex mesh. Run::

    .venv/bin/pytest tests/benchmarks/test_bench_wsc.py --benchmark-only
    TISSUEBENCH_BENCH_FULL=1 ... # paper mesh (7744 vertices / 37800 tets)

The RMSE beside the step time is the harness's (``tissuebench sweep --preset wsc_table1``,
A/B latency and exact errors in one run); here only the step cost is timed.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

from tissuebench.cases import load
from tissuebench.refsolvers.backends import make_backend
from tissuebench.rom import Training, make_method

pytestmark = pytest.mark.benchmark

FULL = os.environ.get("TISSUEBENCH_BENCH_FULL", "") == "1"
ROUNDS = int(os.environ.get("TISSUEBENCH_BENCH_ROUNDS", "20"))
WARMUP_STEPS = 10
# (handles, cubature elements) at the paper mesh; fractions of it at ci
CONFIGS = {"paper_default": (250, 3000), "small": (20, 400)}
PAPER_SIZE = (7744, 37800)


@pytest.fixture(scope="module")
def scene_and_backend():
    scene = load("cube_tension_twist", resolution="paper" if FULL else "ci", variant="tension_dynamic")
    return scene, make_backend("skfem", scene.to_problem())


@pytest.mark.parametrize("config", sorted(CONFIGS))
def test_wsc_step_time(benchmark, scene_and_backend, config):
    scene, be = scene_and_backend
    h, c = CONFIGS[config]
    if not FULL:
        h = max(2, round(h * be.problem.mesh.n_vertices / PAPER_SIZE[0]))
        c = max(10, round(c * be.problem.mesh.n_cells / PAPER_SIZE[1]))
    dt = float(scene.analysis["dt"])
    model = make_method("wsc", handles=h, cubature_elements=c, rtol=1e-3).build(Training(backend=be, dt=dt))
    model.start()
    clock = {"k": 0}

    def step():
        clock["k"] += 1
        t = clock["k"] * dt
        if t > scene.analysis["t_end"] + 1e-12:  # end of the pull: restart from rest
            model.start()
            clock["k"], t = 1, dt
        res = model.step({"time": t, "load_factor": float(scene.history(t))})
        model.outputs(res)
        return res

    for _ in range(WARMUP_STEPS):
        step()
    results = []
    benchmark.pedantic(lambda: results.append(step()), rounds=ROUNDS, iterations=1, warmup_rounds=0)
    assert all(r.ok for r in results), [r.message for r in results if not r.ok]
    benchmark.extra_info.update({"handles": h, "cubature_elements": c, "n_z": model.info["n_z"],
                                 "n_vertices": be.problem.mesh.n_vertices, "full_size": FULL,
                                 "evaluations": [r.info["evaluations"] for r in results]})
    assert np.all(np.isfinite(results[-1].q))
