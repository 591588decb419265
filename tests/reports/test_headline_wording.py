"""Issue 52, what the report says, word for word: each unit's headline (peak-normalised), state-
relative and absolute errors side by side; where the state-relative error exceeds the requirement,
in the scene's units; when nothing meets a requirement, an honest closest, the best unit per
clause among those that meet the others, and the machine's load while the units were timed; a
store written before the headline error says its validity radii are state-relative."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pyarrow.parquet as pq

from _report_store import build_store, unit_row
from tissuebench.reports.html import write_report
from tissuebench.reports.recommend import parse_requirement, rank_units
from tissuebench.reports.report_sections import (STATE_RELATIVE_RADII, clause_lines, errors_text, load_text,
                                                 recommendation, state_relative_text, validity_text)

REQUIRE = "rate>=1kHz, error<=5%"
RANGE = ("training range only: the steps past it are extrapolation, not counted; evaluation.extrapolation = true "
         "counts them")


def _unit(method, options, key, **values):
    row = unit_row("c", method, options, np.nan, 5e-5, 1e-4, False)
    row.update(unit_key=key, haptic_n=2000, **values)
    return row


def _static():
    """A reduced model on a static path (load factor 1 = 2 N): 0.34 % peak-normalised, 5.1 %
    state-relative (near rest), 12 µm; its points: two above 5 % state-relative in the training
    range (the larger at 0.02 = 0.04 N, 0.02 µm off), one past the top and one flagged (not counted)."""
    units = pd.DataFrame([_unit("pod_newton", {"n_modes": 3}, "s1", claimed_error=0.0034, max_rel_l2=0.051,
                                max_abs_error=1.2e-5, length_unit="m", x_scale=2.0, x_unit="N", validity_1pct=1.0,
                                validity_5pct=1.0, validity_range="training")])
    points = pd.DataFrame({"unit_key": "s1", "x": [0.0002, 0.003, 0.02, 0.5, 1.0, 1.5, 0.7],
                           "rel_l2": [0.051, 0.05, 0.06, 0.002, 0.001, 0.3, 0.2],
                           "abs_error": [4e-9, 1e-8, 2e-8, 1e-7, 1e-7, 5e-6, 1e-6],
                           "status": ["ok"] * 5 + ["extrapolation"] * 2, "beyond": [False] * 5 + [True, False],
                           "has_reference": True})
    return units, points


def test_a_unit_that_meets_it_shows_its_errors_side_by_side_and_where_the_state_relative_one_exceeds():
    units, points = _static()
    rec = recommendation(units, parse_requirement(REQUIRE), "claimed_error", points)
    assert rec["verdict"] == "1 of 1 units meet it, ranked by margin (the smallest headroom of the clauses):"
    # 5 % exactly (at 0.003) is not above 5 %: two of the five points of the training range are
    assert rec["lines"] == [
        "pod_newton n_modes=3: p99 100 µs (10 kHz; 2000 steps, 20 beyond the p99), median 50 µs, error 0.34 % "
        "(claimed_error), state-relative worst 5.1 % (max_rel_l2), absolute 1.2e-05 m (max_abs_error), margin 10x; "
        f"valid to 2 N at 1 % / 2 N at 5 % ({RANGE}); state-relative error above 5 % at 2 of 5 points, all at or "
        "below 0.04 N, where the absolute error is at most 2e-08 m"]


def test_the_state_relative_words_on_both_sides_and_without_what_they_need():
    units, points = _static()
    r = next(units.itertuples())
    assert state_relative_text(r, points, 0.06) == ""  # 6 % exactly is not above it
    assert state_relative_text(r, points, 0.0595) == ("state-relative error above 5.95 % at 1 of 5 points, all at or "
                                                      "below 0.04 N, where the absolute error is at most 2e-08 m")
    # extrapolation asked: the flagged step and the one past the top count too
    asked = next(units.assign(validity_range="extrapolation").itertuples())
    assert state_relative_text(asked, points, 0.06) == ("state-relative error above 6 % at 2 of 7 points, all at or "
                                                        "below 3 N, where the absolute error is at most 5e-06 m")
    # no scene unit: the abscissa by name; no absolute error column (a store before issue 52): not said
    bare = next(units.assign(x_unit="").itertuples())
    assert state_relative_text(bare, points.drop(columns="abs_error"), 0.0595) == (
        "state-relative error above 5.95 % at 1 of 5 points, all at or below load_factor 0.02")
    other = points.assign(unit_key="other")
    for pts in (None, points.iloc[:0], points.drop(columns="unit_key"), other):
        assert state_relative_text(r, pts, 0.01) == ""


def test_errors_side_by_side_skip_the_metric_itself_and_what_is_unknown():
    r = next(pd.DataFrame([{"error": 0.051, "claimed_error": 0.0034, "max_rel_l2": 0.051, "max_abs_error": np.nan,
                            "length_unit": "mm"}]).itertuples())
    assert errors_text(r, "max_rel_l2") == "error 5.1 % (max_rel_l2), headline 0.34 % (claimed_error)"
    r = next(pd.DataFrame([{"error": 0.0034, "max_abs_error": 0.25}]).itertuples())  # a store before issue 52
    assert errors_text(r, "claimed_error") == "error 0.34 % (claimed_error), absolute 0.25 (max_abs_error)"


def _motion(load_ecsw=6.0, cpus=2):
    """The dynamic organ of issue 52: a look-up table 3.8x over 5 %, POD-Galerkin ECSW missing
    1 kHz by 2.5x on a machine 3x loaded, full assembly 10x."""
    return pd.DataFrame([
        _unit("nearest", {}, "d1", peak_rel_l2=0.19, haptic_p99_s=2e-4, load_average=3.0, n_cpus=cpus),
        _unit("pod_galerkin", {"hyper": "ecsw"}, "d2", peak_rel_l2=0.045, haptic_p99_s=2.5e-3,
              load_average=load_ecsw, n_cpus=cpus),
        _unit("pod_galerkin", {"hyper": "none"}, "d3", peak_rel_l2=0.04, haptic_p99_s=1e-2, load_average=1.0,
              n_cpus=cpus)])


PER_CLAUSE = ("Per clause, among the units that meet the others: rate>=1kHz: the fastest with error<=5% is "
              "pod_galerkin hyper=ecsw: rate 400 Hz (p99 2.5 ms) is 2.5x short of 1 kHz; error<=5%: the most "
              "accurate with rate>=1kHz is nearest: error 19 % is 3.8x over 5 %.")


def test_none_meets_names_an_honest_closest_the_best_per_clause_and_the_load():
    rec = recommendation(_motion(), parse_requirement(REQUIRE), "peak_rel_l2")
    assert rec["verdict"] == (
        "None meets it. Closest: pod_galerkin hyper=ecsw (margin 0.4x as timed; 1.11x with its latency scaled by the "
        "machine's load factor 3): rate 400 Hz (p99 2.5 ms) is 2.5x short of 1 kHz. " + PER_CLAUSE
        + " Timed at a 1-minute load average of 1 to 6 on 2 CPUs: 2 of 3 unit(s) on a loaded machine (more runnable "
        "tasks than CPUs), whose steps waited for a CPU: their latency misses are scaled by load / CPUs when naming "
        "the closest.")


def test_on_an_idle_machine_the_closest_is_by_margin_and_the_load_is_said():
    # ECSW's 0.4 rate headroom on an idle machine is a real miss: the margin decides (0.4 > 0.263 here too)
    rec = recommendation(_motion(load_ecsw=2.0, cpus=4), parse_requirement(REQUIRE), "peak_rel_l2")
    assert rec["verdict"] == (
        "None meets it. Closest: pod_galerkin hyper=ecsw (margin 0.4x): rate 400 Hz (p99 2.5 ms) is 2.5x short of "
        "1 kHz. " + PER_CLAUSE + " Timed at a 1-minute load average of 1 to 3 on 4 CPUs: not loaded (no more runnable "
        "tasks than CPUs).")


def test_the_load_in_words():
    ranked = rank_units(_motion(), parse_requirement(REQUIRE), "peak_rel_l2")
    one = ranked[ranked["label"] == "nearest"].assign(n_cpus=1, load_average=0.5, load_factor=0.5)
    assert load_text(one) == "Timed at a 1-minute load average of 0.5 on 1 CPU: not loaded (no more runnable tasks " \
                             "than CPUs)."
    mixed = ranked.assign(n_cpus=[2, 4, 4], load_average=4.0, load_factor=[2.0, 1.0, 1.0])
    assert load_text(mixed) == ("Timed at a 1-minute load average of 4 on 2 or 4 CPUs: 1 of 3 unit(s) on a loaded "
                                "machine (more runnable tasks than CPUs), whose steps waited for a CPU: their latency "
                                "misses are scaled by load / CPUs when naming the closest.")
    unknown = ("The machine's load while the units were timed was not recorded (a store written before issue 52): a "
               "latency miss may be the machine's, not the method's.")
    assert load_text(ranked.assign(load_factor=np.nan)) == unknown
    assert load_text(ranked.drop(columns="load_factor")) == unknown


def test_clause_lines_when_no_unit_meets_the_others_and_for_one_clause():
    units = _motion().iloc[[0]]  # the table alone: it meets the rate, nothing meets the error
    ranked = rank_units(units, parse_requirement(REQUIRE), "peak_rel_l2")
    assert clause_lines(ranked, parse_requirement(REQUIRE)) == (
        "Per clause, among the units that meet the others: rate>=1kHz: no unit meets error<=5%; error<=5%: the most "
        "accurate with rate>=1kHz is nearest: error 19 % is 3.8x over 5 %.")
    one = parse_requirement("error<=5%")
    assert clause_lines(rank_units(units, one, "peak_rel_l2"), one) == ""
    # a unit that meets the others and this clause too (a requirement met: not in the verdict, said if asked)
    easy = parse_requirement("rate>=1kHz, error<=20%")
    assert clause_lines(rank_units(units, easy, "peak_rel_l2"), easy).endswith(
        "error<=20%: the most accurate with rate>=1kHz is nearest: it meets this clause too.")


def test_validity_radii_of_a_unit_without_a_headline_are_said_to_be_state_relative():
    from tissuebench.reports.report_sections import radius_table

    units, _ = _static()
    r = next(units.itertuples())
    assert validity_text(r) == f"valid to 2 N at 1 % / 2 N at 5 % ({RANGE})"
    old = next(units.assign(claimed_error=np.nan).itertuples())
    assert validity_text(old) == f"valid to 2 N at 1 % / 2 N at 5 % ({RANGE}) ({STATE_RELATIVE_RADII})"
    assert validity_text(next(units.drop(columns="claimed_error").itertuples())).endswith(f"({STATE_RELATIVE_RADII})")
    both = pd.concat([units, units.assign(claimed_error=np.nan), units.assign(unit_status="failed")])
    reads = [row[4] for row in radius_table("r", both)["rows"]]
    assert reads == ["peak-normalised (peak_rel)", "state-relative (rel_l2: a store written before issue 52)", "-"]
    assert radius_table("r", units.drop(columns="claimed_error"))["rows"][0][4].startswith("state-relative")


def test_a_store_written_before_the_headline_error_still_reports(tmp_path):
    """Unit and point files without the columns of issue 52 (claimed_error, load_average, n_cpus;
    peak_rel, abs_error): the report reads them, says its radii are state-relative and that the
    load was not recorded."""
    root = build_store(tmp_path / "results")
    dropped = {"claimed_error", "load_average", "n_cpus", "peak_rel", "abs_error"}
    files = list(root.glob("case=*/method=*/*.parquet")) + list((root / "_points").glob("case=*/method=*/*.parquet"))
    assert files
    for path in files:
        table = pq.read_table(path)
        pq.write_table(table.drop_columns([c for c in table.column_names if c in dropped]), path)
    out = write_report(root, tmp_path / "r.html", require="rate>=10kHz, error<=1%")
    page = out.read_text()
    assert "state-relative (rel_l2: a store written before issue 52)" in page
    assert "was not recorded (a store written before issue 52)" in page
    assert "None meets it. Closest: fast_rough n_modes=2 (margin 0.333x): error 3 % is 3x over 1 %." in page


def test_the_ranking_table_shows_the_state_relative_and_absolute_errors_and_the_load():
    from tissuebench.reports.report_sections import ranking_table
    ranked = rank_units(_motion(), parse_requirement(REQUIRE), "peak_rel_l2").assign(max_rel_l2=0.5,
                                                                                     max_abs_error=1e-4,
                                                                                     length_unit="mm")
    table = ranking_table("t", ranked)
    cols = table["columns"]
    row = dict(zip(cols, table["rows"][0]))
    assert row["state-relative worst (max_rel_l2)"] == "50 %" and row["absolute error (max_abs_error)"] == \
        "0.0001 mm"
    assert row["load average / CPUs while timed"] == "6 / 2" and row["unit"] == "pod_galerkin hyper=ecsw"
    bare = dict(zip(cols, ranking_table("t", ranked.drop(columns=["max_abs_error", "load_average"]))["rows"][0]))
    assert bare["absolute error (max_abs_error)"] == "-" and bare["load average / CPUs while timed"] == "-"
    assert {"closeness", "load_average", "n_cpus", "max_rel_l2", "max_abs_error"} <= set(table["data"].columns)
