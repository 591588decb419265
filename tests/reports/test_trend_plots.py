"""The grid-following figures of a sweep (tissuebench/reports/trend_plots.py): which lines
they draw from which units, and that a real sweep writes them into ``_derived/``."""
from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tissuebench.cli import main
from tissuebench.reports.trend_plots import case_trends, option_trends, plot_histories


def _units():
    rows = []
    for modes in (1, 3, 7):
        for scheme in ("hht", "bathe"):
            rows.append({"case": "wave", "method": "pgd_direct", "kind": "trajectory",
                         "options": json.dumps({"integrator": scheme, "pod_modes": modes}),
                         "label": f"pgd_direct integrator={scheme} pod_modes={modes}",
                         "rmse_rel": 0.1 / modes if scheme == "hht" else 0.2 / modes})
    # two values of an option only: no trend (a line needs >= 3 abscissae over the case)
    rows += [{"case": "cube", "method": "wsc", "kind": "trajectory", "options": json.dumps({"handles": h}),
              "label": f"wsc handles={h}", "rmse_rel": 0.01 * h} for h in (10, 20)]
    return pd.DataFrame(rows)


def test_option_trends_draw_one_line_per_setting_of_the_other_options():
    trends = option_trends(_units(), "rmse_rel")
    assert set(trends) == {("wave", "pod_modes")}
    lines = trends[("wave", "pod_modes")]
    assert set(lines) == {"pgd_direct integrator=hht", "pgd_direct integrator=bathe"}
    x, y = lines["pgd_direct integrator=hht"]
    assert x == [1, 3, 7] and np.allclose(y, [0.1, 0.1 / 3, 0.1 / 7])


def test_case_trends_follow_the_one_scene_parameter_that_differs():
    units = pd.DataFrame([{"case": f"beam-dt{dt}", "method": "pgd_direct", "label": "pgd_direct bathe",
                           "rmse_rel": dt} for dt in (0.05, 0.01, 0.005)])
    cases = [{"id": f"beam-dt{dt}", "name": "clamped_beam", "variant": None, "resolution": "ci", "mu": {"dt": dt}}
             for dt in (0.05, 0.01, 0.005)]
    trends = case_trends(units, cases, "rmse_rel")
    assert list(trends) == [("clamped_beam", "dt")]
    assert trends[("clamped_beam", "dt")]["pgd_direct bathe"] == ([0.05, 0.01, 0.005], [0.05, 0.01, 0.005])
    # a second parameter varying as well: no single abscissa, no figure
    cases[0]["mu"] = {"dt": 0.05, "t_end": 2.0}
    assert case_trends(units, cases, "rmse_rel") == {}


def test_histories_need_trajectory_units_with_points(tmp_path):
    units = _units()
    assert plot_histories(units, pd.DataFrame(), pd.DataFrame(), tmp_path) == []
    units["unit_key"] = [f"k{i}" for i in range(len(units))]
    units["x_name"] = "time"
    points = pd.DataFrame([{"unit_key": k, "x": 0.1 * s, "rel_l2": 0.01 * (s + 1)}
                           for k in units["unit_key"] for s in range(5)])
    outputs = pd.DataFrame([{"unit_key": k, "point": s, "x": 0.1 * s, "monitor": "tip", "reference": np.sin(s),
                             "rom": np.sin(s) + 0.01} for k in units["unit_key"] for s in range(5)])
    paths = plot_histories(units, points, outputs, tmp_path, "rmse_rel")
    assert sorted(p.name for p in paths) == ["history_cube.png", "history_wave.png"]
    assert all(p.stat().st_size > 10_000 for p in paths)


def test_a_sweep_writes_its_histories_and_trends(tmp_path):
    """A direct-integrator sweep over three POD-mode counts: the history of its trajectory
    case and the error-versus-modes trend land in ``_derived/``."""
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "t"\nerror_metric = "rmse_rel"\n[protocol]\nlatency_steps = 20\nwarmup = 2\n'
                    '[[case]]\nname = "frame_2dof"\ntraining = { kind = "trajectory" }\n'
                    'evaluation = { kind = "trajectory" }\n[[method]]\nname = "pgd_direct"\n'
                    'options = { integrator = "central_difference", n_nodes = 20 }\n'
                    'grid = { pgd_modes = [1, 2, 8] }\n')
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--quiet"]) == 0
    derived = out / "_derived"
    assert (derived / "history_frame_2dof.png").is_file()
    assert (derived / "trend_frame_2dof_pgd_modes.png").is_file()


def test_histories_draw_the_energy_panel_where_points_carry_energy(tmp_path):
    """Units whose points carry the window's energy (``energy_rel``) get a third panel: the
    energy change of the reference and of each unit (paper Fig. 17)."""
    from matplotlib.image import imread

    units = _units()
    units["unit_key"] = [f"k{i}" for i in range(len(units))]
    units["energy_drift"] = 0.01
    points = pd.DataFrame([{"unit_key": k, "point": s, "x": 0.1 * s, "rel_l2": 0.01 * (s + 1),
                            "energy_rel": np.nan if s < 2 else 0.001 * s,
                            "reference_energy_rel": np.nan if s < 2 else 0.0}
                           for k in units["unit_key"] for s in range(5)])
    (tmp_path / "a").mkdir(), (tmp_path / "b").mkdir()
    with_energy = plot_histories(units, points, pd.DataFrame(), tmp_path / "a", "rmse_rel")
    without = plot_histories(units, points.drop(columns=["energy_rel", "reference_energy_rel"]), pd.DataFrame(),
                             tmp_path / "b", "rmse_rel")
    heights = [imread(p).shape[0] for p in with_energy], [imread(p).shape[0] for p in without]
    assert heights[0] == [720, 720] and heights[1] == [360, 360]


def test_a_sweep_stores_the_energy_history_of_its_trajectory_units(tmp_path):
    """frame_2dof under a step load: every stored step is in the constant-load window; the
    points carry the model's and the reference's E / scale, and the history figure has the
    energy panel."""
    from matplotlib.image import imread

    from tissuebench.studies.results import read_outputs, read_points, read_units

    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "t"\nerror_metric = "rmse_rel"\n[protocol]\nlatency_steps = 20\nwarmup = 2\n'
                    '[[case]]\nname = "frame_2dof"\ntraining = { kind = "trajectory" }\n'
                    'evaluation = { kind = "trajectory" }\n[[method]]\nname = "pgd_direct"\n'
                    'options = { integrator = "central_difference", n_nodes = 20, pgd_modes = 8 }\n')
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--quiet"]) == 0
    unit = read_units(out).iloc[0]
    points = read_points(out)
    inside = points[np.isfinite(points["reference_energy_rel"])]
    assert len(inside) >= 0.5 * len(points)
    assert np.isfinite(points["energy_rel"]).sum() >= len(inside) - 2  # the last step has no k + 1 neighbour
    # the drift column is the fitted trend of the stored history
    e = inside[np.isfinite(inside["energy_rel"])].sort_values("x")
    slope = np.polyfit(e["x"] - e["x"].iloc[0], e["energy_rel"], 1)[0]
    span = e["x"].iloc[-1] - unit["energy_window_start"]
    assert abs(slope * span - unit["energy_drift"]) <= 0.05 * abs(unit["energy_drift"]) + 1e-9
    panels = 2 + (not read_outputs(out).empty)  # (monitor), error, energy
    assert imread(out / "_derived" / "history_frame_2dof.png").shape[0] == 360 * panels


def test_output_spectra_show_the_frequency_a_unit_lost_over_the_window(tmp_path):
    """paper Fig. 20 from any sweep: the reference rings at 5 and 20 Hz after t = 0.5 s, one unit
    keeps both, one only 5 Hz; the spectra read the window only (before it the units are 0)
    and give the sinusoids' amplitudes (Hann window, exact bins: 1 and 0.5)."""
    from tissuebench.reports.trend_plots import output_spectra, plot_spectra

    t = np.arange(0, 2.5 + 1e-9, 0.005)
    ring = np.where(t >= 0.5, np.sin(2 * np.pi * 5 * t) + 0.5 * np.sin(2 * np.pi * 20 * t), 7.0)
    low = np.where(t >= 0.5, np.sin(2 * np.pi * 5 * t), 0.0)
    units = pd.DataFrame([{"case": "liver", "method": "m", "kind": "trajectory", "unit_key": k, "label": k,
                           "rmse_rel": e, "energy_window_start": 0.5} for k, e in (("both", 0.01), ("low", 0.3))])
    rows = []
    for key, rom in (("both", np.where(t >= 0.5, ring, 0.0)), ("low", low)):
        rows += [{"unit_key": key, "point": i, "x": x, "monitor": "tip", "reference": r, "rom": y}
                 for i, (x, r, y) in enumerate(zip(t, ring, rom))]
    spectra = output_spectra(units, pd.DataFrame(rows), "liver")
    assert set(spectra) == {"reference", "both (0.01)", "low (0.3)"}

    def at(label, hz):
        f, amp = spectra[label]
        return amp[np.argmin(np.abs(f - hz))]

    for label in ("reference", "both (0.01)"):
        assert at(label, 5) == pytest.approx(1.0, rel=0.02) and at(label, 20) == pytest.approx(0.5, rel=0.02)
    assert at("low (0.3)", 5) == pytest.approx(1.0, rel=0.02) and at("low (0.3)", 20) < 1e-3
    paths = plot_spectra(units, pd.DataFrame(rows), tmp_path)
    assert [p.name for p in paths] == ["spectrum_liver.png"] and paths[0].stat().st_size > 10_000


def test_pareto_plot_draws_the_papers_points_of_paper_resolution_cases(tmp_path, monkeypatch):
    """``case.paper_points`` of a paper-resolution case are drawn beside the units (hollow
    squares, counted in the legend); a ci case's points are not (other mesh)."""
    import matplotlib.figure

    from tissuebench.reports.sweep_plots import plot_pareto
    from tissuebench.studies.sweep import paper_points

    cases = [{"id": "cube", "resolution": "paper", "paper_points": [
                 {"label": "74/1880", "step_ms": 10.7, "error": 0.2182},
                 {"label": "364/2350", "step_ms": 18.41, "error": 0.0229}]},
             {"id": "lv", "resolution": "ci", "paper_points": [{"label": "300/3600", "step_ms": 21.8, "error": 0.024}]}]
    (tmp_path / "_sweep.json").write_text(json.dumps({"cases": cases}))
    paper = paper_points(tmp_path)
    assert paper["case"].tolist() == ["cube", "cube"] and paper["step_ms"].tolist() == [10.7, 18.41]
    pareto = pd.DataFrame([{"case": "cube", "method": "wsc", "label": f"wsc h={h}", "error": e, "haptic_median_s": t,
                            "pareto": True, "reference_step_s": 0.5, "error_metric": "rmse_rel"}
                           for h, e, t in ((10, 0.02, 6e-4), (40, 0.01, 2e-3))])
    figures = []
    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", lambda fig, *a, **k: figures.append(fig))
    plot_pareto(pareto, tmp_path, paper)
    ax = figures[0].axes[0]
    squares = [c for c in ax.collections if c.get_label().startswith("paper")]
    assert len(squares) == 1 and squares[0].get_label() == "paper (2 points, its mesh and machine)"
    np.testing.assert_allclose(squares[0].get_offsets(), [[10.7, 0.2182], [18.41, 0.0229]])
    figures.clear()
    plot_pareto(pareto, tmp_path, paper_points(tmp_path / "missing"))
    assert not [c for c in figures[0].axes[0].collections if c.get_label().startswith("paper")]


def test_each_energy_curve_starts_from_its_own_window_start():
    """The reference's E carries the cumulative external work, a model's the load potential:
    a constant apart. A model whose energy equals the reference's plus that constant draws on
    top of it (before: one energy scale above it, linear FE included)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from tissuebench.reports.trend_plots import _draw_energy

    x = np.linspace(1.0, 1.5, 6)
    ref = -0.01 * (x - 1.0)
    energy = pd.DataFrame({"unit_key": "m", "point": range(6), "x": x, "energy_rel": ref + 1.06,
                           "reference_energy_rel": ref})
    chosen = pd.DataFrame({"unit_key": ["m"], "label": ["linear_fe"], "energy_drift": [-0.005]})
    fig, ax = plt.subplots()
    _draw_energy(ax, energy, chosen)
    (rx, ry), (mx, my) = (line.get_data() for line in ax.get_lines()[:2])
    np.testing.assert_allclose(my, ry, atol=1e-12)
    assert ry[0] == 0.0 and len(mx) == len(rx) == 6
    plt.close(fig)
