"""Figures of a sweep that follow its grid: histories of trajectory units and error trends.

Written by :func:`~tissuebench.studies.sweep.write_derived` into ``_derived/`` beside the
Pareto front, for every sweep and any method (no per-method plotting code):

* ``history_<case>.png`` (trajectory units): the first monitored output against time, the
  reference beside the best units and the one the report recommends (default requirement),
  each unit's relative l2 error history (the papers'
  displacement-history and error-history figures, e.g. pgd-pod-direct Figs. 2, 15-16, 20)
  and, where the load ends constant, the energy history of the reference and of the units
  over that window (pgd-pod-direct Fig. 17: Bathe inside the step over 10 s);
* ``spectrum_<case>.png`` (trajectory units with a monitored output): the amplitude spectrum
  of that output over the constant-load window (the free vibration after a release, or all
  of a step response), the reference beside the best units: the frequency content a few
  modes lose (pgd-pod-direct Fig. 20), up to the Nyquist frequency of the stored steps;
* ``trend_<case>_<option>.png``: the error against a numeric option that varies in the grid
  (POD modes, handles, parameter-mesh nodes ...), one line per setting of the other options;
* ``trend_<case name>_<mu key>.png``: the error against a scene parameter that varies between
  the cases of one scene (the time step of ``direct_clamped_beam``: paper Fig. 5).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import periodogram

from .figures import pyplot
from .recommend import LATENCY_STATISTIC, parse_requirement, rank_units
from .sweep_plots import _file_part

__all__ = ["plot_histories", "recommended_unit", "plot_spectra", "output_spectra", "plot_option_trends",
           "plot_case_trends", "option_trends", "case_trends"]

MAX_HISTORY_UNITS = 8


def _numeric(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _variant(row) -> tuple:
    """A unit's method and its categorical options (projection, integrator, enrichment ...):
    what a reader compares; the numeric ones (modes, handles) are what the best of it picks."""
    try:
        opts = json.loads(row["options"]) if isinstance(row.get("options"), str) else {}
    except ValueError:
        opts = {}
    return (row["method"], *sorted((k, str(v)) for k, v in opts.items() if isinstance(v, (str, bool))))


def _best_units(group: pd.DataFrame, error_metric: str, n: int) -> pd.DataFrame:
    """The best unit of every method first, then of every other variant (method and
    categorical options: srb beside prb, Bathe beside HHT), then the best of the rest, ``n``
    in all."""
    ranked = group.assign(_e=group[error_metric].fillna(np.inf)).sort_values("_e", kind="stable")
    first = list(ranked.drop_duplicates("method").index)
    seen, second = {_variant(ranked.loc[i]) for i in first}, []
    for i in ranked.index:
        v = _variant(ranked.loc[i])
        if i not in first and v not in seen:
            seen.add(v)
            second.append(i)
    rest = [i for i in ranked.index if i not in first and i not in second]
    return ranked.loc[first + second + rest].head(n).drop(columns="_e")


def _energy_rows(points, keys) -> pd.DataFrame:
    if "energy_rel" not in points:
        return points.iloc[:0]
    sel = points[points["unit_key"].isin(keys)]
    return sel[np.isfinite(sel["energy_rel"]) | np.isfinite(sel["reference_energy_rel"])]


def _label(row, error_metric) -> str:
    return f"{row.label} ({getattr(row, error_metric, np.nan):.3g})"


def _draw_monitor(ax, mon, chosen, monitor, case, error_metric):
    ref = mon.drop_duplicates("point").sort_values("x")
    ax.plot(ref["x"], ref["reference"], "k-", lw=2.2, label="reference", zorder=1)
    for row in chosen.itertuples():
        m = mon[mon["unit_key"] == row.unit_key].sort_values("x")
        ax.plot(m["x"], m["rom"], lw=1, label=_label(row, error_metric))
    ax.set_ylabel(monitor)
    ax.set_title(f"{case}: {monitor}, reference and the best {len(chosen)} units ({error_metric})", fontsize=9)
    ax.legend(fontsize=6)
    ax.grid(alpha=0.3)


def _draw_errors(ax, points, chosen, error_metric, legend):
    for row in chosen.itertuples():
        p = points[(points["unit_key"] == row.unit_key) & np.isfinite(points["rel_l2"])].sort_values("x")
        ax.plot(p["x"], np.maximum(p["rel_l2"], 1e-16), lw=1, label=_label(row, error_metric) if legend else None)
    ax.axhline(0.01, color="tab:red", ls=":", lw=0.8)
    ax.set_yscale("log")
    ax.set_ylabel("relative l2 error of the field")
    ax.grid(alpha=0.3, which="both")
    if legend:
        ax.legend(fontsize=6)


def _draw_energy(ax, energy, chosen):
    """Energy change over the constant-load window, relative to the reference's largest
    KE + W there; a flat line conserves, a slope is the drift (studies/energy.py). Each curve
    starts from its own first value: the reference's E carries the cumulative external work,
    a model's the load potential -f.u, which differ by a constant in a constant-load window
    (drawn from the reference's start, every model sat about one scale above it, linear FE
    included, whose field is exact to 1e-12)."""
    ref = energy[np.isfinite(energy["reference_energy_rel"])].drop_duplicates("point").sort_values("x")
    e0 = float(ref["reference_energy_rel"].iloc[0]) if len(ref) else 0.0
    ax.plot(ref["x"], ref["reference_energy_rel"] - e0, "k-", lw=2.2, label="reference", zorder=1)
    for row in chosen.itertuples():
        m = energy[(energy["unit_key"] == row.unit_key) & np.isfinite(energy["energy_rel"])].sort_values("x")
        drift = getattr(row, "energy_drift", np.nan)
        # no energy history for the model (a follower load has no potential): the label says so
        text = f"drift {drift:+.2g}" if np.isfinite(drift) else "no energy history"
        m0 = float(m["energy_rel"].iloc[0]) if len(m) else 0.0
        ax.plot(m["x"], m["energy_rel"] - m0, lw=1, label=f"{row.label} ({text})")
    ax.set_yscale("symlog", linthresh=1e-4)
    ax.set_ylabel("(E(t) - E(t_c)) / max(KE + W)_ref")
    ax.set_title("energy E = KE + W - f.u over the constant-load window (paper Fig. 17)", fontsize=9)
    ax.legend(fontsize=6)
    ax.grid(alpha=0.3, which="both")


def recommended_unit(group: pd.DataFrame, error_metric: str, require: str | None = None) -> str | None:
    """The unit key the report's recommendation names for ``require`` (default: its default
    requirement) among ``group`` (one case's units): the one that meets it with the largest
    margin, else the closest (:func:`~.recommend.rank_units`); None when no unit is measurable (or
    the rows lack a status or a latency)."""
    if not {"unit_status", LATENCY_STATISTIC, error_metric} <= set(group):
        return None
    ranked = rank_units(group, parse_requirement(require), error_metric)
    ranked = ranked[ranked["measurable"]]
    return str(ranked["unit_key"].iloc[0]) if len(ranked) else None


def _with_recommended(chosen, group, metric, require):
    """``chosen`` with the recommended unit first (it may not be among the most accurate), labelled."""
    key = recommended_unit(group, metric, require)
    if key is None:
        return chosen
    row = group[group["unit_key"] == key].assign(label=lambda g: g["label"] + " [recommended]")
    rest = chosen[chosen["unit_key"] != key]
    return pd.concat([row, rest.head(MAX_HISTORY_UNITS - 1)])


def plot_histories(units, points, outputs, folder: Path, error_metric: str = "rmse_rel",
                   require: str | None = None) -> list[Path]:
    """``history_<case>.png`` for every case with trajectory units (see the module docstring), the
    unit the recommendation names for ``require`` (default: the report's default requirement)
    among them, marked ``[recommended]``."""
    if units.empty or points.empty or "kind" not in units:
        return []
    plt = pyplot()
    paths = []
    for case, group in units[units["kind"] == "trajectory"].groupby("case"):
        metric = error_metric if error_metric in group else "max_rel_l2"
        chosen = _with_recommended(_best_units(group, metric, MAX_HISTORY_UNITS), group, metric, require)
        outs = outputs[outputs["unit_key"].isin(chosen["unit_key"])] if not outputs.empty else outputs
        monitor = str(outs["monitor"].iloc[0]) if len(outs) else None
        energy = _energy_rows(points, chosen["unit_key"])
        panels = ["monitor"] * bool(monitor) + ["errors"] + ["energy"] * (not energy.empty)
        fig, axes = plt.subplots(len(panels), 1, figsize=(8, 3.6 * len(panels)), sharex=True, squeeze=False)
        ax = dict(zip(panels, axes[:, 0]))
        if monitor:
            _draw_monitor(ax["monitor"], outs[outs["monitor"] == monitor], chosen, monitor, case, metric)
        _draw_errors(ax["errors"], points, chosen, metric, legend=not monitor)
        if "energy" in ax:
            _draw_energy(ax["energy"], energy, chosen)
        axes[-1, 0].set_xlabel(str(group["x_name"].iloc[0]) if "x_name" in group else "time")
        fig.tight_layout()
        path = Path(folder) / f"history_{_file_part(case)}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths


def _amplitude(x, y):
    """(frequencies [1/unit of x], amplitude spectrum) of samples ``y`` at uniform ``x``
    (Hann window, mean removed), or None when there are too few or uneven samples."""
    dx = np.diff(x)
    if len(y) < 8 or not np.all(np.isfinite(y)) or np.ptp(dx) > 1e-6 * dx.mean():
        return None
    f, power = periodogram(y, fs=1.0 / dx.mean(), window="hann", detrend="constant", scaling="spectrum")
    return f, np.sqrt(2.0 * power)


def output_spectra(units, outputs, case: str, error_metric: str = "rmse_rel") -> dict:
    """``{"reference" | unit label: (frequencies, amplitudes)}`` of the first monitored output of
    ``case`` over the constant-load window (``energy_window_start`` of its units; the whole
    history when there is none), for the reference and the best :data:`MAX_HISTORY_UNITS`
    units with a complete history there; ``{}`` without a monitored output."""
    group = units[units["case"] == case]
    metric = error_metric if error_metric in group else "max_rel_l2"
    chosen = _best_units(group, metric, MAX_HISTORY_UNITS)
    outs = outputs[outputs["unit_key"].isin(chosen["unit_key"])] if not outputs.empty else outputs
    if outs.empty:
        return {}
    mon = outs[outs["monitor"] == outs["monitor"].iloc[0]]
    starts = group["energy_window_start"].dropna() if "energy_window_start" in group else pd.Series(dtype=float)
    mon = mon[mon["x"] >= (float(starts.iloc[0]) if len(starts) else -np.inf) - 1e-12]
    ref = mon.drop_duplicates("point").sort_values("x")
    spectra = {"reference": _amplitude(ref["x"].to_numpy(float), ref["reference"].to_numpy(float))}
    for row in chosen.itertuples():
        m = mon[mon["unit_key"] == row.unit_key].sort_values("x")
        if len(m) == len(ref):
            spectra[_label(row, metric)] = _amplitude(m["x"].to_numpy(float), m["rom"].to_numpy(float))
    return {k: v for k, v in spectra.items() if v is not None}


def plot_spectra(units, outputs, folder: Path, error_metric: str = "rmse_rel") -> list[Path]:
    """``spectrum_<case>.png`` for every trajectory case of :func:`output_spectra`."""
    if units.empty or outputs.empty or "kind" not in units:
        return []
    plt = pyplot()
    paths = []
    for case in sorted(units.loc[units["kind"] == "trajectory", "case"].unique()):
        spectra = output_spectra(units, outputs, case, error_metric)
        if "reference" not in spectra:
            continue
        fig, ax = plt.subplots(figsize=(8, 4.2))
        for label, (f, amp) in spectra.items():
            ref = label == "reference"
            ax.plot(f, np.maximum(amp, 1e-300), "k-" if ref else "-", lw=2.2 if ref else 1, label=label,
                    zorder=1 if ref else 2)
        peak = float(np.max(spectra["reference"][1]))
        ax.set_yscale("log")
        ax.set_ylim(max(peak * 1e-6, 1e-300), peak * 3 if peak > 0 else 1.0)
        ax.set_xlabel("frequency [1/s]")
        ax.set_ylabel(f"amplitude of {outputs['monitor'].iloc[0]}")
        ax.set_title(f"{case}: spectrum over the constant-load window (to the stored steps' Nyquist "
                     f"{spectra['reference'][0][-1]:.3g} 1/s)", fontsize=9)
        ax.legend(fontsize=6)
        ax.grid(alpha=0.3, which="both")
        fig.tight_layout()
        path = Path(folder) / f"spectrum_{_file_part(case)}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        paths.append(path)
    return paths


def _trend_figure(lines: dict, x_name: str, error_metric: str, title: str, path: Path) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.8))
    dropped = 0
    for label, (x, y) in sorted(lines.items()):
        x, y = np.asarray(x, float), np.asarray(y, float)
        ok = np.isfinite(y) & (y > 0)
        dropped += int((~ok).sum())
        order = np.argsort(x[ok])
        ax.plot(x[ok][order], y[ok][order], "o-", ms=4, lw=1, label=label)
    ax.axhline(0.01, color="tab:red", ls=":", lw=0.8)
    ax.set_yscale("log")
    ax.set_xlabel(x_name)
    ax.set_ylabel(error_metric)
    ax.set_title(title + (f" ({dropped} failed or infinite, not drawn)" if dropped else ""), fontsize=9)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=6, ncol=2 if len(lines) > 8 else 1)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def option_trends(units, error_metric: str = "max_rel_l2") -> dict:
    """``{(case, option): {line label: (x values, errors)}}`` for every numeric option with at
    least 3 values in a case; a line is one setting of the other options (>= 2 points)."""
    trends = {}
    for case, group in units.groupby("case") if not units.empty else ():
        opts = [json.loads(o) if o else {} for o in group["options"]]
        for key in sorted({k for o in opts for k, v in o.items() if _numeric(v)}):
            lines: dict = {}
            for o, row in zip(opts, group.itertuples()):
                if _numeric(o.get(key)):
                    rest = " ".join(f"{k}={v}" for k, v in sorted(o.items()) if k != key)
                    x, y = lines.setdefault(f"{row.method} {rest}".strip(), ([], []))
                    x.append(o[key])
                    y.append(getattr(row, error_metric))
            lines = {k: v for k, v in lines.items() if len(set(v[0])) >= 2}
            if len({x for v in lines.values() for x in v[0]}) >= 3:
                trends[(case, key)] = lines
    return trends


def case_trends(units, cases: list[dict], error_metric: str = "max_rel_l2") -> dict:
    """``{(scene name, key): {unit label: (mu[key] values, errors)}}`` for a numeric scene
    parameter ``mu[key]`` that is the only difference between >= 2 cases of one scene (same
    name, variant and resolution)."""
    trends = {}
    by_scene: dict = {}
    for c in cases or ():
        by_scene.setdefault((c.get("name"), c.get("variant"), c.get("resolution")), []).append(c)
    for (name, _, _), group in by_scene.items():
        mus = [c.get("mu") or {} for c in group]
        varying = [k for k in set().union(*mus) if len({json.dumps(m.get(k), sort_keys=True) for m in mus}) > 1]
        if len(group) < 2 or len(varying) != 1 or not all(_numeric(m.get(varying[0])) for m in mus):
            continue
        key = varying[0]
        value = {c["id"]: m[key] for c, m in zip(group, mus)}
        lines: dict = {}
        for row in units[units["case"].isin(list(value))].itertuples() if not units.empty else ():
            x, y = lines.setdefault(row.label, ([], []))
            x.append(value[row.case])
            y.append(getattr(row, error_metric))
        if lines:
            trends[(name, key)] = lines
    return trends


def plot_option_trends(units, folder: Path, error_metric: str = "max_rel_l2") -> list[Path]:
    """``trend_<case>_<option>.png`` for every entry of :func:`option_trends`."""
    return [_trend_figure(lines, key, error_metric, f"{case}: error versus {key}",
                          Path(folder) / f"trend_{_file_part(case)}_{_file_part(key)}.png")
            for (case, key), lines in option_trends(units, error_metric).items()]


def plot_case_trends(units, cases: list[dict], folder: Path, error_metric: str = "max_rel_l2") -> list[Path]:
    """``trend_<scene name>_<mu key>.png`` for every entry of :func:`case_trends`."""
    return [_trend_figure(lines, key, error_metric, f"{name}: error versus the scene's {key}",
                          Path(folder) / f"trend_{_file_part(name)}_{_file_part(key)}.png")
            for (name, key), lines in case_trends(units, cases, error_metric).items()]
