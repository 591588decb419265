"""Cost versus size: how each method's cost grows with the mesh, fitted as ``cost ~ n_dof^p``.

A *scaling group* is one scene on several meshes: the case entries of a sweep spec that carry the
same ``scaling_group = "NAME"`` and differ only in ``mesh`` (the builder parameters, e.g. the
cube's ``divisions``). Every other key of the entry (``name``, ``variant``, ``backend``,
``training``, ``evaluation``, ``mu``) must agree, and no two cases of a group may have the same
mesh at the sweep's resolution: :func:`check_scaling_groups` refuses anything else when the spec
loads, naming ``case[i].scaling_group`` and what differs. A group has at least 2 cases.

:func:`scaling_table` reads a sweep's unit rows and, per group, method setting (method and
options: the same options on every mesh) and quantity (:data:`QUANTITIES`: offline time, model
memory, haptic step median and p99, reconstruction, the sweep's error metric) fits the exponent
``p`` of ``value = c n_dof^p`` by least squares in log-log (:func:`fit_exponent`,
``scipy.stats.linregress``) with its 95 % interval ``p +- t_{0.975, k-2} stderr`` over the ``k``
sizes with a finite positive value. With 2 sizes the line is exact and there is no interval
(NaN, said in ``note``). The full model's own step (``reference_step_s``, the median over the
case's units: each times it in its own process) is a row of its own, ``method = "reference"``.
``n_dof`` is the case's reference field size (the store's ``n_dof``: every unit of a case has
the same).

:func:`~tissuebench.studies.sweep.write_derived` writes the table as ``_derived/scaling.parquet``
(:data:`SCALING_COLUMNS`) when the sweep has a group with cases of at least 2 sizes; the reports
layer draws it (``reports/scaling.py``: ``scaling_<quantity>.png`` and the report's section).
"""
from __future__ import annotations

import json
import math
import re

import numpy as np
import pandas as pd
from scipy import stats

__all__ = ["QUANTITIES", "SCALING_COLUMNS", "REFERENCE", "check_group_name", "check_scaling_groups",
           "fit_exponent", "group_sizes", "scaling_groups", "scaling_points", "scaling_table"]

# unit columns fitted against n_dof ("error" stands for the sweep's error metric column)
QUANTITIES = ("offline_s", "model_bytes", "haptic_median_s", "haptic_p99_s", "reconstruct_median_s", "error")
REFERENCE = "reference"  # the method name of the full model's step row
SCALING_COLUMNS = ["scaling_group", "case_name", "variant", "method", "options", "label", "quantity", "exponent",
                   "ci_low", "ci_high", "stderr", "n_sizes", "n_dof_min", "n_dof_max", "value_at_min",
                   "value_at_max", "cases", "note"]
CONFIDENCE = 0.95
_GROUP = re.compile(r"[A-Za-z0-9_.-]{1,100}")
# the keys of a case entry that make it the same scene (all but its id, mesh and published points)
_SAME_SCENE = ("name", "variant", "backend", "resolution", "training", "evaluation", "mu")


def check_group_name(path: str, value) -> str:
    """A group name: 1 to 100 letters, digits, '_', '.', '-' (it names figure rows and files)."""
    if not isinstance(value, str) or not _GROUP.fullmatch(value):
        raise ValueError(f"{path} = {value!r}: expected a name of 1 to 100 letters, digits, '_', '.', '-' "
                         "(the cases of one scene on several meshes share it)")
    return value


def check_scaling_groups(cases: list) -> None:
    """Refuse a group (module docstring) whose cases are not one scene on distinct meshes, or that
    has a single case; ``cases`` are the checked entries of a spec, in spec order."""
    groups: dict = {}
    for i, c in enumerate(cases):
        if "scaling_group" in c:
            groups.setdefault(c["scaling_group"], []).append(i)
    for name, members in groups.items():
        first = cases[members[0]]
        if len(members) < 2:
            raise ValueError(f"case[{members[0]}].scaling_group = {name!r}: the only case of its group ("
                             f"{first['id']!r}); a scaling group is one scene on at least 2 meshes")
        meshes = {}
        for i in members:
            c = cases[i]
            for key in _SAME_SCENE:
                if c.get(key) != first.get(key):
                    raise ValueError(f"case[{i}].scaling_group = {name!r}: case {c['id']!r} differs from "
                                     f"{first['id']!r} of the same group in {key} ({c.get(key)!r} against "
                                     f"{first.get(key)!r}); the cases of a group differ only in mesh")
            mesh = json.dumps(c.get("mesh", {}).get(c["resolution"], {}), sort_keys=True, default=str)
            if mesh in meshes:
                raise ValueError(f"case[{i}].scaling_group = {name!r}: case {c['id']!r} has the same mesh at "
                                 f"resolution {c['resolution']!r} as {meshes[mesh]!r} ({mesh}); the cases of a "
                                 "group differ in mesh")
            meshes[mesh] = c["id"]


def scaling_groups(cases: list) -> dict:
    """``{case id: group}`` of the case entries (a sweep manifest's ``cases``) that have one."""
    return {c["id"]: c["scaling_group"] for c in cases if isinstance(c, dict) and c.get("scaling_group")}


def fit_exponent(n_dof, values, confidence: float = CONFIDENCE) -> dict:
    """Least-squares fit of ``log(values) = log(c) + p log(n_dof)`` over the finite positive pairs.

    Returns ``{"exponent", "stderr", "ci_low", "ci_high", "n_sizes", "note"}``: ``p`` with its
    ``confidence`` interval ``p +- t_{(1 + confidence) / 2, k - 2} stderr`` (Student t, ``k``
    sizes). ``k = 2``: the exact line through both, no interval (NaN); fewer than 2 distinct
    sizes: ``p`` is NaN. ``note`` says what was left out and why.
    """
    n = np.asarray(n_dof, float)
    y = np.asarray(values, float)
    if n.shape != y.shape or n.ndim != 1:
        raise ValueError(f"fit_exponent: n_dof and values must be 1-D of one length, got {n.shape} and {y.shape}")
    keep = np.isfinite(n) & (n > 0) & np.isfinite(y) & (y > 0)
    notes = [f"{int((~keep).sum())} size(s) without a finite positive value left out"] if (~keep).any() else []
    n, y = n[keep], y[keep]
    k = len(np.unique(n))
    out = {"exponent": math.nan, "stderr": math.nan, "ci_low": math.nan, "ci_high": math.nan, "n_sizes": k}
    if k < 2:
        return {**out, "note": "; ".join(notes + [f"{k} size(s): no fit"])}
    fit = stats.linregress(np.log(n), np.log(y))
    p = float(fit.slope)
    if len(n) == 2:
        return {**out, "exponent": p, "note": "; ".join(notes + ["2 sizes: the exact line, no interval"])}
    se = float(fit.stderr)
    half = float(stats.t.ppf(0.5 + confidence / 2, len(n) - 2)) * se
    return {**out, "exponent": p, "stderr": se, "ci_low": p - half, "ci_high": p + half, "note": "; ".join(notes)}


def _label(method: str, options: str) -> str:
    opts = json.loads(options) if options else {}
    return f"{method} {' '.join(f'{k}={v}' for k, v in sorted(opts.items()))}".strip()


def group_sizes(units: pd.DataFrame, cases: list) -> pd.DataFrame:
    """One row per case of a scaling group with its size: columns ``scaling_group, case, n_dof``
    (the median of its ok units' ``n_dof``), sorted by group and size; cases without an ok unit
    are left out."""
    groups = scaling_groups(cases)
    ok = units[units["case"].isin(groups) & (units["unit_status"] == "ok") & (units["n_dof"] > 0)]
    sizes = ok.groupby("case", sort=False)["n_dof"].median().rename("n_dof").reset_index()
    sizes.insert(0, "scaling_group", sizes["case"].map(groups))
    return sizes.sort_values(["scaling_group", "n_dof"]).reset_index(drop=True)


_POINT_COLUMNS = ["scaling_group", "case_name", "variant", "method", "options", "label", "quantity", "case", "n_dof",
                  "value"]


def scaling_points(units: pd.DataFrame, cases: list, error_metric: str = "max_rel_l2") -> pd.DataFrame:
    """The values the fits read: one row per (group, method setting, quantity, case) with the
    case's ``n_dof`` and the median ``value`` over its ok units of that setting (one unit each in a
    spec without repeats), and the reference step per case (``method = "reference"``, quantity
    ``reference_step_s``, the median over the case's ok units). Only groups with at least 2
    distinct sizes. Columns ``scaling_group, case_name, variant, method, options, label,
    quantity, case, n_dof, value``; the error quantity is named after ``error_metric``."""
    sizes = group_sizes(units, cases)
    frames = []
    for group, gs in sizes.groupby("scaling_group", sort=False):
        if gs["n_dof"].nunique() < 2:
            continue
        ok = units[units["case"].isin(gs["case"]) & (units["unit_status"] == "ok")].drop(columns="n_dof")
        ok = ok.merge(gs[["case", "n_dof"]], on="case")
        scene = {"scaling_group": group, "case_name": ok["case_name"].iloc[0], "variant": ok["variant"].iloc[0]}
        ref = ok.groupby("case", sort=False).agg(n_dof=("n_dof", "first"), value=("reference_step_s", "median"))
        frames.append(ref.reset_index().assign(**scene, method=REFERENCE, options="", label="reference FE step",
                                               quantity="reference_step_s"))
        for (method, options), grp in ok.groupby(["method", "options"], sort=False):
            for q in QUANTITIES:
                col = error_metric if q == "error" else q
                per_case = grp.groupby("case", sort=False).agg(n_dof=("n_dof", "first"), value=(col, "median"))
                frames.append(per_case.reset_index().assign(**scene, method=method, options=options,
                                                            label=_label(method, options), quantity=col))
    if not frames:
        return pd.DataFrame(columns=_POINT_COLUMNS)
    return pd.concat(frames, ignore_index=True)[_POINT_COLUMNS]


def scaling_table(units: pd.DataFrame, cases: list, error_metric: str = "max_rel_l2") -> pd.DataFrame:
    """The fitted exponents (module docstring): one row per group, method setting and quantity of
    :func:`scaling_points` (the reference step a row of its own). Columns :data:`SCALING_COLUMNS`."""
    points = scaling_points(units, cases, error_metric)
    rows = []
    keys = ["scaling_group", "case_name", "variant", "method", "options", "label", "quantity"]
    for key, grp in points.groupby(keys, sort=False):
        grp = grp.sort_values("n_dof")
        rows.append({**dict(zip(keys, key)), **fit_exponent(grp["n_dof"].to_numpy(float),
                                                             grp["value"].to_numpy(float)),
                     "n_dof_min": int(grp["n_dof"].min()), "n_dof_max": int(grp["n_dof"].max()),
                     "value_at_min": float(grp["value"].iloc[0]), "value_at_max": float(grp["value"].iloc[-1]),
                     "cases": ",".join(grp["case"])})
    return pd.DataFrame(rows, columns=SCALING_COLUMNS)
