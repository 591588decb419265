"""Scene defects of the second hostile probe (issue 37): a load entirely on clamped dofs (1), two
bodies in one mesh with one of them free (3). Each is refused by the scene's problem, so that
``scene check``, ``run`` and ``sweep --scene`` refuse it alike, naming the load or the body."""
from __future__ import annotations

import re

import meshio
import numpy as np
import pytest

from tissuebench.cases.meshes import box_mesh
from tissuebench.cases.scene import load
from tissuebench.cli import main
from tissuebench.refsolvers import BodyForce, Dirichlet, LinearElastic, PointLoad, Problem, SurfaceTraction
from tissuebench.reference import solve
from tissuebench.refsolvers.well_posed import IdleLoadError, check_loads_do_work

from _mesh_scene import scene_file as mesh_scene_file, write_block

BAR = """
[case]
name = "bar"
description = "a bar clamped at x = 0"
[units]
length = "m"
force = "N"
[mesh]
{mesh}
[material]
name = "linear"
E = 1000.0
nu = 0.3
{dirichlet}
{load}
[[monitor]]
name = "tip"
quantity = "displacement"
point = [1.0, 0.05, 0.05]
component = "y"
[analysis]
type = "static"
load_steps = 2
"""
BOX = """builder = "box"
element = "{element}"
[mesh.params]
lengths = [1.0, 0.1, 0.1]
cell_type = "{cell}"
[mesh.ci]
divisions = [8, 2, 2]
[mesh.paper]
divisions = [8, 2, 2]"""
CLAMP = '[[dirichlet]]\nregion = {{ plane = "x", value = 0.0, tol = 1e-9 }}\ncomponents = "{c}"\n'
X0 = '{ plane = "x", value = 0.0, tol = 1e-9 }'


def bar(tmp_path, load_text, clamp="xyz", element="P1", mesh=None, extra_dirichlet=""):
    cell = "hexahedron" if element == "Q1" else "tetra"
    text = BAR.format(mesh=mesh or BOX.format(element=element, cell=cell),
                      dirichlet=CLAMP.format(c=clamp) + extra_dirichlet, load=load_text)
    path = tmp_path / "bar.toml"
    path.write_text(text)
    return path


def _load(kind, value, region=X0, extra=""):
    return f'[[load]]\ntype = "{kind}"\nregion = {region}\nvalue = {value}\n{extra}'


IDLE = r"bar: load\[0\] \(type = '{kind}', region = \{{'plane': 'x', 'value': 0.0.*\}}\) acts only on fixed dofs: " \
       r"its \d+ loaded nodes are held .* by dirichlet\[0\] \(region = .*components = {c}\).*does no work"


# the other end held too, where the clamp at x = 0 holds only some components
FAR = CLAMP.replace("0.0", "1.0").format(c="xyz")


@pytest.mark.parametrize("kind, value, clamp, element", [
    ("point", "[0.0, -1.0, 0.0]", "xyz", "P1"),
    ("point", "[0.0, -1.0, 0.0]", "y", "P1"),        # the force's component held, the others free
    ("traction", "[0.0, -1.0, 0.0]", "xyz", "P2"),   # edge nodes of the facets included
    ("pressure", "1.0", "x", "Q1"),                  # the x = 0 face pushed along x, held along x
    ("follower_pressure", "1.0", "x", "P1"),
])
def test_1_a_load_entirely_on_clamped_dofs_is_refused_naming_the_load_and_the_clamp(tmp_path, kind, value, clamp,
                                                                                     element):
    path = bar(tmp_path, _load(kind, value), clamp, element, extra_dirichlet=FAR if clamp != "xyz" else "")
    with pytest.raises(ValueError, match=IDLE.format(kind=kind, c=clamp)):
        load(path).to_problem()


@pytest.mark.parametrize("kind, value, clamp, region", [
    ("point", "[0.0, -1.0, 0.0]", "xz", X0),         # held in x and z: the y force moves the face
    ("point", "[0.0, -1.0, 0.0]", "xyz", '{ box = [[0.0, 0.0, 0.0], [0.13, 0.1, 0.1]] }'),  # partly on the clamp
    ("traction", "[0.0, -1.0, 0.0]", "xz", X0),
    ("pressure", "1.0", "yz", X0),                   # pushed along x, free along x
])
def test_1_a_load_with_a_free_dof_in_its_direction_is_accepted(tmp_path, kind, value, clamp, region):
    path = bar(tmp_path, _load(kind, value, region), clamp, extra_dirichlet=FAR if clamp != "xyz" else "")
    assert load(path).to_problem().loads


def test_1_scene_check_run_and_sweep_refuse_a_load_on_the_clamp(tmp_path, capsys):
    path = bar(tmp_path, _load("point", "[0.0, -1.0, 0.0]"))
    for argv in (["scene", "check", str(path), "--out", "-"], ["run", str(path), "--out", str(tmp_path / "run")],
                 ["sweep", "--scene", str(path), "--all-methods", "--out", str(tmp_path / "sweep")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert re.search(IDLE.format(kind="point", c="xyz"), err) and "Traceback" not in err, (argv, err)
    assert not (tmp_path / "run").exists() and not (tmp_path / "sweep").exists()


def test_1_gravity_on_a_body_clamped_everywhere_is_refused_and_on_a_clamped_end_accepted():
    mesh = box_mesh((1.0, 0.1, 0.1), (4, 1, 1), "tetra")
    gravity = BodyForce(np.array([0.0, 0.0, -9.81]))
    end = Dirichlet(lambda x: x[:, 0] < 1e-9)
    check_loads_do_work(Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[end], loads=[gravity]))
    everywhere = Dirichlet(lambda x: np.ones(len(x), bool), (2,))
    with pytest.raises(IdleLoadError, match=r"loads\[0\] \(BodyForce\): every dof it acts on \(20 dofs on 20 nodes\) "
                                            r"is fixed by dirichlet\[0\], dirichlet\[1\]") as info:
        check_loads_do_work(Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[end, everywhere], loads=[gravity]))
    assert info.value.load == 0 and info.value.clamps == [0, 1] and info.value.n_nodes == 20


def test_1_a_zero_component_on_a_free_dof_does_not_count_as_work():
    """The y force of a load whose x component (0) lies on free dofs: what counts is where the
    nonzero force acts, on both sides (the y component held: refused; free: accepted)."""
    mesh = box_mesh((1.0, 0.1, 0.1), (4, 1, 1), "tetra")
    end = Dirichlet(lambda x: x[:, 0] < 1e-9)
    tip = Dirichlet(lambda x: x[:, 0] > 1 - 1e-9, (1,))
    on_tip = PointLoad(lambda x: x[:, 0] > 1 - 1e-9, np.array([0.0, 2.0, 0.0]))
    with pytest.raises(IdleLoadError, match=r"dirichlet\[1\]"):
        check_loads_do_work(Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[end, tip], loads=[on_tip]))
    along = PointLoad(lambda x: x[:, 0] > 1 - 1e-9, np.array([2.0, 0.0, 0.0]))
    check_loads_do_work(Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[end, tip], loads=[along]))
    # a traction on the tip face held in y, pulling in y and x: the x part does work
    tip_face = SurfaceTraction(lambda x: x[:, 0] > 1 - 1e-9, np.array([1.0, 2.0, 0.0]))
    check_loads_do_work(Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[end, tip], loads=[tip_face]))


def test_1_a_1d_load_on_its_support_is_refused(tmp_path, capsys):
    source = 'region = { nearest = [0.5, 0.0, 0.0], count = 1 }'
    text = load("heat1d_source").path.read_text().split("[parameters.position]")[0]
    assert source in text
    path, moved = tmp_path / "heat.toml", tmp_path / "moved.toml"
    path.write_text(text.replace(source, 'region = { plane = "x", value = 1.0 }'))
    moved.write_text(text.replace(source, 'region = { plane = "x", value = 0.5 }'))
    with pytest.raises(ValueError, match=r"load\[0\] \(type = 'point', region = .*\) acts only on fixed dofs: its 1 "
                                         r"loaded nodes are held by dirichlet\[1\]"):
        load(path).line_model()
    assert main(["scene", "check", str(path), "--out", "-"]) == 2
    assert "acts only on fixed dofs" in capsys.readouterr().err
    assert load(moved).line_model().loads


# ---------------------------------------------------------------------------------------------- item 3
TWO_BODIES = 'file = "two.vtu"\nunit = "m"\nelement = "P1"'


def two_bodies(tmp_path, gap=1.0, cell="tetra"):
    """Two 1 x 0.1 x 0.1 bars in one mesh file, the second ``gap`` past the first along x."""
    a = box_mesh((1.0, 0.1, 0.1), (4, 1, 1), cell)
    b = a.points + [1.0 + gap, 0.0, 0.0]
    path = tmp_path / ("two.vtu" if cell == "tetra" else "two_hex.vtu")
    meshio.Mesh(np.vstack([a.points, b]), [(cell, np.vstack([a.cells, a.cells + len(a.points)]))]).write(path)
    return path


def test_3_a_free_second_body_is_refused_naming_it(tmp_path, capsys):
    two_bodies(tmp_path)
    path = bar(tmp_path, _load("point", "[0.0, -1.0, 0.0]", '{ plane = "x", value = 1.0, tol = 1e-9 }'),
               mesh=TWO_BODIES)
    body = (r"dirichlet: body 1 of 2 \(a connected part of the mesh: 20 nodes, e.g. node 20, bounding box "
            r"\[2.0, 0.0, 0.0\] to \[3.0, 0.1, 0.1\]\) has no fixed dof")
    with pytest.raises(ValueError, match=body):
        load(path).to_problem()
    for argv in (["scene", "check", str(path), "--out", "-"], ["run", str(path), "--out", str(tmp_path / "run")],
                 ["sweep", "--scene", str(path), "--all-methods", "--out", str(tmp_path / "sweep")]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert re.search(body, err) and "Traceback" not in err, (argv, err)
    assert not (tmp_path / "sweep").exists()


def test_3_two_bodies_each_held_are_accepted_and_said(tmp_path, capsys):
    two_bodies(tmp_path)
    second = CLAMP.replace("0.0", "2.0").format(c="xyz")
    path = bar(tmp_path, _load("point", "[0.0, -1.0, 0.0]", '{ plane = "x", value = 1.0, tol = 1e-9 }'),
               mesh=TWO_BODIES, extra_dirichlet=second)
    assert len(load(path).to_problem().fixed_dofs) == 2 * 4 * 3
    assert main(["scene", "check", str(path), "--out", "-"]) == 0
    assert "remove all 6 rigid-body modes of each of the 2 bodies" in capsys.readouterr().out


@pytest.mark.parametrize("cell", ["tetra", "hexahedron"])
def test_3_a_second_body_held_on_a_line_only_is_refused_with_its_rank(cell, tmp_path):
    """Each body's own modes: the second held on its axis-parallel edge keeps the rotation about it."""
    pts = np.vstack([box_mesh((1.0, 0.1, 0.1), (4, 1, 1), cell).points] * 2)
    pts[len(pts) // 2:, 0] += 2.0
    cells = box_mesh((1.0, 0.1, 0.1), (4, 1, 1), cell).cells
    from tissuebench.refsolvers import Mesh

    mesh = Mesh(pts, np.vstack([cells, cells + len(pts) // 2]), cell)
    first = Dirichlet(lambda x: x[:, 0] < 1e-9)
    edge = Dirichlet(lambda x: (x[:, 0] > 2 - 1e-9) & (x[:, 1] < 1e-9) & (x[:, 2] < 1e-9))
    element = "Q1" if cell == "hexahedron" else "P1"
    with pytest.raises(ValueError, match=r"remove only 5 of 6 rigid-body modes of body 1 of 2"):
        Problem(mesh, LinearElastic(1e3, 0.3), element, dirichlet=[first, edge])
    end = Dirichlet(lambda x: np.abs(x[:, 0] - 3.0) < 1e-9)
    assert Problem(mesh, LinearElastic(1e3, 0.3), element, dirichlet=[first, edge, end]).fixed_dofs.size
    assert mesh.components.tolist() == [0] * (len(pts) // 2) + [1] * (len(pts) // 2)


# ---------------------------------------------------------------------------------------------- item 4
def test_4_a_mm_mesh_declared_in_metres_converges_and_says_its_load_is_small(tmp_path):
    """The block of 40 mm read as 40 m: its 0.1 N load strains it 1e-9; Newton stalled at load
    factor 1/4096 (residual 2e-9 above rtol * 0.05), then every sweep unit failed 'cannot reshape'."""
    write_block(tmp_path)
    scene = load(mesh_scene_file(tmp_path, mesh='file = "block.msh"\nunit = "m"\nelement = "P1"'))
    ref = solve(scene, "skfem")
    assert ref.status == "success" and ref.steps.tolist() == [0.0, 0.5, 1.0], ref.message
    assert "only to the round-off floor of the residual" in ref.message
    assert "the load is small against the body's stiffness" in ref.message


# ---------------------------------------------------------------------------------------------- item 5
DYNAMIC = '[analysis]\ntype = "dynamic"\ndt = 0.01\nt_end = 0.05\nintegrator = "newmark"'
TIP = '{ plane = "x", value = 1.0, tol = 1e-9 }'


def _dynamic_bar(tmp_path, history):
    path = bar(tmp_path, _load("point", "[0.0, -1.0, 0.0]", TIP, f"history = {history}\n"))
    text = path.read_text().replace('nu = 0.3\n', 'nu = 0.3\ndensity = 1000.0\n', 1)
    path.write_text(text.replace('[analysis]\ntype = "static"\nload_steps = 2', DYNAMIC))
    return path


def test_5_a_history_that_is_nan_at_t0_is_refused_by_scene_check_and_run_naming_it(tmp_path, capsys):
    """2 pi x 1e308 overflows: sin(inf x 0) is NaN at t = 0; run said 'load(t) at t=0.0 contains a
    non-finite value nan at index 0', scene check said valid."""
    path = _dynamic_bar(tmp_path, '{ type = "sine", frequency = 1e308 }')
    message = r"load\[0\].history = \{'type': 'sine', 'frequency': 1e\+308\}: the load factor it gives is nan at t = 0"
    with pytest.raises(ValueError, match=message):
        load(path)
    for argv in (["scene", "check", str(path), "--out", "-"], ["run", str(path), "--out", str(tmp_path / "run")]):
        assert main(argv) == 2
        assert re.search(message, capsys.readouterr().err)
    # the other side: a large, finite product is a history (a frequency of 1e300 is finite too, but no
    # time step resolves it: tests/cases/test_history_resolution.py)
    large = load(_dynamic_bar(tmp_path, '{ type = "sine", frequency = 1.0, phase = 1e300 }'))
    assert large.loads[0]["history"]["phase"] == 1e300


def test_5_a_history_infinite_only_inside_the_horizon_is_refused_at_that_time(tmp_path):
    # finite at its times, overflowing between them: -1.7e308 / 0.01 is -inf
    path = _dynamic_bar(tmp_path, '{ type = "tabulated", t = [0.0, 0.01, 0.03], values = [0.0, -1.7e308, 1.7e308] }')
    with pytest.raises(ValueError, match=r"load\[0\].history = .*the load factor it gives is -inf at t = 0.005"):
        load(path)
    fine = _dynamic_bar(tmp_path, '{ type = "tabulated", t = [0.0, 0.01, 0.03], values = [0.0, -1e300, 1e300] }')
    assert load(fine).loads[0]["history"]["values"][2] == 1e300


def test_5_a_monitor_point_off_the_body_is_refused_by_scene_check_as_by_run(tmp_path, capsys):
    path = bar(tmp_path, _load("point", "[0.0, -1.0, 0.0]", TIP))
    off = tmp_path / "off.toml"
    off.write_text(path.read_text().replace("point = [1.0, 0.05, 0.05]", "point = [5.0, 0.05, 0.05]"))
    message = "bar: monitor 'tip': point [5.0, 0.05, 0.05] is not on the body: it lies 4 from the mesh"
    errors = []
    for argv in (["scene", "check", str(off), "--out", "-"], ["run", str(off), "--out", str(tmp_path / "run")],
                 ["sweep", "--scene", str(off), "--all-methods", "--out", str(tmp_path / "sweep")]):
        assert main(argv) == 2, argv
        errors.append(capsys.readouterr().err.strip().splitlines()[-1])
    assert errors[0] == errors[1] == errors[2] and message in errors[0], errors
    # the other side: a point just off the faceted surface (within half a cell) is read there
    near = tmp_path / "near.toml"
    near.write_text(path.read_text().replace("point = [1.0, 0.05, 0.05]", "point = [1.01, 0.05, 0.05]"))
    assert main(["scene", "check", str(near), "--out", "-"]) == 0


def _alarm(seconds):
    """A test that would hang (a FIFO opened for reading) fails instead."""
    import signal

    def fail(*_):
        raise TimeoutError(f"no answer in {seconds} s: the file was opened")
    signal.signal(signal.SIGALRM, fail)
    signal.alarm(seconds)


@pytest.mark.parametrize("kind, message", [
    ("folder", r"mesh file .*special.msh is a folder, not a mesh file"),
    ("fifo", r"mesh file .*special.msh is a FIFO \(named pipe\), not a regular file: not read"),
    ("loop", r"mesh file .*special.msh is a loop of symbolic links: it never reaches a file"),
    ("device", r"mesh file /dev/zero is a character device, not a regular file: not read"),
    ("dangling", r"mesh file .*special.msh is a symbolic link to 'nowhere.msh', which does not exist \(a relative"),
    ("missing", r"mesh file .*special.msh does not exist \(a relative path is taken from the scene file's folder"),
])
def test_5_a_mesh_file_that_is_not_a_regular_file_is_said_for_what_it_is_never_opened(tmp_path, capsys, kind,
                                                                                     message):
    import os
    import signal

    target = tmp_path / "special.msh"
    {"folder": lambda: target.mkdir(), "fifo": lambda: os.mkfifo(target), "loop": lambda: target.symlink_to(target),
     "dangling": lambda: target.symlink_to("nowhere.msh"), "device": lambda: None, "missing": lambda: None}[kind]()
    name = "/dev/zero" if kind == "device" else "special.msh"
    path = mesh_scene_file(tmp_path, mesh=f'file = "{name}"\nunit = "mm"\nelement = "P1"')
    _alarm(30)
    try:
        with pytest.raises(ValueError, match=rf"mesh.file = '{re.escape(name)}': {message}"):
            load(path)
        assert main(["scene", "check", str(path), "--out", "-"]) == 2
        assert re.search(message, capsys.readouterr().err)
    finally:
        signal.alarm(0)
    # the other side: the same name as a regular mesh file loads
    if kind != "device":
        if target.is_dir():
            target.rmdir()
        target.unlink(missing_ok=True)
        write_block(tmp_path, name="special.msh")
        assert load(mesh_scene_file(tmp_path, mesh='file = "special.msh"\nunit = "mm"\nelement = "P1"')).mesh.n_cells


def test_5_read_mesh_refuses_a_fifo_without_opening_it(tmp_path):
    import os
    import signal

    from tissuebench.cases.io import read_mesh

    os.mkfifo(tmp_path / "pipe.vtu")
    _alarm(30)
    try:
        with pytest.raises(ValueError, match=r"mesh file .*pipe.vtu is a FIFO"):
            read_mesh(tmp_path / "pipe.vtu")
    finally:
        signal.alarm(0)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        read_mesh(tmp_path / "none.vtu")
