"""``"coarse_fe"``: a full FE model of the same body on a coarser mesh, mapped to the scene's mesh.

What a trainer does when the scene's mesh is too fine for the frame budget: the same
geometry, element and boundary conditions on a mesh ``coarsening`` times coarser (ratio of
element sizes), with the physics ``model`` = ``"full"`` (the scene's material), ``"linear"``
(its small-strain linear elasticity, :mod:`.linear`) or ``"corotational"`` (:mod:`.corotational`).

* **The coarse mesh** comes from the case builder's parameters where it has them (box
  divisions / c; the cornea's core, ring and layer counts / c; netgen's ``maxh`` x c; an
  STL liver's ``maxh`` x c), else (a mesh read from a file: the shipped liver) from the
  boundary surface remeshed by gmsh at c x the mean edge length
  (:func:`~tissuebench.refsolvers.remesh.remesh`; where gmsh cannot be imported the method
  does not apply to such a scene, and says why),
  corrected up to twice towards the requested ratio. ``model_info`` records the mesh and
  the ratio achieved (mean edge length, coarse over fine). The Dirichlet sets are the scene's
  regions resolved on the coarse mesh.
* **Loads**: the fine mesh's dead nodal force vector ``f`` is transferred as ``T^T f``
  (``T`` the interpolation below: the load a tool puts on the coarse element that holds it,
  consistent in virtual work); a follower pressure keeps the scene's own (re-resolved).
* **To the fine mesh**: every fine node is located in the coarse mesh and takes the coarse
  field there by the element's shape functions (barycentric on tetrahedra, trilinear on
  hexahedra; :func:`~tissuebench.cases.probes.make_probe`: a fine boundary node outside the
  coarser faceted surface takes the value of its closest coarse point, the largest such
  distance is in ``model_info``); the fine prescribed values are placed exactly. The fine
  mesh's output functionals are pulled back (``C T``) so the haptic outputs cost nothing more.

Statics: ``map`` (linear) or ``path`` (Newton); dynamics: ``trajectory`` with the reference's
mass kind and integrator (or ``integrator``), from rest.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import scipy.sparse as sp

from ...cases.builtmesh import BuiltMesh
from ...cases.probes import hex_shape_functions, make_probe
from ...refsolvers.backends import make_backend
from ...refsolvers.mesh import node_layout
from ...refsolvers.remesh import gmsh_import_error, mean_edge_length, remesh
from ..base import Applies, RomMethod, Training, check_choice, register
from .common import DeadLoads, FieldMap, contact_load, contact_nodes_of, intact_backend, scene_of
from .corotational import corotational_backend, roundoff_force
from .linear import is_dynamic, linear_static_model
from .stepping import (NewtonPathModel, TrajectoryModel, dynamic_system, integrator_choice, load_history,
                       newton_options, with_atol)

__all__ = ["CoarseFe", "coarse_scene", "coarse_problem", "nodal_map"]

MODELS = ("full", "linear", "corotational")
_COUNTS = {"box": ("divisions",), "cornea_dome": ("core_cells", "ring_cells", "layers")}
_SIZES = {"netgen_box": "maxh", "lv_ellipsoid": "maxh"}


def _coarser_count(n, c) -> int:
    return max(1, int(n / c + 0.5))


def _by_parameters(scene, c):
    """The scene on its builder's coarser parameters, or None when the builder has none to coarsen."""
    builder, p = scene.mesh_spec["builder"], dict(scene.mesh_spec["params"])
    if builder in _COUNTS:
        new = {k: ([_coarser_count(n, c) for n in p[k]] if isinstance(p.get(k), list) else _coarser_count(p[k], c))
               for k in _COUNTS[builder] if k in p}
        if builder == "cornea_dome":  # the builder's defaults when the scene does not set them
            new = {**{k: _coarser_count(d, c) for k, d in (("core_cells", 4), ("ring_cells", 3), ("layers", 2))},
                   **new}
        return scene.with_mesh(new), "builder parameters " + ", ".join(f"{k} = {v}" for k, v in new.items())
    if builder in _SIZES or (builder == "liver" and str(p.get("path", "")).lower().endswith(".stl")):
        key = _SIZES.get(builder, "maxh")
        default = {"netgen_box": None, "lv_ellipsoid": 2.0, "liver": 14.0}[builder]
        h = float(p.get(key, default)) * c
        return scene.with_mesh({key: h}), f"builder parameter {key} = {h:g}"
    return None


def _by_parameters_known(scene) -> bool:
    """True when :func:`_by_parameters` coarsens ``scene``'s mesh without gmsh."""
    builder, p = scene.mesh_spec["builder"], scene.mesh_spec.get("params", {})
    return builder in _COUNTS or builder in _SIZES or (
        builder == "liver" and str(p.get("path", "")).lower().endswith(".stl"))


def _by_remeshing(scene, c):
    """The scene on its boundary surface remeshed by gmsh at ``c`` x its mean edge length."""
    mesh = scene.mesh
    h_fine = mean_edge_length(mesh)
    size, coarse = c * h_fine, None
    for _ in range(3):  # the patches' boundaries keep small edges: correct the size towards the ratio
        coarse = remesh(mesh, size)
        ratio = mean_edge_length(coarse) / h_fine
        if abs(ratio / c - 1.0) <= 0.15:
            break
        size *= c / ratio
    new = dataclasses.replace(scene)
    new.__dict__["built"] = BuiltMesh(coarse, {"builder": "gmsh remesh", "size": size,
                                               "source": scene.mesh_spec["builder"]})
    return new, f"boundary surface remeshed by gmsh at element size {size:.4g}"


def coarse_scene(scene, coarsening: float):
    """``(scene on a coarser mesh, how it was made)`` (module docstring); ``scene`` without its ``[cut]``."""
    if scene.cut is not None:
        scene = dataclasses.replace(scene, cut=None)
    out = _by_parameters(scene, coarsening)
    if out is None:
        if scene.mesh.cell_type != "tetra":
            raise ValueError(f"coarse_fe: builder {scene.mesh_spec['builder']!r} has no size parameter and its "
                             f"{scene.mesh.cell_type} mesh cannot be remeshed (tetrahedra only)")
        out = _by_remeshing(scene, coarsening)
    return out


def coarse_problem(problem, coarsening: float):
    """``(problem on its mesh remeshed by gmsh at coarsening x its mean edge length, how)`` for a
    problem without a scene: its Dirichlet sets must select nodes by a callable of the coordinates."""
    if any(not callable(d.nodes) for d in problem.dirichlet):
        raise ValueError("coarse_fe: without a scene (Training.scene) every Dirichlet set must select its "
                         "nodes by a callable of the coordinates, to be resolved on the coarser mesh")
    if problem.mesh.cell_type != "tetra":
        raise ValueError("coarse_fe: without a scene only a tetrahedral mesh can be coarsened (gmsh remeshing)")
    h = mean_edge_length(problem.mesh)
    mesh = remesh(problem.mesh, coarsening * h)
    return dataclasses.replace(problem, mesh=mesh), f"mesh remeshed by gmsh at element size {coarsening * h:.4g}"


def _inside_tets(mesh, points, k=12):
    """``(cell, barycentric (n, 4))`` of the points in a tetrahedral mesh: each point tried in the ``k``
    cells with the nearest centroids (a KD-tree); cell -1 where none of them contains it."""
    from scipy.spatial import cKDTree

    X = mesh.points[mesh.cells]  # (c, 4, 3)
    _, cand = cKDTree(X.mean(axis=1)).query(points, k=min(k, mesh.n_cells))
    cand = cand.reshape(len(points), -1)
    T = np.transpose(X[:, 1:] - X[:, :1], (0, 2, 1))  # (c, 3, 3): columns x_i - x_0
    Tinv = np.linalg.inv(T)
    l123 = np.einsum("pkij,pkj->pki", Tinv[cand], points[:, None, :] - X[cand, 0])
    lam = np.concatenate([1.0 - l123.sum(axis=2, keepdims=True), l123], axis=2)  # (p, k, 4)
    score = lam.min(axis=2)
    best = np.argmax(score, axis=1)
    rows = np.arange(len(points))
    found = score[rows, best] >= -1e-10
    return np.where(found, cand[rows, best], -1), lam[rows, best]


def _inside_hexes(mesh, points, k=8, iterations=12):
    """``(cell, reference coordinates (n, 3))`` of the points in a trilinear hexahedral mesh: Newton's
    inversion of the map of the ``k`` cells with the nearest centroids, batched; cell -1 where none
    of them holds the point in [-1, 1]^3."""
    from scipy.spatial import cKDTree

    X = mesh.points[mesh.cells]  # (c, 8, 3)
    _, cand = cKDTree(X.mean(axis=1)).query(points, k=min(k, mesh.n_cells))
    cand = cand.reshape(len(points), -1)
    Xc = X[cand].reshape(-1, 8, 3)
    p = np.repeat(points, cand.shape[1], axis=0)
    xi = np.zeros((len(p), 3))
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        for _ in range(iterations):
            N, dN = hex_shape_functions(xi)
            r = p - np.einsum("ma,mai->mi", N, Xc)
            J = np.einsum("mai,maj->mij", Xc, dN)
            xi = np.clip(xi + np.linalg.solve(J, r[..., None])[..., 0], -2.0, 2.0)  # far cells stay bounded
        N, _ = hex_shape_functions(xi)
        miss = np.linalg.norm(p - np.einsum("ma,mai->mi", N, Xc), axis=1)
    score = np.where(miss <= 1e-10 * np.abs(points).max(), -np.abs(xi).max(axis=1), -np.inf).reshape(cand.shape)
    best = np.argmax(score, axis=1)
    rows = np.arange(len(points))
    found = score[rows, best] >= -1.0 - 1e-10
    return np.where(found, cand[rows, best], -1), xi.reshape(len(points), -1, 3)[rows, best]


def nodal_map(coarse_problem, points, max_distance: float = 1.0):
    """``(T (n_points, n_coarse_nodes) sparse, largest clip distance)``: the coarse shape functions at
    ``points``. Points inside a P1 tetrahedron or a Q1 hexahedron, batched (barycentric coordinates;
    Newton's inversion of the trilinear map); the others (P2, points outside the coarse mesh) by
    :func:`~tissuebench.cases.probes.make_probe`."""
    mesh, element = coarse_problem.mesh, coarse_problem.element
    nodes, cells = node_layout(mesh, element)
    points = np.asarray(points, float)
    rows, cols, vals, far = [], [], [], 0.0
    todo = np.arange(len(points))
    if element == "P1":
        cell, lam = _inside_tets(mesh, points)
        inside = cell >= 0
        lam = np.clip(lam[inside], 0.0, None)
        rows.append(np.repeat(np.flatnonzero(inside), 4))
        cols.append(cells[cell[inside]].ravel())
        vals.append((lam / lam.sum(axis=1, keepdims=True)).ravel())
        todo = np.flatnonzero(~inside)
    elif element == "Q1":
        cell, xi = _inside_hexes(mesh, points)
        inside = cell >= 0
        rows.append(np.repeat(np.flatnonzero(inside), 8))
        cols.append(cells[cell[inside]].ravel())
        vals.append(hex_shape_functions(np.clip(xi[inside], -1.0, 1.0))[0].ravel())
        todo = np.flatnonzero(~inside)
    for i in todo:
        pr = make_probe(mesh, nodes, element, points[i], cell_nodes=cells, label=f"fine node {i}",
                        max_distance=max_distance)
        rows.append(np.full(len(pr.nodes), i))
        cols.append(pr.nodes)
        vals.append(pr.weights)
        far = max(far, pr.distance)
    T = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                      shape=(len(points), len(nodes)))
    return T, far


@register
class CoarseFe(RomMethod):
    """A full FE model on a coarser mesh of the same body (module docstring).

    Parameters
    ----------
    coarsening : float
        Ratio of element sizes, coarse over the scene's (>= 1; 1 keeps the builder's mesh).
    model : {"full", "linear", "corotational"}
        The physics on the coarse mesh.
    rtol, max_iterations, min_increment, linear_solver
        The Newton of a static step (``model`` full or corotational), as in ``corotational_fe``.
    integrator : str, optional
        Dynamics: the time integrator (default: the scene's).
    """

    name = "coarse_fe"
    kind = "path"  # statics (linear: a map); on a dynamic scene the online model is a "trajectory"
    training_kinds = ("path", "operators", "trajectory")
    applies = Applies()  # any finite-element scene: it learns nothing, it solves the scene

    def __init__(self, coarsening: float = 2.0, model: str = "full", rtol: float = 1e-9, max_iterations: int = 15,
                 min_increment: float = 1.0 / 16, linear_solver: str = "auto", integrator: str | None = None):
        if isinstance(coarsening, bool) or not isinstance(coarsening, (int, float)) or not (
                math.isfinite(coarsening) and coarsening >= 1):
            raise ValueError(f"coarse_fe: coarsening must be a number >= 1 (ratio of element sizes), "
                             f"got {coarsening!r}")
        check_choice(self.name, "model", model, MODELS)
        newton_options(self.name, rtol, max_iterations, min_increment, linear_solver, 0)
        self.coarsening, self.model = float(coarsening), model
        self.rtol, self.max_iterations, self.min_increment = rtol, max_iterations, min_increment
        self.linear_solver, self.integrator = linear_solver, integrator

    @classmethod
    def why_not(cls, scene, options=None) -> str:
        """Besides :attr:`applies`: a mesh without builder parameters to coarsen is remeshed by gmsh,
        so where gmsh cannot be imported the method does not apply to it (named, with the fix)."""
        why = super().why_not(scene, options)
        if why or not getattr(scene, "is_fe", False) or _by_parameters_known(scene):
            return why
        return gmsh_import_error()

    def build(self, training: Training):
        scene = scene_of(training, self.name)
        if scene is not None and not scene.is_fe:
            raise ValueError(f"coarse_fe: needs a finite-element scene, {scene.name!r} is {scene.model!r}")
        fine_be = intact_backend(training, scene, self.name)
        fine = fine_be.problem
        if scene is None:  # a Problem made in Python: its mesh remeshed, its selectors re-evaluated
            cpb, how = coarse_problem(fine, self.coarsening)
        else:
            cscene, how = coarse_scene(scene, self.coarsening)
            cpb = cscene.to_problem()
        T, far = nodal_map(cpb, fine.nodes)
        fmap = FieldMap(cpb, fine, T)
        be = make_backend(type(fine_be), cpb)
        follower = fine_be.external_tangent(np.zeros(fine.ndof), 1.0) is not None
        atol = None
        if self.model == "corotational":
            be = corotational_backend(be)
            atol = 10.0 * roundoff_force(be)  # the corotational force's round-off floor (see corotational.py)
        loaded = be if follower else DeadLoads(be, fmap.to_solve(fine_be.external_force(np.zeros(fine.ndof), 1.0)))
        info = {"physics": self.model, "coarsening": self.coarsening, "mesh": how,
                "n_dof": int(cpb.ndof), "n_cells": int(cpb.mesh.n_cells), "fine_n_dof": int(fine.ndof),
                "achieved_ratio": mean_edge_length(cpb.mesh) / mean_edge_length(fine.mesh),
                "max_clip_distance": far, "loads": "scene's (follower)" if follower else "T^T f (transferred)"}
        contact = None if follower else _contact(fine, fmap)
        if is_dynamic(training, scene):
            name, options = integrator_choice(self.name, self.integrator, scene)
            linear = self.model == "linear" or (self.model == "full" and cpb.material.is_linear)
            history = load_history(training, scene)
            system = dynamic_system(loaded, training, name, linear, history)
            options = options if atol is None else with_atol(name, options, atol)
            return TrajectoryModel(self.name, system, (name, options), fmap, info, history)
        if self.model == "linear" or cpb.material.is_linear:
            model = linear_static_model(self.name, loaded, fmap, info, contact=contact)
        else:
            opts = newton_options(self.name, self.rtol, self.max_iterations, self.min_increment, self.linear_solver,
                                  len(fmap.free))
            info["linear_solver"] = opts["linear_solver"]
            if atol is not None:
                opts["atol"] = info["newton_atol"] = atol
            model = NewtonPathModel(self.name, loaded, fmap, info, opts, contact)
        model.accessible_nodes = contact_nodes_of(scene, fine) if contact else None
        return model


def _contact(fine, fmap):
    """``node -> coarse force`` of the fine problem's single point load moved onto a fine node, or None."""
    try:
        contact_load(fine, 0)
    except ValueError:
        return None
    return lambda node: fmap.to_solve(contact_load(fine, node))
