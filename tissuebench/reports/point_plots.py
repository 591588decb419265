"""Figures of a sweep along each case's evaluation abscissa: error and step time per point.

Written by :func:`~tissuebench.studies.sweep.write_derived` into ``_derived/`` for every sweep
and any method (trajectory units have their own ``history_<case>.png``):

* ``errors_<case>.png``: each unit's relative l2 error of the field against the evaluation
  abscissa (load factor, held-out distance, parameter, cut length: pgd-cutting Fig. 7, the
  error as the scalpel advances), the largest error where several points share an abscissa;
* ``latency_<case>.png``: the distribution of every timed haptic step of each unit (box: the
  quartiles, whiskers: 1st and 99th percentiles) beside the full model's step measured in the
  same process, and, where the timed steps fall on a few abscissae (cut lengths, load factors),
  the median and 99th percentile at each one (pgd-cutting Fig. 8: step time per cut length).

Both draw the same units: the best of every method first, then the best of every variant
(categorical options: srb and prb, cracking-node and condensed), then the best of the rest.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from .figures import pyplot
from .format import seconds
from .sweep_plots import _file_part
from .trend_plots import _best_units

__all__ = ["plot_point_errors", "plot_latency", "latency_by_abscissa", "MAX_UNITS", "HAPTIC_BUDGET_S"]

MAX_UNITS = 8
HAPTIC_BUDGET_S = 1e-3  # 1 kHz: the haptic rate the papers aim at
MAX_ABSCISSAE = 60  # more distinct abscissae than this (random draws): no per-abscissa panel


def _per_case(units: pd.DataFrame, table: pd.DataFrame, error_metric: str):
    """Yield ``(case, units drawn, error metric, rows of table of those units)`` for every case
    of the non-trajectory units that finished and have rows in ``table``."""
    if units.empty or table.empty:
        return
    ok = units[(units["unit_status"] == "ok") & (units["kind"] != "trajectory")]
    for case, group in ok.groupby("case"):
        metric = error_metric if error_metric in group else "max_rel_l2"
        chosen = _best_units(group, metric, MAX_UNITS)
        rows = table[table["unit_key"].isin(chosen["unit_key"])]
        if not rows.empty:
            yield case, chosen, metric, rows


def _short_labels(chosen: pd.DataFrame) -> tuple[list[str], str]:
    """The units' labels without the words they all share, and those words (for the title):
    ``pgd_cutting n_modes=10 strip_rings=1`` and ``pgd_cutting n_modes=6 strip_rings=1`` are
    ``n_modes=10`` and ``n_modes=6`` of ``pgd_cutting strip_rings=1``."""
    words = [str(label).split() for label in chosen["label"]]
    common = [w for w in words[0] if all(w in ws for ws in words)] if len(words) > 1 else []
    short = [" ".join(w for w in ws if w not in common) or " ".join(ws) for ws in words]
    return short, " ".join(common)


def _save(plt, fig, folder: Path, stem: str, case: str) -> Path:
    fig.tight_layout()
    path = Path(folder) / f"{stem}_{_file_part(case)}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_point_errors(units: pd.DataFrame, points: pd.DataFrame, folder: Path,
                      error_metric: str = "max_rel_l2") -> list[Path]:
    """``errors_<case>.png`` for every case with at least two abscissae with a reference."""
    plt = pyplot()
    paths = []
    finite = points[np.isfinite(points["rel_l2"]) & points["has_reference"].astype(bool)] if len(points) else points
    for case, chosen, metric, mine in _per_case(units, finite, error_metric):
        if mine["x"].nunique() < 2:
            continue
        fig, ax = plt.subplots(figsize=(8, 4.2))
        short, common = _short_labels(chosen)
        for label, row in zip(short, chosen.itertuples()):
            worst = mine[mine["unit_key"] == row.unit_key].groupby("x")["rel_l2"].max()
            ax.plot(worst.index, np.maximum(worst.to_numpy(), 1e-16), "o-", ms=3, lw=1,
                    label=f"{label} ({getattr(row, metric):.3g})")
        ax.set_yscale("log")
        ax.set_xlabel(str(chosen["x_name"].iloc[0]) if "x_name" in chosen else "x")
        ax.set_ylabel("relative l2 error of the field")
        ax.set_title(f"{case}: error along the evaluation ({metric} in the legend)\n{common}", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6)
        paths.append(_save(plt, fig, folder, "errors", case))
    return paths


def _distribution_panel(ax, chosen, samples, short):
    data = [samples.loc[samples["unit_key"] == k, "haptic_s"].to_numpy() for k in chosen["unit_key"]]
    keep = [i for i, d in enumerate(data) if d.size]
    ax.boxplot([data[i] for i in keep], orientation="horizontal", whis=(1, 99), flierprops={"markersize": 2})
    ax.set_yticks(range(1, len(keep) + 1), [short[i] for i in keep], fontsize=7)
    ax.invert_yaxis()  # the best unit on top, as in the legends
    ref = chosen["reference_step_s"].to_numpy(float) if "reference_step_s" in chosen else np.array([])
    ref = ref[np.isfinite(ref)]
    if ref.size:
        ax.axvline(float(np.median(ref)), color="k", ls="--", lw=1,
                   label=f"full model's step {seconds(float(np.median(ref)))} (same process)")
    ax.axvline(HAPTIC_BUDGET_S, color="tab:red", ls=":", lw=1, label="1 ms (1 kHz)")
    ax.set_xscale("log")
    ax.set_xlabel("haptic step [s]")
    ax.grid(alpha=0.3, which="both", axis="x")
    ax.legend(fontsize=6)


def latency_by_abscissa(latency: pd.DataFrame) -> pd.DataFrame:
    """Per unit and abscissa (samples with a finite ``x``): ``n``, ``median_s``, ``p99_s`` and
    ``max_s`` of the haptic step [s] (pgd-cutting Fig. 8: the step time per cut length)."""
    finite = latency[np.isfinite(latency["x"])]
    by = finite.groupby(["unit_key", "x"])["haptic_s"]
    return pd.DataFrame({"n": by.size(), "median_s": by.median(), "p99_s": by.quantile(0.99),
                         "max_s": by.max()}).reset_index()


def _abscissa_panel(ax, chosen, samples, short):
    table = latency_by_abscissa(samples)
    for i, (label, key) in enumerate(zip(short, chosen["unit_key"])):
        mine = table[table["unit_key"] == key]
        if mine.empty:
            continue
        colour = f"C{i % 10}"
        ax.plot(mine["x"], mine["median_s"], "o-", ms=3, lw=1, color=colour, label=label)
        ax.plot(mine["x"], mine["p99_s"], ":", lw=1, color=colour)
    ax.axhline(HAPTIC_BUDGET_S, color="tab:red", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_xlabel(str(chosen["x_name"].iloc[0]) if "x_name" in chosen else "x")
    ax.set_ylabel("haptic step [s]: median (line), p99 (dotted)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6)


def plot_latency(units: pd.DataFrame, latency: pd.DataFrame, folder: Path,
                 error_metric: str = "max_rel_l2") -> list[Path]:
    """``latency_<case>.png`` for every case whose drawn units have timed steps."""
    plt = pyplot()
    paths = []
    for case, chosen, _, samples in _per_case(units, latency, error_metric):
        n_x = samples.loc[np.isfinite(samples["x"])].groupby("unit_key")["x"].nunique()
        per_x = len(n_x) > 0 and 1 < n_x.max() <= MAX_ABSCISSAE
        short, common = _short_labels(chosen)
        fig, axes = plt.subplots(1 + per_x, 1, figsize=(8, 4.2 * (1 + per_x)), squeeze=False)
        _distribution_panel(axes[0, 0], chosen, samples, short)
        axes[0, 0].set_title(f"{case}: every timed haptic step (box: quartiles, whiskers: 1-99 %)\n{common}",
                             fontsize=9)
        if per_x:
            _abscissa_panel(axes[1, 0], chosen, samples, short)
        paths.append(_save(plt, fig, folder, "latency", case))
    return paths
