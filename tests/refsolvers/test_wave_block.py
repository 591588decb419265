"""Wave in a block (pgd-pod §6.1-6.2): 1D wave-front verification, cross-backend
agreement, the long-time stability study at small size; and the volume-mesh reader
(:mod:`tissuebench.cases.io`) that the liver cases use.

The problem builder lives in ``examples/wave_block_stability.py`` (self-contained until
the case catalogue takes it over); it is loaded here by path.

Why a 1 x 1 x 40 hexahedral column for the wave front: with the normal displacement
fixed on the four lateral faces and a uniform top load, the exact solution is 1D
(uniaxial strain, u = u_z(z, t)), and one Q1 cell across makes the FE model exactly that
1D column. Along z, at the paper's dt = 0.00125 s the front moves c dt = 0.555 m per
step, so the time discretisation limits how sharp the front can be: the arrival time and
top displacement do not change between nz = 40 (h = 0.25 m, c dt / h = 2.2) and
nz = 160 (measured: fitted arrival 0.01120 s vs 0.01117 s), while nz = 20 is still
coarse in space. nz = 40 keeps each run well below a second.
"""
from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import meshio
import numpy as np
import pytest

from tissuebench.cases.io import DATA_ENV, PACKAGE_DATA_DIR, data_dir, liver_mesh_path, read_mesh
from tissuebench.refsolvers.dynamics import integrate

ROOT = Path(__file__).resolve().parents[2]


def _load_example():
    name = "wave_block_stability"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, ROOT / "examples" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


wb = _load_example()

H = wb.LENGTHS[2]                  # 10 m
C = wb.p_wave_speed()              # 443.9 m/s
T_MID = 0.5 * H / C                # 0.01126 s: arrival of the front at mid-height
T_REFLECT = 2 * H / C              # 0.04505 s: reflected front back at the top


def test_case_data():
    assert C == pytest.approx(443.9, abs=0.05)
    assert T_MID == pytest.approx(0.01126, abs=5e-6)


def test_column_solution_is_consistent():
    """The analytical 1D solution: u = 0 at the bottom, top triangle wave, static mean."""
    lam, mu = wb.lame()
    M = lam + 2 * mu
    t = np.linspace(0, 4 * H / C, 401)
    assert np.all(wb.column_displacement(0.0, t) == 0)
    top = wb.column_top_displacement(t)
    early = t <= T_REFLECT
    np.testing.assert_allclose(top[early], -wb.PRESSURE * C * t[early] / M, rtol=1e-12, atol=1e-18)
    assert top.min() == pytest.approx(-2 * wb.PRESSURE * H / M, rel=1e-12)
    assert wb.column_top_displacement(4 * H / C) == pytest.approx(0.0, abs=1e-15)
    # front at mid-height: zero before T_MID, ramp of slope p c / M after
    assert wb.column_displacement(H / 2, 0.99 * T_MID) == 0.0
    assert wb.column_displacement(H / 2, 2 * T_MID) == pytest.approx(-wb.PRESSURE * C * T_MID / M, rel=1e-12)


@pytest.fixture(scope="module")
def column_run():
    """HHT(alpha=-0.05), dt = 0.00125 s on the 1 x 1 x 40 column, over 0.1 s (> 4 H / c)."""
    problem = wb.wave_block_problem("linear", (1, 1, 40), "Q1")
    _, system = wb.wave_block_system(problem, "skfem")
    mid = wb.node_at(problem, (0.0, 0.0, H / 2))
    top = wb.node_at(problem, (0.0, 0.0, H))
    assert problem.nodes[mid, 2] == pytest.approx(H / 2) and problem.nodes[top, 2] == pytest.approx(H)
    res = integrate(system, None, None, wb.DT, 0.1, method="hht", alpha=wb.HHT_ALPHA,
                    dofs=[3 * mid + 2, 3 * top + 2])
    assert res.success, res.message
    return res


def arrival_time_fit(t, u, t_mid=T_MID, window=(0.25, 0.75)):
    """Arrival time of the front at a point: the zero of a straight line fitted to u(t)
    over the middle of its ramp (after the front, before the wave reflected at the bottom
    comes back, which takes H / c: t_mid + [0.25, 0.75] * H / c). The fit uses the mean slope, so it measures where the
    front's centre passed, unlike a threshold crossing which the smeared front delays."""
    span = H / C
    w = (t > t_mid + window[0] * span) & (t < t_mid + window[1] * span)
    slope, icpt = np.polyfit(t[w], u[w], 1)
    return -icpt / slope, slope


def test_front_reaches_mid_height(column_run):
    res = column_run
    lam, mu = wb.lame()
    t_arr, slope = arrival_time_fit(res.t, res.u[:, 0])
    assert t_arr == pytest.approx(T_MID, rel=0.05)
    assert t_arr == pytest.approx(T_MID, rel=0.02)  # measured: 0.01120 s
    # the ramp's slope is the particle velocity behind the front, p / (rho c)
    assert slope == pytest.approx(-wb.PRESSURE / (wb.DENSITY * C), rel=0.02)
    # nothing arrives before the front (up to the scheme's small precursor)
    before = res.t < 0.5 * T_MID
    assert np.max(np.abs(res.u[before, 0])) < 0.05 * wb.PRESSURE * C * T_MID / (lam + 2 * mu)


def test_front_half_velocity_crossing_with_smaller_step():
    """Second measure: time at which v_z at mid-height reaches half the particle velocity
    p / (rho c). The threshold crossing sees the smearing of the front by the time step
    (0.0119 s = +6 % at dt = 0.00125 s), so it is checked with dt / 4 on an 80-cell column."""
    problem = wb.wave_block_problem("linear", (1, 1, 80), "Q1")
    _, system = wb.wave_block_system(problem, "skfem")
    mid = wb.node_at(problem, (0.0, 0.0, H / 2))
    res = integrate(system, None, None, wb.DT / 4, 0.03, method="hht", alpha=wb.HHT_ALPHA,
                    dofs=[3 * mid + 2])
    v_half = -0.5 * wb.PRESSURE / (wb.DENSITY * C)
    v, t = res.v[:, 0], res.t
    k = int(np.argmax(v <= v_half))
    assert k > 0
    t_cross = t[k - 1] + (v_half - v[k - 1]) * (t[k] - t[k - 1]) / (v[k] - v[k - 1])
    assert t_cross == pytest.approx(T_MID, rel=0.05)  # measured: 0.01150 s (+2.1 %)


def test_top_displacement_matches_1d_solution(column_run):
    """u_z at the top = -p c t / (lambda + 2 mu) until the reflection returns (t = 2H/c),
    then the triangle wave: peak 2 p H / (lambda + 2 mu) at t = 2H/c."""
    res = column_run
    t, top = res.t, res.u[:, 1]
    exact = wb.column_top_displacement(t)
    lam, mu = wb.lame()
    peak = 2 * wb.PRESSURE * H / (lam + 2 * mu)
    ramp = t <= T_REFLECT
    assert np.max(np.abs(top[ramp] - exact[ramp])) < 0.04 * peak  # measured: 2.9 %
    # slope of the ramp before reflection (least squares over its middle part)
    w = (t > 0.2 * T_REFLECT) & (t < 0.8 * T_REFLECT)
    assert np.polyfit(t[w], top[w], 1)[0] == pytest.approx(-wb.PRESSURE / (wb.DENSITY * C), rel=0.02)
    # amplitude after the reflection: the peak of the step response, and the static mean
    assert -top.min() == pytest.approx(peak, rel=0.04)  # measured: 0.974 x
    first_period = t <= 4 * H / C
    assert np.mean(top[first_period]) == pytest.approx(-peak / 2, rel=0.03)


def test_block_3d_tets_follow_the_column():
    """The P1 tetrahedral block (lateral motion possible in principle) reproduces the 1D
    response at the centre of the top face within a few per cent."""
    problem = wb.wave_block_problem("linear", (2, 2, 16), "P1")
    _, system = wb.wave_block_system(problem, "skfem")
    top = wb.node_at(problem, (2.5, 2.5, H))
    res = integrate(system, None, None, wb.DT, T_REFLECT, method="hht", alpha=wb.HHT_ALPHA,
                    dofs=[3 * top, 3 * top + 1, 3 * top + 2])
    assert res.success
    exact = wb.column_top_displacement(res.t)
    scale = np.max(np.abs(exact))
    assert np.max(np.abs(res.u[:, 2] - exact)) < 0.05 * scale
    # the 6-tet split of a hexahedron is not symmetric: its lateral forces do not cancel
    # between layers of different strain, a discretisation effect (measured 0.9 %)
    assert np.max(np.abs(res.u[:, :2])) < 0.02 * scale


# ------------------------------------------------------------------ cross-backend
@pytest.mark.ngsolve
@pytest.mark.parametrize("material, tol", [("linear", 1e-8), ("svk", 1e-6)])
@pytest.mark.parametrize("element", ["P1", "Q1"])
@pytest.mark.parametrize("method", ["hht", "bathe"])
def test_backends_give_the_same_trajectory(element, material, tol, method):
    """skfem and NGSolve on the same 2 x 2 x 4 block, 24 steps: same u, v and energies
    (SPEC: 1e-8 linear, 1e-6 nonlinear; measured ~1e-12 and ~1e-15)."""
    problem = wb.wave_block_problem(material, (2, 2, 4), element)
    opts = {"alpha": wb.HHT_ALPHA} if method == "hht" else {}
    runs = {}
    for name, bopts in (("skfem", {}), ("ngsolve", {"threads": 1})):
        _, system = wb.wave_block_system(problem, name, **bopts)
        runs[name] = integrate(system, None, None, wb.DT, 0.03, method=method, **opts)
        assert runs[name].success, runs[name].message
    a, b = runs["skfem"], runs["ngsolve"]
    assert np.linalg.norm(a.u - b.u) <= tol * np.linalg.norm(a.u)
    assert np.linalg.norm(a.v - b.v) <= tol * np.linalg.norm(a.v)
    np.testing.assert_allclose(b.total_energy, a.total_energy, rtol=tol, atol=tol * a.total_energy.max())


# ------------------------------------------------------------------ stability study
@pytest.mark.slow  # ~9 s: the default run keeps the block's integrators by the tests above
def test_stability_study_small(tmp_path):
    """SVK block, 1 x 1 x 8 hexes, 0.5 s (400 steps), trapezoidal vs Bathe vs HHT."""
    out = wb.run_study(tmp_path / "study", t_end=0.5, divisions=(1, 1, 8), verbose=False)
    paths = out["paths"]
    for key in ("energy", "summary", "plot"):
        assert paths[key].is_file() and paths[key].stat().st_size > 0
    import pandas as pd

    energy = pd.read_csv(paths["energy"])
    for col in ("method", "t", "kinetic", "strain", "external_work", "energy_error"):
        assert col in energy.columns
    assert set(energy["method"]) == {"newmark", "bathe", "hht"}
    assert len(energy) == 3 * 401
    summary = out["summary"].set_index("method")
    assert (summary["status"] == "success").all()
    np.testing.assert_allclose(summary["t_reached"], 0.5)
    # Bathe: bounded, dissipative energy error (measured: -1.26e-2 of the largest energy)
    bathe = energy[energy["method"] == "bathe"]
    scale = max(np.max(np.abs(bathe["kinetic"] + bathe["strain"])), np.max(np.abs(bathe["external_work"])))
    assert np.max(np.abs(bathe["energy_error"])) / scale < 0.05
    assert np.max(bathe["energy_error"]) / scale < 1e-6  # never creates energy
    assert summary.loc["bathe", "energy_growth_ratio"] <= 1.0 + 1e-6
    # trapezoidal rule: conserves the balance to Newton tolerance (measured 6.5e-7)
    assert summary.loc["newmark", "max_abs_relative_energy_error"] < 1e-4
    # HHT(alpha=-0.05): dissipative, bounded (measured -1.4e-2)
    assert summary.loc["hht", "max_abs_relative_energy_error"] < 0.05
    assert summary.loc["hht", "final_relative_energy_error"] < 0


def test_study_cli_writes_files(tmp_path):
    rc = wb.main(["--t-end", "0.02", "--divisions", "1,1,4", "--out", str(tmp_path), "--methods", "bathe,hht"])
    assert rc == 0
    assert (tmp_path / "energy.csv").is_file() and (tmp_path / "energy_error.png").is_file()
    with pytest.raises(SystemExit):
        wb.main(["--methods", "rk4", "--out", str(tmp_path)])


def test_problem_builder_rejects_bad_input():
    with pytest.raises(ValueError, match="material"):
        wb.wave_block_problem("rubber")
    with pytest.raises(ValueError, match="element"):
        wb.wave_block_problem("linear", element="P2")


# ------------------------------------------------------------------ mesh reader
def test_data_dir_default_and_override(monkeypatch, tmp_path):
    monkeypatch.delenv(DATA_ENV, raising=False)
    # the default is inside the package: a clone or a wheel needs nothing beside it
    assert data_dir() == PACKAGE_DATA_DIR == ROOT / "tissuebench" / "data"
    assert liver_mesh_path(must_exist=True) == PACKAGE_DATA_DIR / "liver" / "liver_tet.vtu"
    monkeypatch.setenv(DATA_ENV, str(tmp_path))
    assert data_dir(must_exist=True) == tmp_path
    assert liver_mesh_path() == tmp_path / "liver" / "liver_tet.vtu"
    monkeypatch.setenv(DATA_ENV, str(tmp_path / "missing"))
    with pytest.raises(FileNotFoundError, match="missing"):
        data_dir(must_exist=True)


def test_shipped_liver_mesh_is_the_documented_file(monkeypatch):
    import hashlib

    monkeypatch.delenv(DATA_ENV, raising=False)
    path = liver_mesh_path(must_exist=True)
    readme = (path.parent / "README.md").read_text()
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert digest in readme and "LGPL" in readme  # source, licence and checksum stated beside it


def test_read_liver_mesh(monkeypatch):
    monkeypatch.delenv(DATA_ENV, raising=False)
    mesh = read_mesh(liver_mesh_path(must_exist=True))
    assert mesh.cell_type == "tetra"
    assert (mesh.n_vertices, mesh.n_cells) == (2866, 10995)
    assert mesh.n_reoriented == mesh.n_cells  # every tet of the file is negatively oriented
    assert np.all(mesh.cell_volumes() > 0)
    # millimetres: ~194 x 154 x 156 mm, ~1.46 L
    assert np.ptp(mesh.points, axis=0) == pytest.approx([194.2, 153.1, 156.1], abs=1.0)
    assert mesh.cell_volumes().sum() == pytest.approx(1.458e6, rel=0.01)


def _tet_points():
    return np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)


def test_read_mesh_ignores_other_blocks_and_unused_points(tmp_path):
    pts = np.vstack([_tet_points(), [[5.0, 5.0, 5.0]]])  # point 5 only in a vertex block
    cells = [("triangle", np.array([[0, 1, 2]])), ("tetra", np.array([[0, 2, 1, 3]])),
             ("vertex", np.array([[5]])), ("tetra", np.array([[1, 2, 3, 4]]))]
    path = tmp_path / "mixed.vtu"
    meshio.write(path, meshio.Mesh(pts, cells))
    mesh = read_mesh(path)
    assert mesh.n_cells == 2 and mesh.n_vertices == 5
    assert mesh.n_reoriented == 1
    assert np.all(mesh.cell_volumes() > 0)


def test_read_hexahedra(tmp_path):
    from tissuebench.cases.meshes import box_mesh

    box = box_mesh((1, 2, 3), (2, 1, 3), "hexahedron")
    path = tmp_path / "box.vtk"
    meshio.write(path, meshio.Mesh(box.points, [("hexahedron", box.cells)]))
    mesh = read_mesh(path)
    assert mesh.cell_type == "hexahedron" and mesh.n_cells == 6
    assert mesh.cell_volumes().sum() == pytest.approx(6.0)


def test_read_mesh_errors_name_the_path(tmp_path):
    missing = tmp_path / "nope.vtu"
    with pytest.raises(FileNotFoundError, match="nope.vtu"):
        read_mesh(missing)
    surf = tmp_path / "surface.vtu"
    meshio.write(surf, meshio.Mesh(_tet_points(), [("triangle", np.array([[0, 1, 2], [0, 1, 3]]))]))
    with pytest.raises(ValueError, match=r"surface\.vtu.*no volume cells"):
        read_mesh(surf)
    flat = tmp_path / "flat.vtu"
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 0, 1]], float)
    meshio.write(flat, meshio.Mesh(pts, [("tetra", np.array([[0, 1, 2, 4], [0, 1, 2, 3]]))]))
    with pytest.raises(ValueError, match=r"flat\.vtu.*zero volume"):
        read_mesh(flat)
    garbage = tmp_path / "garbage.vtu"
    garbage.write_text("not a mesh")
    with pytest.raises(ValueError, match="garbage.vtu"):
        read_mesh(garbage)
