"""From a validated scene to a solvable model: node sets, prescribed values, loads.

:func:`fe_problem` builds the :class:`~tissuebench.refsolvers.Problem` of a
finite-element scene; :func:`line_model` the :class:`LineModel` of a 1D scene. Both
resolve the region selectors of the scene on the node coordinates.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..refsolvers import BodyForce, Dirichlet, FollowerPressure, PointLoad, Problem, SurfaceTraction
from ..refsolvers.mesh import node_layout
from ..refsolvers.well_posed import IdleLoadError, check_loads_do_work
from .histories import History
from .monitors import unit_vector

__all__ = ["LineModel", "fe_problem", "line_model"]


@dataclass(frozen=True)
class LineModel:
    """A 1D discrete model: its mesh, parameters, fixed (node, component) pairs, loads."""

    model: str
    mesh: Any
    params: dict
    fixed: list          # [(node indices, component index)]
    loads: list          # [(node indices, value per node, History)]


def _per_node(ld, value, idx):
    # "total" spreads the value evenly over the selected nodes; "per_node" applies it to each
    return value / len(idx) if ld["distribute"] == "total" else value


def rotation_motion(m):
    """The prescribed motion of a ``{type = "rotation"}`` table: ``(x, lam) -> displacement``
    of the points ``x`` (n, 3) rotated by ``lam`` times ``angle_deg`` about ``axis``
    through ``center``."""
    axis = unit_vector(m["axis"])
    theta = math.radians(m["angle_deg"])
    c = np.asarray(m["center"], float)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])

    def motion(x, lam):
        # Rodrigues' rotation formula
        angle = theta * lam
        R = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
        return (x - c) @ R.T + c - x
    return motion


def _plane_normal(scene, path, facets):
    p = scene.mesh.points
    n = np.cross(p[facets[:, 1]] - p[facets[:, 0]], p[facets[:, 2]] - p[facets[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    # a dead pressure has one direction; on a curved surface it would not be a pressure
    if np.max(np.linalg.norm(n - n[0], axis=1)) > 1e-6:
        raise ValueError(f"{scene.name}: {path}: a dead 'pressure' needs a plane region; "
                         f"use follower_pressure or traction")
    return n[0]


def _fe_load(scene, i, ld, nodes):

    kind, path = ld["type"], f"load[{i}]"
    if kind == "body":
        return BodyForce(np.asarray(ld["value"], float))
    if kind == "point" and ld["distribute"] == "interpolate":
        return _interpolated_point_load(scene, path, ld, nodes)
    if kind == "point":
        idx = scene.select(path, ld["region"], nodes)
        return PointLoad(idx, _per_node(ld, np.asarray(ld["value"], float), idx))
    facets = scene.mesh.select_facets(scene.region(ld["region"]))
    if len(facets) == 0:
        raise ValueError(f"{scene.name}: {path}.region {ld['region']} selects no boundary facet")
    if kind == "follower_pressure":
        return FollowerPressure(facets, float(ld["value"]))
    if kind == "traction":
        return SurfaceTraction(facets, np.asarray(ld["value"], float))
    # dead pressure on a plane region: a traction -p N
    return SurfaceTraction(facets, -float(ld["value"]) * _plane_normal(scene, path, facets))


def _interpolated_point_load(scene, path, ld, nodes):
    """A point force at the region's ``nearest`` point (bbox frame allowed), consistent nodal
    forces ``w_i F`` with the shape-function weights ``w_i`` of the point in its cell."""
    from .probes import make_probe

    region = ld["region"]
    if "nearest" not in region:
        raise ValueError(f"{scene.name}: {path}.distribute = 'interpolate' needs a 'nearest' point region")
    point = np.asarray(region["nearest"], float)
    if region.get("frame") == "bbox":
        lo, hi = scene.mesh.points.min(axis=0), scene.mesh.points.max(axis=0)
        point = lo + point * (hi - lo)
    layout_nodes, cell_nodes = node_layout(scene.mesh, scene.element)
    # a point off the body loads the closest point of the body (its surface)
    probe = make_probe(scene.mesh, layout_nodes, scene.element, point, cell_nodes=cell_nodes, label=path,
                       max_distance=np.inf)
    # PointLoad pairs forces with its nodes in sorted order
    order = np.argsort(probe.nodes)
    force = np.outer(probe.weights[order], np.asarray(ld["value"], float))
    return PointLoad(probe.nodes[order], force)


def fe_problem(scene, element: str | None = None):
    """The :class:`~tissuebench.refsolvers.Problem` of a finite-element ``scene``
    (see :meth:`tissuebench.cases.scene.Scene.to_problem`)."""

    element = element or scene.element
    nodes = node_layout(scene.mesh, element)[0]
    dirichlet = [Dirichlet(scene.select(f"dirichlet[{i}]", d["region"], nodes), tuple(d["components"]),
                           np.asarray(d["value"], float), d["scaled"],
                           motion=rotation_motion(d["motion"]) if "motion" in d else None)
                 for i, d in enumerate(scene.dirichlet)]
    loads = [_fe_load(scene, i, ld, nodes) for i, ld in enumerate(scene.loads)]
    problem = Problem(scene.mesh, scene.make_material(), element, dirichlet=dirichlet, loads=loads,
                      density=scene.density or 1.0)
    try:
        check_loads_do_work(problem)
        return problem
    except IdleLoadError as exc:  # said in the scene's own keys: the load's type and region, the clamp's region
        ld = scene.loads[exc.load]
        where = "" if ld["type"] == "body" else f", region = {ld['region']}"
        clamps = "; ".join(f"dirichlet[{k}] (region = {scene.dirichlet[k]['region']}, components = "
                           f"{''.join('xyz'[c] for c in scene.dirichlet[k]['components'])})" for k in exc.clamps)
        raise ValueError(f"{scene.name}: load[{exc.load}] (type = {ld['type']!r}{where}) acts only on fixed dofs: "
                         f"its {exc.n_nodes} loaded nodes are held in the direction of its force by {clamps}. The "
                         "load does no work (the supports carry it; the solution would be the unloaded one): move "
                         "it off the clamp, or free those components") from None


def line_model(scene) -> LineModel:
    """The 1D discrete model of ``scene`` with resolved node sets."""
    x = scene.mesh.points
    fixed = [(scene.select(f"dirichlet[{i}]", d["region"], x), c)
             for i, d in enumerate(scene.dirichlet) for c in d["components"]]
    loads = []
    held = np.concatenate([idx for idx, c in fixed if c == 0] + [np.zeros(0, dtype=np.int64)])
    for i, ld in enumerate(scene.loads):
        if ld["type"] == "point" and ld["distribute"] == "interpolate":
            mine = [(np.array([node]), share, History(ld["history"]))
                    for node, share in _interpolated_line_load(scene, i, ld, x[:, 0])]
        else:
            idx = scene.select(f"load[{i}]", ld["region"], x)
            mine = [(idx, _per_node(ld, ld["value"], idx), History(ld["history"]))]
        loaded = np.concatenate([idx for idx, value, _ in mine if value != 0])
        if loaded.size and np.isin(loaded, held).all():  # the loads act on component 0 (u or w)
            clamps = sorted({k for k, d in enumerate(scene.dirichlet) if 0 in d["components"]
                             and np.isin(loaded, scene.select(f"dirichlet[{k}]", d["region"], x)).any()})
            raise ValueError(f"{scene.name}: load[{i}] (type = {ld['type']!r}, region = {ld['region']}) acts only on "
                             f"fixed dofs: its {len(np.unique(loaded))} loaded nodes are held by "
                             f"{', '.join(f'dirichlet[{k}]' for k in clamps)}. The load does no work (the supports "
                             "carry it; the solution would be the unloaded one): move it off the support")
        loads += mine
    return LineModel(scene.model, scene.mesh, dict(scene.model_params), fixed, loads)


def _interpolated_line_load(scene, i, ld, x):
    """A point load at ``region.nearest[0]`` split between the two nodes of its element by the
    linear shape functions (the source moves continuously between nodes)."""
    if "nearest" not in ld["region"]:
        raise ValueError(f"{scene.name}: load[{i}].distribute = 'interpolate' needs a 'nearest' point region")
    s = float(ld["region"]["nearest"][0])
    if ld["region"].get("frame") == "bbox":
        s = x.min() + s * (x.max() - x.min())
    if not x.min() <= s <= x.max():
        raise ValueError(f"{scene.name}: load[{i}] at x = {s:g} lies outside the interval [{x.min():g}, {x.max():g}]")
    order = np.argsort(x)
    k = min(int(np.searchsorted(x[order], s, side="right")) - 1, len(x) - 2)
    a, b = order[k], order[k + 1]
    t = (s - x[a]) / (x[b] - x[a])
    return [(int(a), (1.0 - t) * ld["value"]), (int(b), t * ld["value"])]
