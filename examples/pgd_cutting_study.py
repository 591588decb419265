"""PGD vademecum + cracking-node cutting on the cornea (pgd-vademecum-cutting §5, Figs. 7-8).

``python examples/pgd_cutting_study.py --resolution paper --out results/pgd_cutting``

For one incision of cornea_cut (the scene's first, 0 deg, r = 1.5 .. 4.5 mm) and every cut
length c (cracked nodes along it, :mod:`tissuebench.rom.pgd.strip`), with the scalpel on
the crack tip pressing with the scene's contact force:

* **error**: relative L2 error (mass norm) of the reduced field against the full linear
  FE of the same cut mesh, for modes 1..N x {srb, prb} x {cracking_node (the paper's
  enrichment), condensed (corrected by the intact response, :mod:`tissuebench.rom.pgd.enrichment`)}
  (one vademecum of N modes, the modes being nested: built once, truncated);
* **latency**: the haptic step (``step`` + ``outputs``: reduced solve at s_p including the
  enrichment after a cut, the contact force split and the cut criterion), per call, a
  session advancing the cut from 0 to its longest with ``steps_per_length`` steps per
  length (the first step at a new length enriches), repeated; median / p99 overall and
  per cut length; the full FE step of the same cut (assembly of K and f, factorisation,
  solve) timed in the same process, and the speed-up;
* **figures**: error vs cut length (Fig. 7) and step-time statistics per cut length
  (Fig. 8); ``heat1d``: the one-mode identity of eqs. 18-19; ``--svk``: the SVK Ritz model
  against the full SVK Newton solve on the intact cornea.

Outputs in ``--out``: ``errors.parquet``, ``latency.parquet``, ``reference.parquet``,
``svk.parquet`` (with --svk), ``summary.json``, ``fig7_error_vs_cut_length.png``,
``fig8_step_time.png``; the table is printed. Functions are small so the sweep harness
can call them.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
import pandas as pd

from tissuebench.cases.scene import load
from tissuebench.refsolvers import make_backend
from tissuebench.rom import make_method
from tissuebench.rom.pgd import CuttingModel, PgdSvkModel, pgd_training
from tissuebench.rom.pgd.enrichment import condense
from tissuebench.rom.pgd.projections import srb_beta_in_modes
from tissuebench.rom.pgd.reference import cut_problem, l2_error, linear_reference
from tissuebench.studies.timing import latency_stats

__all__ = ["build_family", "cut_references", "error_rows", "latency_rows", "heat1d_identity", "svk_rows",
           "plot_errors", "plot_latency", "main"]


ENRICHMENTS = ("cracking_node", "condensed")


def build_family(scene, n_modes: int, backend: str = "skfem", **options) -> dict:
    """{(n, projection, enrichment): CuttingModel} for n = 1..n_modes from one build
    (nested modes; the condensed enrichment from the same operators)."""
    t0 = time.perf_counter()
    base = make_method("pgd_cutting", n_modes=n_modes, projection="srb", **options).build(pgd_training(scene, backend))
    build_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    enr = {"cracking_node": base.enrichment, "condensed": condense(base.enrichment, base.vademecum.family.K)}
    condense_s = time.perf_counter() - t0
    models = {}
    for n in range(1, base.vademecum.n_modes + 1):
        vad = base.vademecum.truncated(n)
        for proj in ("srb", "prb"):
            for kind in ENRICHMENTS:
                models[n, proj, kind] = CuttingModel("pgd_cutting", vad, proj, enr[kind], base.F_cut, base.points,
                                                     base.problem)
    models["build_s"], models["condense_s"], models["base"] = build_s, condense_s, base
    return models


def cut_references(scene, model, backend: str = "skfem") -> list[dict]:
    """Per cut length: the full linear FE field, the mass matrix and the full-step times."""
    out = []
    for c in range(model.strip.max_cut_length + 1):
        t0 = time.perf_counter()
        be = make_backend(backend, cut_problem(scene, model.strip, c, model.force))
        setup = time.perf_counter() - t0
        u, times = linear_reference(be)
        out.append({"c": c, "u": u, "mass": be.mass(), "setup_s": setup, **times,
                    "full_step_s": times["assemble_s"] + times["factor_s"] + times["solve_s"],
                    "n_dof": be.ndof, "cracked_nodes": int(model.strip.n_enriched[c])})
    return out


def _mu(model, c):
    return {"node": model.strip.tip(c), "cut_length": c}


def error_rows(models, refs) -> pd.DataFrame:
    rows = []
    for key, m in models.items():
        if not isinstance(key, tuple):
            continue
        m.start()
        for ref in refs:
            r = m.step(_mu(m, ref["c"]))
            rows.append({"n_modes": key[0], "projection": key[1], "enrichment": key[2], "cut_length": ref["c"],
                         "cracked_nodes": ref["cracked_nodes"], "status": r.status,
                         "l2_error": l2_error(m.reconstruct(r), ref["u"], ref["mass"])})
    return pd.DataFrame(rows)


def _session(model, steps_per_length):
    return [_mu(model, c) for c in range(model.strip.max_cut_length + 1) for _ in range(steps_per_length)]


def latency_rows(models, steps_per_length: int = 20, repeats: int = 10, modes=None) -> pd.DataFrame:
    """Haptic step (step + outputs) timings, one row per (n, projection, cut length) and
    one per (n, projection) over the whole session (cut_length = -1)."""
    rows = []
    for key, m in models.items():
        if not isinstance(key, tuple) or (modes is not None and key[0] not in modes):
            continue
        mus = _session(m, steps_per_length)
        for mu in mus[:steps_per_length]:  # warm-up of the intact steps (no enrichment)
            m.outputs(m.step(mu))
        samples = np.zeros((repeats, len(mus)))
        for k in range(repeats):
            m.start()  # forget the enrichment: every pass enriches on the fly again
            for i, mu in enumerate(mus):
                t0 = time.perf_counter()
                m.outputs(m.step(mu))
                samples[k, i] = time.perf_counter() - t0
        cut = np.array([mu["cut_length"] for mu in mus])
        first = np.r_[True, cut[1:] != cut[:-1]]
        for c in [-1] + sorted(set(cut.tolist())):
            sel = np.ones(len(mus), bool) if c == -1 else cut == c
            st = latency_stats(samples[:, sel].ravel())
            en = latency_stats(samples[:, sel & first].ravel())
            rows.append({"n_modes": key[0], "projection": key[1], "enrichment": key[2], "cut_length": c,
                         **st.as_dict("step_"),
                         "enrich_step_median_s": en.median, "enrich_step_max_s": en.max,
                         "n_reduced_max": m.r + 3 * int(m.strip.n_enriched[-1])})
    return pd.DataFrame(rows)


def heat1d_identity(resolution: str = "ci", positions=(0.5, 0.3, 0.71)) -> pd.DataFrame:
    """One-mode srb / prb on heat1d_source: beta_srb, S(s_p), beta_prb, (gamma/alpha) S(s_p)."""
    tr = pgd_training(load("heat1d_source", resolution))
    prb = make_method("pgd", n_modes=1, projection="prb").build(tr)
    vad, rows = prb.vademecum, []
    ga = vad.gamma[0] / vad.alpha[0, 0]
    for s in positions:
        rv = vad.family.load_at(s)
        b_srb, b_prb, S = srb_beta_in_modes(vad, *rv)[0], prb.proj.beta(*rv)[0], vad.S_at(s)[0]
        rows.append({"s_p": s, "beta_srb": b_srb, "S_sp": S, "beta_prb": b_prb, "gamma_over_alpha": ga,
                     "eq18_rel_diff": abs(b_prb - ga * b_srb) / abs(b_prb),
                     "eq19_rel_diff": abs(b_prb - ga * S) / abs(b_prb)})
    return pd.DataFrame(rows)


def svk_rows(scene, modes=(2, 4, 6, 8, 10), backend: str = "skfem", steps: int = 200) -> pd.DataFrame:
    """pgd_svk (intact cornea, scene load node) against the full SVK Newton solve."""
    from tissuebench.refsolvers.newton import NewtonOptions, newton_solve

    tr = pgd_training(scene, backend)
    t0 = time.perf_counter()
    n_steps = int(scene.analysis.get("load_steps", 1))  # as the reference runner: the scene's increments
    ref = newton_solve(tr.backend, 1.0, NewtonOptions(n_increments=n_steps, max_increment=1.0 / n_steps))
    full_s = time.perf_counter() - t0
    node = int(tr.backend.problem.loads[0].nodes[0])
    t0 = time.perf_counter()
    big = make_method("pgd_svk", n_modes=max(modes)).build(tr)
    build_s = time.perf_counter() - t0
    rows = []
    for n in [n for n in modes if n <= big.n_reduced]:  # the build may stop earlier (its record says why)
        m = PgdSvkModel(big.name, big.vademecum.truncated(n), big.basis[:, :n], big.poly.leading(n), big.problem,
                        big.rtol, big.max_iterations, big.max_increments)
        r = m.step({"node": node})
        # no error against a reference that did not reach the load (its last state is another load)
        err = np.linalg.norm(m.reconstruct(r) - ref.u) / np.linalg.norm(ref.u) if ref.success else np.nan
        ts = []
        for _ in range(steps):
            t = time.perf_counter()
            m.step({"node": node})
            ts.append(time.perf_counter() - t)
        st = latency_stats(ts)
        rows.append({"n_modes": n, "status": r.status, "rel_error": err, "newton_iterations": len(r.info.get(
            "residual_norms", [])) - 1, "step_median_s": st.median, "step_p99_s": st.p99, "build_s": build_s,
            "full_newton_s": full_s, "full_newton_success": ref.success, "full_newton_load_factor": ref.load_factor,
            "full_newton_message": ref.message,
            "vademecum_stop": big.info["stop_reason"], "vademecum_modes": big.n_reduced})
    return pd.DataFrame(rows)


def plot_errors(errors: pd.DataFrame, path, modes=(6, 10)):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.5))
    modes = [n for n in modes if n <= errors.n_modes.max()]
    for n in modes:
        for proj, kind, style in (("srb", "cracking_node", "o-"), ("prb", "cracking_node", "s--"),
                                  ("srb", "condensed", "^-")):
            d = errors[(errors.n_modes == n) & (errors.projection == proj) & (errors.enrichment == kind)]
            d = d.sort_values("cut_length")
            ax.semilogy(d.cracked_nodes, d.l2_error, style, label=f"{proj}, {kind}, {n} modes")
    ax.axhline(7e-3, color="k", lw=0.8, ls=":", label="paper bound 7e-3")
    ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
    ax.set_xlabel("nodes in the cut zone (cracked nodes)")
    ax.set_ylabel("relative L2 error vs full FE of the same cut")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def plot_latency(latency: pd.DataFrame, path, n_modes=6):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    for proj, dx in (("srb", -0.15), ("prb", 0.15)):
        d = latency[(latency.n_modes == n_modes) & (latency.projection == proj) & (latency.cut_length >= 0)
                    & (latency.enrichment == "cracking_node")]
        x = d.cut_length.to_numpy() + dx
        ax.errorbar(x, 1e3 * d.step_median_s, yerr=[0 * x, 1e3 * (d.step_p99_s - d.step_median_s)], fmt="o",
                    capsize=3, label=f"{proj}: median, bar to p99")
        ax.plot(x, 1e3 * d.enrich_step_max_s, "x", label=f"{proj}: slowest enrichment step")
    ax.axhline(1.0, color="k", lw=0.8, ls=":", label="1 ms (1 kHz)")
    ax.xaxis.set_major_locator(plt.MaxNLocator(integer=True))
    ax.set_yscale("log")
    ax.set_xlabel("cut length (cut nodes along the incision)")
    ax.set_ylabel("haptic step time [ms]")
    ax.set_title(f"{n_modes} PGD modes")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _table(errors, latency, refs):
    full = np.median([r["full_step_s"] for r in refs])
    keys = ["enrichment", "projection", "n_modes"]
    err = errors.groupby(keys).l2_error.agg(["max", "median"]).rename(
        columns={"max": "err_max", "median": "err_median"})
    lat = latency[latency.cut_length == -1].set_index(keys)[
        ["step_median_s", "step_p99_s", "enrich_step_max_s"]]
    t = err.join(lat)
    t["speedup"] = full / t["step_median_s"]
    return t, full


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--resolution", default="ci", choices=("ci", "paper"))
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--modes", type=int, default=10)
    ap.add_argument("--steps-per-length", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--radii", type=float, nargs=2, default=None, help="override the incision radii (mm)")
    ap.add_argument("--svk", action="store_true", help="also the SVK Ritz model vs the full SVK Newton")
    ap.add_argument("--latency-modes", type=int, nargs="*", default=None, help="modes timed (default: all)")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    scene = load("cornea_cut", args.resolution)
    models = build_family(scene, args.modes, radii=args.radii)
    refs = cut_references(scene, models["base"])
    errors = error_rows(models, refs)
    latency = latency_rows(models, args.steps_per_length, args.repeats, args.latency_modes)
    heat = heat1d_identity()
    errors.to_parquet(args.out / "errors.parquet")
    latency.to_parquet(args.out / "latency.parquet")
    pd.DataFrame([{k: v for k, v in r.items() if k not in ("u", "mass")} for r in refs]).to_parquet(
        args.out / "reference.parquet")
    plot_errors(errors, args.out / "fig7_error_vs_cut_length.png", sorted({6, 10, args.modes}))
    plot_latency(latency, args.out / "fig8_step_time.png", min(6, args.modes))
    table, full = _table(errors, latency, refs)
    summary = {"resolution": args.resolution, "build_s": models["build_s"], "condense_s": models["condense_s"],
               "full_fe_step_median_s": full,
               "cut_lengths": len(refs) - 1, "n_dof_cut_max": refs[-1]["n_dof"],
               "build_info": {k: v for k, v in models["base"].info.items() if k != "operators"},
               "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS"), "heat1d": heat.to_dict("records")}
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
    pd.set_option("display.width", 200)
    print(heat.to_string(index=False))
    print(errors.pivot_table(index=["enrichment", "projection", "n_modes"], columns="cut_length",
                             values="l2_error").to_string(float_format=lambda x: f"{x:.2e}"))
    print(f"full FE step of the same cut (assemble + factorise + solve), median over cut lengths: {full:.3f} s")
    print(table.to_string(float_format=lambda x: f"{x:.3g}"))
    if args.svk:
        svk = svk_rows(scene)
        svk.to_parquet(args.out / "svk.parquet")
        summary["svk"] = svk.to_dict("records")
        (args.out / "summary.json").write_text(json.dumps(summary, indent=1, default=float))
        print(svk.to_string(index=False))
    return summary


if __name__ == "__main__":
    main()
