"""Error metrics of a sweep (docs: errors): per evaluation point, per unit, validity radius, Pareto front.

* relative l2 error of the nodal displacement ``||u_rom - u_ref|| / ||u_ref||`` per point
  (``inf`` for a step that failed where a reference exists: never a silent NaN; NaN only
  where there is no reference to compare with, e.g. loads past the path);
* each monitored scalar the model outputs, relative to the reference's value;
* where the reference of a point is zero (a trajectory at rest before its load starts), the
  error is relative to the largest reference of the evaluation (the field's, or the
  monitor's); where every reference of the evaluation is zero, no relative error exists and
  it is ``inf``: a model matching a zero field is never "0 % error" (issue 37);
* the relative RMSE over a history (the wsc paper's):
  ``sqrt(sum_k ||u_rom,k - u_ref,k||^2 / sum_k ||u_ref,k||^2)``;
* beside it, what a user feels of a motion (issue 42: a relative error over a window of small
  motion makes a harmless phase error look like a failure): the peak-normalised error
  ``max_k ||u_rom,k - u_ref,k|| / max_k ||u_ref,k||`` (``peak_rel_l2``: the worst step's error
  against the largest displacement of the run), and the absolute error in the scene's length
  unit, the largest nodal displacement error ``max_k max_node |u_rom - u_ref|``
  (``max_abs_error``; :data:`ABSOLUTE_ERROR_METRICS`);
* **the claimed (headline) error** of a unit (issue 52): peak-normalised over the range it claims
  (:func:`claimed_range`: along a path the training range, its held-out states, quarter points and
  loads near rest; every point of a motion), ``claimed_error = max_k ||u_rom,k - u_ref,k|| /
  max_k ||u_ref,k||`` over the points of that range with a reference, and per point ``peak_rel =
  ||u_rom,k - u_ref,k|| / max_j ||u_ref,j||`` (the same denominator) beside ``rel_l2`` and the
  point's largest nodal error ``abs_error`` [length unit]. Why not the state-relative error: at the
  near-rest point (1/1024 of the first training state) the displacement is so small that a
  constant offset of the model dominates its relative error (an organ: 5.1 % there, 0.34 %
  peak-normalised), which tells a user nothing they act on; the state-relative worst
  (``max_rel_l2``) and the absolute error stay beside it;
* the validity radius: the largest abscissa (load factor, distance to the nearest stored
  position, time) up to which every peak-normalised error (``peak_rel``) stays within a
  tolerance (1 %, 5 %); along a path, within the training range unless the evaluation asks
  ``extrapolation = true`` (:func:`claimed_range`);
* the Pareto front per scene: units not beaten in both haptic latency and error.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from .timing import max_displacement

__all__ = ["point_rows", "output_rows", "summarise_points", "validity_radius", "pareto_front", "TOLERANCES",
           "seen_points", "SEEN_RTOL", "ABSOLUTE_ERROR_METRICS", "nodal_error", "claimed_range", "claimed_mask",
           "peak_normalise", "FLAGGED"]

TOLERANCES = (0.01, 0.05)
#: the statuses of a step the model itself flags as outside its training envelope
FLAGGED = ("extrapolation", "beyond_validity")
#: a reference field within this relative distance of a training snapshot is the snapshot
SEEN_RTOL = 1e-6
#: the error columns in the scene's length unit (``[units] length``), not relative: the others are
ABSOLUTE_ERROR_METRICS = ("max_abs_error",)


def nodal_error(u, ref) -> float:
    """Largest nodal error magnitude of node-major fields (3 components per node when the size
    allows it, else per dof) [the fields' length unit]."""
    e = np.asarray(u, float) - np.asarray(ref, float)
    return float(np.linalg.norm(e.reshape(-1, 3), axis=1).max() if e.size % 3 == 0 else np.abs(e).max())


def seen_points(evaluation, snapshots) -> list[bool]:
    """Per evaluation point, whether its reference field coincides with a column of the training
    ``snapshots`` (n_dof, n_snap) to :data:`SEEN_RTOL`: the model was trained on the answer (a
    path state learnt from, a trajectory replayed, a stored position). Points without a
    reference, or a zero one, are never seen; nor is anything without snapshots (operators)."""
    out = [False] * len(evaluation.points)
    if snapshots is None or not np.size(snapshots):
        return out
    S = np.asarray(snapshots, float)
    idx = [k for k, p in enumerate(evaluation.points) if p.reference is not None and p.reference.size == S.shape[0]]
    if not idx:
        return out
    s2 = np.einsum("ij,ij->j", S, S)
    for chunk in range(0, len(idx), 256):  # (n_dof, 256) at a time: a long trajectory stays small
        ks = idx[chunk:chunk + 256]
        R = np.column_stack([evaluation.points[k].reference for k in ks])
        r2 = np.einsum("ij,ij->j", R, R)
        d2 = r2[:, None] + s2[None, :] - 2.0 * (R.T @ S)  # squared distances (n_eval, n_snap)
        hit = (d2.min(axis=1) <= (SEEN_RTOL ** 2) * r2) & (r2 > 0)
        for k, h in zip(ks, hit):
            out[k] = bool(h)
    return out


#: the message of a point whose evaluation has nothing but zero references
ZERO_REFERENCE = "every reference field of the evaluation is zero: no relative error (inf)"


def _relative(diff: float, ref: float, scale: float) -> float:
    """``diff / ref``, or ``diff / scale`` where the reference ``ref`` is zero; ``inf`` where the
    evaluation's largest reference ``scale`` is zero too (module docstring)."""
    if ref > 0:
        return diff / ref
    return diff / scale if scale > 0 else np.inf


def _magnitudes(ref) -> tuple[float, float]:
    """(l2 norm, largest nodal displacement) of a reference field."""
    return float(np.linalg.norm(ref)), max_displacement(ref) if ref.size % 3 == 0 else float(np.abs(ref).max())


def point_rows(evaluation, driven, seen=None) -> list[dict]:
    """One row per evaluation point: mu, abscissa, step status, errors (``rel_l2``; the
    peak-normalised ``peak_rel`` and the largest nodal error ``abs_error``: :func:`_peak_rows`),
    ``seen`` (:func:`seen_points`)."""
    rows = []
    seen = seen or [False] * len(evaluation.points)
    refs = [_magnitudes(p.reference) for p in evaluation.points if p.reference is not None and p.reference.size]
    scale_l2, scale_max = np.max(refs, axis=0) if refs else (0.0, 0.0)
    for k, (p, res, u) in enumerate(zip(evaluation.points, driven.results, driven.fields)):
        status = "initial" if res is None and k == 0 and evaluation.kind == "trajectory" else (
            "not_reached" if res is None else res.status)
        ref = p.reference
        if ref is None or status == "initial":
            rel, dmax = np.nan, np.nan
        elif u is None:
            rel, dmax = np.inf, np.inf
        elif not np.all(np.isfinite(u)) or np.abs(u).max() > 1e150:  # a blow-up: its error is inf
            rel, dmax = np.inf, np.inf
        else:
            den, rm = _magnitudes(ref)
            rel = float(_relative(np.linalg.norm(u - ref), den, scale_l2))
            um = max_displacement(u) if u.size % 3 == 0 else float(np.abs(u).max())
            dmax = float(_relative(abs(um - rm), rm, scale_max))
        message = "" if res is None else res.message[:300]
        if ref is not None and status != "initial" and scale_l2 == 0:
            message = "; ".join(filter(None, [message, ZERO_REFERENCE]))
        rows.append({"point": k, "x": p.x, "group": np.nan if p.group is None else p.group,
                     "mu": _mu_text(p.mu), "status": status, "message": message,
                     "rel_l2": rel, "rel_max_displacement": dmax, "has_reference": ref is not None,
                     "seen": bool(seen[k]) and status != "initial", "beyond": bool(getattr(p, "beyond", False))})
    _peak_rows(rows, evaluation, driven.fields)
    return rows


def _peak_rows(rows: list[dict], evaluation, fields) -> None:
    """Add to each row of :func:`point_rows` its largest nodal error ``abs_error`` [length unit]
    and ``peak_rel`` (:func:`peak_normalise`): NaN without a reference or at the initial state,
    inf where the step failed or blew up (no field, a non-finite one, one beyond 1e150)."""
    errors, norms = [], []
    for row, p, u in zip(rows, evaluation.points, fields):
        measured = p.reference is not None and row["status"] != "initial"
        failed = u is None or not np.all(np.isfinite(u)) or np.abs(u).max() > 1e150
        errors.append(np.nan if not measured else np.inf if failed else float(np.linalg.norm(u - p.reference)))
        row["abs_error"] = np.nan if not measured else np.inf if failed else nodal_error(u, p.reference)
        norms.append(float(np.linalg.norm(p.reference)) if measured else 0.0)
    for row, peak in zip(rows, peak_normalise(rows, errors, norms, evaluation)):
        row["peak_rel"] = peak


def peak_normalise(rows: list[dict], errors, norms, evaluation) -> list[float]:
    """Per point, ``errors[k] / R`` with ``R`` the largest of ``norms`` (``||u_ref||``; 0 without
    a reference) over the points of the claimed range (:func:`claimed_range` of ``rows``); NaN
    where ``errors[k]`` is (no reference), ``inf`` where every reference of the range is zero (as
    :func:`_relative`: a model matching a zero field is never "0 % error")."""
    if not rows:
        return []
    claimed, _ = claimed_range(pd.DataFrame(rows), evaluation)
    scale = float(np.max(np.asarray(norms, float)[claimed.to_numpy()], initial=0.0))
    return [float(e) if np.isnan(e) else (e / scale if scale > 0 else np.inf) for e in errors]


def output_rows(evaluation, driven) -> list[dict]:
    """Long form: one row per (point, monitored output the model reports and the reference has)."""
    rows = []
    scale: dict = {}
    for p in evaluation.points:
        for name, r in p.monitors.items():
            scale[name] = max(scale.get(name, 0.0), abs(float(r)))
    for k, (p, out) in enumerate(zip(evaluation.points, driven.outputs)):
        for name, value in out.items():
            if name in p.monitors:
                r = p.monitors[name]
                rows.append({"point": k, "x": p.x, "monitor": name, "reference": r, "rom": float(value),
                             "rel_error": float(_relative(abs(value - r), abs(r), scale[name]))})
    return rows


def _mu_text(mu: dict) -> str:
    return ", ".join(f"{k}={v:.6g}" for k, v in sorted(mu.items()))


def validity_radius(x, errors, tol: float) -> float:
    """Largest abscissa up to which every error (NaN: no reference, ignored) is <= ``tol``;
    0 when the first fails, NaN without any reference."""
    x, e = np.asarray(x, float), np.asarray(errors, float)
    keep = ~np.isnan(e)
    if not keep.any():
        return float("nan")
    x, e = x[keep], e[keep]
    order = np.argsort(x, kind="stable")
    x, e = x[order], e[order]
    bad_x = x[e > tol]
    if bad_x.size == 0:
        return float(x.max())
    ok = x[x < bad_x.min()]
    return float(ok.max()) if ok.size else 0.0


def summarise_points(points: pd.DataFrame, outputs: pd.DataFrame, evaluation, fields) -> dict:
    """The unit-level error columns from its point rows: over the points with a reference, but
    those past the training path (``beyond``), which enter the validity radius only; the claimed
    (headline) error ``claimed_error`` and the validity radii over the claimed range
    (:func:`claimed_range`), from the rows' ``peak_rel``."""
    past = points["beyond"].astype(bool) if "beyond" in points else pd.Series(False, index=points.index)
    has_ref = points["has_reference"] & (points["status"] != "initial") & ~past
    rel = points.loc[has_ref, "rel_l2"].to_numpy(float)
    # inside the envelope: every point the model did not flag as outside it; a step that failed
    # there counts (its rel_l2 is inf), so a unit that fails on its own range is never "accurate"
    inside = ~points.loc[has_ref, "status"].isin(FLAGGED).to_numpy()
    num = den = 0.0
    peak_err = peak_ref = abs_err = 0.0
    for p, u, use in zip(evaluation.points, fields, has_ref.to_numpy()):
        if not use:
            continue
        with np.errstate(over="ignore", invalid="ignore"):  # a blown-up step counts as inf, said once
            failed = u is None or not np.all(np.isfinite(u))
            e2 = np.inf if failed else float(np.sum((u - p.reference) ** 2))
            abs_err = max(abs_err, np.inf if failed else nodal_error(u, p.reference))
        num += e2
        den += float(np.sum(p.reference ** 2))
        peak_err, peak_ref = max(peak_err, np.sqrt(e2)), max(peak_ref, float(np.linalg.norm(p.reference)))
    counts = points["status"].value_counts()
    n_seen = int((points["seen"] & has_ref).sum()) if "seen" in points else 0
    row = {"n_points": int(len(points)), "n_reference_points": int(has_ref.sum()),
           "n_seen": n_seen, "seen": bool(has_ref.sum()) and n_seen == int(has_ref.sum()),
           "n_beyond_reference": int((points["has_reference"] & past).sum()),
           "max_rel_l2": float(rel.max()) if rel.size else np.nan,
           "mean_rel_l2": float(rel.mean()) if rel.size else np.nan,
           "max_rel_l2_in_envelope": float(rel[inside].max()) if inside.any() else np.nan,
           "rmse_rel": float(np.sqrt(num / den)) if den > 0 else (np.inf if has_ref.any() else np.nan),
           "peak_rel_l2": float(peak_err / peak_ref) if peak_ref > 0 else (np.inf if has_ref.any() else np.nan),
           "max_abs_error": float(abs_err) if has_ref.any() else np.nan,
           "max_monitor_rel_error": float(outputs["rel_error"].max()) if len(outputs) else np.nan,
           "x_name": evaluation.x_name}
    for status in ("ok", "extrapolation", "beyond_validity", "failed", "not_reached"):
        row[f"n_{status}"] = int(counts.get(status, 0))
    claimed, row["validity_range"] = claimed_range(points, evaluation)
    for tol in TOLERANCES:
        row[f"validity_{int(round(tol * 100))}pct"] = validity_radius(points.loc[claimed, "x"],
                                                                      points.loc[claimed, _radius_column(points)], tol)
    # the headline: the worst peak-normalised error of the claimed range (peak_rel is NaN where there
    # is nothing to compare with; rows without it, as a store's before issue 52: NaN, radii on rel_l2)
    row["claimed_error"] = float(points.loc[claimed, "peak_rel"].max()) if "peak_rel" in points else np.nan
    return row


def _radius_column(points: pd.DataFrame) -> str:
    """The error the validity radius reads: ``peak_rel``, or ``rel_l2`` in rows without it."""
    return "peak_rel" if "peak_rel" in points else "rel_l2"


def claimed_range(points: pd.DataFrame, evaluation) -> tuple[pd.Series, str]:
    """``(mask of the points the claimed error and the validity radius read, what they are)``. A
    path evaluation (``evaluation.info["extrapolation"]`` set) without ``extrapolation = true``:
    the training range only (``"training"``), neither the points past the path's top (``beyond``)
    nor those the model flags (:data:`FLAGGED`), so "valid to" never reaches past what the unit
    learnt; with it, every point (``"extrapolation"``). Other kinds: every point (``""``: no
    training range along the abscissa: a distance to the stored positions, a time)."""
    asked = (getattr(evaluation, "info", None) or {}).get("extrapolation")
    what = "" if asked is None else ("extrapolation" if asked else "training")
    return claimed_mask(points, what), what


def claimed_mask(points: pd.DataFrame, validity_range: str) -> pd.Series:
    """The claimed range of stored point rows from their unit's ``validity_range`` (what
    :func:`claimed_range` returned): ``"training"``: neither ``beyond`` (a store without the
    column: nothing is) nor a :data:`FLAGGED` status; anything else: every point."""
    if validity_range != "training":
        return pd.Series(True, index=points.index)
    past = points["beyond"].astype(bool) if "beyond" in points else pd.Series(False, index=points.index)
    return ~past & ~points["status"].isin(FLAGGED)


def pareto_front(units: pd.DataFrame, error: str = "max_rel_l2", latency: str = "haptic_median_s") -> pd.DataFrame:
    """``units`` with a boolean ``pareto`` column: per case, not beaten in both latency and error
    by another unit (failed units and units without error or latency are never on the front)."""
    out = units.copy()
    out["pareto"] = False
    for _, grp in out.groupby("case"):
        ok = grp[(grp["unit_status"] == "ok") & np.isfinite(grp[error]) & np.isfinite(grp[latency])]
        e, t = ok[error].to_numpy(), ok[latency].to_numpy()
        for i, idx in enumerate(ok.index):
            dominated = np.any((e <= e[i]) & (t <= t[i]) & ((e < e[i]) | (t < t[i])))
            out.loc[idx, "pareto"] = not dominated
    return out
