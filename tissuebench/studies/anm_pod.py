"""The ANM-POD study (anm-pod-large-deformations §6): accuracy, validity, latency.

``tissuebench study anm_pod`` on cornea_pinch and liver_palpation. Per case:

1. the Newton-Raphson reference along the scene's load path (timed in this process);
2. ANM-POD (one series from the origin with the reduced tangent at the origin, the
   paper's method) for every (modes, order): relative l2 and max-displacement errors
   at every reference load factor, the validity range (largest load factor below which
   the error stays under 1 % and 5 %), a_max of the series, online latency (median and
   99th percentile, with and without reconstruction) against the reference's time for
   the same load path; the reduced tensors are built once per case for the largest
   basis and sliced (POD modes are nested);
3. Newton's own radius: the largest single load step from rest that converges;
4. interpolation between stored load positions (:mod:`.anm_pod_interp`).

Results: ``study.parquet`` (one row per configuration, with provenance),
``curves.parquet`` (errors per load factor), ``interpolation.parquet``, and PNG plots.
"""
from __future__ import annotations

import time

import numpy as np
import pandas as pd

from ..cases.scene import load
from ..refsolvers import make_backend
from .reference import solve
from ..refsolvers.newton import newton_solve
from ..rom import Training, make_method
from .timing import max_displacement, relative_l2, time_online_steps

__all__ = ["reference_path", "sweep_case", "newton_radius", "validity_range"]


def reference_path(case, resolution="ci", backend="skfem"):
    """(scene, result, Training, reference time per load path [s]) of a static scene."""
    scene = load(case, resolution=resolution)
    ref = solve(scene, backend=backend)
    be = make_backend(backend, ref.problem)
    states = ref.displacement[1:].reshape(len(ref.displacement) - 1, -1)
    lams = ref.steps[1:]
    training = Training(states.T, [{"load_factor": float(lam)} for lam in lams], be,
                        info={"case": scene.name, "resolution": resolution, "backend": backend})
    t = ref.table
    ref_time = float(t.loc[t["converged"], "wall_s"].sum())
    return scene, ref, training, ref_time


def validity_range(lams, errors, tol) -> float:
    """Largest load factor up to which every error stays below ``tol`` (0 if the first fails)."""
    ok = np.asarray(errors) < tol
    if ok.all():
        return float(lams[-1])
    first_bad = int(np.argmin(ok))
    return float(lams[first_bad - 1]) if first_bad > 0 else 0.0


def newton_radius(backend, lam_hi, lam_lo=0.0, iterations=6) -> float:
    """Largest single load step from rest that Newton converges in (bisection on
    [lam_lo, lam_hi], no step cutting; ``lam_hi`` itself when it converges)."""
    lo, hi = lam_lo, lam_hi
    if newton_solve(backend, hi, n_increments=1, min_increment=1.0, store_states=False).success:
        return float(hi)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if newton_solve(backend, mid, n_increments=1, min_increment=1.0, store_states=False).success:
            lo = mid
        else:
            hi = mid
    return float(lo)


def _errors(model, training, lams):
    S = training.snapshots
    rel, maxd, rom_max, statuses = [], [], [], []
    for k, lam in enumerate(lams):
        res = model.step({"load_factor": float(lam)})
        statuses.append(res.status)
        if res.q is None:  # a failed step: infinite error, flagged by its status
            rel.append(np.inf)
            maxd.append(np.inf)
            rom_max.append(np.nan)
            continue
        u = model.reconstruct(res)
        rel.append(relative_l2(u, S[:, k]))
        ref_max = max_displacement(S[:, k])
        rom_max.append(max_displacement(u))
        maxd.append(abs(rom_max[-1] - ref_max) / ref_max)
    return np.array(rel), np.array(maxd), np.array(rom_max), statuses


# the load range the paper's accuracy claim covers, as a reference max displacement [scene units]
PAPER_RANGE = {"liver_palpation": 5e-3}


def sweep_case(case, modes, orders, resolution="ci", eps=1e-6, latency_steps=1000, progress=None):
    """Rows (one per configuration) and curves (one per configuration and load factor).

    ``max_rel_l2_in_range`` is the largest error over the load factors whose reference max
    displacement is within :data:`PAPER_RANGE` (liver: about 5 mm; elsewhere the whole path).
    """
    scene, ref, training, ref_time = reference_path(case, resolution)
    lams = np.array([p["load_factor"] for p in training.parameters])
    ref_max = np.array([max_displacement(u) for u in training.snapshots.T])
    in_range = ref_max <= PAPER_RANGE.get(scene.name, np.inf) * (1 + 1e-12)
    t0 = time.perf_counter()
    full = make_method("anm_pod", n_modes=max(modes), order=max(orders), eps=eps, max_segments=1).build(training)
    offline = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    mus = [{"load_factor": float(x)} for x in rng.uniform(0, lams[-1], latency_steps)]
    rows, curves, seen = [], [], set()
    for m in modes:
        for order in orders:
            model = full.variant(n_modes=m, order=order, max_segments=1)
            key = (model.n_reduced, order)
            if progress:
                progress()
            if key in seen:  # fewer independent snapshots than requested modes
                continue
            seen.add(key)
            rel, maxd, rom_max, statuses = _errors(model, training, lams)
            step, both, _ = time_online_steps(model, mus, warmup=50)
            series = model.path[0]
            rows.append({"case": scene.name, "resolution": resolution, "method": "anm_pod",
                         "modes_requested": m, "modes": model.n_reduced, "order": order, "eps": eps,
                         "a_max": series.a_end, "lam_at_a_max": series.load_factor(series.a_end),
                         "max_rel_l2": float(np.max(rel)), "max_rel_maxdisp": float(np.max(maxd)),
                         "max_rel_l2_in_range": float(np.max(rel[in_range])) if in_range.any() else np.nan,
                         "range_max_displacement": float(ref_max[in_range].max()) if in_range.any() else 0.0,
                         "validity_1pct": validity_range(lams, rel, 0.01),
                         "validity_5pct": validity_range(lams, rel, 0.05),
                         "validity_1pct_maxdisp_m": _disp_at(ref, validity_range(lams, rel, 0.01)),
                         "beyond_validity_steps": statuses.count("beyond_validity"),
                         **step.as_dict("step_"), **both.as_dict("step_recon_"),
                         "reference_path_s": ref_time, "reference_step_s": ref_time / len(lams),
                         "speedup_per_step": ref_time / len(lams) / step.median,
                         "offline_s": offline, "tensor_evals": full.poly.n_evals,
                         "pod_message": full.info.get("pod_message", "")})
            curves += [{"case": scene.name, "modes": model.n_reduced, "order": order, "load_factor": lam,
                        "rel_l2": e, "rel_maxdisp": d, "status": s, "rom_max_displacement": rm,
                        "ref_max_displacement": max_displacement(training.snapshots[:, k])}
                       for k, (lam, e, d, rm, s) in enumerate(zip(lams, rel, maxd, rom_max, statuses))]
    # the path may end where load stepping stalls; one step from rest is searched up to twice that
    radius = newton_radius(training.backend, 2.0 * float(lams[-1]))
    for r in rows:
        r["newton_radius"] = radius
    return rows, curves, (scene, ref, training)


def _disp_at(ref, lam):
    """Max displacement of the reference at load factor ``lam`` (0 at 0)."""
    if lam <= 0:
        return 0.0
    k = int(np.argmin(np.abs(ref.steps - lam)))
    return float(np.linalg.norm(ref.displacement[k], axis=1).max())
