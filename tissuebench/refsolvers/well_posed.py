"""Checks that a :class:`~tissuebench.refsolvers.problem.Problem` is well posed, before anything
is assembled.

* **Every body is held.** The fixed dofs must remove the six rigid-body modes
  ``u = a + w x X`` of each connected body of the mesh (cells sharing a vertex), not only of the
  mesh as a whole: a second, free body in the same file makes the stiffness singular however
  well the first is clamped (:func:`check_rigid_body_modes`, in :mod:`.rigid_modes`: the problem
  checks it of itself when built, so it sits below :mod:`.problem`, this module above).
* **Every load does work** (:func:`check_loads_do_work`, which a scene's problem passes: a
  :class:`Problem` built in code may hold an idle load, e.g. a pressure on every face of a box to
  check that the resultant vanishes). A load whose every nonzero nodal force lies on a fixed dof
  (a point load or a patch on the clamp, a body force on a body clamped everywhere) is carried by
  the supports alone: the solution is the unloaded one, and any model reproduces it with "zero
  error". Such a load is refused (:class:`IdleLoadError`); a load partly on fixed dofs is not.
"""
from __future__ import annotations

import numpy as np

from .mesh import facet_nodes
from .problem import BodyForce, FollowerPressure, PointLoad
from .rigid_modes import check_rigid_body_modes, node_bodies  # noqa: F401  (the held-bodies half of this check)

__all__ = ["IdleLoadError", "check_rigid_body_modes", "check_loads_do_work", "load_dofs"]

# a normal component below this fraction of the normal's length is round-off of a plane facet
_NORMAL_RTOL = 1e-12


class IdleLoadError(ValueError):
    """A load whose nodal forces all act on fixed dofs: it does no work.

    Attributes
    ----------
    load : int
        Its index in ``Problem.loads``.
    clamps : list of int
        The indices (in ``Problem.dirichlet``) of the sets that fix those dofs.
    n_nodes : int
        How many nodes the load acts on.
    """

    def __init__(self, message: str, load: int, clamps: list, n_nodes: int):
        super().__init__(message)
        self.load, self.clamps, self.n_nodes = load, clamps, n_nodes


def load_dofs(problem, load) -> np.ndarray:
    """The dofs ``load`` (one of ``problem.loads``) puts a nonzero force on at the reference
    configuration, sorted. A surface load counts every node of its facets, in the components of
    its traction (or, for a pressure, of its facets' normals)."""
    nodes = problem.nodes
    if isinstance(load, PointLoad):
        idx, force = load.resolve(nodes)
        on = force != 0.0
    elif isinstance(load, BodyForce):
        idx = np.arange(len(nodes))
        on = np.broadcast_to(np.asarray(load.force, float) != 0.0, (len(idx), 3))
    else:
        facets = problem.facets_of(load)
        fn = facet_nodes(problem.mesh, facets, problem.element)
        if isinstance(load, FollowerPressure):
            n = _facet_normals(problem.mesh.points, facets)
            per_facet = (np.abs(n) > _NORMAL_RTOL * np.linalg.norm(n, axis=1, keepdims=True)) & (load.pressure != 0)
        else:
            per_facet = np.broadcast_to(np.asarray(load.traction, float) != 0.0, (len(facets), 3))
        idx = fn.ravel()
        on = np.repeat(per_facet, fn.shape[1], axis=0)
    dofs = 3 * np.asarray(idx, dtype=np.int64)[:, None] + np.arange(3)
    return np.unique(dofs[on])


def _facet_normals(points, facets) -> np.ndarray:
    p = points[facets]
    if facets.shape[1] == 3:
        return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])  # quad: cross of the diagonals


def check_loads_do_work(problem) -> None:
    """Refuse (:class:`IdleLoadError`) a load of ``problem`` whose every nonzero nodal force acts on
    a fixed dof. A zero load (no dof) is not this check's business."""
    fixed = problem.fixed_dofs
    for i, load in enumerate(problem.loads):
        dofs = load_dofs(problem, load)
        if not dofs.size or np.setdiff1d(dofs, fixed).size:
            continue
        clamps = [k for k, d in enumerate(problem.dirichlet)
                  if np.intersect1d(d.resolve(problem.nodes)[0], dofs).size]
        n_nodes = len(np.unique(dofs // 3))
        held = ", ".join(f"dirichlet[{k}]" for k in clamps)
        raise IdleLoadError(f"loads[{i}] ({type(load).__name__}): every dof it acts on ({dofs.size} dofs on "
                            f"{n_nodes} nodes) is fixed by {held}; the load does no work and the solution would "
                            "be the unloaded one: load a part of the body that can move", i, clamps, n_nodes)
