"""PGD-POD direct time integrator (pgd-pod-direct-integration): the paper's four scenes.

``python examples/direct_study.py --out results/direct [--scenes frame,beam,wave,liver] [--quick]``

Per scene, rows (Parquet ``rows.parquet`` + ``rows.csv``) with the error against the
reference, the online step latency (median / p99 of ``step`` + ``outputs``; ``reconstruct``
apart), our own full-order HHT step timed in the same process and the speed-up, offline
cost (PGD modes per solve, fixed-point iterations, seconds) and extrapolated steps; PNGs
of the paper's figures next to ours (``fig2_frame.png``, ``fig5_beam.png``,
``fig15_16_wave.png``, ``fig17_wave_bathe.png``, ``fig20_liver.png`` and the error
versus modes / parameter-mesh curves). Standalone until the sweep harness lands; the
functions ``frame``, ``beam``, ``wave`` (``direct_study_wave.py``), ``liver`` return their
rows; ``direct_study_common.py`` holds the timing protocol and the row builder,
``direct_study_plots.py`` the figures. A unit that fails (build or run) becomes a row
with its ``error``, the others go on.

Conventions: the training of every scene is its own reference run (the paper: "POD modes
have been extracted from this reference solution"); the load factor of a step is the
history at the step's end, held over the step (``load_at="end"``); the paper's explicit
"forward Euler" on ``u^n, u^{n-1}`` is our ``central_difference`` (our ``forward_euler`` is
the first-order scheme on (u, v)).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the sibling modules below

from direct_study_common import (
    build,
    guarded,
    model_row,
    modes_curve,
    plots_module,
    projection_error,
    time_direct,
    time_full_step,
)
from direct_study_wave import wave

from tissuebench.refsolvers.line_models import frame_step_response
from tissuebench.rom.direct.diagnostics import (
    full_run,
    relative_rmse,
    simulate,
    spectrum_peaks,
)
from tissuebench.studies.trajectories import (
    output_functionals,
    reference_run,
    scene_system,
    trajectory_training,
)


def frame(out, quick=False):
    """Fig. 2: 8 PGD modes, forward Euler (both readings), step load 1e4 N vs the analytical response."""
    tr = trajectory_training("frame_2dof")
    ss = scene_system("frame_2dof")
    times, hist = tr.parameter_values("time"), tr.history
    exact = frame_step_response([2000.0, 4000.0], 1e5, 1e4, times, 2)
    ref_lat = time_full_step(ss, tr.dt, "hht", alpha=-0.05)
    rows, curves = [], {"t": times, "analytical": exact}
    for integ in ("central_difference", "forward_euler"):
        model, bs = build(tr, pod_modes=2, integrator=integ, pgd_modes=8)
        traj = simulate(model, times, hist)
        u = traj.u[:, 1:3]
        n = len(u)
        curves[integ] = u
        full = full_run(model, times, hist)
        lat, rec = time_direct(model, times, hist)
        rows.append(model_row("frame_2dof", model, bs, lat, rec, ref_lat,
                              rmse_vs_reference=relative_rmse(u, exact[:n]),
                              rmse_full_same_integrator_vs_reference=relative_rmse(full.u[:n, 1:3], exact[:n]),
                              rmse_vs_full_same_integrator=relative_rmse(u, full.u[:n, 1:3]),
                              extrapolated_steps=traj.extrapolations, failed_at=traj.failed_at,
                              reference="analytical (modal)"))
    plots_module().frame(curves, out / "fig2_frame.png")
    return rows


BEAM_CASES = (("forward_euler", "end", 1), ("central_difference", "end", 1), ("bathe", "end", 1),
              ("bathe", "end", 4), ("bathe", "mid", 4))


def _beam_row(c, integ, load_at, m):
    tr, mid, ref = c["tr"], c["mid"], c["ref"]
    times, dt = tr.parameter_values("time"), tr.dt
    model, bs = build(tr, pod_modes=m, integrator=integ, load_at=load_at)
    traj = simulate(model, times, tr.history)
    w = traj.u @ mid
    if load_at == "end":
        c["curves"][(integ, m, dt)] = (traj.t, w)
    lat, rec = time_direct(model, times, tr.history)
    stable = traj.failed_at is None and np.max(np.abs(w)) < 10 * np.max(np.abs(ref))
    full = full_run(model, times, tr.history)
    w_full = full.u @ mid
    full_ok = full.failed_at is None and np.max(np.abs(w_full)) < 10 * np.max(np.abs(ref))
    return model_row("clamped_beam", model, bs, lat, rec, c["ref_lat"], dt=dt, load_at=load_at,
                     rmse_vs_reference=relative_rmse(w, ref[:len(w)]) if stable else np.inf,
                     rmse_full_same_integrator_vs_reference=(
                         relative_rmse(w_full, ref[:len(w_full)]) if full_ok else np.inf),
                     rmse_vs_full_same_integrator=relative_rmse(w, w_full) if stable and full_ok else np.nan,
                     stable=bool(stable), extrapolated_steps=traj.extrapolations, failed_at=traj.failed_at,
                     reference="full Bathe, dt = 1e-4 s")


def beam(out, quick=False):
    """Fig. 5 / 6: 20 sin(2 pi t), dt 0.05 .. 0.005, explicit schemes vs Bathe inside the step.

    1 POD mode is the paper's one-dof beam (reduced omega = 488 rad/s: central difference
    is stable for dt < 4.1 ms); 4 modes reach 15 400 rad/s (stable below 0.13 ms).
    """
    ss = scene_system("clamped_beam")
    t_end = 2.0
    fine = reference_run(ss, dt=1e-4, t_end=t_end, integrator="bathe")
    mid = output_functionals(ss)["midpoint_w"]
    rows, curves = [], {"reference": (fine.t, fine.u @ mid)}
    # the paper's dt range, then smaller steps where the explicit one-mode models are stable
    for dt in (0.05, 0.025, 0.01, 0.005, 0.002, 0.001, 0.0005):
        tr = trajectory_training(ss, dt=dt, t_end=t_end)
        ctx = {"tr": tr, "mid": mid, "ref": np.interp(tr.parameter_values("time"), fine.t, fine.u @ mid),
               "ref_lat": time_full_step(ss, dt, "hht", alpha=-0.05), "curves": curves}
        for integ, load_at, m in BEAM_CASES:
            base = {"scene": "clamped_beam", "integrator": integ, "dt": dt, "load_at": load_at, "pod_modes": m}
            guarded(rows, base, lambda i=integ, la=load_at, m=m, c=ctx: _beam_row(c, i, la, m))
    plots_module().beam(curves, rows, out / "fig5_beam.png")
    return rows


def _liver_cases(quick):
    """(integrator, POD modes, load_at, velocity basis) of the liver rows."""
    integs = ("hht",) if quick else ("hht", "bathe", "central_difference")
    cases = [(i, m, "end", "velocity") for i in integs for m in (1, 3, 7)]
    cases += [(i, m, "end", "displacement") for i in integs if i != "central_difference" for m in (1, 3, 7)]
    return cases + [("hht", 7, "mid", "displacement")]


def _liver_row(c, integ, m, load_at, vb):
    tr, tip, free = c["tr"], c["tip"], c["free"]
    times, U_ref = tr.parameter_values("time"), tr.snapshots.T
    model, bs = build(tr, pod_modes=m, integrator=integ, load_at=load_at, velocity_basis=vb)
    traj = simulate(model, times, tr.history)
    full = full_run(model, times, tr.history)
    n, nf = len(traj.u), min(len(traj.u), len(full.u))
    y = traj.u @ tip
    if load_at == "end":
        c["hist"][(integ, m, vb)] = y
    peaks = spectrum_peaks(y[free[:n]], tr.dt) if n == len(times) else (np.array([]), np.array([]))
    lat, rec = time_direct(model, times, tr.history)
    return model_row("liver_dynamic", model, bs, lat, rec, c["ref_lat"], load_at=load_at, velocity_basis=vb,
                     rmse_vs_reference=relative_rmse(traj.u, U_ref[:n]),
                     rmse_full_same_integrator_vs_reference=relative_rmse(full.u[:nf], U_ref[:nf]),
                     rmse_vs_full_same_integrator=relative_rmse(traj.u[:nf], full.u[:nf]),
                     tip_rmse_vs_reference=relative_rmse(y, U_ref[:n] @ tip),
                     projection_floor=projection_error(U_ref, model, model.ops.M),
                     peaks_hz=json.dumps(np.round(peaks[0], 2).tolist()),
                     reference_peaks_hz=json.dumps(np.round(c["ref_peaks"][0], 2).tolist()),
                     extrapolated_steps=traj.extrapolations, failed_at=traj.failed_at, reference="HHT alpha=-0.05")


def liver(out, quick=False):
    """Fig. 20: 5 N ramp and release, free vibration; 1, 3, 7 modes vs HHT: error history, spectrum."""
    ss = scene_system("liver_dynamic")
    tr = trajectory_training(ss)
    times, U_ref = tr.parameter_values("time"), tr.snapshots.T
    tip = tr.outputs["tool_tip_uy"]
    y_ref = U_ref @ tip
    free = times >= 0.5
    ref_peaks = spectrum_peaks(y_ref[free], tr.dt)
    ref_lat = time_full_step(ss, tr.dt, "hht", alpha=-0.05)
    rows, hist = [], {"t": times, "reference": y_ref}
    ctx = {"tr": tr, "tip": tip, "free": free, "ref_peaks": ref_peaks, "ref_lat": ref_lat, "hist": hist}
    for integ, m, load_at, vb in _liver_cases(quick):
        base = {"scene": "liver_dynamic", "integrator": integ, "pod_modes": m, "load_at": load_at,
                "velocity_basis": vb}
        guarded(rows, base, lambda i=integ, m=m, la=load_at, vb=vb: _liver_row(ctx, i, m, la, vb))
    rows += modes_curve("liver_dynamic", tr, (10,) if quick else (2, 5, 10, 15, 20))
    plots_module().liver(hist, rows, out / "fig20_liver.png")
    return rows


SCENES = {"frame": frame, "beam": beam, "wave": wave, "liver": liver}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("results/direct"), help="output folder")
    ap.add_argument("--scenes", default=",".join(SCENES), help=f"comma-separated subset of {list(SCENES)}")
    ap.add_argument("--quick", action="store_true", help="fewer curve points and a 2 s long run")
    args = ap.parse_args(argv)
    names = [s.strip() for s in args.scenes.split(",") if s.strip()]
    bad = sorted(set(names) - set(SCENES))
    if bad:
        ap.error(f"unknown scene(s) {bad}; valid: {list(SCENES)}")
    import pandas as pd

    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in names:
        tic = time.perf_counter()
        new = SCENES[name](args.out, args.quick)
        rows += new
        df = pd.DataFrame(new)
        df.to_csv(args.out / f"rows_{name}.csv", index=False)
        print(f"--- {name} ({time.perf_counter() - tic:.0f} s)")
        print(summary(df).to_string(index=False), flush=True)
    df = pd.DataFrame(rows)
    df.to_parquet(args.out / "rows.parquet", index=False)
    df.to_csv(args.out / "rows.csv", index=False)
    print("written:", args.out)
    return 0


def summary(df):
    """The columns of the closing note: error, median, p99, speed-up, extrapolations, drift."""
    cols = [c for c in ("scene", "variant", "curve", "integrator", "velocity_basis", "load_at", "dt", "pod_modes",
                        "n_nodes", "separated_terms",
                        "rmse_vs_reference", "rmse_full_same_integrator_vs_reference", "rmse_vs_full_same_integrator",
                        "projection_floor", "median_step_s",
                        "p99_step_s", "speedup_vs_hht", "extrapolated_steps", "failed_at", "energy_drift_final",
                        "offline_s") if c in df]
    return df[cols]


if __name__ == "__main__":
    sys.exit(main())
