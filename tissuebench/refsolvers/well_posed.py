"""Checks that a :class:`~tissuebench.refsolvers.problem.Problem` is well posed, before anything
is assembled.

* **Every body is held.** The fixed dofs must remove the six rigid-body modes
  ``u = a + w x X`` of each connected body of the mesh (cells sharing a vertex), not only of the
  mesh as a whole: a second, free body in the same file makes the stiffness singular however
  well the first is clamped.
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


def node_bodies(problem) -> np.ndarray:
    """Connected body of each discretisation node of ``problem``, shape (n_nodes,)."""
    nodes, cell_nodes = problem.layout
    labels = np.empty(len(nodes), dtype=np.int64)
    labels[cell_nodes] = problem.mesh.components[problem.mesh.cells[:, 0]][:, None]
    return labels


def _rigid_rank(coords, dofs) -> int:
    """How many of the 6 rigid-body modes the fixed ``dofs`` remove on nodes at ``coords`` (the
    nodes of one body). Centred and scaled by the body's size: the verdict does not depend on the
    unit of length (a 1 m bar and the same bar in pm are the same problem)."""
    if not len(dofs):
        return 0
    centre = coords.mean(axis=0)
    size = float(np.max(np.abs(coords - centre), initial=0.0)) or 1.0
    X = (coords[dofs // 3] - centre) / size
    comps = dofs % 3
    rows = np.zeros((len(dofs), 6))
    rows[np.arange(len(dofs)), comps] = 1.0
    e = np.eye(3)
    for k in range(3):  # rotation part: (w x X)_c
        rows[:, 3 + k] = np.cross(e[k], X)[np.arange(len(dofs)), comps]
    s = np.linalg.svd(rows, compute_uv=False)
    return int(np.sum(s > 1e-10 * max(1.0, s.max(initial=0.0))))


def _body_text(problem, labels, body) -> str:
    idx = np.flatnonzero(labels == body)
    lo, hi = problem.nodes[idx].min(axis=0), problem.nodes[idx].max(axis=0)
    return (f"body {body} of {labels.max() + 1} (a connected part of the mesh: {len(idx)} nodes, e.g. node "
            f"{idx[0]}, bounding box {np.round(lo, 6).tolist()} to {np.round(hi, 6).tolist()})")


def check_rigid_body_modes(problem) -> None:
    """Refuse a constraint set that leaves a rigid-body mode of a body of ``problem`` free: a
    ValueError naming the body (nodes, a node id, its bounding box) when the mesh has several."""
    dofs = problem.fixed_dofs
    labels = node_bodies(problem)
    n_bodies = int(labels.max()) + 1
    if n_bodies == 1:
        rank = _rigid_rank(problem.nodes, dofs)
        if rank < 6:
            raise ValueError(f"dirichlet: the fixed dofs remove only {rank} of 6 rigid-body modes")
        return
    held = np.bincount(labels[dofs // 3], minlength=n_bodies)
    free = np.flatnonzero(held == 0)
    if len(free):
        raise ValueError(f"dirichlet: {_body_text(problem, labels, free[0])} has no fixed dof: its 6 rigid-body "
                         f"modes are free ({len(free)} of the {n_bodies} bodies of the mesh are held nowhere); "
                         "hold every body, or mesh the body as one piece")
    for body in range(n_bodies):
        mine = labels == body
        local = np.cumsum(mine) - 1  # node index -> index among this body's nodes
        own = dofs[mine[dofs // 3]]
        rank = _rigid_rank(problem.nodes[mine], 3 * local[own // 3] + own % 3)
        if rank < 6:
            raise ValueError(f"dirichlet: the fixed dofs remove only {rank} of 6 rigid-body modes of "
                             f"{_body_text(problem, labels, body)}; hold every body")


def load_dofs(problem, load) -> np.ndarray:
    """The dofs ``load`` (one of ``problem.loads``) puts a nonzero force on at the reference
    configuration, sorted. A surface load counts every node of its facets, in the components of
    its traction (or, for a pressure, of its facets' normals)."""
    from .problem import BodyForce, FollowerPressure, PointLoad

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
