"""Table 1 of the wsc paper against ours, per row, from a ``wsc_table1`` sweep (issue 31).

    tissuebench sweep --preset wsc_table1 --resolution paper --cases cube-tension --out OUT
    python docs/studies/wsc_table1_cputime.py CPU.csv bgbc        # optional: CPU time per step
    python docs/studies/wsc_table1_table.py OUT[,OUT2] docs/studies/wsc_table1_paper [CPU.csv ...]

writes ``<stem>.csv``, ``<stem>.md`` (paper RMSE and ms per step beside ours for the BGBC and
RBF cubatures: RMSE, median and p99 step (wall), the speed-up over our FE step measured in the
same process, whether the median is within the paper's time; with CPU.csv files the
stepping thread's CPU time per step and its RMSE where the sweep has no row) and
``<stem>_vs_paper.png``.
"""
from __future__ import annotations

import json
import sys
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

PRESET = Path(__file__).resolve().parents[2] / "tissuebench" / "studies" / "presets" / "wsc_table1.toml"


def paper_rows() -> pd.DataFrame:
    spec = tomllib.loads(PRESET.read_text())
    case = next(c for c in spec["case"] if c["id"] == "cube-tension")
    rows = []
    for p in case["paper_points"]:
        h, c = (int(x) for x in p["label"].split("/"))
        rows.append({"handles": h, "elements": c, "paper_rmse_%": 100 * p["error"], "paper_ms": p["step_ms"]})
    return pd.DataFrame(rows)


def ours(sweep) -> pd.DataFrame:
    """Our rows from one sweep folder, or several separated by commas (e.g. one per cubature)."""
    df = pd.concat([pd.read_parquet(Path(s) / "case=cube-tension") for s in str(sweep).split(",")],
                   ignore_index=True)
    opts = df["options"].map(json.loads)
    info = df["model_info"].map(json.loads)
    out = pd.DataFrame({
        "cubature": opts.map(lambda o: o.get("cubature")),
        "handles": opts.map(lambda o: o.get("handles")),
        "elements": opts.map(lambda o: o.get("cubature_elements")),
        "rmse_%": 100 * df["rmse_rel"], "ms_median": 1e3 * df["haptic_median_s"], "ms_p99": 1e3 * df["haptic_p99_s"],
        "fe_ms": 1e3 * df["reference_step_s"], "speedup": df["speedup"],
        "solve": info.map(lambda i: f"{i.get('step_matrix', {}).get('kind', '?')}/"
                                    f"{i.get('step_matrix', {}).get('precision', '?')}"),
        "status": df["unit_status"]})
    return out[out["cubature"].isin(["bgbc", "rbf"])]


def table(sweep, cpu_files=()) -> pd.DataFrame:
    paper, mine = paper_rows(), ours(sweep)
    cpu = pd.concat([pd.read_csv(f) for f in cpu_files]) if cpu_files else pd.DataFrame(
        columns=["handles", "elements", "cubature", "cpu_ms_median", "rmse_rel"])
    cpu = cpu.drop_duplicates(["handles", "elements", "cubature"], keep="last")
    for cub in ("bgbc", "rbf"):
        part = mine[mine["cubature"] == cub].drop(columns="cubature")
        part = part.rename(columns={c: f"{cub}_{c}" for c in part.columns if c not in ("handles", "elements")})
        paper = paper.merge(part, on=["handles", "elements"], how="left")
        paper[f"{cub}_within_paper_ms"] = _within(paper[f"{cub}_ms_median"], paper["paper_ms"])
        c = cpu[cpu["cubature"] == cub][["handles", "elements", "cpu_ms_median", "rmse_rel"]]
        c = c.rename(columns={"cpu_ms_median": f"{cub}_cpu_ms", "rmse_rel": f"{cub}_cpu_run_rmse_%"})
        c[f"{cub}_cpu_run_rmse_%"] *= 100
        paper = paper.merge(c, on=["handles", "elements"], how="left")
        paper[f"{cub}_cpu_within_paper_ms"] = _within(paper[f"{cub}_cpu_ms"], paper["paper_ms"])
    return paper


def _within(ours_ms, paper_ms):
    """yes / no, or blank where ours was not measured."""
    return np.where(ours_ms.isna(), "", np.where(ours_ms <= paper_ms, "yes", "no"))


def markdown(t: pd.DataFrame) -> str:
    """A pipe table (pandas' to_markdown needs tabulate, not a project dependency)."""
    def cell(v):
        return ("" if np.isnan(v) else f"{v:.3g}") if isinstance(v, float) else str(v)
    lines = ["| " + " | ".join(t.columns) + " |", "|" + "---|" * len(t.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in t.itertuples(index=False)]
    return "\n".join(lines)


def figure(t: pd.DataFrame, path: Path):
    fig, ax = plt.subplots(figsize=(8, 5.5))
    ax.scatter(t["paper_ms"], t["paper_rmse_%"], marker="s", facecolors="none", edgecolors="k", label="paper (its CPU)")
    for cub, m in (("bgbc", "o"), ("rbf", "^")):
        if f"{cub}_ms_median" in t:
            ax.scatter(t[f"{cub}_ms_median"], t[f"{cub}_rmse_%"], marker=m, label=f"ours, {cub.upper()}")
    for _, r in t.iterrows():
        ax.annotate(f"{r['handles']}/{r['elements']}", (r["paper_ms"], r["paper_rmse_%"]), fontsize=6, alpha=0.6)
    ax.set(xscale="log", yscale="log", xlabel="step, median [ms]", ylabel="relative RMSE of the displacement [%]",
           title="wsc Table 1 (cube, 7744 vertices / 37800 tets): paper vs ours")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(sweep, stem, *cpu_files):
    stem = Path(stem)
    t = table(sweep, cpu_files)
    t.to_csv(stem.with_suffix(".csv"), index=False, float_format="%.4g")
    cols = ["handles", "elements", "paper_rmse_%", "paper_ms"]
    for cub in ("bgbc", "rbf"):
        cols += [f"{cub}_rmse_%", f"{cub}_ms_median", f"{cub}_ms_p99", f"{cub}_within_paper_ms", f"{cub}_speedup",
                 f"{cub}_solve", f"{cub}_cpu_ms", f"{cub}_cpu_within_paper_ms"]
        if cub == "rbf":
            cols.append("rbf_cpu_run_rmse_%")
    shown = t[[c for c in cols if c in t]]
    md = markdown(shown.loc[:, [not (shown[c].isna() | (shown[c] == "")).all() for c in shown]])  # measured columns
    fe = np.nanmedian(t.get("bgbc_fe_ms", pd.Series([np.nan])))
    stem.with_suffix(".md").write_text(f"Our FE step (same processes, median): {fe:.4g} ms\n\n{md}\n")
    figure(t, stem.parent / f"{stem.name}_vs_paper.png")
    print(md)


if __name__ == "__main__":
    main(*sys.argv[1:])
