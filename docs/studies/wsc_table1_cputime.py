"""Table 1's step times as CPU time of the stepping thread, beside the wall time (issue 31).

    PYTHONPATH=$PWD python docs/studies/wsc_table1_cputime.py OUT.csv [bgbc|rbf] [h/c ...]
    WSC_SCENE=left_ventricle:mooney_rivlin_dynamic ... OUT.csv bgbc 300/3600   # the ventricle

On a shared machine (2 cores, load 9-14 while we measured) the wall time of a step counts the
time the process waits for a core; the CPU time of the stepping thread
(``time.thread_time``, one BLAS thread as in the harness) does not, and is what the step costs
on a core of its own (memory-bandwidth contention from the other processes still counts). For
every Table 1 row (handles / cubature elements on the 7744-vertex cube), the ROM is built
(the cubature rule computed once per element budget), warmed up by 20 steps and driven through
the 200-step pull timed step by step (step + outputs, as the harness's latency pass). Writes
one row per configuration: the relative RMSE of the displacement history against the cached
FE reference (the harness's), wall and CPU medians and p99, evaluations per step, the
step-matrix operator, and the load average.
"""
from __future__ import annotations

import functools
import os
import sys
import time

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

import tissuebench.rom.wsc.method as wsc_method
from tissuebench.cases import load
from tissuebench.refsolvers.backends import make_backend
from tissuebench.rom import Training, make_method
from tissuebench.reference import cached_solve

WARMUP = 20
ROWS = [(h, c) for c in (1880, 2350, 2820) for h in (74, 108, 150, 180, 220, 250, 290, 327, 364)]


def main(out, cubature="bgbc", *rows):
    rows = [tuple(int(x) for x in r.split("/")) for r in rows] or ROWS
    for name in ("bgbc_cubature", "rbf_cubature"):  # one rule per element budget (one mesh here)
        setattr(wsc_method, name, _per_budget(getattr(wsc_method, name)))
    name, variant = os.environ.get("WSC_SCENE", "cube_tension_twist:tension_dynamic").split(":")
    scene = load(name, resolution="paper", variant=variant)
    be = make_backend("skfem", scene.to_problem())
    dt = float(scene.analysis["dt"])
    n = int(round(scene.analysis["t_end"] / dt))
    ref, _ = cached_solve(scene, "skfem")  # the harness's reference run (cached): the RMSE beside the times
    U_ref = ref.displacement.reshape(len(ref.steps), -1)[1:n + 1]
    records = []
    for h, c in rows:
        model = make_method("wsc", handles=h, cubature_elements=c, cubature=cubature, rtol=1e-3).build(
            Training(backend=be, dt=dt))
        wall, cpu, evals, fields = [], [], [], []
        with threadpool_limits(1):
            model.start()
            for k in range(1, WARMUP + 1):  # warm-up steps, then the timed pull from the start
                model.step({"time": k * dt, "load_factor": float(scene.history(k * dt))})
            model.start()
            for k in range(1, n + 1):
                mu = {"time": k * dt, "load_factor": float(scene.history(k * dt))}
                w0, c0 = time.perf_counter(), time.thread_time()
                r = model.step(mu)
                model.outputs(r)
                c1, w1 = time.thread_time(), time.perf_counter()
                wall.append(w1 - w0)
                cpu.append(c1 - c0)
                evals.append(r.info.get("evaluations", np.nan))
                fields.append(model.reconstruct(r) if r.ok else np.full(U_ref.shape[1], np.nan))
        sm = model.info.get("step_matrix", {})
        U = np.array(fields)
        rec = {"handles": h, "elements": c, "cubature": cubature, "n_z": model.info["n_z"],
               "rmse_rel": float(np.sqrt(np.sum((U - U_ref) ** 2) / np.sum(U_ref ** 2))),
               "wall_ms_median": 1e3 * np.median(wall), "wall_ms_p99": 1e3 * np.percentile(wall, 99),
               "cpu_ms_median": 1e3 * np.median(cpu), "cpu_ms_p99": 1e3 * np.percentile(cpu, 99),
               "evaluations": float(np.mean(evals)), "solve": f"{sm.get('kind')}/{sm.get('precision')}",
               "load_1min": os.getloadavg()[0]}
        records.append(rec)
        print(rec, flush=True)
        pd.DataFrame(records).to_csv(out, index=False, float_format="%.4g")


def _per_budget(rule):
    """The cubature rule computed once per (count, seed, ...): every call here is on one mesh."""
    cache = {}

    @functools.wraps(rule)
    def wrapper(*args, **kwargs):
        key = tuple(a for a in args if not isinstance(a, np.ndarray)) + tuple(sorted(kwargs.items()))
        if key not in cache:
            cache[key] = rule(*args, **kwargs)
        return cache[key]
    return wrapper


if __name__ == "__main__":
    main(*sys.argv[1:])
