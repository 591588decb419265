"""Every body is held: the fixed dofs of a :class:`~tissuebench.refsolvers.problem.Problem` must
remove the six rigid-body modes ``u = a + w x X`` of each connected body of the mesh (cells sharing
a vertex), not only of the mesh as a whole: a second, free body in the same file makes the
stiffness singular however well the first is clamped.

The check a :class:`~tissuebench.refsolvers.problem.Problem` makes of itself when it is built, so
it reads the problem's attributes only and sits below it (:mod:`.well_posed`, which checks the
loads against the problem's load types, sits above it).
"""
from __future__ import annotations

import numpy as np

__all__ = ["check_rigid_body_modes", "node_bodies"]


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
