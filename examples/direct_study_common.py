"""Shared pieces of ``direct_study.py``: timing protocol, builds, result rows, figure module."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from tissuebench.refsolvers.dynamics import make_integrator
from tissuebench.rom import make_method
from tissuebench.rom.direct.diagnostics import relative_rmse, simulate
from tissuebench.studies.timing import latency_stats


def plots_module():
    """The figure module next to this script (``direct_study_plots.py``)."""
    here = str(Path(__file__).resolve().parent)
    if here not in sys.path:
        sys.path.insert(0, here)
    import direct_study_plots

    return direct_study_plots

LATENCY_STEPS, WARMUP = 400, 40


# ----------------------------------------------------------------------------- timing
def time_direct(model, times, history):
    """Median/p99 [s] of ``step`` + ``outputs`` (the haptic step) and of ``reconstruct``.

    The run is restarted (``reset``) at the end of the history or after a failed step
    until ``LATENCY_STEPS`` completed steps are timed (failed steps are not timed).
    """
    mus = [{"time": float(t), "load_factor": float(history(t))} for t in times[1:]]
    model.start({"time": float(times[0]), "load_factor": float(history(times[0]))}, None, times[1] - times[0])
    steps, recs, k = [], [], 0
    while len(steps) < LATENCY_STEPS + WARMUP:
        if k == len(mus):
            model.reset()
            k = 0
        t0 = time.perf_counter()
        r = model.step(mus[k])
        model.outputs(r)
        t1 = time.perf_counter()
        k += 1
        if r.q is None:
            model.reset()
            k = 0
            continue
        model.reconstruct(r)
        recs.append(time.perf_counter() - t1)
        steps.append(t1 - t0)
    return latency_stats(steps[WARMUP:]), latency_stats(recs[WARMUP:])


def time_full_step(ss, dt, method="hht", n=LATENCY_STEPS, **opts):
    """Median/p99 [s] of our full-order integrator step on the scene's system (same process)."""
    integ = make_integrator(method, **opts).start(ss.system, None, None, dt)
    for _ in range(WARMUP):
        integ.step()
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        integ.step()
        samples.append(time.perf_counter() - t0)
    return latency_stats(samples)


def build(training, **options):
    tic = time.perf_counter()
    model = make_method("pgd_direct", **options).build(training)
    return model, time.perf_counter() - tic


def guarded(rows, base, fn):
    """Append ``fn()`` (a row) to ``rows``; a failure becomes a row with its error, never a crash."""
    try:
        rows.append(fn())
    except Exception as exc:  # noqa: BLE001  (a numerical failure of one unit must not lose the others)
        print(f"    failed: {base}: {exc!r}", flush=True)
        rows.append({**base, "error": repr(exc)})


def model_row(scene, model, build_s, lat, rec, ref_lat, **extra):
    """One result row: options, offline record, latency, speed-up."""
    info = model.info
    row = {"scene": scene, "integrator": model.scheme.name, "pod_modes": max(info["pod_modes"].values()),
           "n_params": model.vademecum.n_params, "n_nodes": model.vademecum.meshes[0].n_nodes,
           "separated_terms": model.vademecum.n_modes, "pgd_modes": json.dumps(info["pgd_modes"]),
           "fixed_point_max": max(max(v) for v in info["fixed_point_iterations"].values()),
           "offline_s": build_s, "median_step_s": lat.median, "p99_step_s": lat.p99,
           "median_reconstruct_s": rec.median if rec else np.nan,
           "full_hht_median_s": ref_lat.median, "full_hht_p99_s": ref_lat.p99,
           "speedup_vs_hht": ref_lat.median / lat.median}
    row.update(extra)
    return row


# ----------------------------------------------------------------------------- scenes
def projection_error(U_ref, model, M):
    """Relative RMSE of the reference history projected on the model's displacement basis (a floor)."""
    B = model.bases["u"]
    free = model.free_dofs
    P = U_ref[:, free] @ (M @ B) @ B.T
    return relative_rmse(P, U_ref[:, free])


def modes_curve(scene, tr, modes, integrator="hht", variant=None):
    """Error versus POD modes for both velocity bases, with the projection floor."""
    times, U_ref = tr.parameter_values("time"), tr.snapshots.T
    rows = []
    for vb in ("velocity", "displacement"):
        for m in modes:
            base = {"scene": scene, "curve": "modes", "variant": variant, "integrator": integrator,
                    "velocity_basis": vb, "pod_modes": m, "n_nodes": 100}

            def one(base=base, m=m, vb=vb):
                model, bs = build(tr, pod_modes=m, integrator=integrator, velocity_basis=vb)
                traj = simulate(model, times, tr.history)
                return {**base, "offline_s": bs, "rmse_vs_reference": relative_rmse(traj.u, U_ref[:len(traj.u)]),
                        "extrapolated_steps": traj.extrapolations,
                        "projection_floor": projection_error(U_ref, model, model.ops.M)}

            guarded(rows, base, one)
    return rows
