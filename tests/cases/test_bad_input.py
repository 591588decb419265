"""Bad input is refused with a ValueError naming the field and the offending value;
solver failures are reported as data (status, last converged state), never as NaN."""
from __future__ import annotations

import re

import numpy as np
import pytest

from _fe_helpers import BACKEND_PARAMS, element_mesh, on_plane
from tissuebench.cases.io import liver_mesh_path
from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.materials import (Guccione, LinearElastic, MooneyRivlin, NeoHookean,
                                              SaintVenantKirchhoff, make_material)
from tissuebench.refsolvers.mesh import Mesh
from tissuebench.refsolvers.newton import NewtonError, newton_solve
from tissuebench.refsolvers.problem import (Dirichlet, FollowerPressure, PointLoad, Problem,
                                            SurfaceTraction)


CLAMP = Dirichlet(lambda x: x[:, 0] < 1e-9)


def unit_tet_mesh():
    return box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "tetra")


# --------------------------------------------------------------------------- materials
@pytest.mark.parametrize("cls", [LinearElastic, SaintVenantKirchhoff, NeoHookean])
@pytest.mark.parametrize("E", [0.0, -1.0, float("nan"), float("inf")])
def test_young_modulus_not_positive(cls, E):
    with pytest.raises(ValueError, match=rf"\bE\b.*{re.escape(repr(E))}"):
        cls(E=E, nu=0.3)


@pytest.mark.parametrize("cls", [LinearElastic, SaintVenantKirchhoff, NeoHookean])
@pytest.mark.parametrize("nu", [-1.0, -1.5, 0.5, 0.7])
def test_poisson_ratio_out_of_range(cls, nu):
    with pytest.raises(ValueError, match=rf"\bnu\b.*{re.escape(repr(nu))}"):
        cls(E=1.0, nu=nu)


def test_poisson_ratio_limits_inside_are_accepted():
    LinearElastic(E=1.0, nu=-0.999)
    NeoHookean(E=1.0, nu=0.4999)


@pytest.mark.parametrize("kappa", [0.0, -2.0])
def test_bulk_modulus_not_positive(kappa):
    with pytest.raises(ValueError, match=rf"\bkappa\b.*{re.escape(repr(kappa))}"):
        MooneyRivlin(mu1=1.0, mu2=0.5, kappa=kappa)
    with pytest.raises(ValueError, match=rf"\bkappa\b.*{re.escape(repr(kappa))}"):
        Guccione(C=1.0, bf=8.0, bt=2.0, bfs=4.0, kappa=kappa)


def test_mooney_rivlin_negative_mu2():
    with pytest.raises(ValueError, match=r"\bmu2\b.*-0\.5"):
        MooneyRivlin(mu1=1.0, mu2=-0.5, kappa=1.0)


def test_make_material_checks_through():
    with pytest.raises(ValueError, match=r"\bE\b.*-3"):
        make_material("svk", E=-3.0, nu=0.3)
    with pytest.raises(ValueError, match=r"\bnu\b.*0\.5"):
        make_material("neo_hookean", E=1.0, nu=0.5)


def test_unknown_material_name():
    with pytest.raises(ValueError, match=r"material.*'rubber'"):
        make_material("rubber", E=1.0, nu=0.3)


def test_material_wrong_parameter_name_is_value_error():
    with pytest.raises(ValueError, match=r"'linear'.*young"):
        make_material("linear", young=1.0, nu=0.3)


# --------------------------------------------------------------------------- meshes
def test_zero_volume_tetrahedron():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float)  # coplanar
    with pytest.raises(ValueError, match=r"cells\[0\] = \[0, 1, 2, 3\].*zero volume"):
        Mesh(pts, [[0, 1, 2, 3]], "tetra")


def test_negative_tetrahedron_is_reoriented():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    m = Mesh(pts, [[0, 2, 1, 3]], "tetra")
    assert m.n_reoriented == 1 and m.cell_volumes()[0] == pytest.approx(1 / 6)


def test_tangled_hexahedron():
    m = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "hexahedron")
    pts = m.points.copy()
    cells = m.cells.copy()
    # swap two top vertices: a bow-tie top face, corner Jacobians of both signs
    cells[0, [6, 7]] = cells[0, [7, 6]]
    with pytest.raises(ValueError, match=r"cells\[0\] = \[.*\].*tangled"):
        Mesh(pts, cells, "hexahedron")


def test_flat_hexahedron():
    m = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "hexahedron")
    pts = m.points.copy()
    pts[:, 2] = 0.0
    with pytest.raises(ValueError, match=r"cells\[0\].*(degenerate|tangled)"):
        Mesh(pts, m.cells, "hexahedron")


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_coordinates(bad):
    m = unit_tet_mesh()
    pts = m.points.copy()
    pts[5, 1] = bad
    with pytest.raises(ValueError, match=rf"points\[5, 1\] = {re.escape(str(bad))}.*not finite"):
        Mesh(pts, m.cells, "tetra")


def test_unknown_cell_type():
    with pytest.raises(ValueError, match=r"cell_type='wedge'"):
        Mesh(np.zeros((6, 3)), [[0, 1, 2, 3, 4, 5]], "wedge")


def test_cells_out_of_range():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    with pytest.raises(ValueError, match=r"cells.*vertex 7"):
        Mesh(pts, [[0, 1, 2, 7]], "tetra")


def test_liver_mesh_is_reoriented():
    meshio = pytest.importorskip("meshio")
    raw = meshio.read(liver_mesh_path(must_exist=True))
    cells = raw.get_cells_type("tetra")
    m = Mesh(raw.points[:, :3], cells, "tetra")
    assert m.n_reoriented == len(cells)
    assert np.all(m.cell_volumes() > 0)


# --------------------------------------------------------------------------- loads and BCs
def test_nan_point_load():
    with pytest.raises(ValueError, match=r"PointLoad\.force.*nan"):
        PointLoad([0], np.array([np.nan, 0.0, 0.0]))


def test_inf_point_load():
    with pytest.raises(ValueError, match=r"PointLoad\.force.*inf"):
        PointLoad([0], np.array([0.0, np.inf, 0.0]))


def test_nan_traction():
    with pytest.raises(ValueError, match=r"SurfaceTraction\.traction.*nan"):
        SurfaceTraction(on_plane(0, 1.0), np.array([0.0, 0.0, np.nan]))


def test_nan_follower_pressure():
    with pytest.raises(ValueError, match=r"FollowerPressure\.pressure.*nan"):
        FollowerPressure(on_plane(0, 1.0), float("nan"))


def test_nan_dirichlet_value_constant():
    with pytest.raises(ValueError, match=r"Dirichlet\.value.*nan"):
        Dirichlet(on_plane(0, 0.0), (0, 1, 2), np.array([0.0, np.nan, 0.0]))


def test_nan_dirichlet_value_callable():
    bad = Dirichlet(on_plane(0, 0.0), (0, 1, 2), lambda x: np.where(x > 0.5, np.nan, 0.0))
    with pytest.raises(ValueError, match=r"Dirichlet\.value\(x\).*nan"):
        Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P1", [CLAMP, bad])


def test_bad_dirichlet_component():
    with pytest.raises(ValueError, match=r"Dirichlet\.components.*\(0, 3\)"):
        Dirichlet(on_plane(0, 0.0), (0, 3))


def test_no_dirichlet_condition():
    with pytest.raises(ValueError, match=r"dirichlet.*no Dirichlet condition.*rigid-body"):
        Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P1", [])


@pytest.mark.parametrize("components,rank", [((0, 1, 2), 3), ((0,), 1)])
def test_dirichlet_on_one_node_leaves_rigid_modes(components, rank):
    with pytest.raises(ValueError, match=rf"dirichlet.*only {rank} of 6 rigid-body modes"):
        Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P1", [Dirichlet([0], components)])


def test_dirichlet_on_a_line_leaves_a_rotation():
    # all nodes on the x axis fixed: rotation about x is free (rank 5)
    on_axis = lambda x: (np.abs(x[:, 1]) < 1e-9) & (np.abs(x[:, 2]) < 1e-9)  # noqa: E731
    with pytest.raises(ValueError, match=r"dirichlet.*only 5 of 6"):
        Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P1", [Dirichlet(on_axis)])


def test_empty_node_selection():
    with pytest.raises(ValueError, match=r"Dirichlet\.nodes.*empty"):
        Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P1", [Dirichlet(on_plane(0, 7.0))])


def test_unknown_element_name():
    with pytest.raises(ValueError, match=r"element='P3'"):
        Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P3", [CLAMP])


def test_element_cell_mismatch():
    with pytest.raises(ValueError, match=r"element='Q1'.*hexahedron.*tetra"):
        Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "Q1", [CLAMP])


def test_unknown_backend_name():
    pb = Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P1", [CLAMP])
    with pytest.raises(ValueError, match=r"backend 'fenics'"):
        make_backend("fenics", pb)


def test_guccione_fibres_per_cell_count():
    fib = np.tile([1.0, 0.0, 0.0], (5, 1))
    mat = Guccione(C=1.0, bf=8.0, bt=2.0, bfs=4.0, kappa=10.0, fibres=fib)
    with pytest.raises(ValueError, match=r"fibres has 5 rows.*6 cells"):
        Problem(unit_tet_mesh(), mat, "P1", [CLAMP])


def test_non_finite_load_factor():
    pb = Problem(unit_tet_mesh(), LinearElastic(E=1.0, nu=0.3), "P1", [CLAMP])
    with pytest.raises(ValueError, match=r"load_factor.*nan"):
        newton_solve(make_backend("skfem", pb), float("nan"))


# --------------------------------------------------------------------------- solver failures
def _huge_load_problem(sign=1.0):
    mesh = element_mesh("Q1", lengths=(2.0, 1.0, 1.0), divisions=(4, 2, 2))
    return Problem(mesh, NeoHookean(E=1.0, nu=0.3), "Q1", [CLAMP],
                   [SurfaceTraction(on_plane(0, 2.0), np.array([sign * 1e3, 0.0, 0.0]))])


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_newton_divergence_is_reported(backend):
    """A compressive end traction 1000 x E on neo-Hookean: not reached, reported as data."""
    b = make_backend(backend, _huge_load_problem(-1.0))
    res = newton_solve(b, 1.0, max_iterations=10, min_increment=1 / 64)
    assert res.status != "success" and not res.success
    assert np.all(np.isfinite(res.u))
    assert 0.0 <= res.load_factor < res.target_load_factor == 1.0
    assert b.min_jacobian(res.u) > 0
    assert any(not inc.converged and inc.message for inc in res.increments)
    assert "last converged load factor" in res.message
    # strict mode raises, carrying the same result
    with pytest.raises(NewtonError) as info:
        newton_solve(b, 1.0, max_iterations=10, min_increment=1 / 64, strict=True)
    assert info.value.result.load_factor == pytest.approx(res.load_factor)
    assert np.all(np.isfinite(info.value.result.u))


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_inverted_elements_are_reported_not_nan(backend):
    """A prescribed end displacement pushing the free end through the clamp inverts elements
    in the first Newton update: the attempt is refused ("inverted"), never returns NaN."""
    mesh = element_mesh("P1", lengths=(1.0, 1.0, 1.0), divisions=(2, 2, 2))
    pb = Problem(mesh, NeoHookean(E=1.0, nu=0.3), "P1",
                 [CLAMP, Dirichlet(on_plane(0, 1.0), (0,), -1.5)])
    b = make_backend(backend, pb)
    res = newton_solve(b, 1.0, max_iterations=8, min_increment=1 / 8)
    assert not res.success
    assert np.all(np.isfinite(res.u))
    assert b.min_jacobian(res.u) > 0
    assert any("invert" in inc.message for inc in res.increments), [i.message for i in res.increments]
    for inc in res.increments:
        assert all(np.isfinite(r) for r in inc.residual_norms), inc


def test_mu_integrator_is_checked_by_name():
    """``mu.integrator`` (the reference's integrator of a dynamic scene) names the key and the
    valid integrators; a static scene has none to change; the scene's own options are dropped
    with another integrator (HHT's alpha would not configure Bathe)."""
    from tissuebench.cases import load

    with pytest.raises(ValueError, match=r"mu\.integrator = 'rk4': expected one of \['hht'"):
        load("frame_2dof").at({"integrator": "rk4"})
    with pytest.raises(ValueError, match="mu.integrator.*not dynamic"):
        load("cube_tension_twist").at({"integrator": "hht"})
    wave = load("wave_block", variant="linear")
    assert wave.analysis["integrator_options"] == {"alpha": -0.05}
    assert "integrator_options" not in wave.at({"integrator": "bathe"}).analysis
    assert wave.at({"integrator": "hht"}).analysis["integrator_options"] == {"alpha": -0.05}


def test_an_unknown_parameter_with_a_non_bare_name_is_quoted(tmp_path):
    """Fuzzing finding (profile fuzz): an extra ``[parameters]`` entry whose name has a space
    was reported unquoted, so the message did not show where the key ends."""
    from tissuebench.cases.parameters import check_parameters_table

    with pytest.raises(ValueError, match=r"^parameters\.'paper §4\.2' = \[\]: unknown parameter"):
        check_parameters_table("parameters", {"paper §4.2": []}, [])
