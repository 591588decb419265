"""Paper versus ours: every ``[paper]`` figure of a scene beside our measurement where one maps.

Rows come from three places of the scene's catalogue TOML:

* ``[paper]`` numbers. Those with a counterpart in the sweep's unit rows (:data:`MEASURED`:
  rate, step times, speed-up, RMSE, node count) are put beside the value of the *best unit*:
  the most accurate finished unit (sweep error metric) of the paper's methods
  (``[paper.methods]``) when one was measured, else of all methods; the row says which unit
  and how the value is derived. The others are listed with "not measured by this sweep".
* ``[paper.compare.<monitor>]`` (value, note): our reference run's final monitored value,
  read **only from the reference cache** (:mod:`tissuebench.reference.cache`; the
  report never solves), with the stated reason they differ.
* ``[paper.methods.<method>]``: the paper's settings beside the option values measured.
"""
from __future__ import annotations

import json

import numpy as np
import pandas as pd

from ..studies.describe import paper_comparison
from ..reference.cache import cached_table

__all__ = ["MEASURED", "best_unit", "paper_rows", "cached_reference_table"]

# paper key -> (what of the best unit, or of the scene's units, is put beside it)
MEASURED = {
    "rate_hz": ("1 / haptic median of {best} [Hz]", lambda b, u: 1.0 / b["haptic_median_s"]),
    "rom_step_ms": ("haptic median of {best} [ms]", lambda b, u: 1e3 * b["haptic_median_s"]),
    "solve_s": ("haptic median of {best} [s]", lambda b, u: b["haptic_median_s"]),
    "speedup": ("reference step / haptic median of {best}", lambda b, u: b["speedup"]),
    "rmse_percent": ("relative RMSE of {best} [%]", lambda b, u: 100 * b["rmse_rel"]),
    "fe_step_ms": ("reference step (median over the units, same process) [ms]",
                   lambda b, u: 1e3 * float(np.nanmedian(u["reference_step_s"]))),
    "nodes": ("displacement nodes (n_dof / 3) of our mesh", lambda b, u: _nodes(u)),
}
_OPTION_ALIASES = {"modes": "n_modes", "orders": "order", "pod_modes": "n_modes"}


def _nodes(units):
    n = units["n_dof"][units["n_dof"] > 0]
    return float(n.iloc[0] // 3) if len(n) and n.iloc[0] % 3 == 0 else float("nan")


def best_unit(units: pd.DataFrame, paper: dict, error_metric: str):
    """``(row, why)``: the most accurate finished unit of the paper's methods (else of all), or
    ``(None, reason)``."""
    ok = units[(units["unit_status"] == "ok") & np.isfinite(units[error_metric].astype(float))]
    methods = set(paper.get("methods", {}))
    pool = ok[ok["method"].isin(methods)] if methods & set(ok["method"]) else ok
    if pool.empty:
        return None, "no finished unit with a finite error"
    row = pool.loc[pool[error_metric].astype(float).idxmin()]
    among = "the paper's method" if methods & set(ok["method"]) else "all methods (the paper's is not measured)"
    return row, f"{row['case']}: {row['label']} (lowest {error_metric} among {among})"


def _flat(table: dict, prefix: str = ""):
    for k, v in table.items():
        if isinstance(v, dict):
            yield from _flat(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v


def _text(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, list):
        return "[" + ", ".join(_text(x) for x in v) + "]"
    return str(v)


def cached_reference_table(scene, backend: str = "skfem") -> pd.DataFrame | None:
    """The cached reference run's table of ``scene`` (None when not cached or not a valid entry:
    :func:`~tissuebench.reference.cache.cached_table`); nothing is solved."""
    return cached_table(scene, backend)


def _measured_rows(scene, units, error_metric):
    best, why = best_unit(units, scene.paper, error_metric)
    rows = []
    for key, value in _flat({k: v for k, v in scene.paper.items() if k not in ("compare", "methods")}):
        row = {"section": "paper", "key": key, "paper": _text(value), "ours": "-", "how": "not measured by this sweep",
               "note": ""}
        if key in MEASURED:
            how, fn = MEASURED[key]
            uses_best = "{best}" in how
            if uses_best and best is None:
                row["how"] = why
            else:
                ours = fn(best, units)
                row.update(ours=_text(float(ours)), how=how.format(best=why))
        rows.append(row)
    return rows


def _compare_rows(scene, units, outputs):
    compare = scene.paper.get("compare", {})
    if not compare:
        return []
    table = cached_reference_table(scene, units["backend"].iloc[0])
    if table is not None:
        cmp = paper_comparison(scene, table)
        return [{"section": "compare", "key": r["monitor"], "paper": _text(r["paper"]), "ours": _text(r["ours"]),
                 "how": f"final value of the cached reference run (ratio ours / paper {r['ratio']:.3g})",
                 "note": r["note"]} for _, r in cmp.iterrows()]
    rows = []
    for name, ref in compare.items():
        mine = outputs[(outputs["monitor"] == name) & outputs["unit_key"].isin(units["unit_key"])] \
            if len(outputs) else outputs
        if len(mine):
            last = mine.loc[mine["x"].idxmax()]
            ours, how = _text(float(last["reference"])), (f"reference value at the last evaluation point "
                                                          f"(x = {last['x']:.4g}) in the store; no cached run")
        else:
            ours, how = "-", (f"no cached reference run of {scene.name} at {scene.resolution}: "
                              f"`tissuebench run {scene.name}` fills the cache")
        rows.append({"section": "compare", "key": name, "paper": _text(ref["value"]), "ours": ours, "how": how,
                     "note": ref.get("note", "")})
    return rows


def _method_rows(scene, units):
    rows = []
    for method, settings in scene.paper.get("methods", {}).items():
        mine = units[units["method"] == method]
        options = [json.loads(o) for o in mine["options"]]
        for key, value in settings.items():
            opt = _OPTION_ALIASES.get(key, key)
            measured = sorted({o[opt] for o in options if opt in o}, key=str)
            ours = _text(measured) if measured else "-"
            how = (f"option {opt} measured" if measured else
                   "method not in this sweep" if mine.empty else f"no option {opt!r} of {method}")
            rows.append({"section": f"methods.{method}", "key": key, "paper": _text(value), "ours": ours,
                         "how": how, "note": ""})
    return rows


def paper_rows(scene, units: pd.DataFrame, outputs: pd.DataFrame, error_metric: str) -> pd.DataFrame:
    """Every ``[paper]`` figure of ``scene`` beside ours (module docstring): columns section, key,
    paper, ours, how (what our value is), note (the catalogue's reason where they differ)."""
    rows = _measured_rows(scene, units, error_metric) + _compare_rows(scene, units, outputs) + \
        _method_rows(scene, units)
    return pd.DataFrame(rows, columns=["section", "key", "paper", "ours", "how", "note"])
