"""Point probes: interpolation of a nodal field at a physical point of the mesh.

A :class:`Probe` holds the node indices and weights that interpolate a nodal field
(displacement, reference coordinates) at one point with the shape functions of the
discretisation (``P1``, ``P2`` on tetrahedra, ``Q1`` on hexahedra). :func:`make_probe`
builds it:

* a point that coincides with a discretisation node (within ``1e-9`` x the bounding-box
  diagonal) is that node with weight 1, so a monitor on a node reads exactly the nodal
  value;
* otherwise the cell containing the point is located (tetrahedra: barycentric
  coordinates; hexahedra: Newton inversion of the trilinear map from the cell centre)
  and the weights are the element's shape functions there;
* a point slightly outside the mesh (a point of a curved surface, off the faceted
  boundary) is replaced by the closest point of the mesh, and the weights are those of
  its local coordinates, clipped to the cell (tetrahedra: exact closest point;
  hexahedra: Gauss-Newton projected on the reference cube); :attr:`Probe.distance`
  records how far it moved. A point farther than ``max_distance`` x the size of that
  cell is not on the body: ``ValueError``.

Probes fix the monitor location in physical space, so a mesh-refinement study of a
monitored value is not polluted by the O(h) wandering of a nearest node on
unstructured meshes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..refsolvers.mesh import HEX_CORNERS, ELEMENTS, TET_EDGES, TET_FACES, Mesh, node_layout

__all__ = ["Probe", "make_probe", "tet_shape_weights", "hex_shape_functions"]

# Cells whose bounding box is nearer than the nearest vertex are examined for points
# outside the mesh; this many of the nearest such boxes at most (bounds the cost for a
# far point, which is an error anyway).
_MAX_OUTSIDE_CANDIDATES = 64


@dataclass(frozen=True, eq=False)
class Probe:
    """Interpolation of a nodal field at one physical point.

    Attributes
    ----------
    nodes : ndarray of int, shape (k,)
        Discretisation node indices (k = 1 at a node, 4 for P1, 10 for P2, 8 for Q1).
    weights : ndarray, shape (k,)
        Shape-function values at the point; they sum to 1.
    point : ndarray, shape (3,)
        The requested point (length unit of the mesh).
    location : ndarray, shape (3,)
        The interpolated reference position ``weights @ nodes_xyz[nodes]``; equal to
        ``point`` unless the point lay outside the mesh and was clipped into a cell.
    distance : float
        ``|location - point|`` (length unit); 0 up to round-off inside the mesh.
    cell : int
        The cell used, or -1 when the point is a node.
    """

    nodes: np.ndarray
    weights: np.ndarray
    point: np.ndarray
    location: np.ndarray
    distance: float
    cell: int

    def __call__(self, field) -> np.ndarray:
        """Interpolated value of ``field`` (shape (n_nodes, ...)) at the point, shape (...)."""
        return np.tensordot(self.weights, np.asarray(field)[self.nodes], axes=1)


def make_probe(mesh: Mesh, nodes, element: str, point, *, cell_nodes=None, label: str = "",
               max_distance: float = 0.5) -> Probe:
    """The :class:`Probe` interpolating nodal fields of ``element`` at ``point``.

    Parameters
    ----------
    mesh : Mesh
        Tetrahedra (``P1``, ``P2``) or hexahedra (``Q1``).
    nodes : array_like, shape (n_nodes, 3)
        Discretisation node coordinates (:func:`~tissuebench.refsolvers.mesh.node_layout`).
    element : {"P1", "P2", "Q1"}
    point : array_like, shape (3,)
        Physical point (length unit of the mesh).
    cell_nodes : ndarray of int, shape (n_cells, n_local), optional
        Node indices per cell (``problem.layout[1]``); computed when not given.
    label : str
        Name of the point in error messages (e.g. the monitor name).
    max_distance : float
        Largest accepted distance of a point outside the mesh, as a fraction of the size
        (longest vertex-to-vertex distance) of the cell it is clipped into.

    Raises
    ------
    ValueError
        Element incompatible with the mesh, or a point farther from the mesh than
        ``max_distance`` x the local cell size (the message names ``label``, the point
        and the distance).
    """
    if ELEMENTS.get(element) != mesh.cell_type:
        raise ValueError(f"element={element!r} does not fit a {mesh.cell_type!r} mesh")
    nodes = np.asarray(nodes, float)
    p = np.asarray(point, float).reshape(3)
    diag = float(np.linalg.norm(np.ptp(mesh.points, axis=0))) or 1.0
    d_node = np.linalg.norm(nodes - p, axis=1)
    i = int(np.argmin(d_node))
    if d_node[i] <= 1e-9 * diag:
        return Probe(np.array([i]), np.ones(1), p, nodes[i].copy(), float(d_node[i]), -1)
    cand = _candidate_cells(mesh, p)
    local, x = _clipped_local(mesh, cand, p)
    dist = np.linalg.norm(x - p, axis=1)
    k = int(np.argmin(dist))
    cell = int(cand[k])
    size = _cell_size(mesh.points[mesh.cells[cell]])
    if dist[k] > max_distance * size:
        name = f"{label!r} " if label else ""
        raise ValueError(f"point {name}{p.tolist()} is not on the body: it lies {dist[k]:.4g} from the mesh, "
                         f"more than {max_distance} x the local cell size {size:.4g}")
    if cell_nodes is None:
        cell_nodes = node_layout(mesh, element)[1]
    weights = _weights(element, local[k])
    idx = np.asarray(cell_nodes[cell], dtype=np.int64)
    return Probe(idx, weights, p, weights @ nodes[idx], float(np.linalg.norm(weights @ nodes[idx] - p)), cell)


def _candidate_cells(mesh, p):
    """Cells that may contain ``p`` or hold its closest mesh point.

    The closest mesh point is no farther than the nearest vertex, so only cells whose
    bounding box lies within that distance qualify; every box that contains ``p``
    is kept, plus the nearest others up to :data:`_MAX_OUTSIDE_CANDIDATES`.
    """
    xc = mesh.points[mesh.cells]  # (n_cells, n_vertices, 3)
    gap = np.maximum(xc.min(axis=1) - p, 0.0) + np.maximum(p - xc.max(axis=1), 0.0)
    box_dist = np.linalg.norm(gap, axis=1)
    d_vertex = np.linalg.norm(mesh.points - p, axis=1).min()
    near = np.flatnonzero(box_dist <= d_vertex * (1 + 1e-12))
    inside = near[box_dist[near] == 0.0]
    rest = near[box_dist[near] > 0.0]
    rest = rest[np.argsort(box_dist[rest], kind="stable")[:_MAX_OUTSIDE_CANDIDATES]]
    return np.concatenate([inside, rest])


def _clipped_local(mesh, cand, p):
    """Local coordinates of the point of each cell ``cand`` closest to ``p`` (``p``
    itself in a cell containing it): barycentric, shape (m, 4), or in [-1, 1]^3, shape
    (m, 3); and that physical point, shape (m, 3)."""
    X = mesh.points[mesh.cells[cand]]
    if mesh.cell_type == "tetra":
        x = _tet_closest_point(X, p)
        # round-off only: the closest point lies in the cell
        lam = np.maximum(_barycentric(X, x), 0.0)
        lam /= lam.sum(axis=1, keepdims=True)
        return lam, np.einsum("ma,mai->mi", lam, X)
    xi = _hex_closest_local(X, p)
    N, _ = hex_shape_functions(xi)
    return xi, np.einsum("ma,mai->mi", N, X)


def _barycentric(X, p):
    """Barycentric coordinates of the points ``p`` ((3,) or (m, 3)) in the tetrahedra
    ``X`` (m, 4, 3), shape (m, 4)."""
    T = np.transpose(X[:, 1:] - X[:, :1], (0, 2, 1))  # (m, 3, 3): columns x_i - x_0
    l123 = np.linalg.solve(T, (p - X[:, 0])[..., None])[..., 0]
    return np.column_stack([1.0 - l123.sum(axis=1), l123])


def _tet_closest_point(X, p):
    """Point of each tetrahedron ``X`` (m, 4, 3) closest to ``p``, shape (m, 3).

    The closest point of a convex polytope is ``p`` itself (inside), the orthogonal
    projection onto a face plane when it falls in the face, or the closest point of an
    edge (vertices included); every candidate is a point of the cell, so the nearest
    of them is exact.
    """
    m = len(X)
    inside = _barycentric(X, p).min(axis=1) >= 0.0
    best = np.where(inside[:, None], p, np.nan)
    dist = np.where(inside, 0.0, np.inf)

    def keep(q, valid):
        d = np.where(valid, np.linalg.norm(q - p, axis=1), np.inf)
        better = d < dist
        best[better], dist[better] = q[better], d[better]

    for a, b, c in TET_FACES:
        e = np.stack([X[:, b] - X[:, a], X[:, c] - X[:, a]], axis=1)  # (m, 2, 3)
        st = np.linalg.solve(e @ np.transpose(e, (0, 2, 1)), (e @ (p - X[:, a])[..., None]))[..., 0]
        keep(X[:, a] + np.einsum("mk,mki->mi", st, e), (st >= 0).all(axis=1) & (st.sum(axis=1) <= 1))
    for a, b in TET_EDGES:
        d = X[:, b] - X[:, a]
        t = np.clip(np.einsum("mi,mi->m", p - X[:, a], d) / np.einsum("mi,mi->m", d, d), 0.0, 1.0)
        keep(X[:, a] + t[:, None] * d, np.ones(m, bool))
    return best


def _hex_closest_local(X, p, iters=50):
    """Reference coordinates in [-1, 1]^3 of the point of each trilinear hexahedron
    ``X`` (m, 8, 3) closest to ``p``, shape (m, 3).

    Gauss-Newton on ``|x(xi) - p|`` from the cell centre, projected on [-1, 1]^3: a
    coordinate at its bound whose step points outwards is held there and the step is
    solved for the others (least squares), which projects an outside point orthogonally
    onto the face. Inside the cell this is Newton's inversion of the trilinear map.
    """
    xi = np.zeros((len(X), 3))
    for _ in range(iters):
        N, dN = hex_shape_functions(xi)
        r = p - np.einsum("ma,mai->mi", N, X)
        J = np.einsum("mai,maj->mij", X, dN)  # dx_i / dxi_j
        step = np.einsum("mij,mj->mi", np.linalg.pinv(J), r)
        held = (np.abs(xi) >= 1.0) & (step * xi > 0)
        if held.any():
            # pinv of J with the held columns zeroed: least squares over the free ones
            Jf = J * ~held[:, None, :]
            step = np.einsum("mij,mj->mi", np.linalg.pinv(Jf), r)
        new = np.clip(xi + step, -1.0, 1.0)
        done = np.max(np.abs(new - xi)) < 1e-13
        xi = new
        if done:
            break
    return xi


def hex_shape_functions(xi):
    """Trilinear shape functions of the VTK hexahedron at reference points ``xi``.

    Parameters
    ----------
    xi : array_like, shape (m, 3)
        Reference coordinates in [-1, 1]^3.

    Returns
    -------
    N : ndarray, shape (m, 8)
    dN : ndarray, shape (m, 8, 3)
        Derivatives ``dN_a / dxi_j``.
    """
    xi = np.atleast_2d(np.asarray(xi, float))
    f = 1.0 + xi[:, None, :] * HEX_CORNERS[None]  # (m, 8, 3): 1 + c_a,j xi_j
    N = f.prod(axis=2) / 8.0
    dN = np.stack([HEX_CORNERS[None, :, j] * np.prod(np.delete(f, j, axis=2), axis=2) for j in range(3)],
                  axis=2) / 8.0
    return N, dN


def tet_shape_weights(lam, element: str) -> np.ndarray:
    """P1 (4) or P2 (10, VTK ``tetra10`` order) shape-function values at barycentric
    coordinates ``lam`` (shape (4,)): vertices ``lam_i (2 lam_i - 1)``, then the edges of
    :data:`~tissuebench.refsolvers.mesh.TET_EDGES` ``4 lam_a lam_b``."""
    lam = np.asarray(lam, float)
    if element == "P1":
        return lam.copy()
    return np.concatenate([lam * (2.0 * lam - 1.0), 4.0 * lam[TET_EDGES[:, 0]] * lam[TET_EDGES[:, 1]]])


def _weights(element, local):
    if element == "Q1":
        return hex_shape_functions(local[None])[0][0]
    return tet_shape_weights(local, element)


def _cell_size(X):
    """Longest distance between two vertices of a cell (length unit)."""
    return float(np.max(np.linalg.norm(X[:, None] - X[None], axis=2)))
