"""Point probes (tissuebench.cases.probes) and the point monitors built on them: exact
interpolation of the element's polynomial fields, nodes read exactly, points just off a
curved boundary clipped in, far points refused, existing node monitors unchanged."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tissuebench.cases import monitors
from tissuebench.cases.meshes import box_mesh
from tissuebench.cases.probes import make_probe
from tissuebench.cases.scene import load
from tissuebench.refsolvers.mesh import node_layout

LENGTHS, ORIGIN = (2.0, 1.0, 1.5), (-0.5, 0.25, 1.0)


def _mesh(cell_type, jitter=0.3, divisions=(4, 3, 3)):
    # jittered interior vertices: distorted tetrahedra and non-parallelepiped hexahedra
    return box_mesh(LENGTHS, divisions, cell_type, ORIGIN, jitter=jitter, seed=7)


def _interior_points(n, seed=3):
    rng = np.random.default_rng(seed)
    return np.asarray(ORIGIN) + rng.uniform(0.02, 0.98, (n, 3)) * np.asarray(LENGTHS)


def _linear(x):
    A = np.array([[1.0, -2.0, 0.5], [0.3, 0.7, -1.1], [2.0, 0.1, 0.4]])
    return x @ A.T + np.array([0.1, -0.2, 0.3])


def _quadratic(x):
    x, y, z = x.T
    return np.column_stack([x * x - 2 * x * y + 0.5 * z + 1, y * z + 3 * x * x - y, z * z - x * z + 0.2 * y * y])


@pytest.mark.parametrize("element, cell_type, field", [("P1", "tetra", _linear), ("Q1", "hexahedron", _linear),
                                                       ("P2", "tetra", _quadratic)])
def test_interpolates_the_element_fields_exactly(element, cell_type, field):
    mesh = _mesh(cell_type)
    nodes, cell_nodes = node_layout(mesh, element)
    F = field(nodes)
    for p in _interior_points(20):
        pr = make_probe(mesh, nodes, element, p, cell_nodes=cell_nodes)
        assert pr.cell >= 0 and len(pr.nodes) == {"P1": 4, "P2": 10, "Q1": 8}[element]
        assert pr.weights.sum() == pytest.approx(1.0, abs=1e-12)
        assert pr.distance < 1e-12 and np.allclose(pr.location, p, atol=1e-12)
        np.testing.assert_allclose(pr(F), field(p[None])[0], rtol=0, atol=1e-11)


def test_p2_cell_nodes_default_to_the_layout():
    mesh = _mesh("tetra")
    nodes, cell_nodes = node_layout(mesh, "P2")
    p = _interior_points(1)[0]
    a, b = make_probe(mesh, nodes, "P2", p), make_probe(mesh, nodes, "P2", p, cell_nodes=cell_nodes)
    assert np.array_equal(a.nodes, b.nodes) and np.array_equal(a.weights, b.weights)


@pytest.mark.parametrize("element, cell_type", [("P1", "tetra"), ("P2", "tetra"), ("Q1", "hexahedron")])
def test_a_node_is_read_with_weight_one(element, cell_type):
    mesh = _mesh(cell_type)
    nodes, _ = node_layout(mesh, element)
    # an interior vertex, and for P2 an edge midpoint
    for i in (len(mesh.points) // 2, len(nodes) - 5):
        pr = make_probe(mesh, nodes, element, nodes[i] + 1e-12)
        assert pr.nodes.tolist() == [i] and pr.weights.tolist() == [1.0] and pr.cell == -1


@pytest.mark.parametrize("element, cell_type", [("P1", "tetra"), ("Q1", "hexahedron")])
def test_a_point_just_outside_a_face_is_clipped_onto_it(element, cell_type):
    mesh = _mesh(cell_type)
    nodes, _ = node_layout(mesh, element)
    face = np.array([ORIGIN[0] + LENGTHS[0], 0.61, 1.93])  # on the plane face x = max
    pr = make_probe(mesh, nodes, element, face + [1e-3, 0, 0])
    assert pr.distance == pytest.approx(1e-3, rel=1e-6)
    np.testing.assert_allclose(pr.location, face, atol=1e-12)
    assert np.all(pr.weights >= 0) and pr.weights.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(pr(_linear(nodes)), _linear(face[None])[0], atol=1e-11)
    # beyond an edge and beyond a corner: the closest point is on the edge, the corner
    hi = np.asarray(ORIGIN) + LENGTHS
    for target, off in [([hi[0], 0.61, hi[2]], [1e-3, 0, 2e-3]), (hi, [1e-3, 1e-3, 1e-3])]:
        pr = make_probe(mesh, nodes, element, np.add(target, off))
        assert pr.distance == pytest.approx(np.linalg.norm(off), rel=1e-6)
        np.testing.assert_allclose(pr.location, target, atol=1e-12)


@pytest.fixture(scope="module")
def lv():
    s = load("left_ventricle", variant="guccione")
    return s, s.to_problem()


def test_lv_apex_points_are_on_the_faceted_body(lv):
    s, pb = lv
    # the endocardial apex lies inside the mesh (facets of a convex cavity bulge into it),
    # the epicardial one just outside it (facets of a convex outer surface cut inside)
    endo = make_probe(pb.mesh, pb.nodes, "P1", [0.0, 0.0, -17.0])
    epi = make_probe(pb.mesh, pb.nodes, "P1", [0.0, 0.0, -20.0])
    assert endo.distance < 1e-12
    assert 0 < epi.distance < 0.2  # the faceting gap h^2 / (8 R), R = 5 mm at the epicardial apex
    vals = s.evaluate_monitors(pb, np.zeros(pb.ndof))
    assert vals["apex_endo_z"] == pytest.approx(-17.0, abs=1e-12)
    # the monitor reports the requested material point (moved by u), not the faceted one
    assert vals["apex_epi_z"] == pytest.approx(-20.0, abs=1e-12)


def test_a_point_off_the_body_is_refused_by_name(lv):
    _, pb = lv
    with pytest.raises(ValueError, match=r"'far apex' \[0.0, 0.0, -25.0\] is not on the body: it lies 5"):
        make_probe(pb.mesh, pb.nodes, "P1", [0.0, 0.0, -25.0], label="far apex")
    # inside the cavity: near the mesh's bounding box but not on the body
    with pytest.raises(ValueError, match="not on the body"):
        make_probe(pb.mesh, pb.nodes, "P1", [0.0, 0.0, -5.0])


def test_a_monitor_off_the_body_names_the_scene_and_monitor():
    s = load("wave_block")
    bad = dict(s.monitors[0], name="outside", point=[2.5, 2.5, 14.0])
    s = dataclasses.replace(s, monitors=[bad])
    with pytest.raises(ValueError, match="wave_block: monitor 'outside': point .* is not on the body"):
        s.evaluate_monitors(s.to_problem(), np.zeros(s.to_problem().ndof))


def _nearest_node_value(m, nodes, U):
    """The former monitor rule: the value at the node nearest to the point."""
    i = int(np.argmin(np.linalg.norm(nodes - np.asarray(m["point"]), axis=1)))
    vec = U[i] + (nodes[i] if m["quantity"] == "deformed_coordinate" else 0.0)
    return float(vec[monitors.AXES[m["component"]]]) * m.get("scale", 1.0)


@pytest.mark.parametrize("name, variant, names", [("land_beam", None, {"tip_z"}),
                                                  ("wave_block", "linear", {"mid_uz", "top_uz"})])
def test_monitors_on_nodes_are_unchanged(name, variant, names):
    s = load(name, variant=variant)
    pb = s.to_problem()
    U = 1e-3 * np.random.default_rng(0).normal(size=(len(pb.nodes), 3))
    vals = s.evaluate_monitors(pb, U.ravel())
    for m in s.monitors:
        if m["name"] in names:
            assert monitors._probe(s, m, pb).nodes.size == 1
            assert vals[m["name"]] == _nearest_node_value(m, pb.nodes, U)


def test_bbox_frame_and_boundary_monitors():
    s = load("wave_block")
    pb = s.to_problem()
    U = np.random.default_rng(1).normal(size=pb.ndof) * 1e-3
    mid = next(m for m in s.monitors if m["name"] == "mid_uz")
    # the block is [0, 5] x [0, 5] x [0, 10]: (0.5, 0.5, 0.5) of the box is (2.5, 2.5, 5)
    rel = dict(mid, name="mid_rel", point=[0.5, 0.5, 0.5], frame="bbox")
    # a boundary monitor reads the nearest boundary node, not an interpolation
    bnd = dict(mid, name="side", point=[1.4, 2.6, 5.0], boundary=True)
    s2 = dataclasses.replace(s, monitors=[mid, rel, bnd])
    vals = s2.evaluate_monitors(pb, U)
    assert vals["mid_rel"] == vals["mid_uz"]
    i = s.select("side", {"nearest": bnd["point"], "boundary": True}, pb.nodes)[0]
    assert vals["side"] == U.reshape(-1, 3)[i, 2] * bnd.get("scale", 1.0)
    assert monitors._probe(s2, bnd, pb).nodes.tolist() == [i]


def test_probes_are_built_once_per_problem():
    s = load("wave_block")
    pb = s.to_problem()
    m = s.monitors[0]
    first = monitors._probe(s, m, pb)
    s.evaluate_monitors(pb, np.zeros(pb.ndof))
    assert monitors._probe(s, m, pb) is first
    assert monitors._probe(s, m, s.to_problem()) is not first


def test_interpolated_point_load_moves_continuously():
    """distribute = "interpolate": the consistent nodal forces of a point force; the resultant
    and its moment about the origin are those of the force at the point."""
    import dataclasses

    from tissuebench.cases.scene import load

    s = load("land_beam")
    F = np.array([0.0, 0.0, -1.0])
    for x in (7.3, 7.31, 9.95):
        point = [x, 0.37, 1.0]
        ld = dict(s.loads[0], type="point", value=list(F), distribute="interpolate",
                  region={"nearest": point})
        pb = dataclasses.replace(s, loads=[ld]).to_problem()
        f = pb.point_load_vector().reshape(-1, 3)
        assert np.allclose(f.sum(axis=0), F, atol=1e-14)
        # P2 weights reproduce linear fields: the moment of the nodal forces is that of F at the point
        assert np.allclose(np.cross(pb.nodes, f).sum(axis=0), np.cross(point, F), atol=1e-12)
