"""The fidelity ladder (studies/ladder.py, reports/ladder.py): thresholds on a table built by hand,
the sentences, and a small sweep where the answer is known (a linear scene: linear FE is exact;
the cube pulled: linear FE's error is first order in the load, so 1 % is crossed where the
small-load slope says)."""
import numpy as np
import pandas as pd
import pytest

from tissuebench.studies.ladder import ladder_statements, ladder_table, rung_of
from tissuebench.studies.results import read_points, read_units
from tissuebench.studies.spec import load_spec
from tissuebench.reports.derived_figures import draw_derived
from tissuebench.studies.sweep import run_sweep


def _unit(case, method, options, key, x_name="load_factor"):
    return {"case": case, "case_name": "scene", "variant": "", "resolution": "ci", "x_name": x_name,
            "method": method, "options": options, "label": f"{method} {options}", "unit_key": key,
            "unit_status": "ok", "haptic_median_s": 1e-4, "haptic_p99_s": 2e-4,
            "model_info": '{"achieved_ratio": 1.9}' if method == "coarse_fe" else "{}"}


def _points(key, x, e):
    return pd.DataFrame({"unit_key": key, "x": x, "rel_l2": e, "group": np.nan, "status": "ok",
                         "has_reference": True})


def test_thresholds_and_sentences_on_a_hand_made_table():
    x = np.array([0.5, 1.0, 1.5, 2.0, 2.5])
    units = pd.DataFrame([_unit("c", "linear_fe", "{}", "lin"), _unit("c", "corotational_fe", "{}", "cor"),
                          _unit("c", "coarse_fe", '{"coarsening":4}', "co4"), _unit("c", "anm_pod", "{}", "rom"),
                          _unit("d", "nearest", "{}", "other")])
    points = pd.concat([_points("lin", x, [0.002, 0.008, 0.02, 0.04, 0.07]),
                        _points("cor", x, [0.001, 0.002, 0.004, 0.006, 0.012]),
                        _points("co4", x, [0.03, 0.03, 0.031, 0.032, 0.033]), _points("rom", x, 0.5)])
    t = ladder_table(units, points)
    assert list(t["case"]) == ["c", "c", "c", "d"]  # the ROM is no rung; case d has none and says so
    by = t.set_index("rung")
    lin = by.loc["linear"]
    assert (lin["within_1pct_to"], lin["first_above_1pct"], lin["within_5pct_to"], lin["first_above_5pct"]) == \
        (1.0, 1.5, 2.0, 2.5)
    assert np.isnan(by.loc["corotational", "first_above_5pct"]) and by.loc["corotational", "first_above_1pct"] == 2.5
    co = by.loc["full, 4x coarser mesh"]
    assert co["within_1pct_to"] == 0.0 and co["max_error"] == 0.033 and co["achieved_coarsening"] == 1.9
    assert by.loc["none", "note"].startswith("no practitioner-baseline unit")
    text = " ".join(ladder_statements(t, "c"))
    assert "Linear elasticity is within 1 % up to load factor 1, within 5 % up to load factor 2" in text
    assert "Beyond, geometric nonlinearity is required: corotational FE" in text and "up to load factor 2" in text
    assert "A 4x coarser mesh, element sizes 1.9x (full model) costs 3.3 %" in text
    assert ladder_statements(t, "d") == []
    # cases with groups (held-out positions, contact nodes) are not one path: no ladder
    grouped = ladder_table(units, points.assign(group=1.0))
    assert "c" not in set(grouped["case"])


def test_rung_names():
    assert rung_of("coarse_fe", '{"coarsening": 2, "model": "linear"}') == ("linear, 2x coarser mesh", "linear", 2.0)
    assert rung_of("linear_fe", '{"condensed": true}')[0] == "linear"
    with pytest.raises(ValueError, match="not a ladder method"):
        rung_of("anm_pod", "{}")


SPEC = """
[sweep]
name = "ladder"
error_metric = "max_rel_l2"
[protocol]
latency_steps = 5
warmup = 1
reference_samples = 1
[[case]]
id = "cube"
name = "cube_tension_twist"
variant = "tension"
training = { kind = "path" }
[[case]]
id = "wave"
name = "wave_block"
variant = "linear"
training = { kind = "trajectory" }
[[method]]
name = "linear_fe"
[[method]]
name = "corotational_fe"
cases = ["cube"]
"""


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    folder = tmp_path_factory.mktemp("ladder")
    spec = folder / "ladder.toml"
    spec.write_text(SPEC)
    out = folder / "out"
    run_sweep(load_spec(spec), out, progress=False, figures=draw_derived)
    return out


def test_a_sweep_writes_the_ladder_with_the_known_answers(sweep):
    t = pd.read_parquet(sweep / "_derived" / "ladder.parquet")
    assert (sweep / "_derived" / "ladder_cube.png").is_file() and (sweep / "_derived" / "ladder_wave.png").is_file()
    wave = t[t["case"] == "wave"].iloc[0]
    assert wave["rung"] == "linear" and wave["max_error"] < 1e-10 and np.isnan(wave["first_above_1pct"])
    assert ladder_statements(t, "wave")[0].startswith("Linear elasticity is within 1 % over the whole run")
    # the cube: linear FE's error is first order in the load factor (exact as the load vanishes) ...
    units, points = read_units(sweep), read_points(sweep)
    key = units.loc[(units["case"] == "cube") & (units["method"] == "linear_fe"), "unit_key"].iloc[0]
    p = points[(points["unit_key"] == key) & points["has_reference"]].sort_values("x")
    x, e = p["x"].to_numpy(), p["rel_l2"].to_numpy()
    assert e[1] / e[0] == pytest.approx(x[1] / x[0], rel=0.03)
    # ... so it crosses 1 % near 0.01 / (small-load slope) (the error grows a little slower than the
    # load: 0.51 predicted, 0.6 measured on the ci cube), and the ladder says where
    lin = t[(t["case"] == "cube") & (t["rung"] == "linear")].iloc[0]
    predicted = 0.01 / (e[0] / x[0])
    assert predicted <= lin["first_above_1pct"] <= 1.3 * predicted
    assert lin["first_above_1pct"] == x[e > 0.01].min()
    assert lin["within_1pct_to"] == x[x < lin["first_above_1pct"]].max()
    cor = t[(t["case"] == "cube") & (t["rung"] == "corotational")].iloc[0]
    assert cor["first_above_1pct"] >= lin["first_above_1pct"]  # the rotations carry some of it


def test_the_report_has_the_ladder_section(sweep, tmp_path):
    from tissuebench.reports.html import write_report

    page = write_report(sweep, tmp_path / "r.html").read_text()
    assert 'id="ladder"' in page and "Fidelity ladder: what each scene requires" in page
    assert "Linear elasticity is within 1 % over the whole run" in page
    assert (tmp_path / "r_data" / "ladder_00_cube.csv").is_file()


def _ranked(rows):
    from tissuebench.reports.recommend import parse_requirement, rank_units

    units = pd.DataFrame([{"case": "c", "method": m, "label": m, "unit_status": "ok", "max_rel_l2": e,
                           "haptic_p99_s": p99, "speedup": 100.0} for m, e, p99 in rows])
    return rank_units(units, parse_requirement("rate>=500Hz, error<=2%"), "max_rel_l2")


def test_versus_baselines_says_whether_a_rom_beats_the_best_practitioner_baseline():
    from tissuebench.reports.ladder import versus_baselines

    text = versus_baselines(_ranked([("anm_pod", 0.001, 1e-5), ("linear_fe", 0.015, 1e-5)]))
    assert text.startswith("A ROM beats every practitioner baseline here: anm_pod") and "less margin" in text
    text = versus_baselines(_ranked([("anm_pod", 0.03, 1e-5), ("linear_fe", 0.015, 1e-5)]))
    assert text.startswith("No ROM beats the practitioner baseline linear_fe") and "misses it: error" in text
    text = versus_baselines(_ranked([("anm_pod", 0.03, 1e-5), ("corotational_fe", 0.001, 0.5)]))
    assert text.startswith("Neither a ROM nor a practitioner baseline meets it")
    assert versus_baselines(_ranked([("anm_pod", 0.001, 1e-5)])) is None


def test_a_coarse_mesh_in_time_costs_its_rmse():
    units = pd.DataFrame([{**_unit("t", "coarse_fe", '{"coarsening":2}', "co", x_name="time"), "rmse_rel": 0.2}])
    t = ladder_table(units, _points("co", np.array([0.1, 0.2, 0.3]), [0.05, 3.5, 0.1]))
    text = ladder_statements(t, "t")[0]
    assert "costs 20 % (relative RMSE over the run; pointwise up to 350 %)" in text, text


def test_a_rung_over_1_percent_from_the_first_point_is_not_quoted_at_its_max():
    """The kidney of issue 27: linear elasticity 3 % at the first point, 37.6 % at the path's end;
    the sentence names the first point and gives the max as the max, not as the first point's."""
    x = [0.1, 0.3, 0.5]
    units = pd.DataFrame([_unit("k", "linear_fe", "{}", "lin")])
    t = ladder_table(units, _points("lin", x, [0.03, 0.2, 0.376]))
    text = ladder_statements(t, "k")[0]
    assert "within 1 % not even at the first point (load factor 0.1), within 5 % up to load factor 0.1" in text
    assert "(max 37.6 % over the path)" in text and "0.1: 37.6" not in text
