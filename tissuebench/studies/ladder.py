"""The fidelity ladder: how much physics a scene requires, read off the sweep's cheaper full models.

"Model only what a scene requires", measured. For every static-path and trajectory case of a
sweep, each *rung* is one cheaper physics measured against the full reference along the load
path (or in time): ``linear`` (``linear_fe``: small-strain linear elasticity on the scene's
mesh), ``corotational`` (``corotational_fe``: large rotations, small strains), and the full,
linear or corotational model on a c x coarser mesh (``coarse_fe``). The rungs are the
practitioner-baseline units of the sweep (:mod:`tissuebench.rom.fe_baselines`; every shipped
preset carries them on its path and trajectory cases): their relative l2 error at every
evaluation point (the store's ``_points``) gives, per rung,

* ``within_1pct_to`` / ``within_5pct_to``: the largest load factor (time) up to which every
  error is within 1 % / 5 % (0 when the first point exceeds it);
* ``first_above_1pct`` / ``first_above_5pct``: the first load factor (time) at which the error
  exceeds 1 % / 5 % (NaN: never on this path);
* ``max_error``, ``final_error`` (at the last point with a reference), ``rmse`` (the unit's
  relative RMSE over the evaluation), ``x_end``.

:func:`ladder_statements` turns a case's rungs into what the scene requires ("linear elasticity
is within 1 % up to 0.52 N; beyond, geometric nonlinearity is required ...; a 2x coarser mesh
costs 24 %"), the report's "Fidelity ladder" section, in the scene's units where the sweep
measured them (``x_scale``, ``x_unit`` of the units: the recommendation's "valid to" speaks
in them too), else in load factors.
:func:`~tissuebench.studies.sweep.write_derived` writes :func:`ladder_table` to
``_derived/ladder.parquet``; its figures (``ladder_<case>.png``: each rung's error along the
path with the 1 % and 5 % lines) are the reports layer's (:mod:`tissuebench.reports.ladder`).
A path or trajectory case without any rung
gets one row ``rung = "none"`` saying so.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd

from .metrics import validity_radius

__all__ = ["RUNG_METHODS", "LADDER_COLUMNS", "rung_of", "ladder_table", "ladder_statements", "in_units"]

RUNG_METHODS = ("linear_fe", "corotational_fe", "coarse_fe")
LADDER_COLUMNS = ["case", "case_name", "variant", "resolution", "x_name", "x_scale", "x_unit", "rung", "physics",
                  "coarsening",
                  "achieved_coarsening", "method", "label", "unit_key", "n_points", "max_error", "final_error", "rmse",
                  "x_end", "within_1pct_to", "first_above_1pct", "within_5pct_to", "first_above_5pct",
                  "haptic_median_s", "haptic_p99_s", "note"]
_LADDER_X = ("load_factor", "time")  # the abscissae of static paths and trajectories


def rung_of(method: str, options) -> tuple[str, str, float]:
    """``(rung, physics, coarsening)`` of a baseline unit, e.g. ``("full, 2x coarser mesh", "full", 2.0)``."""
    opts = json.loads(options) if isinstance(options, str) else dict(options or {})
    if method == "linear_fe":
        return "linear", "linear", 1.0
    if method == "corotational_fe":
        return "corotational", "corotational", 1.0
    if method == "coarse_fe":
        c, physics = float(opts.get("coarsening", 2.0)), opts.get("model", "full")
        return f"{physics}, {c:g}x coarser mesh", physics, c
    raise ValueError(f"rung_of: {method!r} is not a ladder method; valid: {list(RUNG_METHODS)}")


def _first_above(x, e, tol) -> float:
    above = x[e > tol]
    return float(above.min()) if above.size else float("nan")


def _achieved(model_info) -> float:
    try:
        return float(json.loads(model_info).get("achieved_ratio", np.nan))
    except (TypeError, ValueError, AttributeError):
        return float("nan")


def _rung_row(u, pts) -> dict:
    rung, physics, c = rung_of(u["method"], u["options"])
    pts = pts[pts["has_reference"] & (pts["status"] != "initial")]
    x, e = pts["x"].to_numpy(float), pts["rel_l2"].to_numpy(float)
    order = np.argsort(x, kind="stable")
    x, e = x[order], e[order]
    row = {"rung": rung, "physics": physics, "coarsening": c, "method": u["method"], "label": u["label"],
           "unit_key": u["unit_key"], "n_points": int(len(x)), "rmse": float(u.get("rmse_rel", np.nan)),
           "achieved_coarsening": 1.0 if c == 1.0 else _achieved(u.get("model_info")),
           "haptic_median_s": float(u.get("haptic_median_s", np.nan)), "haptic_p99_s": float(u.get("haptic_p99_s",
                                                                                                  np.nan)), "note": ""}
    if not len(x):
        return {**row, "note": "no evaluation point with a reference"}
    row.update(max_error=float(np.max(e)), final_error=float(e[-1]), x_end=float(x[-1]))
    for tol, name in ((0.01, "1pct"), (0.05, "5pct")):
        row[f"within_{name}_to"] = validity_radius(x, e, tol)
        row[f"first_above_{name}"] = _first_above(x, e, tol)
    return row


def ladder_table(units: pd.DataFrame, points: pd.DataFrame) -> pd.DataFrame:
    """One row per (path or trajectory case, rung) of the sweep (module docstring); a rung measured by
    several units (linear_fe condensed or not) keeps the one with the shortest haptic p99."""
    rows = []
    if units.empty:
        return pd.DataFrame(columns=LADDER_COLUMNS)
    for case, group in units.groupby("case", sort=False):
        x_name = group["x_name"].dropna()
        x_name = x_name.iloc[0] if len(x_name) else ""
        case_pts = points[points["unit_key"].isin(group["unit_key"])] if len(points) else points
        if "beyond" in case_pts:  # along the path only: past it (the continued reference) is the validity radius's
            case_pts = case_pts[~case_pts["beyond"].fillna(False).astype(bool)]
        grouped = len(case_pts) and case_pts["group"].notna().any()  # positions, contact nodes: not one path
        if x_name not in _LADDER_X or grouped:
            continue
        head = {"case": case, "case_name": group["case_name"].iloc[0], "variant": group["variant"].iloc[0],
                "resolution": group["resolution"].iloc[0], "x_name": x_name, **_measure(group)}
        ok = group[(group["method"].isin(RUNG_METHODS)) & (group["unit_status"] == "ok")]
        case_rows = [{**head, **_rung_row(u, case_pts[case_pts["unit_key"] == u["unit_key"]])}
                     for _, u in ok.iterrows()]
        if not case_rows:
            rows.append({**head, "rung": "none", "note": "no practitioner-baseline unit (linear_fe, corotational_fe, "
                                                         "coarse_fe) finished on this case"})
            continue
        best = pd.DataFrame(case_rows).sort_values(["coarsening", "physics", "haptic_p99_s"], kind="stable")
        rows += best.drop_duplicates("rung").to_dict("records")
    return pd.DataFrame(rows, columns=LADDER_COLUMNS)


def _measure(group) -> dict:
    """``x_scale``, ``x_unit`` of a case's units: what abscissa 1 is in the scene's units (load
    factor 1: the net force in N ...; :func:`~.evaluation.load_measure`), NaN and "" when unknown."""
    scale = pd.to_numeric(group["x_scale"], errors="coerce").dropna() if "x_scale" in group else pd.Series([])
    unit = group["x_unit"].dropna() if "x_unit" in group else pd.Series([])
    unit = unit[unit.astype(str) != ""]
    return {"x_scale": float(scale.iloc[0]) if len(scale) else np.nan,
            "x_unit": str(unit.iloc[0]) if len(unit) and len(scale) else ""}


def in_units(x_name: str, x: float, scale=np.nan, unit="") -> str:
    """An abscissa as the scene measures it: ``"0.52 N"`` (``x * scale`` in ``unit``), else
    ``"load factor 0.26"`` (``"time 0.5 s"``) without a unit."""
    if isinstance(unit, str) and unit and np.isfinite(scale):
        return f"{x * scale:.3g} {unit}"
    return f"{x_name.replace('_', ' ')} {x:.3g}" + (" s" if x_name == "time" else "")


def _at(rung, x) -> str:
    return in_units(rung["x_name"], x, rung.get("x_scale", np.nan), rung.get("x_unit", ""))


def _pct(e) -> str:
    return "a failed step" if e == math.inf else f"{100 * e:.3g} %"


def _span(x_name) -> str:
    return "run" if x_name == "time" else "path"


def _first(rung) -> str:
    """How far a rung is within 1 % (None when it never exceeds it)."""
    if np.isnan(rung["first_above_1pct"]):
        return None
    if rung["within_1pct_to"] > 0:
        return f"up to {_at(rung, rung['within_1pct_to'])}"
    # the table keeps the max, not the first point's error: name the point only (the max follows)
    return f"not even at the first point ({_at(rung, rung['first_above_1pct'])})"


def ladder_statements(table: pd.DataFrame, case: str) -> list[str]:
    """What the scene requires, in sentences, from its rungs (module docstring); ``[]`` without rungs."""
    rungs = table[(table["case"] == case) & (table["rung"] != "none")]
    if rungs.empty:
        return []
    by = {r["rung"]: r for _, r in rungs.iterrows()}
    span, out = _span(rungs["x_name"].iloc[0]), []
    lin, cor = by.get("linear"), by.get("corotational")
    if lin is not None:
        reach = _first(lin)
        if reach is None:
            out.append(f"Linear elasticity is within 1 % over the whole {span} (max {_pct(lin['max_error'])}): the "
                       "scene requires no nonlinearity.")
        else:
            five = ("" if np.isnan(lin["first_above_5pct"]) else
                    f", within 5 % up to {_at(lin, lin['within_5pct_to'])}")
            out.append(f"Linear elasticity is within 1 % {reach}{five} (max {_pct(lin['max_error'])} over the {span}).")
    if cor is not None and (lin is None or _first(lin) is not None):
        reach = _first(cor)
        lead = "Beyond, geometric nonlinearity is required: " if lin is not None else ""
        if reach is None:
            out.append(f"{lead}corotational FE (large rotations, small strains) is within 1 % over the whole {span} "
                       f"(max {_pct(cor['max_error'])}): the material's large-strain response is not needed.")
        else:
            out.append(f"{lead}corotational FE (large rotations, small strains) is within 1 % {reach} "
                       f"(max {_pct(cor['max_error'])}); past that the full large-strain material is required.")
    for _, r in rungs[rungs["coarsening"] > 1].sort_values(["coarsening", "physics"]).iterrows():
        got = r["achieved_coarsening"]
        achieved = f", element sizes {got:.2g}x" if np.isfinite(got) and abs(got / r["coarsening"] - 1) > 0.1 else ""
        if span == "run":  # in time a pointwise error is large where the reference passes near rest
            cost = (f"{_pct(r['rmse'])} (relative RMSE over the run; pointwise up to {_pct(r['max_error'])})"
                    if np.isfinite(r["rmse"]) else f"{_pct(r['max_error'])} (max over the run)")
        else:
            cost = f"{_pct(r['max_error'])} (max over the {span}; {_pct(r['final_error'])} at its end)"
        out.append(f"A {r['coarsening']:g}x coarser mesh{achieved} ({r['physics']} model) costs {cost}.")
    return out
