"""The report's sections as plain data for the template: tables (header, rows of cells, the CSV
they are written to), texts and figures. Cells are plain strings (escaped by the template)
or ``{"text", "cls"}`` for a styled cell (pass / fail)."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd

from ..cases import load
from ..reference.backend_comparison import RTOL
from .extremes import ENERGY_DRIFT_TOL
from .format import hz, nbytes, number, percent, seconds
from ..studies.metrics import claimed_mask
from ..studies.timing import TAIL_SAMPLES
from .recommend import best_per_clause, rank_units

__all__ = ["Table", "scene_of", "scene_info", "recommendation", "one_line", "p99_samples", "ranking_table",
           "errors_text", "state_relative_text", "load_text", "clause_lines",
           "extremes_table_view", "offline_table", "radius_table", "paper_table", "anchors_table", "backends_table",
           "convergence_table",
           "provenance_rows", "calibration", "plugin_methods"]


def Table(name: str, columns: list, rows: list, data: pd.DataFrame) -> dict:
    """A table for the template; ``data`` (the unformatted values) is written to ``<name>.csv``."""
    return {"name": name, "columns": columns, "rows": rows, "data": data, "csv": f"{name}.csv"}


def scene_of(units: pd.DataFrame):
    """``(scene, error text)`` of the first unit's catalogue case, variant and resolution."""
    u = units.iloc[0]
    try:
        return load(u["case_name"], resolution=u["resolution"] or "ci", variant=u["variant"] or None), ""
    except Exception as exc:  # a moved scene file must not stop the report: said in the section
        return None, f"scene {u['case_name']!r} could not be loaded: {exc}"


def scene_info(scene) -> dict:
    """The scene's own extremes for the extremes table: Poisson ratio (or bulk modulus)."""
    if scene is None or not scene.material:
        return {}
    m = scene.material
    return {"material": m.get("name", ""), "nu": m.get("nu", np.nan), "kappa": m.get("kappa", np.nan)}


def recommendation(units: pd.DataFrame, requirement, error_metric: str, points: pd.DataFrame | None = None) -> dict:
    """The ranked units and the sentence(s) of the recommendation for one case: each unit that
    meets it with its errors side by side (:func:`errors_text`) and where its state-relative error
    exceeds the requirement (:func:`state_relative_text`, from the point rows ``points``); when
    none does, the closest, the best unit per clause among those that meet the others
    (:func:`clause_lines`) and the machine's load while they were timed (:func:`load_text`)."""
    ranked = rank_units(units, requirement, error_metric)
    meets = ranked[ranked["meets"]]
    error_clause = next((c for c in requirement.clauses if c.quantity == "error"), None)
    items = [f"{r.label}: p99 {seconds(r.p99_s)} ({hz(r.rate_hz)}; {p99_samples(r)}), median "
             f"{seconds(r.haptic_median_s)}, "
             f"{errors_text(r, error_metric)}, margin {r.margin:.3g}x" + _seen_note(r)
             + (f"; {v}" if (v := validity_text(r)) else "")
             + (f"; {w}" if error_clause and (w := state_relative_text(r, points, error_clause.value)) else "")
             for r in meets.itertuples()]
    measurable = ranked[ranked["measurable"]]
    if len(meets):
        verdict = f"{len(meets)} of {len(ranked)} units meet it, ranked by margin (the smallest headroom of the " \
                  f"clauses):"
    elif len(measurable):
        c = measurable.iloc[0]
        idle = "" if c["closeness"] == c["margin"] else (
            f" as timed; {c['closeness']:.3g}x with its latency scaled by the machine's load factor "
            f"{c['load_factor']:.3g}")
        verdict = " ".join(filter(None, [
            f"None meets it. Closest: {c['label']} (margin {c['margin']:.3g}x{idle}): {c['misses']}.",
            clause_lines(ranked, requirement), load_text(measurable)]))
    else:
        verdict = "None meets it: no finished unit has a finite error and latency" + (
            " that was measured away from its training data." if ranked["seen"].any() else ".")
    seen = ranked[ranked["seen"]]
    excluded = "" if seen.empty else (
        f"Not considered: {len(seen)} unit(s) evaluated only on their training data (seen; shown greyed in the "
        f"table): {', '.join(seen['label'].head(6))}" + (" ..." if len(seen) > 6 else "") + ".")
    return {"verdict": verdict, "lines": items, "meets": len(meets), "ranked": ranked, "excluded": excluded}


#: what a clause's best unit is, by the clause's quantity (:func:`clause_lines`)
_BEST_WORDS = {"error": "the most accurate", "rate": "the fastest", "latency": "the fastest"}


def clause_lines(ranked: pd.DataFrame, requirement) -> str:
    """``"Per clause, among the units that meet the others: error<=5%: the most accurate with
    rate>=1kHz is A: error 6 % is 1.2x over 5 %; rate>=1kHz: the fastest with error<=5% is B:
    rate 400 Hz (p99 2.5 ms) is 2.5x short of 1 kHz."``
    (:func:`~.recommend.best_per_clause`); "" for a requirement of one clause."""
    parts = []
    for clause, others, best in best_per_clause(ranked, requirement):
        with_others = " and ".join(d.text for d in others)
        if best is None:
            parts.append(f"{clause.text}: no unit meets {with_others}")
        else:
            parts.append(f"{clause.text}: {_BEST_WORDS[clause.quantity]} with {with_others} is {best['label']}: "
                         + (best["misses"] or "it meets this clause too"))
    return ("Per clause, among the units that meet the others: " + "; ".join(parts) + ".") if parts else ""


def load_text(units: pd.DataFrame) -> str:
    """The machine's load while ``units`` (rows of :func:`~.recommend.rank_units`) were timed, in
    words: the range of the 1-minute load average over the CPUs, and how many units ran on a
    loaded machine (more runnable tasks than CPUs: their latency is slowed by the load, and the
    closest is named with it scaled); that it was not recorded, in a store written before it."""
    factor = units["load_factor"].astype(float) if "load_factor" in units else pd.Series(dtype=float)
    known = units[np.isfinite(factor)] if len(factor) else units.iloc[:0]
    if known.empty:
        return ("The machine's load while the units were timed was not recorded (a store written before issue 52): "
                "a latency miss may be the machine's, not the method's.")
    loads, cpus = known["load_average"].astype(float), sorted({int(c) for c in known["n_cpus"]})
    span = number(loads.min(), 3) if loads.min() == loads.max() else f"{number(loads.min(), 3)} to " \
                                                                        f"{number(loads.max(), 3)}"
    text = (f"Timed at a 1-minute load average of {span} on {' or '.join(str(c) for c in cpus)} CPU"
            f"{'s' if cpus != [1] else ''}")
    loaded = int((known["load_factor"].astype(float) > 1.0).sum())
    if not loaded:
        return text + ": not loaded (no more runnable tasks than CPUs)."
    return (text + f": {loaded} of {len(known)} unit(s) on a loaded machine (more runnable tasks than CPUs), whose "
            "steps waited for a CPU: their latency misses are scaled by load / CPUs when naming the closest.")


def errors_text(r, error_metric: str) -> str:
    """``"error 0.34 % (claimed_error), state-relative worst 5.1 % (max_rel_l2), absolute 0.012 mm
    (max_abs_error)"``: a unit's error by the sweep's metric, then the headline, the state-relative
    worst and the absolute error where they are other columns and known (issue 52)."""
    text = f"error {percent(r.error)} ({error_metric})"
    unit = getattr(r, "length_unit", "") or ""
    extra = []
    for col, words, fmt in (("claimed_error", "headline", percent), ("max_rel_l2", "state-relative worst", percent),
                            ("max_abs_error", "absolute", lambda v: f"{number(v, 3)} {unit}".rstrip())):
        v = getattr(r, col, np.nan)
        if col != error_metric and isinstance(v, (int, float)) and np.isfinite(v):
            extra.append(f"{words} {fmt(v)} ({col})")
    return ", ".join([text] + extra)


def state_relative_text(r, points: pd.DataFrame | None, tol: float) -> str:
    """Where a unit's state-relative error (``rel_l2``) exceeds ``tol`` over its claimed range
    (:func:`~tissuebench.studies.metrics.claimed_mask` of its ``validity_range``), from its point
    rows: ``"state-relative error above 5 % at 3 of 24 points, all at or below 0.04 N, where the
    absolute error is at most 0.018 mm"`` (the abscissa in the scene's units, ``x_scale`` ``x_unit``;
    else as ``x_name``); "" where it never does, or without point rows."""
    if points is None or not len(points) or "unit_key" not in points:
        return ""
    pts = points[points["unit_key"] == r.unit_key]
    pts = pts[claimed_mask(pts, getattr(r, "validity_range", "") or "") & pts["has_reference"].astype(bool)
              & (pts["status"] != "initial")]
    over = pts[pts["rel_l2"].astype(float) > tol]
    if over.empty:
        return ""
    x = float(over["x"].max())
    scale, unit = getattr(r, "x_scale", np.nan), getattr(r, "x_unit", "")
    where = f"{number(x * scale, 3)} {unit}" if isinstance(unit, str) and unit and np.isfinite(scale) else \
        f"{getattr(r, 'x_name', 'x') or 'x'} {number(x, 3)}"
    text = f"state-relative error above {percent(tol)} at {len(over)} of {len(pts)} points, all at or below {where}"
    worst = float(over["abs_error"].max()) if "abs_error" in over else np.nan
    if np.isfinite(worst):
        text += f", where the absolute error is at most {number(worst, 3)} {getattr(r, 'length_unit', '') or ''}"
    return text.rstrip()


def one_line(rec: dict) -> str:
    """A case's recommendation (:func:`recommendation`) in one line: the unit that meets the
    requirement with the largest margin, or the verdict naming the closest and what it misses by."""
    if rec["meets"]:
        return f"{rec['meets']} of {len(rec['ranked'])} units meet it; recommended: {rec['lines'][0]}"
    return rec["verdict"]


def p99_samples(r) -> str:
    """``"2000 steps, 20 beyond the p99"``: the samples a unit's p99 rests on (``p99_n``,
    ``p99_tail`` of :func:`~.recommend.rank_units`), with a warning when fewer than
    :data:`~tissuebench.studies.timing.TAIL_SAMPLES` decide it; ``"-"`` when unknown."""
    n, tail = getattr(r, "p99_n", np.nan), getattr(r, "p99_tail", np.nan)
    if not np.isfinite(n):
        return "-"
    text = f"{int(n)} steps, {int(tail)} beyond the p99"
    return text + (f": it rests on fewer than {TAIL_SAMPLES}" if tail < TAIL_SAMPLES else "")


def _seen_note(r) -> str:
    """The share of a unit's evaluation points it was trained on, when there is one."""
    n_seen, n = getattr(r, "n_seen", 0), getattr(r, "n_reference_points", 0)
    return f" ({int(n_seen)} of {int(n)} evaluation points seen in training)" if n_seen and n_seen > 0 else ""


def ranking_table(name: str, ranked: pd.DataFrame) -> dict:
    # floor_s / efficiency: the step's arithmetic floor timed beside it (NaN in a store written before them);
    # the state-relative worst, the absolute error and the machine's load (issue 52) likewise
    def col(c, default=np.nan):
        return ranked[c] if c in ranked else pd.Series(default, index=ranked.index)

    floor, eff, n_seen, n_ref = col("floor_s"), col("efficiency"), col("n_seen", 0), col("n_reference_points", 0)
    floor_tail = col("floor_p99_s") / floor.where(floor > 0)
    state, absolute, unit = col("max_rel_l2"), col("max_abs_error"), col("length_unit", "")
    load, cpus = col("load_average"), col("n_cpus", -1)
    rows = []
    for r, f, ft, e, k, n, sr, a, lu, la, nc in zip(ranked.itertuples(), floor, floor_tail, eff, n_seen, n_ref,
                                                   state, absolute, unit, load, cpus):
        meets = {"text": "seen", "cls": "seen"} if r.seen else \
            {"text": "meets" if r.meets else "no", "cls": "pass" if r.meets else "fail"}
        cells = [r.label, meets, number(r.margin, 3), seconds(r.p99_s), p99_samples(r), hz(r.rate_hz),
                 seconds(r.haptic_median_s), number(r.p99_s / r.haptic_median_s, 3) if r.haptic_median_s > 0 else "-",
                 number(ft, 3) if np.isfinite(ft) else "-", seconds(f), number(e, 2), percent(r.error), percent(sr),
                 f"{number(a, 3)} {lu or ''}".rstrip() if np.isfinite(a) else "-",
                 f"{number(la, 3)} / {int(nc)}" if np.isfinite(la) and nc > 0 else "-",
                 f"{int(k)} / {int(n)}" if k >= 0 and n >= 0 else "", r.misses]
        # a unit evaluated on its training data: greyed, with the reason (recommend.SEEN_REASON)
        rows.append([c if isinstance(c, dict) else {"text": c, "cls": "seen"} for c in cells] if r.seen else cells)
    cols = ["unit", "meets", "margin", "haptic p99", "timed steps behind the p99", "rate on p99", "haptic median",
            "p99 / median (the tail: a frame missed at the p99, not the median)",
            "the machine's tail: the floor's p99 / median, same run", "arithmetic floor",
            "efficiency (floor / median)", "error", "state-relative worst (max_rel_l2)",
            "absolute error (max_abs_error)", "load average / CPUs while timed", "points seen in training",
            "misses by"]
    keep = ["case", "label", "options", "unit_key", "meets", "seen", "margin", "closeness", "p99_s", "p99_n",
            "p99_tail", "rate_hz", "haptic_median_s",
            "error", "misses"] + [c for c in ranked.columns if c.startswith("headroom_")]
    tail = ranked["p99_s"] / ranked["haptic_median_s"].where(ranked["haptic_median_s"] > 0)
    data = ranked[keep].assign(p99_over_median=tail, floor_p99_over_median=floor_tail, floor_s=floor, efficiency=eff,
                               n_seen=n_seen,
                               max_rel_l2=state, max_abs_error=absolute, load_average=load, n_cpus=cpus)
    return Table(name, cols, rows, data)


def extremes_table_view(name: str, ext: pd.DataFrame) -> dict:
    rows = []
    for r in ext.itertuples():
        rows.append([r.label, {"text": r.verdict, "cls": r.verdict}, r.unit_status,
                     " / ".join(_count(v) for v in (r.n_ok, r.n_extrapolation, r.n_beyond_validity, r.n_failed,
                                                    r.n_not_reached)),
                     f"{r.n_without_reference}: {r.statuses_without_reference}" if r.n_without_reference else "0",
                     f"{number(r.x_max_reference)} / {number(r.x_max_evaluated)}", str(r.failed_with_reference),
                     _drift(r), number(getattr(r, "nu", np.nan)), r.reasons])
    cols = ["unit", "verdict", "unit status", "steps ok / extrapolation / beyond validity / failed / not reached",
            "points past the path or without reference: statuses", "largest x with reference / evaluated",
            "failed steps where a reference exists",
            f"long-run energy drift: model / reference (fail above +{ENERGY_DRIFT_TOL:g})",
            "scene nu", "why it fails"]
    return Table(name, cols, rows, ext)


def _drift(r) -> str:
    if np.isnan(r.energy_drift) and np.isnan(r.reference_energy_drift):
        return r.energy_message or "-"
    return f"{number(r.energy_drift, 3)} / {number(r.reference_energy_drift, 3)}"


def _count(v) -> str:
    return "-" if v is None or v < 0 else str(int(v))  # -1: the schema's missing value (a failed unit)


def offline_table(name: str, units: pd.DataFrame) -> dict:
    rows = [[r.label, seconds(r.offline_s), nbytes(r.build_peak_bytes), nbytes(r.model_bytes), _count(r.n_reduced),
             _count(r.n_training_snapshots), seconds(r.reconstruct_median_s), seconds(r.reconstruct_p99_s),
             number(r.haptic_per_calibration, 3)] for r in units.itertuples()]
    cols = ["unit", "offline (build)", "build peak memory", "online model size", "reduced size", "training snapshots",
            "reconstruct median", "reconstruct p99", "haptic median / calibration kernel"]
    keep = ["case", "label", "unit_key", "offline_s", "build_peak_bytes", "model_bytes", "n_reduced",
            "n_training_snapshots", "reconstruct_median_s", "reconstruct_p99_s", "haptic_per_calibration"]
    return Table(name, cols, rows, units[keep])


def validity_text(r) -> str:
    """``valid to 1.2 N at 1 % / 2.3 N at 5 % (training range)``: the validity radii in the scene's
    units (the abscissa times ``x_scale`` ``x_unit``: load factor 1 is the scene's net force ...) and
    what they read (``validity_range``: the training range only, or extrapolation asked; the
    peak-normalised error, or the state-relative one in a store without ``claimed_error``), ""
    where unknown."""
    scale, unit = getattr(r, "x_scale", np.nan), getattr(r, "x_unit", "")
    if not isinstance(unit, str) or not unit or not np.isfinite(scale) or getattr(r, "unit_status", "ok") != "ok":
        return ""
    radii = [(v, p) for v, p in ((r.validity_1pct, 1), (r.validity_5pct, 5)) if np.isfinite(v)]
    valid = [f"{number(v * scale)} {unit} at {p} %" for v, p in radii if v > 0]
    over = [f"{p} %" for v, p in radii if v <= 0]
    text = "; ".join((["valid to " + " / ".join(valid)] if valid else [])
                     + ([f"over {' and '.join(over)} from the first point"] if over else []))
    within = getattr(r, "validity_range", "")
    if text and within in RANGE_WORDS:
        text += f" ({RANGE_WORDS[within]})"
    headline = getattr(r, "claimed_error", np.nan)
    if text and not (isinstance(headline, (int, float)) and np.isfinite(headline)):
        text += f" ({STATE_RELATIVE_RADII})"
    limit = getattr(r, "reference_limit", np.nan)
    if text and within != "training" and np.isfinite(limit) and max(r.validity_1pct, r.validity_5pct) >= limit * (
            1 - 1e-9):
        text += f" (the reference itself stops converging at {number(limit * scale)} {unit})"
    return text


#: what the validity radii of a unit without a headline error read (a store written before issue 52)
STATE_RELATIVE_RADII = "state-relative error: the store has no peak-normalised error of this unit (written before " \
                       "issue 52)"

#: what a unit's validity radius reads (its ``validity_range``, :func:`~tissuebench.studies.metrics.claimed_range`)
RANGE_WORDS = {"training": "training range only: the steps past it are extrapolation, not counted; "
                           "evaluation.extrapolation = true counts them",
               "extrapolation": "extrapolation asked: the steps past the training range are counted"}


def radius_table(name: str, units: pd.DataFrame) -> dict:
    units = units.assign(**{c: units[c] if c in units else np.nan for c in ("x_scale", "reference_limit",
                                                                          "claimed_error")},
                         **{c: units[c] if c in units else "" for c in ("x_unit", "validity_range")})
    rows = [[r.label, number(r.validity_1pct) if r.unit_status == "ok" else "-",
             number(r.validity_5pct) if r.unit_status == "ok" else "-", r.x_name, _radius_reads(r), validity_text(r)]
            for r in units.itertuples()]
    return Table(name, ["unit", "validity radius, error <= 1 %", "validity radius, error <= 5 %", "abscissa",
                        "the error it reads", "in the scene's units"],
                 rows, units[["case", "label", "unit_key", "x_name", "validity_1pct", "validity_5pct", "x_scale",
                              "x_unit", "reference_limit", "validity_range", "claimed_error"]])


def _radius_reads(r) -> str:
    """What a unit's validity radii read: the peak-normalised error of its claimed range, or (a
    unit without ``claimed_error``: a store written before issue 52) the state-relative one."""
    if r.unit_status != "ok":
        return "-"
    return "peak-normalised (peak_rel)" if np.isfinite(r.claimed_error) else "state-relative (rel_l2: a store " \
                                                                              "written before issue 52)"


def paper_table(name: str, rows: pd.DataFrame) -> dict:
    cells = [[r.section, r.key, r.paper, r.ours, r.how, r.note] for r in rows.itertuples()]
    return Table(name, ["table", "figure", "paper", "ours", "our value is", "why they differ (catalogue note)"],
                 cells, rows)


def anchors_table(name: str, anchors: pd.DataFrame) -> dict:
    rows = [[str(r.case), str(r.quantity), number(r.ours), number(r.anchor), f"[{number(r.low)}, {number(r.high)}]",
             str(r.source), {"text": str(r.verdict), "cls": "pass" if str(r.verdict).lower() in ("pass", "ok")
                             else "fail"}] for r in anchors.itertuples()]
    return Table(name, ["case", "quantity", "ours", "anchor", "spread [low, high]", "source", "verdict"], rows, anchors)


def _monitor_diff(r) -> str:
    values = f"{number(r.monitor_skfem)} / {number(r.monitor_ngsolve)}"
    return f"{r.worst_monitor}: {values} ({number(r.monitor_rel_diff, 2)})"


def backends_table(name: str, agreement: pd.DataFrame) -> dict:
    rows = [[str(r.case), f"{r.scene} {r.variant}".strip(), _count(r.ndof) if np.isfinite(r.ndof) else "-",
             f"{r.skfem_status} / {r.ngsolve_status}" if isinstance(r.skfem_status, str) else "-",
             number(r.field_rel_diff, 2),
             _monitor_diff(r) if isinstance(r.worst_monitor, str) and r.worst_monitor else "-",
             {"text": str(r.verdict), "cls": {"agree": "pass", "n/a": ""}.get(str(r.verdict), "fail")}, str(r.how)]
            for r in agreement.itertuples()]
    cols = ["case", "scene", "dofs", "status skfem / ngsolve", "final field: relative L2 difference",
            "monitor: skfem / ngsolve (largest relative difference)", f"verdict (agree within {RTOL:g})", "how"]
    return Table(name, cols, rows, agreement)


def convergence_table(name: str, conv: pd.DataFrame) -> dict:
    """The reference's h/2 check (``_convergence.parquet``): one row per monitored quantity."""
    def col(r, k, default="-"):
        return getattr(r, k, default)

    rows = [[str(r.case), str(col(r, "formulation")), str(col(r, "formulation_h_half", col(r, "formulation"))),
             str(r.quantity), number(r.h), number(r.h_half),
             number(r.rel_diff, 2), f"{col(r, 'dofs_h')} / {col(r, 'dofs_h_half')}",
             f"{col(r, 'status_h')} / {col(r, 'status_h_half')}"] for r in conv.itertuples()]
    cols = ["case", "formulation at h", "formulation at h/2", "quantity", "at h", "at h/2", "relative difference",
            "dofs h / h/2", "status h / h/2"]
    return Table(name, cols, rows, conv)


def provenance_rows(manifest: dict, units: pd.DataFrame) -> list:
    """``(key, value)`` pairs: the sweep's manifest (spec text apart) and what the unit rows record."""
    out = []
    for k, v in manifest.items():
        if k in ("units", "spec_text"):
            continue
        out.append((k, json.dumps(v, sort_keys=True) if isinstance(v, (dict, list)) else str(v)))
    for col in ("git_commit", "code_hash", "tissuebench", "numpy", "scipy", "python", "machine", "blas",
                "blas_threads"):
        if col in units:
            out.append((f"units: {col}", ", ".join(sorted({str(v) for v in units[col]}))))
    if "date" in units and len(units):
        out.append(("units: dates", f"{units['date'].min()} .. {units['date'].max()}"))
    plugins = plugin_methods(units)
    if plugins:
        out.append(("units: methods from other packages", "; ".join(plugins)))
    return out


def plugin_methods(units: pd.DataFrame) -> list:
    """One line per method from another package in ``units`` and version of it: its distribution,
    version, class path and code hash (the unit rows' ``method_*`` columns)."""
    cols = ["method", "method_source", "method_distribution", "method_version", "method_code_hash"]
    if "method_source" not in units:
        return []
    rows = units[cols].fillna("")
    rows = rows[rows["method_source"] != ""].drop_duplicates()
    return [f"{r.method}: {r.method_distribution or 'no installed distribution'} {r.method_version}".rstrip()
            + f" ({r.method_source}, code {r.method_code_hash[:12] or 'unknown'})"
            for r in rows.sort_values(cols).itertuples()]


def calibration(units: pd.DataFrame) -> dict:
    c = units["calibration_s"].astype(float)
    c = c[np.isfinite(c) & (c > 0)]
    if c.empty:
        return {"median": "-", "range": "-", "n": 0}
    return {"median": seconds(float(c.median())), "range": f"{seconds(float(c.min()))} .. {seconds(float(c.max()))}",
            "n": int(len(c))}
