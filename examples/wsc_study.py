"""Weighted skinning + cubature (wsc) study: the paper's Table 1, Table 3, the LV figure,
energy drift, offline cost and memory, and the RMSE-versus-step-time plot.

Standalone until the sweep harness lands (its functions are small so the harness can
call them). Every figure is measured against the full FE reference on the same mesh,
with the FE step timed in the same process:

* reference runs (``reference``): the catalogue scene's dynamic run through
  ``tissuebench.studies.reference.solve``, cached as NPZ in the output folder;
* the FE step time (``fe_step_times``): a few backward-Euler steps of the same system,
  timed here (median, p99);
* the ROM (``measure``): offline build timed per stage, model memory, then
  ``time_online_steps`` over the whole trajectory (warm-up, median, p99 of the step,
  step + reconstruction apart), relative RMSE of the displacement history
  ``sqrt(sum_n |u_n - u_FE,n|^2 / sum_n |u_FE,n|^2)`` over all steps.

Usage::

    PYTHONPATH=$PWD OPENBLAS_NUM_THREADS=1 nice -n 10 python examples/wsc_study.py OUT \\
        --resolution paper --parts table1,lv,table3,drift,nnls

``--resolution ci`` runs the same parts on the CI meshes in a few minutes (the grid is
scaled to the vertex count). Outputs in OUT: ``<part>.parquet``, ``pareto.png``,
``summary.md`` (also printed), the cached references ``ref_*.npz``.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from tissuebench.cases.scene import load
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.dynamics import SecondOrderSystem, make_integrator
from tissuebench.rom import Training, make_method
from tissuebench.studies.timing import latency_stats

CUBE = "cube_tension_twist"
# the solver tolerance of every measured configuration: the RMSE equals that of rtol = 1e-6 to
# three digits (ci, 10 handles: 0.0087 for rtol 1e-6 .. 1e-2) with 4.3 instead of 7.6 evaluations
RTOL = {"rtol": 1e-3}
LV = ("left_ventricle", "mooney_rivlin_dynamic")
# the paper's Table 1 (7273 / 37592 mesh): (handles, cubature elements, RMSE %, ms per step)
PAPER_TABLE1 = [(74, 1880, 21.82, 10.70), (108, 1880, 15.80, 12.00), (150, 1880, 16.42, 12.18),
                (180, 1880, 16.11, 12.73), (220, 1880, 10.31, 13.25), (250, 1880, 5.59, 13.87),
                (290, 1880, 3.90, 15.11), (327, 1880, 3.38, 15.42), (364, 1880, 2.59, 15.75),
                (74, 2350, 8.60, 12.82), (108, 2350, 5.43, 13.82), (150, 2350, 4.90, 14.08),
                (180, 2350, 5.97, 14.28), (220, 2350, 4.44, 15.48), (250, 2350, 4.99, 15.80),
                (290, 2350, 3.31, 16.69), (327, 2350, 2.55, 17.81), (364, 2350, 2.29, 18.41),
                (74, 2820, 11.24, 14.51), (108, 2820, 6.17, 15.45), (150, 2820, 6.26, 15.75),
                (180, 2820, 9.66, 16.17), (220, 2820, 7.47, 17.33), (250, 2820, 4.05, 18.01),
                (290, 2820, 5.64, 18.63), (327, 2820, 3.16, 19.49), (364, 2820, 2.48, 21.22)]
PAPER_FE_MS, PAPER_LV = 688.83, {"rom_ms": 21.81, "fe_ms": 932.35, "rmse_percent": 2.4}
# Table 3 rows of the paper: low (2519 / 12499) and high (9284 / 43517) resolution
PAPER_TABLE3 = {"low": [(75, 815, 7.78, 10.47), (101, 815, 1.93, 12.86), (126, 815, 2.10, 15.28)],
                "high": [(278, 2720, 6.77, 46.38), (371, 2720, 3.92, 55.35), (462, 2720, 2.89, 64.34)]}


# ----------------------------------------------------------------------------- scenes, references
def scene_at(case, variant, resolution, divisions=None):
    """A catalogue scene; ``divisions`` overrides the box divisions (Table 3 meshes)."""
    scene = load(case, resolution="ci" if resolution == "ci" else "paper", variant=variant)
    if divisions is not None:
        scene = dataclasses.replace(scene, mesh_spec=dict(scene.mesh_spec, params={**scene.mesh_spec["params"],
                                                                                   "divisions": list(divisions)}))
    return scene


def reference(scene, out: Path, tag: str) -> dict:
    """FE reference trajectory ``{"t", "u" (n_steps + 1, ndof), "wall" (per step)}``, cached."""
    path = out / f"ref_{tag}.npz"
    if path.is_file():
        z = np.load(path, allow_pickle=False)
        return {k: z[k] for k in z.files}
    from tissuebench.studies.reference import solve

    tic = time.perf_counter()
    r = solve(scene)
    if r.status != "success":
        raise RuntimeError(f"reference {tag}: {r.status}: {r.message}")
    ref = {"t": np.asarray(r.steps), "u": r.displacement.reshape(len(r.steps), -1),
           "wall": r.table["wall_s"].to_numpy()[1:], "run_s": np.array(time.perf_counter() - tic)}
    np.savez_compressed(path, **ref)
    return ref


def fe_step_times(scene, backend, n_steps=5):
    """Wall times [s] of ``n_steps`` full-order steps of the scene's integrator, this process."""
    a = scene.analysis
    system = SecondOrderSystem.from_backend(backend, scene.history)
    integ = make_integrator(a["integrator"], **a.get("integrator_options", {}))
    integ.start(system, None, None, float(a["dt"]))
    times = []
    for _ in range(n_steps):
        tic = time.perf_counter()
        rep = integ.step()
        times.append(time.perf_counter() - tic)
        if not rep.converged:
            raise RuntimeError(f"FE step failed: {rep.message}")
    return np.array(times)


def training_of(scene, backend, ref) -> Training:
    history = scene.history
    params = [{"time": float(t), "load_factor": float(history(t))} for t in ref["t"]]
    return Training(snapshots=ref["u"].T, parameters=params, backend=backend, dt=float(scene.analysis["dt"]),
                    history=history, info={"case": scene.name, "variant": scene.variant})


def step_parameters(scene, ref):
    history = scene.history
    return [{"time": float(t), "load_factor": float(history(t))} for t in ref["t"][1:]]


# ----------------------------------------------------------------------------- one ROM
def time_trajectory(model, mus, dt, warmup=20, min_steps=200):
    """The harness's latency protocol for a trajectory model (studies.protocol): ``warmup``
    untimed steps, then passes over the trajectory from rest (restarted untimed) until at
    least ``min_steps`` haptic steps (``step`` + ``outputs``) are timed one by one; the
    reconstruction is timed apart. Returns (haptic stats, reconstruction stats, results of
    the first timed pass)."""
    model.start(dt=dt)
    for mu in mus[:warmup]:
        res = model.step(mu)
        if res.q is not None:
            model.reconstruct(res)
    haptic, recon, first = [], [], None
    while len(haptic) < min_steps:
        model.start(dt=dt)
        results = []
        for mu in mus:
            t0 = time.perf_counter()
            res = model.step(mu)
            model.outputs(res)
            haptic.append(time.perf_counter() - t0)
            results.append(res)
            if res.q is None:
                break
            t1 = time.perf_counter()
            model.reconstruct(res)
            recon.append(time.perf_counter() - t1)
        first = first or results
        if results[-1].q is None:
            break
    return latency_stats(haptic), (latency_stats(recon) if recon else None), first


def model_nbytes(model) -> int:
    """Bytes of the arrays the online model keeps (weights, subspace, cubature, matrices)."""
    seen, total = set(), 0

    def add(a):
        nonlocal total
        if a is None or id(a) in seen:
            return
        seen.add(id(a))
        if hasattr(a, "nnz") and hasattr(a, "data"):
            total += a.data.nbytes + getattr(a, "indices", np.empty(0)).nbytes + getattr(a, "indptr",
                                                                                            np.empty(0)).nbytes
        elif isinstance(a, np.ndarray):
            total += a.nbytes

    st, sub, f = model.stepper, model.sub, model.stepper.forces
    for a in (sub.weights, sub.phi, sub.P, sub.N, st.M_q, st.M_z, st.M_zb, f.W, f.WT_w, f.Xt, f.w,
              f.kernel.grad, f.kernel._G, f.kernel.dx):
        add(a)
    for H in st._H.values():
        add(getattr(H, "inv", None))
        lu = getattr(H, "lu", None)
        if lu is not None:
            add(lu.L)
            add(lu.U)
    return int(total)


def measure(scene, backend, ref, options, warmup=20, training=None, keep_dofs=None) -> dict:
    """Build, time and compare one ROM configuration; returns a table row (dict). With
    ``keep_dofs`` the row also holds ``series``: the ROM's values of those dofs per step."""
    row = {"case": scene.name, "variant": scene.variant, **{f"opt_{k}": v for k, v in options.items()}}
    tic = time.perf_counter()
    try:
        model = make_method("wsc", **options).build(training or Training(backend=backend,
                                                                         dt=float(scene.analysis["dt"])))
    except ValueError as exc:  # e.g. an NNLS rule that misses its tolerance: stored, not hidden
        return {**row, "status": "build_failed", "message": str(exc)}
    row["build_s"] = time.perf_counter() - tic
    info = model.info
    row.update({f"offline_{k}": v for k, v in info["offline"].items()})
    row.update(handles=info["handles"], n_z=info["n_z"], cubature_elements=info["cubature_elements"],
               linear_solver=info["linear_solver"],
               vertices=info["mesh"]["vertices"], cells=info["mesh"]["cells"])
    for k in ("heldout_error", "train_error"):
        if k in info["cubature_info"]:
            row[f"nnls_{k}"] = info["cubature_info"][k]
    tic = time.perf_counter()
    model.start(dt=float(scene.analysis["dt"]))
    row["start_s"] = time.perf_counter() - tic
    row["model_MB"] = model_nbytes(model) / 2**20
    mus = step_parameters(scene, ref)
    step, recon, results = time_trajectory(model, mus, float(scene.analysis["dt"]), warmup=warmup)
    row.update(step.as_dict("step_"))
    row.update({"reconstruct_median_s": recon.median if recon else np.nan})
    failed = [r for r in results if r.q is None]
    row["failed_steps"] = len(failed)
    row["message"] = failed[0].message if failed else ""
    row["unconverged_steps"] = sum(1 for r in results if r.q is not None and not r.info.get("converged", True))
    row["evaluations_mean"] = float(np.mean([r.info.get("evaluations", np.nan) for r in results if r.q is not None]))
    if failed:
        row["status"], row["rmse"] = "failed", np.nan
        return row
    U = np.array([model.reconstruct(r) for r in results])
    if keep_dofs is not None:
        row["series"] = U[:, keep_dofs]
    R = ref["u"][1:len(U) + 1]
    row["rmse"] = float(np.sqrt(np.sum((U - R) ** 2) / np.sum(R ** 2)))
    row["final_rel_l2"] = float(np.linalg.norm(U[-1] - R[-1]) / np.linalg.norm(R[-1]))
    row["status"] = "ok"
    return row


def with_fe(row, fe_times):
    s = latency_stats(fe_times)
    row.update(fe_step_median_s=s.median, fe_step_p99_s=s.p99)
    row["speedup"] = s.median / row["step_median_s"] if row.get("step_median_s") else np.nan
    return row


# ----------------------------------------------------------------------------- parts
def scaled(counts, n_now, n_paper):
    """Paper counts scaled to another mesh size (ci runs), at least 1."""
    return sorted({max(1, int(round(c * n_now / n_paper))) for c in counts})


_FE_TIMES: dict = {}


def cube_setup(out, resolution, variant="tension_dynamic"):
    """(scene, backend, reference, FE step times) of a cube variant, the FE timed once per process."""
    scene = scene_at(CUBE, variant, resolution)
    be = make_backend("skfem", scene.to_problem())
    ref = reference(scene, out, f"{variant.split('_')[0]}_{resolution}")
    key = (variant, resolution)
    if key not in _FE_TIMES:
        _FE_TIMES[key] = fe_step_times(scene, be)
    return scene, be, ref, _FE_TIMES[key]


def table1(out, resolution, cubature="bgbc", handles=None, elements=None, extra=None, variant="tension_dynamic",
           train_variant=None, part="table1"):
    """The grid handles x cubature elements on a cube variant; NNLS learns from the reference
    run of ``train_variant`` (default: the same run, in-sample)."""
    scene, be, ref, fe = cube_setup(out, resolution, variant)
    pb = be.problem
    if resolution == "ci" and handles is None:  # the paper's counts scaled to the ci mesh
        handles = scaled([h for h, _, _, _ in PAPER_TABLE1[:9]], pb.mesh.n_vertices, 7273)
        elements = scaled(elements or [2350, 1880, 2820], pb.mesh.n_cells, 37592)
    handles = handles or [h for h, _, _, _ in PAPER_TABLE1[:9]]
    elements = elements or [2350, 1880, 2820]
    training = None
    if cubature == "nnls":
        tscene, _, tref, _ = cube_setup(out, resolution, train_variant or variant)
        training = training_of(tscene, be, tref)  # the snapshots of that run, this problem's operators
    rows = []
    for c in elements:
        for h in handles:
            opts = dict(handles=h, cubature=cubature, cubature_elements=c, **(extra or {}))
            row = with_fe(measure(scene, be, ref, opts, training=training), fe)
            row.update(part=part, trained_on=(train_variant or variant) if cubature == "nnls" else "")
            rows.append(row)
            _progress(row)
    return pd.DataFrame(rows)


def table3(out, fixed=((20, 400), (150, 2350)), extra=None):
    """App. B: the other two cube resolutions (our box divisions): three of the paper's rows per
    level, and the same absolute (handles, elements) on every level (is the step flat in the mesh?)."""
    frames = []
    divisions = load(CUBE, variant="tension_dynamic").paper["methods"]["wsc"]["resolutions"]
    for level in ("low", "high"):
        scene = scene_at(CUBE, "tension_dynamic", "paper", divisions[level])
        be = make_backend("skfem", scene.to_problem())
        ref = reference(scene, out, f"tension_{level}")
        fe = fe_step_times(scene, be)
        for h, c, rmse, ms in PAPER_TABLE3[level] + [(h, c, np.nan, np.nan) for h, c in fixed]:
            row = with_fe(measure(scene, be, ref, dict(handles=h, cubature_elements=c, **(extra or {}))), fe)
            row.update(level=level, paper_rmse_percent=rmse, paper_ms=ms)
            frames.append(row)
            _progress(row)
    return pd.DataFrame(frames)


def lv(out, resolution, configs=None, extra=None):
    scene = scene_at(*LV, resolution)
    be = make_backend("skfem", scene.to_problem())
    ref = reference(scene, out, f"lv_{resolution}")
    fe = fe_step_times(scene, be)
    wsc = scene.paper["methods"]["wsc"]
    configs = configs or [dict(handles=wsc["handles"], cubature_elements=wsc["cubature_elements"]),
                          dict(handles=60, cubature_elements=600), dict(handles=30, cubature_elements=400)]
    configs = [dict(c, **(extra or {})) for c in configs]
    apex = int(np.argmin(np.linalg.norm(be.problem.nodes - [0.0, 0.0, -17.0], axis=1)))  # endocardial apex
    rows, series = [], {}
    for opts in configs:
        if resolution == "ci":
            opts = dict(opts, handles=max(4, opts["handles"] * be.problem.mesh.n_vertices // 15699),
                        cubature_elements=max(20, opts["cubature_elements"] * be.problem.mesh.n_cells // 61659))
        row = with_fe(measure(scene, be, ref, opts, keep_dofs=[3 * apex + 2]), fe)
        if "series" in row:
            series[f"wsc {row['handles']} handles, {row['cubature_elements']} elements"] = row.pop("series")[:, 0]
        rows.append(row)
        _progress(row)
    lv_plot(ref, 3 * apex + 2, series, out / f"lv_{resolution}.png")
    return pd.DataFrame(rows)


def curves(out, resolution, variant, options, every=5):
    """The paper's Fig. 1: the scene's monitors (nominal stress or moment, volume ratio)
    along the pull, FE against the ROM, and the relative RMSE of each curve."""
    scene, be, ref, _ = cube_setup(out, resolution, variant)
    pb = be.problem
    model = make_method("wsc", **options).build(Training(backend=be, dt=float(scene.analysis["dt"])))
    model.start()
    mus = step_parameters(scene, ref)
    rows = []
    for k, mu in enumerate(mus, start=1):
        res = model.step(mu)
        if res.q is None:
            break
        if k % every:
            continue
        for who, u in (("FE", ref["u"][k]), ("wsc", model.reconstruct(res))):
            rows.append({"who": who, "time": mu["time"], "load_factor": mu["load_factor"],
                         **scene.evaluate_monitors(pb, u, be.internal_force(u))})
    df = pd.DataFrame(rows)
    fe, rom = df[df["who"] == "FE"].reset_index(drop=True), df[df["who"] == "wsc"].reset_index(drop=True)
    summary = {"variant": variant, **{f"opt_{k}": v for k, v in options.items()}}
    names = [m["name"] for m in scene.monitors]
    for name in names:
        a, b = fe[name].to_numpy(), rom[name].to_numpy()[:len(fe)]
        summary[f"rmse_{name}"] = float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(a ** 2)))
    _curves_plot(fe, rom, names, out / f"curves_{variant}_{resolution}.png", options)
    return summary


def _curves_plot(fe, rom, names, path, options):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.4))
    for ax, name in zip(np.atleast_1d(axes), names):
        ax.plot(fe["load_factor"], fe[name], "k-", lw=2, label="FE")
        ax.plot(rom["load_factor"], rom[name], "--", label=f"wsc {options.get('handles')} handles, "
                                                          f"{options.get('cubature_elements')} elements")
        ax.set_xlabel("load factor (strain / 0.3, angle / 90 deg)")
        ax.set_ylabel(name)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def lv_plot(ref, dof, series, path):
    """Apex (endocardium) displacement along the axis versus time: FE and the ROMs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.8))
    ax.plot(ref["t"], ref["u"][:, dof], "k-", lw=2, label="FE (backward Euler)")
    for label, values in series.items():
        ax.plot(ref["t"][1:len(values) + 1], values, "--", label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("apex displacement u_z [mm]")
    ax.set_title("left ventricle, dynamic inflation to 0.5 kPa (ramp 0.2 s)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def drift(out, resolution, options, horizon_factor=10):
    """Energy of the reduced dynamics over ``horizon_factor`` times the paper's horizon:
    the pull of [0, 1] s, then the end held to ``horizon_factor`` s."""
    scene = scene_at(CUBE, "tension_dynamic", resolution)
    be = make_backend("skfem", scene.to_problem())
    dt = float(scene.analysis["dt"])
    rows = []
    for integrator in ("backward_euler", "newmark"):
        model = make_method("wsc", track_energy=True, integrator=integrator, **options).build(
            Training(backend=be, dt=dt))
        model.start()
        n = int(round(horizon_factor * scene.analysis["t_end"] / dt))
        e = []
        for k in range(1, n + 1):
            t = k * dt
            r = model.step({"time": t, "load_factor": float(scene.history(t))})
            if r.q is None:
                break
            e.append((t, r.info["kinetic_energy"], r.info["strain_energy"], r.info["reaction_work"]))
        e = np.array(e).reshape(-1, 4)
        row = {"integrator": integrator, "steps": len(e), "steps_planned": n, "failed": len(e) < n,
               "message": "" if len(e) == n else r.message, **{f"opt_{k}": v for k, v in options.items()}}
        if len(e):
            mech = e[:, 1] + e[:, 2] - e[:, 3]  # KE + IE - work of the supports: constant if conservative
            scale = max(np.abs(e[:, 3]).max(), 1e-300)
            hold = e[:, 0] >= 1.0
            row.update(t_end=e[-1, 0], balance_end_rel=mech[-1] / scale, balance_max_rel=np.abs(mech).max() / scale,
                       hold_drift_rel=(mech[hold][-1] - mech[hold][0]) / scale if hold.any() else np.nan,
                       kinetic_end=e[-1, 1], strain_end=e[-1, 2])
        rows.append(row)
        _progress(rows[-1])
    return pd.DataFrame(rows)


def _progress(row):
    keys = ("handles", "cubature_elements", "opt_cubature", "rmse", "step_median_s", "step_p99_s",
            "fe_step_median_s", "build_s", "status", "integrator", "balance_end_rel", "hold_drift_rel")
    print("  " + ", ".join(f"{k}={row[k]:.4g}" if isinstance(row.get(k), float) else f"{k}={row[k]}"
                           for k in keys if k in row), flush=True)


# ----------------------------------------------------------------------------- report
def pareto_plot(frames, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    p = np.array(PAPER_TABLE1)
    ax.scatter(p[:, 3], p[:, 2], marker="x", c="grey", label="paper Table 1 (C++, Xeon E5-1603)")
    markers = {"bgbc": "o", "nnls": "s", "full": "^"}
    for df in frames:
        ok = df[df["status"] == "ok"].copy()
        ok["trained_on"] = ok.get("trained_on", "").fillna("") if "trained_on" in ok else ""
        for (scheme, part, trained), g in ok.groupby(["opt_cubature", "part", "trained_on"]):
            how = {"tension_dynamic": ", in-sample", "twist_dynamic": ", trained on twist"}.get(trained, "")
            ax.scatter(1e3 * g["step_median_s"], 100 * g["rmse"], marker=markers.get(scheme, "o"),
                       label=f"ours: {part}, {scheme}{how}")
    ax.axhline(2.5, ls=":", c="k", lw=0.8)
    ax.axvline(2.0, ls=":", c="k", lw=0.8)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per step [ms]")
    ax.set_ylabel("relative RMSE of the displacement history [%]")
    ax.set_title("cube tension, 7273 / 37592 (paper) vs 7744 / 37800 (ours)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=130)
    plt.close(fig)


def table1_comparison(df):
    """Paper vs ours, row by row (same handles and cubature elements)."""
    ours = df[df["opt_cubature"] == "bgbc"].set_index(["handles", "cubature_elements"])
    rows = []
    for h, c, rmse, ms in PAPER_TABLE1:
        r = ours.loc[(h, c)] if (h, c) in ours.index else None
        rows.append({"handles": h, "elements": c, "paper_rmse_%": rmse, "paper_ms": ms,
                     "ours_rmse_%": np.nan if r is None else 100 * r["rmse"],
                     "ours_ms_median": np.nan if r is None else 1e3 * r["step_median_s"],
                     "ours_ms_p99": np.nan if r is None else 1e3 * r["step_p99_s"],
                     "fe_ms": np.nan if r is None else 1e3 * r["fe_step_median_s"]})
    return pd.DataFrame(rows)


COLUMNS = ["handles", "cubature_elements", "opt_cubature", "trained_on", "rmse", "step_median_s", "step_p99_s",
           "fe_step_median_s", "speedup", "evaluations_mean", "build_s", "model_MB", "status"]


def show(df, extra_cols=(), all_columns=False) -> str:
    """A table of the main columns (or all) with 4 significant digits."""
    cols = list(df.columns) if all_columns else [c for c in COLUMNS + list(extra_cols) if c in df]
    return df[cols].to_string(index=False, float_format=lambda v: f"{v:.4g}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("out", type=Path)
    ap.add_argument("--resolution", choices=("ci", "paper"), default="ci")
    ap.add_argument("--parts", default="table1,target,nnls,twist,curves,lv,table3,drift")
    ap.add_argument("--handles", default=None, help="comma-separated handle counts (Table 1)")
    ap.add_argument("--elements", default=None, help="comma-separated cubature element counts (Table 1)")
    args = ap.parse_args(argv)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    parts = args.parts.split(",")
    handles = [int(x) for x in args.handles.split(",")] if args.handles else None
    elements = [int(x) for x in args.elements.split(",")] if args.elements else None
    print(f"wsc study, resolution {args.resolution}, parts {parts}, load average {os.getloadavg()}", flush=True)
    frames, lines = [], []
    if "table1" in parts:
        df = table1(out, args.resolution, "bgbc", handles, elements, extra=RTOL)
        df.to_parquet(out / "table1.parquet")
        frames.append(df)
        cmp = table1_comparison(df) if args.resolution == "paper" else df
        lines += ["## Table 1 (BGBC cubature, no snapshots)", show(cmp, all_columns=True)]
    if "target" in parts:  # small subspaces and rules: where are <= 2 ms at <= 2.5 %?
        small_h, small_c = handles or [10, 20, 40], elements or [200, 400, 800]
        df = pd.concat([table1(out, args.resolution, "bgbc", small_h, small_c, extra=RTOL, part="target"),
                        table1(out, args.resolution, "nnls", small_h, [max(1, c // 2) for c in small_c],
                               part="target", extra={**RTOL, "nnls_tol": None})])
        df.to_parquet(out / "target.parquet")
        frames.append(df)
        lines += ["## Small configurations (target search; NNLS trained on the tension run itself)",
                  show(df, ["nnls_heldout_error"])]
    if "nnls" in parts:  # in-sample (the run it is measured on) and cross-trained (the twist run)
        df = pd.concat([table1(out, args.resolution, "nnls", handles or [74, 150, 250, 364],
                               elements or [250, 500, 1000], extra={**RTOL, "nnls_tol": None}, train_variant=tv,
                               part="nnls") for tv in ("tension_dynamic", "twist_dynamic")])
        df.to_parquet(out / "table1_nnls.parquet")
        frames.append(df)
        lines += ["## NNLS cubature on the tension run (trained on it: in-sample; on the twist run: cross)",
                  show(df, ["nnls_heldout_error"])]
    if "twist" in parts:
        df = table1(out, args.resolution, "bgbc", handles or [20, 150, 364], elements or [400, 2350],
                    extra=RTOL, variant="twist_dynamic", part="twist")
        df.to_parquet(out / "twist.parquet")
        lines += ["## Twist (BGBC)", show(df)]
    if "curves" in parts:  # Fig. 1 of the paper: monitors along the pull, FE vs ROM
        opts = {"handles": 250 if args.resolution == "paper" else 10,
                "cubature_elements": 3000 if args.resolution == "paper" else 0.3, **RTOL}
        df = pd.DataFrame([curves(out, args.resolution, v, opts) for v in ("tension_dynamic", "twist_dynamic")])
        df.to_parquet(out / "curves.parquet")
        lines += ["## Monitored curves (paper: RMSE strain-stress 4.27 %, strain-volume 3.11 %, rotation-moment "
                  "2.15 %, rotation-volume 2.63 %)", show(df, all_columns=True)]
    if "lv" in parts:
        df = lv(out, args.resolution, extra=RTOL)
        df.to_parquet(out / "lv.parquet")
        lines += [f"## Left ventricle (paper: {PAPER_LV})", show(df, ["n_z", "start_s", "final_rel_l2"])]
    if "table3" in parts and args.resolution == "paper":
        df = table3(out, extra=RTOL)
        df.to_parquet(out / "table3.parquet")
        lines += ["## Table 3 (low / high resolution)", df[["level", "vertices", "cells", "handles",
                                                             "cubature_elements", "rmse", "step_median_s",
                                                             "step_p99_s", "fe_step_median_s", "build_s"]]
                  .to_string(index=False, float_format=lambda v: f"{v:.4g}")]
    if "drift" in parts:
        df = drift(out, args.resolution, {"handles": 150 if args.resolution == "paper" else 10,
                                          "cubature_elements": 2350 if args.resolution == "paper" else 0.5})
        df.to_parquet(out / "drift.parquet")
        lines += ["## Energy over 10x the horizon", df.to_string(index=False, float_format=lambda v: f"{v:.4g}")]
    if frames:
        pareto_plot(frames, out / "pareto.png")
    lines.append(f"load average at the end {os.getloadavg()}")
    text = "\n\n".join(lines)
    (out / "summary.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    sys.exit(main())
