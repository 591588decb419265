"""What the PGD methods learn from: operators, not snapshots (``training_kinds = ("operators",)``).

:func:`pgd_training` builds the :class:`~tissuebench.rom.base.Training` of a scene:

* a 1D scene (heat1d_source, ``model = "poisson1d"``): ``system`` = the assembled
  :class:`~tissuebench.refsolvers.line_models.LineSystem` (its stiffness K);
* a finite-element scene (cornea_cut): ``backend`` = the backend of the **uncut** scene
  (the vademecum is the response of the intact organ; cuts are enriched online), whose
  linear stiffness ``tangent(0)`` and point-load force vector are used.

``Training.scene`` carries the scene itself (mesh, ``[cut]``, ``[methods.*]``, model
parameters). :func:`family_from_training` turns such a Training into the
:class:`~.family.PointLoadFamily` of the vademecum. A Training made by other code may
instead give ``info["case"]`` (+ ``"resolution"``) and, for FE scenes, optionally
``info["accessible_nodes"]`` (mesh node ids) and ``info["weights"]``.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ...reference.formulation import scene_backend
from ...refsolvers import PointLoad, make_backend
from ...refsolvers.line_models import assemble_line_model
from ..base import Training
from ..training_scene import scene_of as training_scene_of
from .family import PointLoadFamily, anterior_nodes, line_family, nodal_areas, surface_family

__all__ = ["pgd_training", "scene_of", "uncut_backend", "family_from_training", "contact_force"]


def pgd_training(scene, backend: str = "skfem") -> Training:
    """The operators Training of ``scene`` (module docstring)."""
    info = {"case": scene.name, "resolution": scene.resolution, "training": "operators"}
    if not scene.is_fe:
        return Training(system=assemble_line_model(scene.line_model()), scene=scene, info=info)

    uncut = dataclasses.replace(scene, cut=None)
    be = scene_backend(uncut, backend)  # the reference's formulation (mean-dilatation Q1 on the cornea)
    return Training(backend=be, free_dofs=np.asarray(be.problem.free_dofs), scene=scene,
                    info={**info, "backend": backend})


def scene_of(training: Training, who: str):
    """The scene a Training refers to (:func:`~..training_scene.scene_of`); ValueError when it names none."""
    return training_scene_of(training, who, required=True)


def uncut_backend(training: Training, scene, who: str):
    """The training backend if it is the intact mesh's, else one built on the uncut scene."""
    be = training.backend
    if be is None:
        raise ValueError(f"{who}: a finite-element scene needs training.backend")
    uncut = dataclasses.replace(scene, cut=None)
    if be.problem.mesh.n_vertices == uncut.mesh.n_vertices:
        return be

    return make_backend(type(be), uncut.to_problem())


def contact_force(problem) -> np.ndarray:
    """The (3,) force of the problem's single point load (the scalpel contact) [N]."""

    pls = [ld for ld in problem.loads if isinstance(ld, PointLoad)]
    if len(pls) != 1:
        raise ValueError(f"the contact needs exactly one point load in the problem, found {len(pls)}")
    idx, force = pls[0].resolve(problem.nodes)
    if len(idx) != 1:
        raise ValueError(f"the contact point load acts on {len(idx)} nodes; one expected")
    return np.asarray(force[0], float)


def _line(training, scene, s_nodes):
    system = training.system
    if system is None or getattr(system, "model", None) != "poisson1d":
        raise ValueError("pgd: a 1D scene needs training.system = the assembled poisson1d LineSystem")
    p = scene.model_params or {}
    if s_nodes is None:
        s_nodes = scene.paper.get("methods", {}).get("pgd", {}).get(f"s_nodes_{scene.resolution}")
    k = float(p.get("conductivity", 1.0))
    # K is the stiffness of -k u''; the family's intensity q is that of the scene's [model]
    return line_family(system.K, np.asarray(scene.mesh.points)[:, 0], system.free, float(p.get("q", 1.0)),
                       p.get("source_range"), s_nodes), k


def family_from_training(training: Training, who: str = "pgd", s_nodes=None) -> PointLoadFamily:
    """The point-load family of a Training (module docstring)."""
    scene = scene_of(training, who)
    if not scene.is_fe:
        return _line(training, scene, s_nodes)[0]
    be = uncut_backend(training, scene, who)
    pb = be.problem
    if np.any(pb.prescribed_values(1.0) != 0.0):
        raise ValueError(f"{who}: nonzero prescribed displacements are not supported (homogeneous Dirichlet only)")
    info = training.info or {}
    mesh = pb.mesh
    nodes, w = info.get("accessible_nodes"), info.get("weights")
    minfo = dataclasses.replace(scene, cut=None).mesh_info
    if nodes is None:
        nodes = anterior_nodes(mesh, minfo, pb.free_dofs, who)
    nodes = np.asarray(nodes, dtype=np.int64)
    if w is None and "nodes_per_layer" in minfo:
        # lumped areas over the whole anterior layer (clamped rim included), then the accessible ones
        layer = minfo["layers"] * minfo["nodes_per_layer"] + np.arange(minfo["nodes_per_layer"])
        if np.isin(nodes, layer).all():
            w = nodal_areas(mesh, layer)[np.searchsorted(layer, nodes)]
    w = nodal_areas(mesh, nodes) if w is None else np.asarray(w, float)
    K = be.tangent(np.zeros(be.ndof))
    return surface_family(K, pb.nodes, pb.free_dofs, nodes, w, contact_force(pb))
