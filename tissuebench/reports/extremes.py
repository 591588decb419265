"""The extremes table of a report: how every unit behaves at the edges, with pass/fail.

Per unit (one row), from its row and its evaluation points (``_points``):

* the unit ran (``unit_status == "ok"``), else **fail** with its message;
* extrapolation is flagged: every evaluation point without a reference (loads past the
  reference path, the scene's ``beyond``) has a non-ok status (``extrapolation``,
  ``beyond_validity`` or ``failed``); a point there reported ``ok`` is a **fail**: the model
  claims an answer nobody checked;
* no step failed (or was not reached) where a reference exists, else **fail**;
* the long-run energy drift of a trajectory (the unit's ``energy_drift`` column, measured
  by the harness over the final constant-load window, :mod:`tissuebench.studies.energy`):
  energy **created** beyond
  :data:`ENERGY_DRIFT_TOL` (relative) is a **fail** (an unstable long run); a loss is
  numerical dissipation, reported beside the reference's own drift, not failed.

``n_beyond_validity`` (steps the model itself marks past its validity) is reported, not
failed: saying so is the contract. The scene's own extremes (Poisson ratio, the largest
load factor evaluated, the reference's largest) are columns beside it.
"""
from __future__ import annotations


import numpy as np
import pandas as pd

from .format import number

__all__ = ["ENERGY_DRIFT_TOL", "extremes_table"]

ENERGY_DRIFT_TOL = 0.01
_COUNTS = ["n_points", "n_reference_points", "n_ok", "n_extrapolation", "n_beyond_validity", "n_failed",
           "n_not_reached"]


def _point_checks(pts: pd.DataFrame) -> dict:
    pts = pts[pts["status"] != "initial"]
    # past the training path (evaluation.beyond), with or without the continued reference: flagged, never ok
    past_path = pts["beyond"].astype(bool) if "beyond" in pts else pd.Series(False, index=pts.index)
    ref = pts["has_reference"].astype(bool) & ~past_path
    past = pts[~ref]
    inside = pts[ref]
    x_ref = inside["x"].to_numpy(float)
    x_all = pts["x"].to_numpy(float)
    return {"n_without_reference": int(len(past)),
            "unflagged_without_reference": int((past["status"] == "ok").sum()),
            "failed_with_reference": int(inside["status"].isin(["failed", "not_reached"]).sum()),
            "beyond_validity_with_reference": int((inside["status"] == "beyond_validity").sum()),
            "first_flagged_x": _first(inside, inside["status"] != "ok"),
            "first_failed_x": _first(inside, inside["status"].isin(["failed", "not_reached"])),
            "statuses_without_reference": ", ".join(f"{s} {n}" for s, n in past["status"].value_counts().items()),
            "x_max_reference": float(np.nanmax(x_ref)) if x_ref.size else np.nan,
            "x_max_evaluated": float(np.nanmax(x_all)) if x_all.size else np.nan}


def _first(pts: pd.DataFrame, mask) -> float:
    x = pts.loc[mask, "x"].to_numpy(float)
    return float(np.min(x)) if x.size else np.nan


def _verdict(row: dict) -> tuple[str, str]:
    reasons = []
    if row["unit_status"] != "ok":
        reasons.append(f"unit failed: {row['message']}")
    else:
        if row["unflagged_without_reference"]:
            reasons.append(f"{row['unflagged_without_reference']} of {row['n_without_reference']} points without a "
                           "reference (or past the training path) reported ok (extrapolation not flagged)")
        if row["failed_with_reference"]:
            reasons.append(f"{row['failed_with_reference']} steps failed or not reached where a reference exists "
                           f"(the first at {row['x_name'] or 'x'} = {number(row['first_failed_x'])}, flagged from "
                           f"{number(row['first_flagged_x'])})")
        drift = row["energy_drift"]
        if np.isfinite(drift) and drift > ENERGY_DRIFT_TOL:
            reasons.append(f"energy drift {number(drift, 3)}: energy created beyond +{ENERGY_DRIFT_TOL:g}")
    return ("fail", "; ".join(reasons)) if reasons else ("pass", "")


def extremes_table(units: pd.DataFrame, points: pd.DataFrame, scene_info: dict | None = None) -> pd.DataFrame:
    """One row per unit (module docstring): counts, checks, ``verdict`` (pass | fail), ``reasons``.

    ``scene_info``: ``{case id: {"nu": ..., ...}}`` columns copied onto the case's rows."""
    scene_info = scene_info or {}
    by_unit = dict(tuple(points.groupby("unit_key"))) if len(points) else {}
    rows = []
    for _, u in units.iterrows():
        pts = by_unit.get(u["unit_key"])
        checks = _point_checks(pts) if pts is not None else {
            "n_without_reference": 0, "unflagged_without_reference": 0, "failed_with_reference": 0,
            "beyond_validity_with_reference": 0, "statuses_without_reference": "", "x_max_reference": np.nan,
            "first_flagged_x": np.nan, "first_failed_x": np.nan,
            "x_max_evaluated": np.nan}
        row = {"case": u["case"], "label": u["label"], "unit_key": u["unit_key"], "unit_status": u["unit_status"],
               "message": u.get("message", ""), "x_name": u.get("x_name", ""),
               **{c: int(u[c]) for c in _COUNTS}, **checks,
               "energy_drift": float(u.get("energy_drift", np.nan)),
               "reference_energy_drift": float(u.get("reference_energy_drift", np.nan)),
               "energy_message": u.get("energy_message", "") or "",
               **scene_info.get(u["case"], {})}
        row["verdict"], row["reasons"] = _verdict(row)
        rows.append(row)
    return pd.DataFrame(rows)
