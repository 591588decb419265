"""The fidelity ladder in the report and in ``_derived/``: what each scene requires.

:func:`plot_ladder` draws ``ladder_<case>.png`` (each rung's relative error along the load
path or in time, log scale, the 1 % and 5 % lines, the points where it first exceeds them);
:func:`ladder_section` gives the report's section: per scene the sentences of
:func:`~tissuebench.studies.ladder.ladder_statements` and the table of rungs (CSV beside the
page). Both read :func:`~tissuebench.studies.ladder.ladder_table`.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from ..studies.ladder import RUNG_METHODS, ladder_statements, ladder_table
from .figures import pyplot
from .format import hz, number, percent, seconds

__all__ = ["plot_ladder", "ladder_section", "versus_baselines"]


def _file_part(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", str(name))


def plot_ladder(table, points, folder) -> list[Path]:
    """``ladder_<case>.png`` for every case with rungs; returns the paths."""
    paths = []
    rungs = table[table["rung"] != "none"]
    if rungs.empty:
        return paths
    plt = pyplot()
    for case, grp in rungs.groupby("case", sort=False):
        fig, ax = plt.subplots(figsize=(7.5, 4.6))
        x_name = grp["x_name"].iloc[0]
        scale, axis = _axis(grp.iloc[0])
        for _, r in grp.sort_values(["coarsening", "physics"]).iterrows():
            p = points[points["unit_key"] == r["unit_key"]]
            p = p[p["has_reference"] & (p["status"] != "initial")].sort_values("x")
            e = p["rel_l2"].to_numpy(float)
            keep = np.isfinite(e) & (e > 0)
            line, = ax.plot(scale * p["x"].to_numpy(float)[keep], e[keep], "o-", ms=3, lw=1.2, label=r["rung"])
            for col in ("first_above_1pct", "first_above_5pct"):
                if np.isfinite(r[col]):
                    ax.axvline(scale * r[col], color=line.get_color(), ls=":", lw=0.7)
        for y, name in ((0.01, "1 %"), (0.05, "5 %")):
            ax.axhline(y, color="tab:red", ls="--", lw=0.8)
            ax.annotate(name, (0.005, y), xycoords=("axes fraction", "data"), color="tab:red", fontsize=7,
                        va="bottom")
        ax.set_yscale("log")
        ax.set_xlabel(axis or x_name.replace("_", " ") + (" [s]" if x_name == "time" else ""))
        ax.set_ylabel("relative l2 error against the full reference")
        ax.set_title(f"{case}: fidelity ladder (dotted: where a rung first exceeds 1 % / 5 %)", fontsize=9)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
        fig.tight_layout()
        path = Path(folder) / f"ladder_{_file_part(case)}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)
    return paths


def _axis(rung) -> tuple[float, str]:
    """``(scale, label)``: the abscissa in the scene's units (``x_scale``, ``x_unit`` of the ladder
    table: load factor 1 is the net force in N ...), or ``(1, "")`` without them."""
    scale, unit = rung.get("x_scale", np.nan), rung.get("x_unit", "")
    if isinstance(unit, str) and unit and np.isfinite(scale):
        what = "time" if rung["x_name"] == "time" else "load"
        return float(scale), f"{what} [{unit}]"
    return 1.0, ""


def _x(v, scale=1.0) -> str:
    return "never" if v != v else number(v * scale, 3)


def ladder_section(data, Table, titles: dict | None = None) -> dict | None:
    """``{"scenes": [{"case", "title", "sentences", "table"}], "tables": [...]}`` of the report, or
    None when the sweep has no path or trajectory case; ``titles``: case id -> the case in words
    (:func:`~.wording.case_titles`; default: the id)."""
    table = ladder_table(data.units, data.points)
    if table.empty:
        return None
    scenes, tables = [], []
    for i, (case, grp) in enumerate(table.groupby("case", sort=False)):
        scale, axis = _axis(grp.iloc[0])
        rows = [[r["rung"], r["label"], percent(r["max_error"]), percent(r["final_error"]),
                 _x(r["within_1pct_to"], scale), _x(r["first_above_1pct"], scale), _x(r["within_5pct_to"], scale),
                 _x(r["first_above_5pct"], scale), seconds(r["haptic_p99_s"])]
                for _, r in grp.iterrows() if r["rung"] != "none"]
        x_name = axis or str(grp["x_name"].iloc[0]).replace("_", " ")
        t = Table(f"ladder_{i:02d}_{_file_part(case)}",
                  ["rung", "unit", "max error", "error at the end", f"within 1 % up to ({x_name})",
                   "first above 1 %", "within 5 % up to", "first above 5 %", "haptic p99"], rows,
                  grp.reset_index(drop=True))
        notes = [n for n in grp["note"].dropna() if n]
        scenes.append({"case": case, "title": (titles or {}).get(case, case),
                       "sentences": ladder_statements(table, case) or notes,
                       "table": t if rows else None})
        if rows:  # every CSV beside the page is linked from it
            tables.append(t)
    return {"scenes": scenes, "tables": tables}


def _unit_text(r) -> str:
    return (f"{r['label']} (error {percent(r['error'])}, p99 {seconds(r['p99_s'])} = {hz(r['rate_hz'])}, "
            f"speed-up {number(r['speedup'], 3)}x on the median)")


def versus_baselines(ranked) -> str | None:
    """One sentence for a case's recommendation: does a ROM beat the best practitioner baseline
    (``linear_fe``, ``corotational_fe``, ``coarse_fe``) for the requirement? ``ranked`` is the
    case's :func:`~tissuebench.reports.recommend.rank_units` table; "beats" = meets the
    requirement with a larger margin (the smallest headroom of its clauses). None without
    baselines or without ROMs among the units."""
    ranked = ranked[ranked["measurable"]]
    is_base = ranked["method"].isin(RUNG_METHODS)
    base, roms = ranked[is_base], ranked[~is_base]
    if base.empty or roms.empty:
        return None
    b, r = base.iloc[0], roms.iloc[0]  # ranked: meeting units first, then by margin
    if r["meets"] and (not b["meets"] or r["margin"] > b["margin"]):
        tail = (f"the best practitioner baseline {_unit_text(b)} " +
                (f"meets it with less margin ({b['margin']:.3g}x against {r['margin']:.3g}x)." if b["meets"]
                 else f"misses it: {b['misses']}."))
        return f"A ROM beats every practitioner baseline here: {_unit_text(r)}; {tail}"
    if b["meets"]:
        return (f"No ROM beats the practitioner baseline {_unit_text(b)}, margin {b['margin']:.3g}x; the best ROM "
                + (f"{_unit_text(r)} meets it with margin {r['margin']:.3g}x." if r["meets"]
                   else f"{_unit_text(r)} misses it: {r['misses']}."))
    return (f"Neither a ROM nor a practitioner baseline meets it: closest ROM {_unit_text(r)} misses it by "
            f"{r['misses']}; closest baseline {_unit_text(b)} by {b['misses']}.")
