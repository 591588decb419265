"""Figures of a sweep's derived tables (matplotlib, Agg): the Pareto front per scene and the
validity radii, written into the results folder's ``_derived/``."""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from .figures import pyplot
from .wording import metric_words

__all__ = ["plot_pareto", "plot_radius"]


_MARKERS = ["o", "s", "D", "^", "v", "p", "h", "*", "P", "X"]


def _file_part(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", str(name))


def plot_pareto(pareto, folder: Path, paper=None) -> list[Path]:
    """``pareto_<case>.png``: error versus haptic median latency (log axes), one colour per
    method and one marker per option set of it, the front joined, the reference's step time as a
    vertical line; ``paper`` (columns case, label, step_ms, error) adds the published points of a case."""
    plt = pyplot()
    paths = []
    for case, grp in pareto.groupby("case"):
        ok = grp[np.isfinite(grp["error"]) & np.isfinite(grp["haptic_median_s"]) & (grp["error"] > 0)]
        fig, ax = plt.subplots(figsize=(7.5, 5))
        for i, (method, g) in enumerate(ok.groupby("method")):  # a colour per method, a marker per option set
            sets = list(g.groupby("options")) if "options" in g else [("", g)]
            for j, (_, rows) in enumerate(sets):
                ax.scatter(rows["haptic_median_s"] * 1e3, rows["error"], s=22, color=f"C{i % 10}",
                           marker=_MARKERS[j % len(_MARKERS)], alpha=0.8,
                           label=rows["label"].iloc[0] if len(sets) > 1 else method)
        pub = paper[paper["case"] == case] if paper is not None and len(paper) else []
        if len(pub):
            ax.scatter(pub["step_ms"], pub["error"], s=30, marker="s", facecolors="none", edgecolors="k",
                       label=f"paper ({len(pub)} points, its mesh and machine)")
        front = ok[ok["pareto"]].sort_values("haptic_median_s")
        if len(front):
            ax.step(front["haptic_median_s"] * 1e3, front["error"], "k-", where="post", lw=1, label="Pareto front")
        ref = grp["reference_step_s"].median()
        if np.isfinite(ref):
            ax.axvline(ref * 1e3, color="grey", ls="--", lw=1, label=f"reference step {ref * 1e3:.3g} ms")
        for y, name in ((0.01, "1 %"), (0.05, "5 %")):
            ax.axhline(y, color="tab:red", ls=":", lw=0.8)
            ax.text(ax.get_xlim()[0] if len(ok) else 1e-3, y, name, color="tab:red", fontsize=7, va="bottom")
        if len(ok):
            ax.set_xscale("log")
            ax.set_yscale("log")
        ax.set_xlabel("haptic step, median [ms]")
        metric = grp["error_metric"].iloc[0]
        ax.set_ylabel(f"{metric_words(metric)}\n({metric})", fontsize=8)
        ax.set_title(f"{case}: accuracy versus latency ({len(ok)} units, {int(ok['pareto'].sum())} on the front)")
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:  # a case whose units all failed draws nothing
            ax.legend(fontsize=7)
        fig.tight_layout()
        path = Path(folder) / f"pareto_{_file_part(case)}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def plot_radius(radius, folder: Path) -> Path:
    """``radius.png``: the validity radius at 1 % and 5 % of every unit, per scene."""
    plt = pyplot()
    cases = list(radius["case"].unique())
    fig, axes = plt.subplots(len(cases), 1, figsize=(8, 0.35 * max(len(radius), 4) / max(len(cases), 1) + 2.2
                                                      * len(cases)), squeeze=False)
    for ax, case in zip(axes[:, 0], cases):
        g = radius[radius["case"] == case].reset_index(drop=True)
        y = np.arange(len(g))
        ax.barh(y + 0.2, g["validity_5pct"].fillna(0), height=0.4, color="tab:orange", label="error <= 5 %")
        ax.barh(y - 0.2, g["validity_1pct"].fillna(0), height=0.4, color="tab:blue", label="error <= 1 %")
        ax.set_yticks(y, g["label"], fontsize=6)
        ax.set_xlabel(g["x_name"].iloc[0] if len(g) else "")
        ax.set_title(f"{case}: validity radius", fontsize=9)
        ax.legend(fontsize=7)
    fig.tight_layout()
    path = Path(folder) / "radius.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
