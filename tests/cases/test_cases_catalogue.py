"""The case catalogue: scene files load and validate, FE scenes build their Problem,
bad scenes fail naming the key, and the mesh builders have the stated geometry."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from tissuebench.cases import builders, scene
from tissuebench.cases.scene import list_cases, load

CASES = ["cornea_pinch", "liver_palpation", "heat1d_source", "cornea_cut", "cube_tension_twist",
         "left_ventricle", "land_beam", "frame_2dof", "clamped_beam", "wave_block", "liver_dynamic"]
NON_FE = {"heat1d_source", "frame_2dof", "clamped_beam"}


def _all_variants():
    out = []
    for name in CASES:
        s = load(name)
        out += [(name, v) for v in (s.variants or (None,))]
    return out


@pytest.fixture(scope="module")
def scenes():
    return {(n, v): load(n, "ci", variant=v) for n, v in _all_variants()}


def test_catalogue_is_complete():
    assert sorted(list_cases()) == sorted(CASES)


@pytest.mark.parametrize("name", CASES)
@pytest.mark.parametrize("resolution", ["ci", "paper"])
def test_scene_loads_and_validates(name, resolution):
    s = load(name, resolution)
    assert s.name == name and s.resolution == resolution
    assert s.case["paper"] and s.case["description"] and s.units["length"]
    assert s.dirichlet and s.analysis["type"] in ("static", "dynamic")
    assert s.is_fe == (name not in NON_FE)
    assert isinstance(s.paper, dict) and s.paper
    for ld in s.loads:
        h = scene.History(ld["history"])
        assert np.isfinite(h(np.linspace(0, 1, 5))).all()


@pytest.mark.parametrize("key", [k for k in _all_variants() if k[0] not in NON_FE],
                         ids=lambda k: f"{k[0]}-{k[1]}")
def test_fe_scene_builds_problem(scenes, key):
    s = scenes[key]
    pb = s.to_problem()  # Problem refuses a constraint set that leaves a rigid mode free
    assert pb.mesh.n_cells > 0 and np.all(pb.mesh.cell_volumes() > 0)
    assert pb.fixed_dofs.size > 0 and pb.free_dofs.size > 0
    if s.loads:
        assert len(pb.loads) == len(s.loads)
        for ld in pb.loads:
            if hasattr(ld, "facets"):
                assert len(pb.facets_of(ld)) > 0
        f = pb.point_load_vector()
        total = sum(np.asarray(ld["value"]) for ld in s.loads if ld["type"] == "point")
        assert np.allclose(f.reshape(-1, 3).sum(axis=0), total)
    # monitors that need no solve evaluate on the undeformed state
    vals = s.evaluate_monitors(pb, np.zeros(pb.ndof), reactions=np.zeros(pb.ndof))
    assert set(vals) == {m["name"] for m in s.monitors}
    if "volume_ratio" in vals:
        assert vals["volume_ratio"] == pytest.approx(1.0)


@pytest.mark.parametrize("name", sorted(NON_FE))
def test_line_models(name):
    s = load(name)
    lm = s.line_model()
    assert lm.fixed and lm.loads
    assert all(idx.size == 1 for idx, _ in lm.fixed)
    with pytest.raises(ValueError, match="not a finite-element scene"):
        s.to_problem()


def test_cube_tension_matches_bar_case(scenes):
    from tissuebench.cases.bar import bar_tension

    ref = bar_tension("ci").problem
    pb = scenes[("cube_tension_twist", "tension")].to_problem()
    assert np.allclose(pb.mesh.points, ref.mesh.points) and np.array_equal(pb.mesh.cells, ref.mesh.cells)
    for k in ("mu1", "mu2", "kappa"):
        assert getattr(pb.material, k) == pytest.approx(getattr(ref.material, k), rel=1e-12)
    assert type(pb.material) is type(ref.material) and pb.density == ref.density
    order, order_ref = np.argsort(pb.fixed_dofs), np.argsort(ref.fixed_dofs)
    assert np.array_equal(pb.fixed_dofs[order], ref.fixed_dofs[order_ref])
    assert np.allclose(pb.prescribed_values(0.7)[order], ref.prescribed_values(0.7)[order_ref])


def test_twist_is_a_rigid_rotation_of_the_end(scenes):
    s = scenes[("cube_tension_twist", "twist")]
    pb = s.to_problem()
    for factor, angle in ((1.0, math.pi / 2), (0.5, math.pi / 4)):
        dofs, vals = pb.fixed_dofs, pb.prescribed_values(factor)
        nodes = dofs // 3
        end = np.isclose(pb.nodes[nodes, 0], 0.08)
        X = pb.nodes[nodes[end]] - [0.08, 0.01, 0.01]
        comp = dofs[end] % 3
        rot = np.column_stack([X[:, 0], math.cos(angle) * X[:, 1] - math.sin(angle) * X[:, 2],
                               math.sin(angle) * X[:, 1] + math.cos(angle) * X[:, 2]])
        assert np.allclose(vals[end], (rot - X)[np.arange(len(X)), comp])


def test_histories():
    H = scene.History
    assert H({"type": "ramp", "t0": 0.0, "t1": 2.0})(1.0) == pytest.approx(0.5)
    assert H({"type": "step", "t0": 0.0})(0.0) == 1.0 and H({"type": "step", "t0": 0.1})(0.05) == 0.0
    rhr = H({"type": "ramp_hold_release", "t_ramp": 0.25, "t_hold": 0.0, "t_release": 0.25})
    assert np.allclose(rhr(np.array([0.0, 0.125, 0.25, 0.375, 0.5, 0.8])), [0, 0.5, 1, 0.5, 0, 0])
    assert H({"type": "sine", "frequency": 1.0})(0.25) == pytest.approx(1.0)
    assert H({"type": "tabulated", "t": [0.0, 1.0], "values": [0.0, 3.0]})(0.5) == pytest.approx(1.5)
    s = load("liver_dynamic")
    assert s.history(0.25) == pytest.approx(1.0) and s.history(0.6) == 0.0


# ------------------------------------------------------------------ bad scenes
BASE = """
[case]
name = "tmp"
paper = "none"
description = "a bad scene"
[units]
length = "m"
[mesh]
builder = "box"
element = "P1"
[mesh.params]
lengths = [1.0, 1.0, 1.0]
[mesh.ci]
divisions = [1, 1, 1]
[mesh.paper]
divisions = [2, 2, 2]
[material]
name = "svk"
E = {E}
nu = {nu}
[[dirichlet]]
region = {{ plane = "x", value = 0.0 }}
[analysis]
type = "dynamic"
integrator = "hht"
dt = {dt}
t_end = 1.0
{extra}
"""


def _write(tmp_path, E="1.0", nu="0.3", dt="0.01", extra=""):
    p = tmp_path / "tmp.toml"
    p.write_text(BASE.format(E=E, nu=nu, dt=dt, extra=extra))
    return p


def test_good_temp_scene_loads(tmp_path):
    s = load(_write(tmp_path))
    assert s.to_problem().mesh.n_cells == 6


@pytest.mark.parametrize("kw, key", [
    (dict(E='"abc"'), "material.E"),
    (dict(E="-1.0"), "material.E"),
    (dict(nu="0.7"), "material.nu"),
    (dict(dt="0.0"), "analysis.dt"),
    (dict(dt="-0.1"), "analysis.dt"),
    (dict(extra="[monitor]\nfoo = 1"), "monitor"),
    (dict(extra="[[load]]\ntype = \"point\"\nregion = { nearest = [0.0, 0.0, 0.0] }\nvalue = [1.0, 0.0]"),
     "load[0].value"),
    (dict(extra="[[load]]\ntype = \"magic\"\nvalue = 1.0"), "load[0].type"),
    (dict(extra="[[load]]\ntype = \"point\"\nregion = { plane = \"x\" }\nvalue = [1.0, 0.0, 0.0]"),
     "load[0].region.value"),
    (dict(extra="[[load]]\ntype = \"point\"\nregion = { nearest = [0.0, 0.0, 0.0] }\n"
                "value = [1.0, 0.0, 0.0]\nhistory = { type = \"ramp\", t1 = -1.0 }"), "load[0].history.t1"),
    (dict(extra="[wibble]\na = 1"), "wibble"),
])
def test_bad_scene_names_the_key(tmp_path, kw, key):
    with pytest.raises(ValueError, match=key.replace("[", r"\[").replace("]", r"\]")):
        load(_write(tmp_path, **kw))


def test_unknown_and_missing_keys(tmp_path):
    p = _write(tmp_path)
    text = p.read_text()
    p.write_text(text.replace('nu = 0.3', 'nu = 0.3\nYoung = 3.0'))
    with pytest.raises(ValueError, match="material.Young: unknown key"):
        load(p)
    p.write_text(text.replace('E = 1.0\n', ''))
    with pytest.raises(ValueError, match="material.E: missing"):
        load(p)
    p.write_text(text.replace('integrator = "hht"', 'integrator = "rk4"'))
    with pytest.raises(ValueError, match="analysis.integrator"):
        load(p)


def test_missing_mesh_path(tmp_path):
    p = _write(tmp_path)
    p.write_text(p.read_text().replace('builder = "box"', 'builder = "liver"')
                 .replace("lengths = [1.0, 1.0, 1.0]", "scale = 1.0").replace("divisions = [2, 2, 2]", "")
                 .replace("divisions = [1, 1, 1]", f'path = "{tmp_path / "nope.vtu"}"'))
    with pytest.raises(FileNotFoundError, match=r"mesh.ci.path = .*nope.vtu.*does not exist"):
        load(p)


def test_unknown_case_lists_valid_names():
    with pytest.raises(ValueError, match="unknown case 'kidney'.*cornea_pinch"):
        load("kidney")
    with pytest.raises(ValueError, match="resolution"):
        load("cornea_pinch", "huge")
    with pytest.raises(ValueError, match="variant"):
        load("wave_block", variant="ogden")


# ------------------------------------------------------------------ geometry
def _cornea_checks(b):
    m = b.mesh
    r = np.linalg.norm(m.points - b.info["centre"], axis=1)
    assert (r.min() + r.max()) / 2 == pytest.approx(7.8, abs=0.1)
    assert r.max() - r.min() == pytest.approx(0.55, abs=0.02)
    base = np.abs(m.points[:, 2]) < 1e-9
    rb = np.linalg.norm(m.points[base, :2], axis=1)
    assert rb.min() + rb.max() == pytest.approx(11.5, abs=0.2)  # mid-surface base diameter
    assert np.all(builders.hex_corner_jacobians(m) > 0) and m.n_reoriented == 0


def test_cornea_dome_ci():
    s = load("cornea_pinch")
    _cornea_checks(s.built)
    assert s.mesh.cell_type == "hexahedron"
    pinched = s.to_problem().loads[0].nodes
    assert len(pinched) == 9


def test_cornea_dome_paper_resolution():
    b = builders.cornea_dome(**load("cornea_pinch", "paper").mesh_spec["params"])
    assert b.mesh.n_vertices == pytest.approx(8514, rel=0.10)
    _cornea_checks(b)


def test_loading_a_scene_does_not_build_its_mesh(monkeypatch):
    """Validating a scene is cheap because it does not mesh (netgen and the paper meshes are
    slow): load() of every case and variant at both resolutions calls no builder; the mesh is
    built once, on first use, and shared by mesh, mesh_info and to_problem()."""
    calls = []

    def spy(name, real):
        def builder(**params):
            calls.append(name)
            return real(**params)
        return builder

    for name, real in list(builders.BUILDERS.items()):
        monkeypatch.setitem(builders.BUILDERS, name, spy(name, real))
    for name, variant in _all_variants():
        for resolution in ("ci", "paper"):
            s = load(name, resolution, variant=variant)
            assert s.mesh_spec["builder"] in builders.BUILDERS
    assert calls == []
    s = load("cornea_pinch", "paper")
    assert s.mesh.n_vertices == pytest.approx(8514, rel=0.10)
    s.mesh_info, s.to_problem()
    assert calls == ["cornea_dome"]


def test_lv_wall_volume(scenes):
    s = scenes[("left_ventricle", "guccione")]
    V = builders.truncated_spheroid_volume
    exact = V(10, 20, 5) - V(7, 17, 5)
    assert s.mesh.cell_volumes().sum() == pytest.approx(exact, rel=0.03)
    p = s.mesh.points
    assert p[:, 2].max() == pytest.approx(5.0) and p[:, 2].min() == pytest.approx(-20.0, abs=0.2)


def test_liver_from_shipped_file(scenes):
    s = scenes[("liver_palpation", None)]
    assert s.mesh.n_vertices == pytest.approx(2866, rel=0.02)
    assert not s.mesh_info["fallback"]
    assert np.ptp(s.mesh.points, axis=0).max() == pytest.approx(0.194, rel=0.05)  # mm -> m


def test_liver_fallback_without_data(tmp_path, monkeypatch):
    monkeypatch.setenv("TISSUEBENCH_DATA", str(tmp_path))
    s = load("liver_palpation")
    with pytest.warns(UserWarning, match="fallback"):
        info = s.mesh_info
    assert info["fallback"] is True
    pb = s.to_problem()
    assert pb.mesh.n_vertices > 100 and len(pb.loads) == 1


def test_liver_reads_any_volume_mesh(tmp_path):
    import meshio

    m = builders.box((1.0, 2.0, 3.0), (2, 2, 2)).mesh
    path = tmp_path / "organ.vtk"
    meshio.write(path, meshio.Mesh(m.points, [("tetra", m.cells)]))
    b = builders.liver(path=str(path), scale=2.0)
    assert b.mesh.n_cells == m.n_cells and np.ptp(b.mesh.points[:, 2]) == pytest.approx(6.0)
    with pytest.raises(FileNotFoundError, match="missing.vtu"):
        builders.liver(path=str(tmp_path / "missing.vtu"))


def test_liver_tetrahedralises_a_surface(tmp_path):
    import meshio

    m = builders.box((1.0, 1.0, 1.0), (1, 1, 1), "hexahedron").mesh
    f = m.boundary_facets
    tris = np.vstack([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
    path = tmp_path / "cube.stl"
    meshio.write(path, meshio.Mesh(m.points, [("triangle", tris)]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        b = builders.liver(path=str(path), maxh=0.5)
    assert b.info["tetrahedralised"] and b.mesh.cell_volumes().sum() == pytest.approx(1.0, rel=1e-6)


def test_scene_at_mu_changes_what_it_names_and_the_hash():
    liver = load("liver_palpation")
    base = liver.content_hash()
    moved = liver.at({"position": 0.4, "max_load_factor": 1.0, "load_steps": 4})
    assert moved.loads[0]["region"] == {"nearest": [0.4, 1.0, 0.5], "frame": "bbox"}
    assert moved.loads[0]["distribute"] == "interpolate"
    assert (moved.analysis["max_load_factor"], moved.analysis["load_steps"]) == (1.0, 4)
    assert not moved.analysis["stop_at_divergence"]
    soft = liver.at({"nu": 0.499})
    assert soft.material["nu"] == 0.499 and liver.material["nu"] == 0.48
    scaled = liver.at({"load_scale": 2.0})
    assert scaled.loads[0]["value"] == [0.0, -2.4, 0.0]
    hashes = {base, moved.content_hash(), soft.content_hash(), scaled.content_hash(),
              liver.at({"position": 0.41}).content_hash()}
    assert len(hashes) == 5 and load("liver_palpation").content_hash() == base
    with pytest.raises(ValueError, match=r"mu.nope = 1: not a parameter of this scene; valid keys: \["):
        liver.at({"nope": 1})
    with pytest.raises(ValueError, match=r"nu = 0.5: expected a Poisson ratio"):
        liver.at({"nu": 0.5})
    with pytest.raises(ValueError, match="declares no \\[parameters.position\\]"):
        load("cube_tension_twist").at({"position": 0.1})


def test_the_mesh_file_is_part_of_the_scene_hash(tmp_path, monkeypatch):
    import shutil

    from tissuebench.cases.io import PACKAGE_DATA_DIR

    base = load("liver_palpation").content_hash()
    (tmp_path / "liver").mkdir()
    shutil.copy(PACKAGE_DATA_DIR / "liver" / "liver_tet.vtu", tmp_path / "liver" / "liver_tet.vtu")
    monkeypatch.setenv("TISSUEBENCH_DATA", str(tmp_path))
    assert load("liver_palpation").content_hash() == base  # same bytes elsewhere: same scene
    with open(tmp_path / "liver" / "liver_tet.vtu", "ab") as fh:
        fh.write(b"\n")
    assert load("liver_palpation").content_hash() != base  # another mesh source: another scene
