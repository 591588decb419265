"""The shipped sweep presets run at ci resolution, and what they measure on the shipped meshes.

The figures asserted are those measured on this project's meshes (the liver of
``tissuebench/data/liver``, the ci cornea dome), not general claims: see docs/explanation/findings.md.
"""
from __future__ import annotations

import json
import tomllib

import numpy as np
import pandas as pd
import pytest

from _fuzz import dumps
from tissuebench.cli import main
from tissuebench.studies.results import read_units
from tissuebench.studies.spec import PRESETS_DIR

pytestmark = pytest.mark.slow


def _run(preset, tmp_path_factory, untimed=()):
    """The preset ``preset`` swept at ci into a fresh folder: its units indexed by (case, label).

    ``untimed``: methods whose latency no test of the preset asserts (``"*"``: every method),
    timed on one pass over the evaluation set without warmup (``latency_steps = 1, warmup =
    0``) instead of the preset's protocol. Their rows still carry a latency; every other
    number of the unit (build, evaluation pass, errors, reference step) is computed as the
    preset computes it (the protocol enters the unit's key only, not its results). It spares
    the Newton-stepped baselines (a full solve per timed step: corotational_fe, coarse_fe,
    pod_newton) a second and third pass over their path (issue 29: CI time)."""
    folder = tmp_path_factory.mktemp(preset)
    out = folder / "out"
    spec = ["--preset", preset] if not untimed else [str(_quick_timing(preset, untimed, folder / f"{preset}.toml"))]
    assert main(["sweep", *spec, "--out", str(out), "--quiet"]) == 0
    units = read_units(out)
    assert (units["unit_status"] == "ok").all(), units.loc[units["unit_status"] != "ok", "message"].tolist()
    # a unit whose model spans fewer modes than asked is labelled 'n_modes=9 (7 built)': the
    # tests name units by what they asked for
    units["label"] = units["label"].str.replace(r" \(\d+ built\)$", "", regex=True)
    frame = units.set_index(["case", "label"])
    frame.attrs["out"] = out
    return frame


_ONE_PASS = {"latency_steps": 1, "warmup": 0}


def _quick_timing(preset, methods, path):
    """``preset`` written to ``path`` with the methods ``methods`` (``"*"``: all) timed on one pass
    (:func:`_run`); every other key as shipped."""
    doc = tomllib.loads((PRESETS_DIR / f"{preset}.toml").read_text())
    names = {m["name"] for m in doc["method"]}
    assert methods == "*" or set(methods) <= names, (preset, methods)
    if methods == "*":
        doc["protocol"] = {**doc.get("protocol", {}), **_ONE_PASS}
    for m in doc["method"]:
        if methods == "*" or m["name"] in methods:
            m["protocol"] = {**m.get("protocol", {}), **_ONE_PASS}
    path.write_text(dumps(doc))
    return path


@pytest.fixture(scope="module")
def anm(tmp_path_factory):
    from tissuebench.refsolvers.remesh import gmsh_available

    if not gmsh_available():  # coarse_fe remeshes the liver's surface
        pytest.skip("gmsh is not installed (the optional extra tissuebench[mesh])")
    return _run("anm_pod", tmp_path_factory, untimed={"corotational_fe", "coarse_fe"})


@pytest.fixture(scope="module")
def interp(tmp_path_factory):
    return _run("interpolation", tmp_path_factory, untimed="*")


def _anm(n, order):
    return f"anm_pod eps=1e-06 max_segments=1 n_modes={n} order={order}"


def test_liver_nine_modes_order_six_within_one_percent_to_5_5(anm):
    """The paper's claim on the shipped liver: 9 POD modes, order 6, one series from the origin:
    error <= 1 % up to load factor 5.5 (6.6 N, reference max displacement 4.7 mm), <= 5 % to 6.5.
    The paper's error is state-relative: read from the points' ``rel_l2``. The stored radii read the
    peak-normalised error (issue 52: over the largest displacement of the claimed range, here up to
    6.5), 0.96 % at 6.0 where the state-relative one is 1.05 %: 1 % holds to 6.0."""
    from tissuebench.studies.metrics import validity_radius
    from tissuebench.studies.results import read_points

    row = anm.loc[("liver_palpation", _anm(9, 6))]
    points = read_points(anm.attrs["out"])
    mine = points[points["unit_key"] == row["unit_key"]]  # extrapolation asked: every point, as the radii
    assert validity_radius(mine["x"], mine["rel_l2"], 0.01) == 5.5
    assert validity_radius(mine["x"], mine["rel_l2"], 0.05) == 6.5
    assert row["validity_1pct"] == 6.0 and row["validity_5pct"] == 6.5
    # order 1 (the linear ROM) is far worse; the steps past the path are flagged
    assert anm.loc[("liver_palpation", _anm(9, 1)), "max_rel_l2"] > 4 * row["max_rel_l2"]
    assert row["n_beyond_validity"] + row["n_extrapolation"] >= 2
    assert row["haptic_median_s"] < row["reference_step_s"]


def test_cornea_series_converge_with_order(anm):
    errs = [anm.loc[("cornea_pinch", _anm(4, o)), "max_rel_l2"] for o in (1, 2, 4, 6, 10)]
    assert errs[0] > 5e-3 and errs[-2] < 1e-8  # order 1 is 1.9 % off (0.78 % on the locking Q1), order 6 exact
    assert all(b <= a * 1.01 for a, b in zip(errs, errs[1:]))


def test_practitioner_baselines_beside_anm_pod(anm):
    """The cheaper full models on both paths (rom/fe_baselines) and the ladder they make. Measured
    (ci): liver linear FE 14.6 % at the end of the path, within 1 % to load factor 0.5; corotational
    9.05 %, within 1 % to 1.5; a 2x coarser remeshed liver 23 % (the point load on larger elements);
    cornea linear 1.9 %, within 1 % to 0.5, corotational 39 %: against the mean-dilatation Q1 of issue 54
    the corotated Q1 locks (on the locking Q1 reference before: linear 0.78 %, corotational 0.076 %)."""
    liver, cornea = anm.loc["liver_palpation"], anm.loc["cornea_pinch"]
    assert liver.loc["linear_fe condensed=False", "max_rel_l2"] == pytest.approx(0.146, abs=0.005)
    assert liver.loc["linear_fe condensed=True", "max_rel_l2"] == pytest.approx(
        liver.loc["linear_fe condensed=False", "max_rel_l2"], rel=1e-9)
    assert 0.05 < liver.loc["corotational_fe", "max_rel_l2"] < liver.loc["linear_fe condensed=False", "max_rel_l2"]
    assert cornea.loc["linear_fe condensed=False", "max_rel_l2"] == pytest.approx(0.019, abs=0.001)
    assert cornea.loc["corotational_fe", "max_rel_l2"] > 0.3  # corotated Q1, without mean dilatation: it locks
    assert (liver.loc["linear_fe condensed=True", "haptic_p99_s"] < 1e-3)
    ladder = pd.read_parquet(anm.attrs["out"] / "_derived" / "ladder.parquet").set_index(["case", "rung"])
    assert ladder.loc[("liver_palpation", "linear"), "within_1pct_to"] == pytest.approx(0.5)
    assert ladder.loc[("liver_palpation", "corotational"), "within_1pct_to"] == pytest.approx(1.5)
    assert ladder.loc[("cornea_pinch", "linear"), "within_1pct_to"] == pytest.approx(0.5)
    assert ladder.loc[("liver_palpation", "full, 2x coarser mesh"), "max_error"] > 0.1


def test_held_out_baselines_beside_anm_pod(anm):
    """Away from the snapshots (trained on every second state): on the liver path the
    non-intrusive POD (coefficients interpolated) is more accurate than ANM-POD at 9/6, and
    the nearest stored state is worst."""
    liver = anm.loc["liver_palpation-heldout"]
    assert liver.loc["pod_interp interpolation=rbf n_modes=9", "max_rel_l2"] < 0.015
    assert liver.loc["pod_interp interpolation=rbf n_modes=9", "max_rel_l2"] < liver.loc[_anm(9, 6), "max_rel_l2"]
    assert liver.loc["nearest", "max_rel_l2"] > 0.3


def test_between_stored_positions_pod_interp_beats_podi_beats_grassmann(interp):
    """Mean error at held-out load positions (5 stored, 4 modes, order 6), as measured on the
    shipped meshes: cornea PODI 2.0 %, Grassmann 2.7 %, POD + linear coefficients 0.04 % (on the
    mean-dilatation Q1 of issue 54; 1.8 %, 7.1 %, 0.02 % on the locking Q1 before); liver PODI 5.0 %,
    Grassmann 6.3 %, POD + linear coefficients 4.2 %; nearest 12 % and 11 %."""
    expected = {"cornea_pinch-positions": (2.0e-2, 2.7e-2, 3.9e-4),
                "liver_palpation-positions": (5.0e-2, 6.3e-2, 4.2e-2)}
    for case, (podi, grassmann, linear) in expected.items():
        t = interp.loc[case, "mean_rel_l2"]
        assert t["podi n_modes=4 order=6"] == pytest.approx(podi, rel=0.1)
        assert t["grassmann n_modes=4 order=6"] == pytest.approx(grassmann, rel=0.1)
        assert t["pod_interp interpolation=linear n_modes=8"] == pytest.approx(linear, rel=0.2)
        assert t["nearest"] > t["grassmann n_modes=4 order=6"]


def test_pod_galerkin_on_the_paths(interp):
    """Reduced Newton on a basis of the whole path reproduces it (the accuracy ceiling)."""
    for case in ("cornea_pinch-path", "liver_palpation-path"):
        t = interp.loc[case]
        assert t.loc["pod_newton n_modes=9", "max_rel_l2"] < 1e-5
        assert t.loc["pod_linear n_modes=9", "max_rel_l2"] > 1e-3  # linear: misses the nonlinearity


def test_pod_galerkin_on_the_cube(tmp_path_factory):
    cube = _run("pod_cube", tmp_path_factory, untimed="*")
    for case in ("cube-tension", "cube-twist"):
        assert cube.loc[(case, "pod_newton n_modes=5"), "max_rel_l2"] < 1e-3
    # the linear model with the tangent at the origin cannot follow a 90 degree twist
    assert cube.loc[("cube-twist", "pod_linear n_modes=3"), "max_rel_l2"] > 0.1


def test_pgd_cutting_preset(tmp_path_factory):
    """The vademecum against the FE of the same cut (cornea_cut, ci: cut lengths 0 and 1 of
    incision 0) and at held-out source positions (heat1d): srb beats prb at every mode count,
    srb improves with modes, srb is exact once the modes span the space (heat1d, 49 modes),
    the condensed enrichment removes the cut's error (ci strip: 13 positions)."""
    pgd = _run("pgd_cutting", tmp_path_factory, untimed={"corotational_fe", "coarse_fe"})
    cut, heat = pgd.loc["cornea_cut"], pgd.loc["heat1d_source"]
    opts = "pgd_cutting accessible=strip n_modes={} projection={} strip_rings=1"
    for n in (1, 2, 4, 6, 10):
        assert cut.loc[opts.format(n, "srb"), "max_rel_l2"] < cut.loc[opts.format(n, "prb"), "max_rel_l2"]
    for n in (1, 2, 5, 10):
        assert heat.loc[f"pgd n_modes={n} projection=srb", "max_rel_l2"] < \
            heat.loc[f"pgd n_modes={n} projection=prb", "max_rel_l2"]
    srb = [cut.loc[opts.format(n, "srb"), "max_rel_l2"] for n in (1, 2, 4, 6, 10)]
    assert all(b <= a for a, b in zip(srb, srb[1:])) and srb[-1] < 0.1
    assert heat.loc["pgd n_modes=49 projection=srb", "max_rel_l2"] < 1e-12
    condensed = "pgd_cutting accessible=strip enrichment=condensed n_modes=10 projection=srb strip_rings=1"
    assert cut.loc[condensed, "max_rel_l2"] < 1e-10
    assert (cut["n_points"] == 2).all()  # the intact cornea and one cut length
    # the build record reaches the store: modes, fixed-point iterations, and the rank floor
    # (ci strip: 10 positions; 6 modes leave a floor > 0)
    info = json.loads(cut.loc[opts.format(6, "srb"), "model_info"])
    assert info["n_modes"] == 6 and len(info["fixed_point_iterations"]) == 6 and info["stop_reason"]
    floor = info["rank_floor"]
    assert floor["n_parameters"] == 10 and 0 < floor["rms_rel_l2"] <= floor["max_rel_l2_svd"]
    assert json.loads(heat.loc["pgd n_modes=49 projection=srb", "model_info"])["rank_floor"]["rms_rel_l2"] < 1e-12
    # pgd_svk (the modes as the Ritz basis of the SVK cornea) against the full SVK Newton solve
    # with the contact at the same node, 5 nodes x the 10 load factors of the path (measured at
    # ci: RMSE 0.79 / 0.44 / 0.36 with 2 / 6 / 10 modes on the mean-dilatation Q1 of issue 54, 0.75 /
    # 0.47 / 0.38 on the locking Q1; the response to a point load is local, so a few modes of a
    # 57-position vademecum miss the positions near the clamped rim)
    svk = pgd.loc["cornea-svk"]
    assert (svk["n_points"] == 50).all() and (svk["n_failed"] == 0).all()
    assert (svk["reference_status"] == "success").all()
    # the practitioner baselines at the same contact nodes (rom/fe_baselines): linear FE misses the SVK
    # response by 15 % (4.8 % on the locking Q1); corotational FE, a full Newton solve per step on the
    # corotated Q1, which locks where the mean-dilatation reference does not (issue 54), by 66 % (1.4 %)
    assert 0.1 < svk.loc["linear_fe", "rmse_rel"] < svk.loc["corotational_fe", "rmse_rel"]
    svk = svk[[label.startswith("pgd") for label in svk.index]]
    errs = [svk.loc[f"pgd_svk n_modes={n}", "rmse_rel"] for n in (2, 6, 10)]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 0.45
    assert (svk["haptic_median_s"] < svk["reference_step_s"]).all()


def test_wsc_table1_preset(tmp_path_factory):
    """The skinning-cubature grid on the ci cube (208 vertices, 648 tets; tension in dynamics,
    relative RMSE of the displacement history against the FE run on the same mesh). Measured:
    with every element integrated the error falls with the handles (1.6 % -> 0.64 %); NNLS
    with 20-40 % of the cells reaches that floor within 25 %; the paper's BGBC budgets
    (5-7.5 % of the cells: 32-49 elements here) do not: with 5 % handles they are 10x off.
    Table 3's levels run on their own meshes (208 -> 81 and 425 vertices at ci)."""
    wsc = _run("wsc_table1", tmp_path_factory)
    full = [wsc.loc[("cube-tension", f"wsc cubature=full handles={h} rtol=0.001"), "rmse_rel"]
            for h in (0.01, 0.03, 0.05)]
    assert full[0] > full[1] > full[2] and full[2] < 0.01
    nnls = wsc.loc[("cube-tension-trained", "wsc cubature=nnls cubature_elements=0.4 handles=0.05 nnls_tol=0.05 "
                    "rtol=0.001")]
    assert nnls["rmse_rel"] < 1.25 * full[2]
    bgbc = wsc.loc[("cube-tension", "wsc cubature=bgbc cubature_elements=0.05 handles=0.05 rtol=0.001"), "rmse_rel"]
    assert bgbc > 10 * full[2]
    # every unit steps faster than the FE step it replaces, measured in the same process
    assert (wsc["haptic_median_s"] < wsc["reference_step_s"]).all()
    # Table 3: the same bar on a coarser and a finer mesh (the case's mesh override), and one
    # absolute configuration (10 handles, 100 elements) on all three meshes: one reduced size
    fixed = "wsc cubature=bgbc cubature_elements=100 handles=10 rtol=0.001"
    levels = wsc.xs(fixed, level="label").loc[["cube-tension-low", "cube-tension", "cube-tension-high"]]
    assert levels["n_dof"].tolist() == [3 * 81, 3 * 208, 3 * 425]
    assert levels["n_reduced"].nunique() == 1
    assert (levels["rmse_rel"] < 0.1).all()  # measured 4.0 / 6.6 / 2.7 %
    for case in ("cube-tension-low", "cube-tension-high"):
        assert len(wsc.loc[case]) == 3


def test_direct_presets(tmp_path_factory):
    """The PGD-POD direct integrator against the scenes' reference runs (relative RMSE over
    the history). frame_2dof: exact to round-off with 2 POD modes (= every dof) and the
reference's scheme inside the step (forward Euler on (u, v) is 20 % off); clamped beam:
    Bathe inside the step converges with dt (mid-step load), the explicit schemes blow up at
    every dt of the grid and the blow-up is a failed step (inf error), never a silent NaN;
    wave block: implicit schemes under 5 % (linear, 3 and 8 modes; HHT with 8 best), central
    difference under 8 % (linear and SVK)."""
    frame = _run("direct_frame_2dof", tmp_path_factory, untimed="*").loc["frame_2dof"]
    cd, fe = ("pgd_direct integrator={} margin=0.25 n_nodes=100 pgd_modes=8 pod_modes=2".format(s)
              for s in ("central_difference", "forward_euler"))
    assert frame.loc[cd, "rmse_rel"] < 1e-10  # the reference's own scheme (central difference)
    assert frame.loc[fe, "rmse_rel"] > 0.1  # forward Euler on (u, v): 20 % off, its scheme error
    beam = _run("direct_clamped_beam", tmp_path_factory, untimed="*")
    opts = "pgd_direct integrator={} load_at={} margin=0.25 n_nodes=100 pod_modes=4"
    errs = [beam.loc[(f"beam-dt{dt}", opts.format("bathe", "mid")), "rmse_rel"] for dt in ("0.05", "0.01", "0.005")]
    assert errs[0] > errs[1] > errs[2] and errs[2] < 2e-3
    for dt in ("0.05", "0.01", "0.005"):
        for scheme in ("forward_euler", "central_difference"):
            row = beam.loc[(f"beam-dt{dt}", opts.format(scheme, "end"))]
            assert row["n_failed"] >= 1 and row["rmse_rel"] == float("inf")
    # paper Fig. 5 (error versus dt) and the histories, drawn by the sweep itself
    derived = beam.attrs["out"] / "_derived"
    assert (derived / "trend_clamped_beam_dt.png").is_file()
    histories = {p.name for p in derived.glob("history_*.png")}
    assert histories == {f"history_beam-dt{dt}.png" for dt in ("0.05", "0.01", "0.005")}
    wave = _run("direct_wave_block", tmp_path_factory, untimed="*")
    lin = wave.loc["wave-linear", "rmse_rel"]
    wopts = "pgd_direct integrator={} margin=0.25 n_nodes=100 pod_modes={}"
    for m in (3, 8):
        assert lin[wopts.format("bathe", m)] < 0.05 and lin[wopts.format("hht", m)] < 0.05
        assert lin[wopts.format("central_difference", m)] < 0.08
    assert lin.idxmin() == wopts.format("hht", 8)  # the reference's own scheme, the most modes
    assert (wave.loc["wave-svk", "rmse_rel"] < 0.08).all()
    _direct_wave_long_run(wave)


def _direct_wave_long_run(wave):
    """Paper Fig. 17 from the preset: 10 s with 8 POD modes; Bathe inside the step stays
    stable and dissipates like the HHT reference (~ -1.5 %), central difference conserves;
    the history figure carries the energy panel of both."""
    from matplotlib.image import imread

    from tissuebench.studies.results import read_points

    opts = "pgd_direct integrator={} margin=0.25 n_nodes=100 pod_modes=8"
    long = wave.loc["wave-linear-10s"]
    for scheme in ("bathe", "central_difference"):
        row = long.loc[opts.format(scheme)]
        assert row["n_failed"] == 0 and row["n_extrapolation"] == 0 and row["n_ok"] == 200
        assert row["rmse_rel"] < 0.3
    bathe, cd = long.loc[opts.format("bathe")], long.loc[opts.format("central_difference")]
    assert -0.03 < bathe["energy_drift"] < -0.005 and -0.03 < bathe["reference_energy_drift"] < -0.005
    assert abs(cd["energy_drift"]) < 1e-3
    points = read_points(wave.attrs["out"])
    mine = points[(points["case"] == "wave-linear-10s") & np.isfinite(points["energy_rel"])]
    assert len(mine) >= 2 * 198 and mine["x"].max() >= 9.9  # the last step has no k + 1 neighbour
    assert imread(wave.attrs["out"] / "_derived" / "history_wave-linear-10s.png").shape[0] == 3 * 360
    assert (wave.attrs["out"] / "_derived" / "spectrum_wave-linear-10s.png").is_file()


# The extremes preset, run in groups of its cases (each a `--cases` sweep), so the suite's
# workers share it (it is the longest preset: ~5 min cold in one piece); together the groups
# cover every case of the preset (test_extremes_groups_cover_the_preset).
_EXTREMES_GROUPS = {
    "liver-locking": ["liver-nu0.45", "liver-nu0.49", "liver-nu0.499", "liver-nu0.4999",
                      "cornea-compression", "cornea-duplicated"],
    "cube": ["cube-nu0.45", "cube-nu0.49", "cube-nu0.499", "cube-nu0.4999", "cube-coarse", "cube-fine"],
    "explicit-and-waves": ["frame-dt0.5x-critical", "frame-dt1x-critical", "frame-dt2x-critical",
                           "frame-dt10x-critical", "frame-10x-horizon", "beam-10x-horizon", "wave-10x-horizon",
                           "wave-bathe-10x-horizon"],
    "held-organs": ["cube-dynamic-10x-horizon", "lv-dynamic-10x-horizon"],
    "liver-free-vibration": ["liver-dynamic-10x-horizon"],
    "dome-locking": ["dome-nu0.49", "dome-nu0.499", "dome-p1-nu0.49", "dome-p1-nu0.499"],
}
_EXTREMES_UNITS = {"liver-locking": 34, "cube": 21, "explicit-and-waves": 12, "held-organs": 2,
                   "liver-free-vibration": 1, "dome-locking": 12}
# points past the training path (measured, issue 27): the beyond factors without a reference (68, 28)
# and the states of the reference continued past the top with the path's increment
_PAST_PATH_LIVER, _PAST_PATH_CUBE = 713, 592


def test_extremes_groups_cover_the_preset():
    from tissuebench.studies.spec import load_spec

    cases = [c.id for c in load_spec("extremes").cases]
    grouped = [c for group in _EXTREMES_GROUPS.values() for c in group]
    assert sorted(grouped) == sorted(cases) and len(grouped) == len(set(grouped))
    assert sum(_EXTREMES_UNITS.values()) == 82


@pytest.mark.parametrize("group", list(_EXTREMES_GROUPS))
def test_extremes_preset(tmp_path_factory, group):
    """Numerical extremes (issue "Reliability"), measured at ci on the shipped meshes: every
    unit has a status and no step past the training envelope is returned as "ok"; P1 locking
    of the liver as nu -> 0.5 (tool tip at 3.6 N: 2.40, 1.77, 0.99, 0.41 mm for nu = 0.45,
    0.49, 0.499, 0.4999); the cornea pinched 200x harder stalls (inverted elements), stored
    as the reference's status; a duplicated rank-5 snapshot set asked for 15 modes gives 5
    and says so; the dynamic extremes (_extremes_dynamic_rows)."""
    import json

    from tissuebench.studies.results import read_outputs, read_points

    folder = tmp_path_factory.mktemp(f"extremes-{group}")
    out = folder / "out"
    spec = _quick_timing("extremes", "*", folder / "extremes.toml")  # no latency asserted here (_run)
    assert main(["sweep", str(spec), "--cases", ",".join(_EXTREMES_GROUPS[group]), "--out", str(out), "--quiet"]) == 0
    units, points, outputs = read_units(out), read_points(out), read_outputs(out)
    assert len(units) == _EXTREMES_UNITS[group] and (units["unit_status"] == "ok").all()
    assert set(units["case"]) == set(_EXTREMES_GROUPS[group])
    assert (units["energy_drift"].dropna().replace(np.inf, np.nan).dropna() < 0.01).all()  # no model creates energy
    # past the training path: the points without a reference, and (issue 27) the states of the
    # reference continued past the path's top, which enter the validity radius only
    beyond = points[~points["has_reference"] | points["beyond"]]
    assert not (beyond["status"] == "ok").any()
    if group == "dome-locking":
        _extremes_dome(outputs)
    if group in ("liver-locking", "cube"):  # every static case evaluates past its training envelope
        assert len(beyond) == {"liver-locking": _PAST_PATH_LIVER, "cube": _PAST_PATH_CUBE}[group]
    if group == "explicit-and-waves":
        _extremes_explicit_and_waves(units, points)
    if group == "held-organs":
        _extremes_held_organs(units)
    if group == "liver-free-vibration":
        liver = units[units["case"] == "liver-dynamic-10x-horizon"]
        assert (abs(liver["reference_energy_drift"] + 0.198) < 0.01).all() and (liver["energy_drift"] < 0).all()
    if group != "liver-locking":
        return
    tips = []
    path_points = points.loc[~points["beyond"], ["unit_key", "point"]]  # the path's, not its continuation
    for nu in ("0.45", "0.49", "0.499", "0.4999"):
        o = outputs[(outputs["case"] == f"liver-nu{nu}") & (outputs["monitor"] == "tool_tip_uy")]
        o = o.merge(path_points, on=["unit_key", "point"])
        tips.append(-1e3 * o.dropna(subset=["reference"]).sort_values("x")["reference"].iloc[-1])
    assert tips == pytest.approx([2.40, 1.77, 0.99, 0.41], abs=0.01)
    stalled = units[units["case"] == "cornea-compression"]
    assert (stalled["reference_status"] == "stalled").all()
    dup = units[(units["case"] == "cornea-duplicated") & units["label"].str.contains("n_modes=15")]
    info = json.loads(dup["model_info"].iloc[0])
    # rank 5 on the mean-dilatation Q1 of issue 54 (4 on the locking Q1)
    assert info["n_modes"] == 5 and "rank 5 < requested 15" in info["pod_message"]


def _extremes_dome(outputs):
    """The nearly incompressible dome (issue 43): the reference's own formulation (average nodal
    pressure) against P1 asked for, at the final load: P1 locks, more at nu = 0.499 than at 0.49
    (apex at 2 N, measured: 12.62 and 10.87 mm at nu = 0.49, 12.27 and 7.73 mm at 0.499)."""
    final = outputs[outputs["monitor"] == "apex_uz"].sort_values("x").groupby("case")["reference"].last()
    for nu, bound in (("0.49", 0.9), ("0.499", 0.7)):
        assert abs(final[f"dome-p1-nu{nu}"]) < bound * abs(final[f"dome-nu{nu}"]), final
    ratio = {nu: abs(final[f"dome-p1-nu{nu}"]) / abs(final[f"dome-nu{nu}"]) for nu in ("0.49", "0.499")}
    assert ratio["0.499"] < ratio["0.49"], ratio
    # the non-locking reference barely moves between the two (the shear modulus barely changes)
    assert abs(final["dome-nu0.499"]) == pytest.approx(abs(final["dome-nu0.49"]), rel=0.1)


def _extremes_explicit_and_waves(units, points):
    """Explicit steps past the critical one on the frame blow up and are flagged within 3 steps
    (failed within 25), below it they hold; over 10x the horizon central difference conserves
    energy (frame: the direct integrator equals its reference to 1e-9; wave block: |drift| <
    1e-3 against HHT's -1.7 %), HHT and Bathe dissipate (wave block ~ -1 %; liver_dynamic's free
    vibration, in its own group: HHT reference -20 %)."""
    from tissuebench.reports.extremes import extremes_table

    by = units.set_index("case")
    ext = extremes_table(units, points).set_index("case")
    for k in ("0.5", "1"):
        case = f"frame-dt{k}x-critical"
        assert by.loc[case, "n_failed"] == 0 and ext.loc[case, "verdict"] == "pass"
    for k, dt in (("2", 2 * 0.18728527698485425), ("10", 10 * 0.18728527698485425)):
        row = ext.loc[f"frame-dt{k}x-critical"]
        assert row["verdict"] == "fail" and by.loc[f"frame-dt{k}x-critical", "n_failed"] == 1
        assert row["first_flagged_x"] <= 3 * dt + 1e-9 and row["first_failed_x"] <= 25 * dt + 1e-9
    frame = units[units["case"] == "frame-10x-horizon"].set_index("label")
    cd = frame.loc[[lbl for lbl in frame.index if "central_difference" in lbl][0]]
    assert cd["rmse_rel"] < 1e-9 and abs(cd["energy_drift"]) < 1e-5
    assert cd["energy_drift"] == pytest.approx(cd["reference_energy_drift"], abs=1e-6)
    wave = units[units["case"] == "wave-10x-horizon"].set_index("label")
    assert wave["reference_energy_drift"].iloc[0] == pytest.approx(-0.017, abs=0.002)
    for lbl, drift in wave["energy_drift"].items():
        assert (abs(drift) < 1e-3) if "central_difference" in lbl else (-0.02 < drift < -0.005), (lbl, drift)
    beam = units[units["case"] == "beam-10x-horizon"]
    assert beam["energy_message"].iloc[0] == "no constant-load window" and beam["rmse_rel"].iloc[0] < 0.01


def _extremes_held_organs(units):
    """The cube held after its pull and the ventricle held after its inflation stay put
    (reference drift < 1e-3; the ventricle's follower pressure has no potential, so the
    model's drift is undefined and says why)."""
    cube = units[units["case"] == "cube-dynamic-10x-horizon"].iloc[0]  # pulled in 1 s, held 9 s
    assert abs(cube["energy_drift"]) < 1e-3 and abs(cube["reference_energy_drift"]) < 1e-3 and cube["n_failed"] == 0
    lv = units[units["case"] == "lv-dynamic-10x-horizon"].iloc[0]  # inflated in 0.2 s, held 4.8 s
    assert lv["energy_message"] == "follower load: no load potential" and np.isnan(lv["energy_drift"])
    assert abs(lv["reference_energy_drift"]) < 1e-3 and lv["n_failed"] == 0 and lv["rmse_rel"] < 0.15


def test_wsc_lv_preset(tmp_path_factory):
    """The ventricle's dynamic inflation at ci (950 nodes): the paper's handle fraction (16
    handles) stays far from the FE history (27 % RMSE), 5 % handles with 20 % of the cells
    come within 10 % (BGBC 9.8 %, NNLS 7.6 %), every step faster than the FE step; the full
    cubature shows the subspace's own error."""
    lv = _run("wsc_lv", tmp_path_factory)
    bgbc = "wsc cubature=bgbc cubature_elements={} handles={} rtol=0.001"
    nnls = "wsc cubature=nnls cubature_elements=0.2 handles={} nnls_tol=0.05 rtol=0.001"
    assert lv.loc[("lv", bgbc.format(0.051, 0.017)), "rmse_rel"] > 0.2
    assert lv.loc[("lv", bgbc.format(0.2, 0.05)), "rmse_rel"] < 0.1
    assert lv.loc[("lv-trained", nnls.format(0.05)), "rmse_rel"] < 0.08
    # the subspace is the limit, not the cubature: every element integrated, 5 % handles
    # stay at 8.6 % (27 % with 1.7 %), and BGBC with 20 % of the cells is within 15 % of it
    full = [lv.loc[("lv", f"wsc cubature=full handles={h} rtol=0.001"), "rmse_rel"] for h in (0.017, 0.05)]
    assert full[0] > 0.2 and 0.05 < full[1] < 0.1
    assert lv.loc[("lv", bgbc.format(0.2, 0.05)), "rmse_rel"] < 1.15 * full[1]
    assert (lv["haptic_median_s"] < lv["reference_step_s"]).all()


def test_pod_galerkin_liver_preset(tmp_path_factory):
    """Issue 42 on the neo-Hookean liver in motion (ci, HHT dt 5 ms; trained at the scene's amplitude
    and half of it, measured at 0.75 of it), by the peak-normalised error: full assembly within 1 %
    with 30 modes (measured 0.25 %; 1.1 % with 20), ECSW within 5 % with 20 modes on about 120
    elements (3.1 %), DEIM within 10 % (5.9 %), the hyper-reduced models above their full-assembly
    ceiling; linear FE off by more than 10 % (17.6 %: the variant is nonlinear), the nearest snapshot
    by 30 %. wsc's units run to an end, ok or failed with the reason stated (the BGBC step matrix of
    this scene was not positive definite: a Cholesky error)."""
    folder = tmp_path_factory.mktemp("pod_galerkin_liver")
    spec = _quick_timing("pod_galerkin_liver", "*", folder / "pod_galerkin_liver.toml")
    assert main(["sweep", str(spec), "--out", str(folder / "out"), "--quiet"]) in (0, 1)
    units = read_units(folder / "out").set_index("label")
    mine = units[units["method"] == "pod_galerkin"]
    assert (mine["unit_status"] == "ok").all() and (mine["n_failed"] == 0).all(), mine["message"].tolist()
    err = mine["peak_rel_l2"]
    none = "pod_galerkin hyper=none n_modes={}"
    assert err[none.format(30)] <= 0.01 < err[none.format(20)] < 0.02
    ecsw = err["pod_galerkin hyper=ecsw n_modes=20"]
    assert err[none.format(20)] < ecsw <= 0.05
    assert json.loads(mine.loc["pod_galerkin hyper=ecsw n_modes=20", "model_info"])["hyper"]["elements"] <= 150
    assert err["pod_galerkin ecsw_tol=0.002 hyper=ecsw n_modes=30"] < ecsw
    assert err["pod_galerkin hyper=deim n_modes=20"] <= 0.1
    assert units.loc["linear_fe", "peak_rel_l2"] > 0.1 and units.loc["nearest", "peak_rel_l2"] > 0.2
    wsc = units[units["method"] == "wsc"]
    assert len(wsc) == 2 and all(s == "ok" or m for s, m in zip(wsc["unit_status"], wsc["message"]))
