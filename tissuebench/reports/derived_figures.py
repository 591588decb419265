"""The figures of a sweep's ``_derived/`` folder, drawn beside its tables.

:func:`draw_derived` is the ``figures`` callable :func:`~tissuebench.studies.sweep.run_sweep`
and :func:`~tissuebench.studies.sweep.write_derived` take: the studies layer computes and
writes the tables, this layer draws (the layer rule of docs/explanation/architecture.md: ``studies`` never imports
``reports``). The CLI passes it; a script calling ``run_sweep`` passes it for the same files::

    from tissuebench.reports.derived_figures import draw_derived
    run_sweep(spec, out, figures=draw_derived)
"""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from ..studies.results import read_latency, read_outputs, read_points
from ..studies.sweep_manifest import read_sweep_manifest
from ..studies.scaling import scaling_points
from ..studies.sweep import paper_points
from .ladder import plot_ladder
from .point_plots import plot_latency, plot_point_errors
from .scaling import plot_scaling
from .sweep_plots import plot_pareto, plot_radius
from .trend_plots import plot_case_trends, plot_histories, plot_option_trends, plot_spectra

__all__ = ["draw_derived", "plot_trends"]


def draw_derived(out: Path, units: pd.DataFrame, tables: dict, folder: Path, error_metric: str) -> list[Path]:
    """Every figure of ``_derived/`` into ``folder``: the Pareto plots (with the paper's points
    of paper-resolution cases), the validity radii, the grid-following trends and histories,
    the per-point errors and latencies, the fidelity ladder, cost versus size. Returns the paths
    written."""
    written = plot_pareto(tables["pareto"], folder, paper_points(out))
    radius = plot_radius(tables["radius"], folder)
    written += [radius] if radius is not None else []
    written += plot_trends(out, units, error_metric, folder)
    points = read_points(out)
    if "beyond" in points:  # the ladder is along the path, as its table (the continuation is the radius's)
        points = points[~points["beyond"].fillna(False).astype(bool)]
    written += plot_ladder(tables["ladder"], points, folder)
    if "scaling" in tables:  # cost versus size: scaling_<quantity>.png
        cases = read_sweep_manifest(out, missing_ok=True).get("cases", [])
        written += plot_scaling(tables["scaling"], scaling_points(units, cases, error_metric), folder)
    return written


def plot_trends(out: Path, units: pd.DataFrame, error_metric: str, folder: Path) -> list[Path]:
    """The grid-following figures of :mod:`.trend_plots` and :mod:`.point_plots` into ``folder``."""
    cases = read_sweep_manifest(out, missing_ok=True).get("cases", [])
    outputs, points = read_outputs(out), read_points(out)
    return (plot_histories(units, points, outputs, folder, error_metric)
            + plot_spectra(units, outputs, folder, error_metric) + plot_option_trends(units, folder, error_metric)
            + plot_case_trends(units, cases, folder, error_metric)
            + plot_point_errors(units, points, folder, error_metric)
            + plot_latency(units, read_latency(out), folder, error_metric))
