"""Cost versus size (studies/scaling.py, reports/scaling.py, the ``scaling`` preset): the exponent fit
against hand-made tables of known exponents, the scaling-group rule of the spec, and the preset at ci."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
from scipy import stats

from tissuebench.studies.scaling import (QUANTITIES, SCALING_COLUMNS, fit_exponent, scaling_points,
                                         scaling_table)
from tissuebench.studies.spec import load_spec

N = np.array([250.0, 1000.0, 4000.0, 16000.0])


def test_exact_power_law_gives_its_exponent():
    fit = fit_exponent(N, 3.0 * N ** 1.5)
    assert abs(fit["exponent"] - 1.5) < 1e-12
    assert fit["n_sizes"] == 4 and fit["note"] == ""
    assert abs(fit["ci_low"] - 1.5) < 1e-9 and abs(fit["ci_high"] - 1.5) < 1e-9


def test_noisy_power_law_interval_covers_and_has_its_nominal_coverage():
    """Log-normal noise (5 %) on cost = 2e-6 n^1.2 at 6 sizes: the 95 % interval covers 1.2 for the
    seed asserted, and in 93-97 % of 2000 seeded repetitions (the t quantile, not the normal one:
    with 4 degrees of freedom the normal quantile would cover about 88 %)."""
    n = np.geomspace(200, 20000, 6)
    rng = np.random.default_rng(0)
    covered = 0
    for i in range(2000):
        fit = fit_exponent(n, 2e-6 * n ** 1.2 * np.exp(rng.normal(0.0, 0.05, n.size)))
        covered += fit["ci_low"] <= 1.2 <= fit["ci_high"]
        if i == 0:
            assert fit["ci_low"] < 1.2 < fit["ci_high"] and fit["ci_high"] - fit["ci_low"] < 0.1
            half = stats.t.ppf(0.975, 4) * fit["stderr"]
            assert fit["ci_high"] - fit["exponent"] == pytest.approx(half)
    assert 0.93 <= covered / 2000 <= 0.97


def test_two_sizes_no_interval_and_bad_values_left_out():
    two = fit_exponent([100, 1000], [1.0, 100.0])
    assert two["exponent"] == pytest.approx(2.0) and math.isnan(two["ci_low"]) and math.isnan(two["stderr"])
    assert "2 sizes" in two["note"] and "no interval" in two["note"]
    dropped = fit_exponent(N, [1.0, np.nan, 0.0, 64.0])  # only 250 and 16000 remain: 64x over 64x
    assert dropped["n_sizes"] == 2 and dropped["exponent"] == pytest.approx(1.0)
    assert "2 size(s) without a finite positive value" in dropped["note"]
    none = fit_exponent(N, [np.nan, 1.0, np.nan, np.nan])
    assert math.isnan(none["exponent"]) and "no fit" in none["note"]
    with pytest.raises(ValueError, match="n_dof and values"):
        fit_exponent(N, [1.0, 2.0])


def _units(sizes, cases_per_group):
    """Unit rows of two methods on a group of cases of these sizes: a flat step (p = 0), a step
    ~ n (p = 1), the reference step ~ n^1.5, offline ~ n^2, memory ~ n, error ~ n^-0.5."""
    rows = []
    for i, n in enumerate(sizes):
        for method, options, p_step in (("pod_linear", '{"n_modes": 3}', 0.0), ("linear_fe", "{}", 1.0)):
            rows.append({"case": f"c-{i}", "case_name": "cube_tension_twist", "variant": "tension",
                         "method": method, "options": options, "unit_status": "ok", "n_dof": int(n),
                         "offline_s": 1e-6 * n ** 2, "model_bytes": 8.0 * n, "haptic_median_s": 1e-6 * n ** p_step,
                         "haptic_p99_s": 2e-6 * n ** p_step, "reconstruct_median_s": 1e-8 * n,
                         "reference_step_s": 1e-7 * n ** 1.5, "rmse_rel": 0.3 * n ** -0.5})
    # a failed unit and a case outside any group change nothing
    rows.append({**rows[0], "unit_status": "failed", "haptic_median_s": 99.0})
    rows.append({**rows[0], "case": "other", "haptic_median_s": 99.0})
    cases = [{"id": f"c-{i}", "scaling_group": "cube"} for i in range(cases_per_group)] + [{"id": "other"}]
    return pd.DataFrame(rows), cases


def test_scaling_table_recovers_known_exponents():
    units, cases = _units(N, len(N))
    table = scaling_table(units, cases, "rmse_rel")
    assert list(table.columns) == SCALING_COLUMNS
    got = table.set_index(["method", "quantity"])["exponent"]
    expected = {("pod_linear", "haptic_median_s"): 0.0, ("linear_fe", "haptic_median_s"): 1.0,
                ("linear_fe", "haptic_p99_s"): 1.0, ("pod_linear", "offline_s"): 2.0,
                ("pod_linear", "model_bytes"): 1.0, ("linear_fe", "reconstruct_median_s"): 1.0,
                ("pod_linear", "rmse_rel"): -0.5, ("reference", "reference_step_s"): 1.5}
    for key, p in expected.items():
        assert abs(got[key] - p) < 1e-12, key
    assert len(table) == 2 * len(QUANTITIES) + 1  # per method every quantity, and the reference row
    ref = table[table["method"] == "reference"].iloc[0]
    assert ref["n_sizes"] == 4 and ref["n_dof_min"] == 250 and ref["n_dof_max"] == 16000
    assert ref["cases"] == "c-0,c-1,c-2,c-3" and ref["label"] == "reference FE step"
    assert set(table["label"]) == {"pod_linear n_modes=3", "linear_fe", "reference FE step"}
    assert set(scaling_points(units, cases, "rmse_rel")["case"]) == {"c-0", "c-1", "c-2", "c-3"}


def test_no_table_without_two_sizes_in_a_group():
    units, cases = _units(N[:1], 1)
    assert scaling_table(units, cases).empty
    units, _ = _units(N, len(N))
    assert scaling_table(units, [{"id": f"c-{i}"} for i in range(4)]).empty  # no group: no table


# ------------------------------------------------------------------------------ the group rule
SPEC = """
[sweep]
name = "groups"

[[case]]
id = "a"
name = "cube_tension_twist"
variant = "tension"
scaling_group = {group_a}
mesh = {{ ci = {{ divisions = [8, 2, 2] }} }}

[[case]]
id = "b"
name = "cube_tension_twist"
variant = "{variant_b}"
scaling_group = "cube"
mesh = {{ ci = {{ divisions = {divisions_b} }} }}

[[method]]
name = "nearest"
cases = ["a", "b"]
"""


def _spec(tmp_path, group_a='"cube"', variant_b="tension", divisions_b="[12, 3, 3]"):
    path = tmp_path / "groups.toml"
    path.write_text(SPEC.format(group_a=group_a, variant_b=variant_b, divisions_b=divisions_b))
    return load_spec(path)


def test_scaling_group_is_kept_on_the_case_entries(tmp_path):
    spec = _spec(tmp_path)
    assert [c.scaling_group for c in spec.cases] == ["cube", "cube"]


@pytest.mark.parametrize("group_a, variant_b, divisions_b, message", [
    ("5", "tension", "[12, 3, 3]", r"case\[0\]\.scaling_group = 5: expected a name"),
    ('"a/b"', "tension", "[12, 3, 3]", r"case\[0\]\.scaling_group = 'a/b': expected a name"),
    ('""', "tension", "[12, 3, 3]", r"case\[0\]\.scaling_group = '': expected a name"),
    ('"cube"', "twist", "[12, 3, 3]", r"case\[1\]\.scaling_group = 'cube': case 'b' differs from 'a' of the same "
                                      r"group in variant"),
    ('"cube"', "tension", "[8, 2, 2]", r"case\[1\]\.scaling_group = 'cube': case 'b' has the same mesh"),
    ('"other"', "tension", "[12, 3, 3]", r"case\[0\]\.scaling_group = 'other': the only case of its group"),
])
def test_malformed_scaling_group_is_refused_naming_the_key(tmp_path, group_a, variant_b, divisions_b, message):
    with pytest.raises(ValueError, match=message):
        _spec(tmp_path, group_a, variant_b, divisions_b)


# ------------------------------------------------------------------------------ the preset at ci
@pytest.mark.slow
def test_scaling_preset_at_ci(tmp_path):
    """``tissuebench sweep --preset scaling`` at ci: every method's rows in scaling.parquet with the
    reference's, the full model's step clearly growing with the dofs, the small reduced
    models' online steps flat (their steps touch m-sized arrays only), and the report's section."""
    from tissuebench.cli import main
    from tissuebench.reports.html import write_report
    from tissuebench.studies.results import read_units

    out = tmp_path / "out"
    assert main(["sweep", "--preset", "scaling", "--out", str(out), "--quiet"]) == 0
    units = read_units(out)
    assert (units["unit_status"] == "ok").all(), units.loc[units["unit_status"] != "ok", "message"].tolist()
    table = pd.read_parquet(out / "_derived" / "scaling.parquet")
    assert list(table.columns) == SCALING_COLUMNS
    assert set(table["scaling_group"]) == {"cube-static", "cube-dynamic", "cornea"}
    assert set(table["method"]) == set(units["method"]) | {"reference"}
    for group, grp in table.groupby("scaling_group"):
        assert grp["n_sizes"].max() == 4 and (grp["n_dof_max"] / grp["n_dof_min"]).max() >= 10, group
        ref = grp[grp["method"] == "reference"]
        # the full model's step clearly grows with the mesh, well above the flat reduced steps below
        # (< 0.3). Not "at least linear": at ci sizes (10x the dofs) fixed costs flatten it, and the
        # timings of a loaded machine move the fit: a static step measured 0.73 (CI, 2 workers) to
        # ~0.9 (idle), the dynamic one (modified Newton keeps its factorisation: a residual and a
        # back-substitution a step) 0.64 idle and 0.26 on CI from a median of 3 steps (now 9, the
        # preset's reference_samples): the dynamic one is asked to grow above the flat steps' 0.3
        floor = 0.3 if group == "cube-dynamic" else 0.5
        assert len(ref) == 1 and ref["exponent"].iloc[0] > floor, (group, ref["exponent"].iloc[0])
    step = table[table["quantity"] == "haptic_median_s"].set_index(["scaling_group", "label"])["exponent"]
    for key in [("cube-static", "pod_linear n_modes=3"), ("cube-static", "pod_interp interpolation=linear n_modes=3"),
                ("cube-static", "nearest")]:
        assert step[key] < 0.3, (key, step[key])  # 10x the dofs: < 2x the step (microseconds: noisy)
    # the steps that solve the full system grow with it
    assert step[("cube-static", "pod_newton n_modes=3")] > 0.5
    assert step[("cube-static", "corotational_fe")] > 0.5
    for q in ("haptic_median_s", "offline_s", "model_bytes", "rmse_rel"):
        assert (out / "_derived" / f"scaling_{q}.png").stat().st_size > 10_000
    page = write_report(out, out / "_report" / "report.html").read_text()
    assert 'id="scaling"' in page and "Cost versus size" in page and "reference FE step" in page
