"""Cost versus size in the report and in ``_derived/``: the exponents of cost ~ n_dof^p.

:func:`plot_scaling` draws ``scaling_<quantity>.png`` (log-log, one panel per scaling group,
one line per method setting with its fitted exponent and 95 % interval in the legend; on the
time quantities the full model's own step, dashed black, beside the methods); :func:`scaling_section`
gives the report's "Cost versus size" section: per group a sentence on the haptic step (which
methods' steps are flat in the mesh size, which grow and how fast against the full model's)
and the table of exponents (CSV beside the page). Both read
:func:`~tissuebench.studies.scaling.scaling_table` / :func:`~tissuebench.studies.scaling.scaling_points`.
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
from matplotlib.ticker import NullFormatter

from ..studies.scaling import REFERENCE, scaling_points, scaling_table
from .figures import pyplot
from .format import number

__all__ = ["plot_scaling", "scaling_section", "exponent_text", "step_statement"]

_TIME = ("offline_s", "haptic_median_s", "haptic_p99_s", "reconstruct_median_s")
_YLABEL = {"offline_s": "offline build [s]", "model_bytes": "model memory [bytes]",
           "haptic_median_s": "haptic step, median [s]", "haptic_p99_s": "haptic step, p99 [s]",
           "reconstruct_median_s": "full-field reconstruction, median [s]"}
# below this exponent a cost is called flat in the mesh size (a 10x finer mesh: < 1.6x)
FLAT = 0.2


def _file_part(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", str(name))


def exponent_text(r) -> str:
    """``"p = 1.02 [0.95, 1.09]"`` (or ``"p = 1.02 (2 sizes, no interval)"``, ``"no fit"``)."""
    p = r["exponent"]
    if not math.isfinite(p):
        return "no fit"
    if math.isfinite(r["ci_low"]):
        return f"p = {p:.2f} [{r['ci_low']:.2f}, {r['ci_high']:.2f}]"
    return f"p = {p:.2f} ({int(r['n_sizes'])} sizes, no interval)"


def plot_scaling(table, points, folder) -> list[Path]:
    """``scaling_<quantity>.png`` for every quantity of ``table`` but the reference's own row
    (drawn on the time quantities); returns the paths."""
    plt = pyplot()
    paths = []
    groups = list(dict.fromkeys(table["scaling_group"]))
    quantities = [q for q in dict.fromkeys(table["quantity"]) if q != "reference_step_s"]
    for q in quantities:
        fig, axes = plt.subplots(1, len(groups), figsize=(5.4 * len(groups), 6.2), squeeze=False)
        for ax, group in zip(axes[0], groups):
            in_group = table["scaling_group"] == group
            rows = table[in_group & ((table["quantity"] == q) | ((table["method"] == REFERENCE) & (q in _TIME)))]
            n_sizes = points.loc[points["scaling_group"] == group, "n_dof"].nunique()
            for _, r in rows.iterrows():
                p = points[(points["scaling_group"] == group) & (points["method"] == r["method"])
                           & (points["options"] == r["options"]) & (points["quantity"] == r["quantity"])]
                p = p.sort_values("n_dof")
                y = p["value"].to_numpy(float)
                keep = np.isfinite(y) & (y > 0)
                if not keep.any():
                    continue
                style = dict(color="k", ls="--", lw=2.0) if r["method"] == REFERENCE else dict(ls="-", lw=1.2)
                fewer = f" ({int(r['n_sizes'])} sizes)" if r["n_sizes"] < n_sizes else ""
                ax.plot(p["n_dof"].to_numpy(float)[keep], y[keep], marker="o", ms=3.5, label=f"{r['label']}{fewer}: "
                        f"{exponent_text(r)}", **style)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("dofs of the mesh (n_dof)")
            ax.set_ylabel(_YLABEL.get(q, f"{q} (error metric)"))
            ax.set_title(f"{group}: {q} ~ n_dof^p (95 % interval)", fontsize=9)
            ax.xaxis.set_minor_formatter(NullFormatter())
            ax.grid(alpha=0.3, which="both")
            ax.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.14))
        fig.tight_layout()
        path = Path(folder) / f"scaling_{_file_part(q)}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def step_statement(table, group) -> str:
    """What the group's haptic steps do as the mesh grows, against the full model's step."""
    rows = table[(table["scaling_group"] == group) & (table["quantity"] == "haptic_median_s")]
    rows = rows[np.isfinite(rows["exponent"].to_numpy(float))]
    ref = table[(table["scaling_group"] == group) & (table["method"] == REFERENCE)]
    flat = [f"{r['label']} ({exponent_text(r)})" for _, r in rows.iterrows() if r["exponent"] < FLAT]
    grow = [f"{r['label']} ({exponent_text(r)})" for _, r in rows.iterrows() if r["exponent"] >= FLAT]
    r0 = ref.iloc[0] if len(ref) else None
    span = f"{int(rows['n_dof_min'].min())} to {int(rows['n_dof_max'].max())} dofs" if len(rows) else ""
    out = [f"From {span}, the full model's step grows as {exponent_text(r0)}." if r0 is not None else ""]
    if flat:
        out.append(f"Independent of the mesh size (p < {FLAT}): {'; '.join(flat)}.")
    if grow:
        out.append(f"Growing with it: {'; '.join(grow)}.")
    return " ".join(s for s in out if s)


def scaling_section(data, Table) -> dict | None:
    """``{"groups": [{"group", "sentence", "table"}], "tables": [...]}`` of the report, or None when
    the sweep has no scaling group with cases of 2 sizes or more."""
    cases = data.manifest.get("cases", [])
    points = scaling_points(data.units, cases, data.error_metric)
    if points.empty:
        return None
    table = scaling_table(data.units, cases, data.error_metric)
    groups, tables = [], []
    for i, (group, grp) in enumerate(table.groupby("scaling_group", sort=False)):
        rows = []
        for _, r in grp.iterrows():
            rows.append([r["label"], r["quantity"], exponent_text(r), int(r["n_sizes"]),
                         f"{int(r['n_dof_min'])} - {int(r['n_dof_max'])}", number(r["value_at_min"], 3),
                         number(r["value_at_max"], 3), r["note"]])
        t = Table(f"scaling_{i:02d}_{_file_part(group)}",
                  ["method setting", "quantity", "exponent p (95 % interval)", "sizes", "n_dof", "at the smallest",
                   "at the largest", "note"], rows, grp.reset_index(drop=True))
        groups.append({"group": group, "scene": f"{grp['case_name'].iloc[0]}"
                       + (f" ({grp['variant'].iloc[0]})" if grp["variant"].iloc[0] else ""),
                       "sentence": step_statement(table, group), "table": t})
        tables.append(t)
    return {"groups": groups, "tables": tables}
