"""Scene and mesh defects found by hostile input (issue 26): contradictory Dirichlet sets (8),
the rigid-body check's dependence on the unit of length (9), a mesh with coincident nodes (minor)."""
from __future__ import annotations

import meshio
import numpy as np
import pytest

from tissuebench.cases.io import coincident_nodes, read_mesh
from tissuebench.cases.meshes import box_mesh
from tissuebench.cases.scene import load
from tissuebench.cli import main
from tissuebench.refsolvers import Dirichlet, LinearElastic, Problem

CUBE = """
[case]
name = "bar"
paper = "none"
description = "a bar"
[units]
length = "m"
force = "N"
stress = "Pa"
mass = "kg"
time = "s"
[mesh]
builder = "box"
element = "P1"
[mesh.params]
lengths = [{L}, {h}, {h}]
cell_type = "tetra"
[mesh.ci]
divisions = [8, 2, 2]
[mesh.paper]
divisions = [8, 2, 2]
[material]
name = "linear"
E = 1000.0
nu = 0.3
[[dirichlet]]
region = {{ plane = "x", value = 0.0, tol = {tol} }}
components = "xyz"
value = 0.0
{extra}
[analysis]
type = "static"
load_steps = 1
max_load_factor = 1.0
"""
END = '[[dirichlet]]\nregion = {{ plane = "x", value = {L}, tol = {tol} }}\ncomponents = {c}\nvalue = {v}\n'


def scene_file(tmp_path, L=1.0, extra=""):
    text = CUBE.format(L=L, h=L / 10, tol=L * 1e-9, extra=extra)
    path = tmp_path / "bar.toml"
    path.write_text(text)
    return path


def _end(L, c, v):
    return END.format(L=L, tol=L * 1e-9, c=c, v=v)


@pytest.mark.parametrize("second, message", [
    (('["x"]', "-0.024"), r"dirichlet\[1\] and dirichlet\[2\] .*0.024 vs -0.024"),
    (('"xyz"', "0.0"), r"dirichlet\[1\] and dirichlet\[2\] .*0.024 vs 0 at load factor 1"),
])
def test_8_contradictory_dirichlet_sets_are_refused_naming_both(tmp_path, capsys, second, message):
    path = scene_file(tmp_path, extra=_end(1.0, '["x"]', "0.024") + _end(1.0, *second))
    with pytest.raises(ValueError, match=message):
        load(path).to_problem()
    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "dirichlet[1] and dirichlet[2]" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_8_overlapping_sets_that_agree_are_accepted_and_a_moved_and_clamped_dof_refused():
    mesh = box_mesh((1.0, 0.1, 0.1), (8, 2, 2), "tetra")
    left, right = (lambda x: x[:, 0] < 1e-9), (lambda x: x[:, 0] > 1 - 1e-9)
    same = [Dirichlet(left), Dirichlet(right, (0,), 0.02), Dirichlet(right, (0,), 0.02)]
    assert len(Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=same).fixed_dofs) == 27 + 9
    turn = Dirichlet(right, (1, 2), motion=lambda x, lf: lf * np.c_[-x[:, 2], x[:, 1]])
    with pytest.raises(ValueError, match=r"dirichlet\[1\] and dirichlet\[2\].*component [yz]"):
        Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[Dirichlet(left), Dirichlet(right), turn])
    fixed_then_scaled = [Dirichlet(left), Dirichlet(right, (0,), 0.02, scaled=False), Dirichlet(right, (0,), 0.02)]
    with pytest.raises(ValueError, match="at load factor 0.5"):
        Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=fixed_then_scaled)


@pytest.mark.parametrize("scale", [1e-12, 1e-6, 1.0, 1e10, 1e12])
def test_9_the_rigid_body_check_does_not_depend_on_the_unit_of_length(scale):
    mesh = box_mesh((scale, 0.1 * scale, 0.1 * scale), (8, 2, 2), "tetra")
    clamp = Dirichlet(lambda x: x[:, 0] < 1e-9 * scale)
    assert len(Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[clamp]).fixed_dofs) == 27
    line = Dirichlet(lambda x: (x[:, 0] < 1e-9 * scale) & (x[:, 1] < 1e-9 * scale) & (x[:, 2] < 1e-9 * scale)
                     | (x[:, 0] > scale * (1 - 1e-9)) & (x[:, 1] < 1e-9 * scale) & (x[:, 2] < 1e-9 * scale))
    with pytest.raises(ValueError, match="remove only 5 of 6 rigid-body modes"):  # a rotation about the line
        Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[line])


@pytest.mark.parametrize("L", [1e-6, 1e10, 1e12])
def test_9_a_scaled_scene_loads_and_builds_its_problem(tmp_path, L):
    assert load(scene_file(tmp_path, L=L)).to_problem().fixed_dofs.size == 27


def test_minor_a_mesh_with_a_coincident_duplicate_node_is_said(tmp_path):
    m = box_mesh((1.0, 1.0, 1.0), (2, 2, 2), "tetra")
    pts, cells = m.points.copy(), m.cells.copy()
    pts = np.vstack([pts, pts[cells[0, 0]]])  # a copy of node cells[0, 0], used by cell 0 alone
    original = int(cells[0, 0])
    cells[0, 0] = len(pts) - 1
    path = tmp_path / "dup.vtu"
    meshio.Mesh(pts, [("tetra", cells)]).write(path)
    with pytest.warns(UserWarning, match=rf"dup.vtu: 1 pairs of coincident nodes \({original}={len(pts) - 1}; e.g. "
                                         rf"nodes {original} and {len(pts) - 1}"):
        read_mesh(path)
    assert coincident_nodes(m.points).shape == (0, 2)
    near = np.vstack([m.points, m.points[3] + 1e-13])
    assert coincident_nodes(near).tolist() == [[3, len(near) - 1]]
