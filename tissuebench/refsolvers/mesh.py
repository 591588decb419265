"""Backend-neutral volume meshes and the node layout shared by every backend.

Conventions (every backend follows them, so vectors are interchangeable):

* ``points`` are the mesh vertices, shape ``(n_vertices, 3)``, in the user's length unit.
* Cells follow meshio/VTK vertex order: ``"tetra"`` (4 vertices) or ``"hexahedron"``
  (8 vertices, bottom face 0-1-2-3 counter-clockwise seen from above, top face 4-7).
* Cells are stored with positive orientation: a cell whose signed volume is negative only
  because of its node order is reoriented on construction (``n_reoriented`` counts them);
  a cell of (near) zero volume, a hexahedron whose corner Jacobians change sign (tangled),
  or a folded mesh (an inverted cell overlapping its neighbour across a shared face, so
  that reorienting it would count its volume twice) is refused, naming the cells.
* Discretisation nodes: for ``P1`` and ``Q1`` they are the vertices; for ``P2`` the
  vertices come first, then one node per mesh edge, edges in lexicographic order of
  their sorted vertex pair ``(a, b)``, ``a < b``.
* DOF ordering is node-major: dof ``3 * node + c`` is component ``c`` (x, y, z) of ``node``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

CELL_TYPES = {"tetra": 4, "hexahedron": 8}
# |coordinate| above this: the cube of a cell size (its volume) may overflow a float
MAX_COORDINATE = 1e100
ELEMENTS = {"P1": "tetra", "P2": "tetra", "Q1": "hexahedron"}

# Local faces with outward normals (right-hand rule) for positively oriented cells.
TET_FACES = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])
HEX_FACES = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4],
                      [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
# VTK tetra10 edge order: the local vertex pairs of nodes 4..9.
TET_EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
# Corners of the reference hexahedron [-1, 1]^3 in VTK order.
HEX_CORNERS = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                         [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], float)


def _tet_signed_volumes(points, cells):
    a, b, c, d = (points[cells[:, i]] for i in range(4))
    return np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) / 6.0


def _hex_jacobians(points, cells, ref_points):
    """det of the trilinear map's Jacobian at reference points in [-1, 1]^3, shape (n_cells, n_points)."""
    x = points[cells]  # (n, 8, 3)
    c = HEX_CORNERS
    dets = np.empty((len(cells), len(ref_points)))
    for k, (xi, eta, zeta) in enumerate(ref_points):
        dN = np.stack([c[:, 0] * (1 + c[:, 1] * eta) * (1 + c[:, 2] * zeta),
                       c[:, 1] * (1 + c[:, 0] * xi) * (1 + c[:, 2] * zeta),
                       c[:, 2] * (1 + c[:, 0] * xi) * (1 + c[:, 1] * eta)]) / 8.0  # (3, 8)
        dets[:, k] = np.linalg.det(np.einsum("nai,da->nid", x, dN))
    return dets


def hex_corner_jacobians(points, cells):
    """Jacobian determinants of the trilinear map at the 8 corners, shape (n_cells, 8)."""
    return _hex_jacobians(points, cells, HEX_CORNERS)


def folded_cell_pairs(points, cells, local_faces) -> np.ndarray:
    """Pairs ``(i, j)`` of positively oriented cells that share a face and lie on the same side
    of it (their outward normals of the shared face point the same way): the mesh folds over
    itself there, shape (n_pairs, 2). Independent of the cells' node order once oriented."""
    nf = len(local_faces)
    faces = cells[:, local_faces].reshape(-1, local_faces.shape[1])
    _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    idx = np.flatnonzero(counts[inv] == 2)
    idx = idx[np.argsort(inv[idx], kind="stable")]
    a, b = idx[0::2], idx[1::2]

    def normals(f):
        p = points[faces[f]]
        if faces.shape[1] == 3:
            return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
        return np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])  # quad: cross of the diagonals
    same_side = np.einsum("ij,ij->i", normals(a), normals(b)) > 0
    return np.column_stack([a[same_side] // nf, b[same_side] // nf])


def _refuse_folds(points, cells, negative, local_faces):
    """A mesh whose cells are oriented both ways may only differ in node order; where an
    inverted cell overlaps its neighbour the mesh is folded (its volume counted twice): refused."""
    if not negative.any() or negative.all():
        return  # uniformly oriented (the shipped liver: all negative, a node-order convention)
    pairs = folded_cell_pairs(points, cells, local_faces)
    if len(pairs):
        inverted = np.flatnonzero(negative)
        named = inverted[np.isin(inverted, pairs)]
        named = named if len(named) else np.unique(pairs)
        raise ValueError(f"folded mesh: cells {named[:12].tolist()}{' ...' if len(named) > 12 else ''} are "
                         f"inverted (negative volume) and overlap their neighbours across shared faces "
                         f"({len(inverted)} of {len(cells)} cells inverted, {len(pairs)} overlapping faces); "
                         f"fix the mesh: reorienting them would count the folded volume twice")


@dataclass(frozen=True, eq=False)
class Mesh:
    """A volume mesh of tetrahedra or hexahedra.

    Parameters
    ----------
    points : array_like, shape (n_vertices, 3)
        Vertex coordinates.
    cells : array_like of int, shape (n_cells, 4) or (n_cells, 8)
        Vertex indices per cell in meshio/VTK order.
    cell_type : {"tetra", "hexahedron"}
    reorient : bool
        Reorient cells with negative signed volume (default) instead of refusing them.
    """

    points: np.ndarray
    cells: np.ndarray
    cell_type: str
    reorient: bool = True
    n_reoriented: int = field(init=False, default=0)

    def __post_init__(self):
        if self.cell_type not in CELL_TYPES:
            raise ValueError(f"cell_type={self.cell_type!r} is not one of {sorted(CELL_TYPES)}")
        pts = np.ascontiguousarray(self.points, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"points must have shape (n, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            bad = np.argwhere(~np.isfinite(pts))[0]
            raise ValueError(f"points[{bad[0]}, {bad[1]}] = {pts[tuple(bad)]} is not finite")
        if pts.size and np.abs(pts).max() > MAX_COORDINATE:
            bad = np.unravel_index(np.argmax(np.abs(pts)), pts.shape)
            raise ValueError(f"points[{bad[0]}, {bad[1]}] = {pts[bad]:.3g}: coordinates beyond {MAX_COORDINATE:g} "
                             f"(cell volumes would overflow; a unit mistake?)")
        cells = np.ascontiguousarray(self.cells, dtype=np.int64)
        nv = CELL_TYPES[self.cell_type]
        if cells.ndim != 2 or cells.shape[1] != nv or len(cells) == 0:
            raise ValueError(f"cells for {self.cell_type!r} must have shape (n>0, {nv}), got {cells.shape}")
        if cells.min() < 0 or cells.max() >= len(pts):
            raise ValueError(f"cells reference vertex {cells.max() if cells.max() >= len(pts) else cells.min()}"
                             f" outside 0..{len(pts) - 1}")
        cells, n_flipped = self._orient(pts, cells)
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "cells", cells)
        object.__setattr__(self, "n_reoriented", n_flipped)
        self.points.setflags(write=False)
        self.cells.setflags(write=False)

    def _orient(self, pts, cells):
        h3 = float(np.prod(np.ptp(pts, axis=0)[np.ptp(pts, axis=0) > 0])) or 1.0
        tol = 1e-12 * h3
        if self.cell_type == "tetra":
            vol = _tet_signed_volumes(pts, cells)
            zero = np.abs(vol) <= tol
            if zero.any():
                i = int(np.argmax(zero))
                raise ValueError(f"cells[{i}] = {cells[i].tolist()} has zero volume ({vol[i]:.3e})")
            neg = vol < 0
            if neg.any() and not self.reorient:
                raise ValueError(f"cells[{int(np.argmax(neg))}] has negative volume and reorient=False")
            cells = cells.copy()
            cells[neg] = cells[neg][:, [0, 2, 1, 3]]
            _refuse_folds(pts, cells, neg, TET_FACES)
            return cells, int(neg.sum())
        dets = hex_corner_jacobians(pts, cells)
        scale = tol / 8.0
        pos, neg = (dets > scale).all(axis=1), (dets < -scale).all(axis=1)
        bad = ~(pos | neg)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"cells[{i}] = {cells[i].tolist()} is degenerate or tangled "
                             f"(corner Jacobians {np.round(dets[i], 12).tolist()})")
        if neg.any() and not self.reorient:
            raise ValueError(f"cells[{int(np.argmax(neg))}] has negative volume and reorient=False")
        cells = cells.copy()
        cells[neg] = cells[neg][:, [4, 5, 6, 7, 0, 1, 2, 3]]
        _refuse_folds(pts, cells, neg, HEX_FACES)
        return cells, int(neg.sum())

    # ------------------------------------------------------------------ topology
    @property
    def n_vertices(self) -> int:
        return len(self.points)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    def cell_volumes(self) -> np.ndarray:
        """Cell volumes, shape (n_cells,) (hexahedra: 2x2x2 Gauss)."""
        if self.cell_type == "tetra":
            return _tet_signed_volumes(self.points, self.cells)
        # 2x2x2 Gauss (weights 1) integrates the trilinear Jacobian exactly
        gauss = HEX_CORNERS / np.sqrt(3.0)
        return _hex_jacobians(self.points, self.cells, gauss).sum(axis=1)

    @cached_property
    def edges(self) -> np.ndarray:
        """Unique tetrahedron edges ``(a, b)``, ``a < b``, lexicographically sorted."""
        if self.cell_type != "tetra":
            raise ValueError("edges are only defined here for tetrahedral meshes (P2 nodes)")
        e = np.sort(self.cells[:, TET_EDGES].reshape(-1, 2), axis=1)
        return np.unique(e, axis=0)

    @cached_property
    def boundary_facets(self) -> np.ndarray:
        """Boundary faces with outward orientation, shape (n_facets, 3 or 4)."""
        local = TET_FACES if self.cell_type == "tetra" else HEX_FACES
        faces = self.cells[:, local].reshape(-1, local.shape[1])
        key = np.sort(faces, axis=1)
        _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
        return faces[counts[inv.ravel()] == 1]

    @cached_property
    def components(self) -> np.ndarray:
        """Connected body of each vertex, shape (n_vertices,), labels ``0 .. n_bodies - 1``: cells
        sharing a vertex belong to one body (two bodies in one file touch nowhere)."""
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components

        # each cell linked as a star from its first vertex: enough for connectivity
        rows = np.repeat(self.cells[:, 0], self.cells.shape[1] - 1)
        graph = coo_matrix((np.ones(rows.size, dtype=np.int8), (rows, self.cells[:, 1:].ravel())),
                           shape=(self.n_vertices, self.n_vertices))
        return connected_components(graph, directed=False)[1]

    def select_facets(self, where) -> np.ndarray:
        """Boundary facets all of whose vertices satisfy ``where(x) -> bool mask``."""
        f = self.boundary_facets
        mask = np.asarray(where(self.points), dtype=bool)
        if mask.shape != (self.n_vertices,):
            raise ValueError(f"facet predicate must return a mask of shape ({self.n_vertices},), got {mask.shape}")
        return f[mask[f].all(axis=1)]


def node_layout(mesh: Mesh, element: str):
    """Discretisation nodes and per-cell node connectivity for ``element``.

    Returns
    -------
    nodes : ndarray, shape (n_nodes, 3)
        Node coordinates (vertices, then edge midpoints for P2).
    cell_nodes : ndarray of int, shape (n_cells, n_local)
        Node indices per cell; P2 cells follow VTK ``tetra10`` order.
    """
    if element not in ELEMENTS:
        raise ValueError(f"element={element!r} is not one of {sorted(ELEMENTS)}")
    if ELEMENTS[element] != mesh.cell_type:
        raise ValueError(f"element={element!r} needs {ELEMENTS[element]!r} cells, mesh has {mesh.cell_type!r}")
    if element != "P2":
        return mesh.points, mesh.cells
    edges = mesh.edges
    nv = mesh.n_vertices
    local = np.sort(mesh.cells[:, TET_EDGES], axis=2)  # (n_cells, 6, 2)
    code = local[..., 0] * nv + local[..., 1]
    edge_ids = np.searchsorted(edges[:, 0] * nv + edges[:, 1], code)
    nodes = np.vstack([mesh.points, mesh.points[edges].mean(axis=1)])
    return nodes, np.hstack([mesh.cells, nv + edge_ids])


def facet_nodes(mesh: Mesh, facets, element: str) -> np.ndarray:
    """Discretisation nodes of boundary ``facets`` (n_facets, 3|4): their vertices, then for
    ``P2`` the nodes of their edges 0-1, 1-2, 0-2, shape (n_facets, 3|4|6)."""
    facets = np.asarray(facets, dtype=np.int64)
    if element != "P2":
        return facets
    nv = mesh.n_vertices
    ours = mesh.edges
    pairs = np.sort(facets[:, [[0, 1], [1, 2], [0, 2]]], axis=2)
    ids = np.searchsorted(ours[:, 0] * nv + ours[:, 1], pairs[..., 0] * nv + pairs[..., 1])
    return np.hstack([facets, nv + ids])
