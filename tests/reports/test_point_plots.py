"""The figures along a case's evaluation abscissa (tissuebench/reports/point_plots.py): the
error per point (pgd-cutting Fig. 7) and the step time per abscissa (Fig. 8), from stored
points and timed steps; which units and panels they draw."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.image import imread

from tissuebench.reports.point_plots import (_short_labels, latency_by_abscissa, plot_latency,
                                             plot_point_errors)


def _units():
    rows = [{"case": "cut", "method": "pgd_cutting", "kind": "map", "unit_status": "ok", "unit_key": f"k{n}{p}",
             "label": f"pgd_cutting n_modes={n} projection={p} strip_rings=1", "x_name": "cut_length",
             "max_rel_l2": 0.1 / n * (2 if p == "prb" else 1), "reference_step_s": 0.02}
            for n in (2, 6) for p in ("srb", "prb")]
    rows.append({"case": "cut", "method": "pgd_cutting", "kind": "map", "unit_status": "failed", "unit_key": "bad",
                 "label": "pgd_cutting n_modes=99", "x_name": "cut_length", "max_rel_l2": np.nan})
    rows.append({"case": "wave", "method": "pgd_direct", "kind": "trajectory", "unit_status": "ok", "unit_key": "traj",
                 "label": "pgd_direct", "x_name": "time", "max_rel_l2": 0.1, "reference_step_s": 0.1})
    return pd.DataFrame(rows)


def test_short_labels_drop_the_words_every_unit_shares():
    short, common = _short_labels(_units().iloc[:4])
    assert short == ["n_modes=2 projection=srb", "n_modes=2 projection=prb", "n_modes=6 projection=srb",
                     "n_modes=6 projection=prb"]
    assert common == "pgd_cutting strip_rings=1"
    assert _short_labels(pd.DataFrame({"label": ["pod n_modes=4"]})) == (["pod n_modes=4"], "")


def test_latency_by_abscissa_gives_each_abscissa_its_own_statistics():
    rng = np.random.default_rng(0)
    rows = [{"unit_key": "a", "sample": i, "x": float(i % 3), "haptic_s": 1e-5 * (1 + i % 3) + 1e-7 * rng.random()}
            for i in range(300)]
    rows.append({"unit_key": "a", "sample": 300, "x": np.nan, "haptic_s": 1.0})  # no abscissa: left out
    table = latency_by_abscissa(pd.DataFrame(rows))
    assert list(table["x"]) == [0.0, 1.0, 2.0] and list(table["n"]) == [100, 100, 100]
    assert table["median_s"].to_numpy() == pytest.approx([1e-5, 2e-5, 3e-5], rel=1e-2)
    assert (table["p99_s"] <= table["max_s"]).all() and table["max_s"].max() < 1e-4


def _points(units):
    return pd.DataFrame([{"unit_key": k, "x": float(c), "rel_l2": e * (1 + c), "has_reference": True}
                         for k, e in zip(units["unit_key"], units["max_rel_l2"].fillna(1.0)) for c in range(4)])


def test_error_figure_per_case_with_two_abscissae_and_not_for_trajectories(tmp_path):
    units = _units()
    paths = plot_point_errors(units, _points(units), tmp_path)
    assert [p.name for p in paths] == ["errors_cut.png"]  # the trajectory case has its history figure
    assert imread(paths[0]).shape[:2] == (420, 800)
    one = _points(units)
    one = one[one["x"] == 0.0]
    assert plot_point_errors(units, one, tmp_path / "b") == []  # a single abscissa: no line to draw
    assert plot_point_errors(units, pd.DataFrame(), tmp_path / "c") == []


def test_latency_figure_has_the_per_abscissa_panel_only_for_few_abscissae(tmp_path):
    (tmp_path / "b").mkdir()
    units = _units()
    rng = np.random.default_rng(1)
    few = pd.DataFrame([{"unit_key": k, "sample": i, "x": float(i % 4), "haptic_s": 3e-5 * (1 + rng.random())}
                        for k in units["unit_key"] for i in range(80)])
    draws = few.assign(x=rng.uniform(0, 1, len(few)))  # a map timed at random parameters
    (a,) = plot_latency(units, few, tmp_path)
    (b,) = plot_latency(units, draws, tmp_path / "b")
    assert a.name == b.name == "latency_cut.png"
    assert imread(a).shape[0] == 840 and imread(b).shape[0] == 420
    assert plot_latency(units, few[few["unit_key"] == "bad"], tmp_path / "c") == []  # only a failed unit timed


def test_the_drawn_units_are_the_best_of_every_method_then_of_every_variant():
    """srb beside prb, cracking-node beside condensed: the best of each categorical variant is
    drawn before a second unit of a variant already shown, however good."""
    import json

    from tissuebench.reports.trend_plots import _best_units

    rows = [{"method": "pgd_cutting", "unit_key": f"{e}-{p}-{n}", "max_rel_l2": err,
             "options": json.dumps({"enrichment": e, "projection": p, "n_modes": n})}
            for e, p, n, err in [("condensed", "srb", 30, 0.02), ("condensed", "srb", 20, 0.03),
                                 ("condensed", "srb", 10, 0.06), ("cracking_node", "srb", 10, 0.28),
                                 ("condensed", "prb", 10, 0.54), ("cracking_node", "prb", 10, 0.77),
                                 ("cracking_node", "prb", 6, 0.8)]]
    rows.append({"method": "pgd", "unit_key": "pgd", "max_rel_l2": 0.5, "options": "{}"})
    chosen = _best_units(pd.DataFrame(rows), "max_rel_l2", 6)
    assert list(chosen["unit_key"]) == ["condensed-srb-30", "pgd", "cracking_node-srb-10", "condensed-prb-10",
                                        "cracking_node-prb-10", "condensed-srb-20"]
