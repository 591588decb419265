"""The report's interactive figures as plain plotly figure dicts (``{"data", "layout"}``) and the
table of every plotted value (written beside the HTML as CSV).

Figures are JSON only (no plotly Python objects): the page draws them with the inlined
plotly.js. Every string that comes from the user (case ids, labels, options) is HTML-escaped
here, because plotly renders a subset of HTML in names and hover texts; non-finite numbers
become ``null`` (JSON has no NaN/inf) with the reason in the hover text.
"""
from __future__ import annotations

import html
import math

import numpy as np
import pandas as pd

from ..studies.metrics import TOLERANCES
from .format import percent, seconds
from .wording import metric_words

__all__ = ["pareto_figure", "error_figure", "PALETTE", "SYMBOLS"]

PALETTE = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22",
           "#17becf"]
ERROR_FLOOR = 1e-6  # errors below (a training snapshot met again) are drawn here; the hover gives the value
_STATUS_SYMBOL = {"ok": "circle", "extrapolation": "triangle-up", "beyond_validity": "diamond",
                  "failed": "x", "not_reached": "x"}


def esc(text) -> str:
    return html.escape(str(text), quote=True)


def _num(v):
    v = float(v)
    return v if math.isfinite(v) else None


def _line(x0, x1, y0, y1, dash, color, xref="x", yref="y"):
    return {"type": "line", "xref": xref, "yref": yref, "x0": x0, "x1": x1, "y0": y0, "y1": y1,
            "line": {"dash": dash, "color": color, "width": 1.2}}


def _log_axis(title, values, fmt, **extra):
    """A log axis with one labelled tick per decade spanning ``values`` (text by ``fmt``: "10 µs", "1 %")."""
    v = np.asarray([x for x in values if x is not None and math.isfinite(x) and x > 0], float)
    lo, hi = (math.floor(math.log10(v.min())), math.ceil(math.log10(v.max()))) if v.size else (-6, 0)
    ticks = [10.0 ** k for k in range(lo, max(hi, lo + 1) + 1)]
    return {"title": {"text": title}, "type": "log", "tickvals": ticks, "ticktext": [fmt(t) for t in ticks],
            "gridcolor": "#e5e5e5", **extra}


def pareto_figure(case: str, units: pd.DataFrame, error_metric: str, requirement=None) -> tuple[dict, pd.DataFrame]:
    """Error versus haptic median (log axes), one marker trace per method (filled: on the
    Pareto front; whisker: up to the p99), the front as a step line, the reference step and
    the requirement's deadline (1 / rate, on the p99) and error as lines.

    Returns ``(figure, data)``: ``data`` has one row per plotted unit."""
    cols = ["case", "method", "label", "options", "unit_key", "error", "haptic_median_s", "haptic_p99_s",
            "speedup", "reference_step_s", "pareto"]
    finite = units[np.isfinite(units["error"].astype(float)) & np.isfinite(units["haptic_median_s"].astype(float))
                   & (units["error"] > 0) & (units["haptic_median_s"] > 0) & (units["unit_status"] == "ok")]
    data = finite[cols].copy()
    traces = []
    for color, symbol, label, g in _option_sets(data):
        hover = [f"<b>{esc(r.method)}</b><br>{esc(r.options)}<br>{esc(metric_words(error_metric))}: "
                 f"{percent(r.error)}<br>median {seconds(r.haptic_median_s)}, p99 {seconds(r.haptic_p99_s)}<br>"
                 f"speed-up {r.speedup:.3g}" + ("<br>on the Pareto front" if r.pareto else "") for r in g.itertuples()]
        traces.append({"type": "scatter", "mode": "markers", "name": esc(label),
                       "legendgroup": esc(g["method"].iloc[0]), "x": [_num(v) for v in g["haptic_median_s"]],
                       "y": [_num(v) for v in g["error"]],
                       "text": hover, "hovertemplate": "%{text}<extra></extra>",
                       "marker": {"size": 10, "color": color, "line": {"width": 1.5},
                                  "symbol": [symbol if p else f"{symbol}-open" for p in g["pareto"]]},
                       "error_x": {"type": "data", "symmetric": False, "thickness": 1, "width": 0,
                                   "array": [_num(p - m) for p, m in zip(g["haptic_p99_s"], g["haptic_median_s"])],
                                   "arrayminus": [0.0] * len(g)}})
    front = data[data["pareto"].astype(bool)].sort_values("haptic_median_s")
    if len(front):
        traces.append({"type": "scatter", "mode": "lines", "name": "Pareto front", "hoverinfo": "skip",
                       "x": [_num(v) for v in front["haptic_median_s"]], "y": [_num(v) for v in front["error"]],
                       "line": {"shape": "hv", "color": "black", "width": 1}})
    shapes, notes = [], []
    ref = float(np.nanmedian(units["reference_step_s"])) if units["reference_step_s"].notna().any() else math.nan
    if math.isfinite(ref) and ref > 0:
        shapes.append(_line(ref, ref, 0, 1, "dash", "#555", yref="paper"))
        notes.append({"x": math.log10(ref), "y": 1, "xref": "x", "yref": "paper", "showarrow": False,
                      "text": f"reference step {seconds(ref)}", "yanchor": "bottom",
                      "font": {"size": 10, "color": "#555"}})
    for c in getattr(requirement, "clauses", ()):
        if c.quantity in ("rate", "latency"):
            t = 1.0 / c.value if c.quantity == "rate" else c.value
            shapes.append(_line(t, t, 0, 1, "dot", "#c00", yref="paper"))
            notes.append({"x": math.log10(t), "y": 0.02, "xref": "x", "yref": "paper", "showarrow": False,
                          "text": f" deadline {seconds(t)} (p99)", "xanchor": "left", "yanchor": "bottom",
                          "font": {"size": 10, "color": "#c00"}})
        else:
            shapes.append(_line(0, 1, c.value, c.value, "dot", "#c00", xref="paper"))
            notes.append({"x": 1, "y": math.log10(c.value), "xref": "paper", "yref": "y", "showarrow": False,
                          "text": f"required error {percent(c.value)}", "xanchor": "right", "yanchor": "bottom",
                          "font": {"size": 10, "color": "#c00"}})
    lines_x = [shape["x0"] for shape in shapes if shape["xref"] == "x"]
    lines_y = [shape["y0"] for shape in shapes if shape["yref"] == "y"]
    layout = {"title": {"text": f"{esc(case)}: accuracy versus latency ({len(data)} units, "
                                f"{int(data['pareto'].sum())} on the front)"},
              "xaxis": _log_axis("haptic step, median (whisker: p99)", list(data["haptic_median_s"])
                                 + list(data["haptic_p99_s"]) + lines_x, seconds),
              "yaxis": _log_axis(metric_words(error_metric, markup=True), list(data["error"]) + lines_y, percent),
              "shapes": shapes, "annotations": notes, "hovermode": "closest", "legend": {"orientation": "v"},
              "margin": {"t": 60, "r": 20},
              "height": 480}
    return {"data": traces, "layout": layout}, data


#: marker shapes of a method's option sets (its colour is the method's): filled on the Pareto front
SYMBOLS = ["circle", "square", "diamond", "triangle-up", "triangle-down", "pentagon", "hexagon", "star", "cross",
           "x"]


def _option_sets(data: pd.DataFrame):
    """``(colour, symbol, legend label, rows)`` per option set of every method in ``data``: a
    method's colour (:data:`PALETTE`, by method), one marker shape per option set of it
    (:data:`SYMBOLS`), so that ``pod_interp`` linear and RBF are told apart on the plot."""
    for i, (method, g) in enumerate(data.groupby("method", sort=True)):
        for j, (_, rows) in enumerate(g.groupby("options", sort=True)):
            label = rows["label"].iloc[0] if g["options"].nunique() > 1 else method
            yield PALETTE[i % len(PALETTE)], SYMBOLS[j % len(SYMBOLS)], label, rows


def _unit_traces(key, g, meta, color, visible, top, y="rel_l2") -> list:
    """One unit's error curve (points with a reference; the error column ``y``), its failed steps
    at ``top`` and its validity radii as diamonds on the tolerance lines, in one legend group."""
    label = esc(meta.loc[key, "label"])
    g = g[g["has_reference"].astype(bool)].sort_values("x")
    finite = np.isfinite(g[y].astype(float))
    ok, bad = g[finite], g[~finite]
    common = {"type": "scatter", "legendgroup": key, "visible": visible}
    text = [f"{label}<br>{esc(r.mu)}<br>status {esc(r.status)}<br>error {percent(getattr(r, y))}"
            + (f" (state-relative {percent(r.rel_l2)})" if y != "rel_l2" else "") for r in ok.itertuples()]
    # held-out positions share their distance: markers only (a line would zigzag between positions)
    mode = "markers" if meta.loc[key, "x_name"] == "distance" else "lines+markers"
    traces = [{**common, "mode": mode, "name": label, "x": [_num(v) for v in ok["x"]],
               "y": [_num(max(v, ERROR_FLOOR)) for v in ok[y]], "text": text,
               "hovertemplate": "%{text}<extra></extra>", "line": {"color": color, "width": 1},
               "marker": {"color": color, "size": 6,
                          "symbol": [_STATUS_SYMBOL.get(s, "circle") for s in ok["status"]]}}]
    if len(bad):
        traces.append({**common, "mode": "markers", "name": f"{label}: failed steps", "showlegend": False,
                       "x": [_num(v) for v in bad["x"]], "y": [top] * len(bad),
                       "hovertemplate": f"{label}<br>failed step (error inf)<extra></extra>",
                       "marker": {"color": "#c00", "symbol": "x", "size": 9}})
    radii = [(float(meta.loc[key, f"validity_{int(round(t * 100))}pct"]), t) for t in TOLERANCES]
    radii = [(r, t) for r, t in radii if math.isfinite(r)]
    traces.append({**common, "mode": "markers", "name": f"{label}: validity radius", "showlegend": False,
                   "x": [r for r, _ in radii], "y": [t for _, t in radii],
                   "hovertemplate": f"{label}<br>validity radius %{{x:.4g}} at error %{{y:.0%}}<extra></extra>",
                   "marker": {"color": color, "symbol": "diamond-tall", "size": 13,
                              "line": {"color": "black", "width": 1}}})
    return traces


def error_figure(case: str, units: pd.DataFrame, points: pd.DataFrame) -> tuple[dict, pd.DataFrame]:
    """Relative l2 error of every evaluation point versus its abscissa (load factor, distance to
    the nearest stored position, time), one line per unit (marker symbol: the step status),
    the 1 % and 5 % tolerances as lines and each unit's validity radius as diamonds on them.
    Failed steps (error inf) are red crosses at the top. Units on the Pareto front are shown,
    the others listed in the legend (a click shows them)."""
    pts = points[points["unit_key"].isin(units["unit_key"]) & (points["status"] != "initial")]
    meta = units.set_index("unit_key")
    data = pts.merge(units[["unit_key", "label", "validity_1pct", "validity_5pct"]], on="unit_key")
    # the validity radius reads the peak-normalised error (issue 52): the curves are that error where
    # the store has it (a store written before: the state-relative rel_l2 its radii read)
    y = "peak_rel" if "peak_rel" in data and data["peak_rel"].notna().any() else "rel_l2"
    data = data[["unit_key", "label", "point", "x", "group", "mu", "status", "has_reference", "rel_l2",
                 "rel_max_displacement", "validity_1pct", "validity_5pct"] + (["peak_rel"] if y != "rel_l2" else [])]
    finite = data[y].replace([np.inf, -np.inf], np.nan)
    top = max(float(np.nanmax(finite)) * 3 if finite.notna().any() else 1.0, 0.1)
    front = set(units.loc[units["pareto"].astype(bool), "unit_key"]) if "pareto" in units else set(units["unit_key"])
    traces = []
    for i, (key, g) in enumerate(data.groupby("unit_key", sort=False)):
        traces += _unit_traces(key, g, meta, PALETTE[i % len(PALETTE)], True if key in front else "legendonly", top,
                               y)
    x_name = esc(units["x_name"].iloc[0]) if len(units) else "x"
    shapes = [_line(0, 1, t, t, "dash", "#c00", xref="paper") for t in TOLERANCES]
    notes = [{"x": 0, "y": math.log10(t), "xref": "paper", "yref": "y", "text": f"{t:.0%}", "showarrow": False,
              "xanchor": "left", "yanchor": "bottom", "font": {"size": 10, "color": "#c00"}} for t in TOLERANCES]
    yaxis = _log_axis("l2 error over the largest reference of the claimed range" if y != "rel_l2"
                      else "relative l2 error", [ERROR_FLOOR, top], percent,
                      range=[math.log10(ERROR_FLOOR) - 0.2, math.log10(top) + 0.2])
    layout = {"title": {"text": f"{esc(case)}: error versus {x_name} (diamonds: validity radius at 1 % and 5 %)"},
              "xaxis": {"title": {"text": x_name}, "gridcolor": "#e5e5e5"}, "yaxis": yaxis, "shapes": shapes,
              "annotations": notes, "hovermode": "closest", "margin": {"t": 60, "r": 20}, "height": 460}
    return {"data": traces, "layout": layout}, data
