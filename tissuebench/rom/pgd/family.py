"""The parametric problem a PGD vademecum solves: a point load that moves over a set of
parameter nodes (pgd-vademecum-cutting §2 and Appendix A).

``K u(s) = f(s)`` on the free dofs, with ``K`` the stiffness of the space discretisation
(poisson1d: ``-k u''``; 3D FE: the tangent at ``u = 0``, i.e. linear elasticity with the
material's Lamé constants) and ``f(s)`` the nodal load of the point load at ``s``. The
vademecum uses these operators only, no snapshot of a full solve: in separated form

    A = K ⊗ W,     f = sum_j kron(f(s_j), w_j e_j),

where ``s_j`` are the parameter nodes and ``W = diag(w)`` the quadrature weights of the
parameter measure (nodal quadrature: trapezoid weights on a 1D interval, lumped nodal
areas on a surface), so that the doubly weak form ``∫_S ∫_Ω ... ds`` becomes
``sum_j w_j (...)(s_j)``. The parameter functions S_i are then nodal values at ``s_j``.

Two families:

* :func:`line_family` (heat1d_source): ``s`` in an interval of the 1D mesh; the load of
  a source at ``s`` between nodes is distributed by the P1 shape functions (``f_k =
  -q N_k(s)``, the sign convention of :mod:`~tissuebench.refsolvers.line_models`).
* :func:`surface_family` (cornea): ``s`` is a node of the accessible surface; the load
  is the force vector ``P`` (3,) on that node.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["PointLoadFamily", "line_family", "surface_family", "anterior_nodes", "nodal_areas"]


@dataclass(eq=False)
class PointLoadFamily:
    """Operators of a moving point load (see the module docstring).

    Attributes
    ----------
    kind : {"line", "surface"}
    K : (n_free, n_free) sparse, stiffness on the free dofs
    loads : (n_free, n_s) sparse, column j = load at parameter node j (free dofs)
    weights : (n_s,) quadrature weights of the parameter measure (length or area)
    coords : (n_s,) parameter coordinates (line) or (n_s, 3) node positions (surface)
    nodes : (n_s,) int, mesh node of each parameter node (surface; line: None)
    free_dofs : (n_free,) int; ndof : int (all dofs)
    force : float (line: intensity q) or (3,) force vector (surface) [N]
    x : (n_nodes,) line mesh coordinates (line only)
    """

    kind: str
    K: sp.csr_matrix
    loads: sp.csc_matrix
    weights: np.ndarray
    coords: np.ndarray
    nodes: np.ndarray | None
    free_dofs: np.ndarray
    ndof: int
    force: object
    x: np.ndarray | None = None

    def __post_init__(self):
        self.free_index = np.full(self.ndof, -1, dtype=np.int64)
        self.free_index[self.free_dofs] = np.arange(len(self.free_dofs))

    def parameter_of_node(self, node: int) -> int:
        """Index of mesh ``node`` among the parameter nodes (surface), -1 if it is not one."""
        table = self.__dict__.get("_node_table")
        if table is None:
            table = self.__dict__["_node_table"] = {int(n): j for j, n in enumerate(self.nodes)}
        return table.get(int(node), -1)

    @property
    def n_parameters(self) -> int:
        return len(self.weights)

    @property
    def n_free(self) -> int:
        return len(self.free_dofs)

    def line_weights(self, s: float) -> tuple[np.ndarray, np.ndarray]:
        """(node ids, P1 shape-function values) of the mesh element holding ``s``
        (ValueError if ``s`` is off the mesh)."""
        x = self.x
        if not (x[0] - 1e-12 * abs(x[-1] - x[0]) <= s <= x[-1] + 1e-12 * abs(x[-1] - x[0])):
            raise ValueError(f"position s = {s!r} is off the mesh [{x[0]:g}, {x[-1]:g}]")
        k = int(np.clip(np.searchsorted(x, s) - 1, 0, len(x) - 2))
        t = (s - x[k]) / (x[k + 1] - x[k])
        return np.array([k, k + 1]), np.array([1.0 - t, t])

    def load_at(self, position) -> tuple[np.ndarray, np.ndarray]:
        """Load of a point load at ``position`` (line: coordinate; surface: mesh node id):
        (indices into the free dofs, values). Fixed dofs are dropped."""
        if self.kind == "line":
            nodes, N = self.line_weights(float(position))
            dofs, vals = nodes, -float(self.force) * N
        else:
            dofs, vals = 3 * int(position) + np.arange(3), np.asarray(self.force, float)
        idx = self.free_index[dofs]
        keep = (idx >= 0) & (vals != 0.0)
        return idx[keep], vals[keep]


def _trapezoid(s):
    w = np.zeros(len(s))
    h = np.diff(s)
    w[:-1] += h / 2
    w[1:] += h / 2
    return w


def line_family(K, x, free_dofs, q: float = 1.0, s_range=None, s_nodes: int | None = None) -> PointLoadFamily:
    """The moving unit source of a 1D P1 model (poisson1d: ``K`` the stiffness of ``-k u''``).

    Parameters
    ----------
    K : (n, n) sparse, all dofs; x : (n,) sorted node coordinates; free_dofs : (n_free,)
    q : float, source intensity (the load of a source at node i is ``-q`` at i)
    s_range : (lo, hi), optional, parameter interval (default: the mesh)
    s_nodes : int, optional, number of uniform parameter nodes (default: the mesh nodes in range)
    """
    x = np.asarray(x, float)
    if np.any(np.diff(x) <= 0):
        raise ValueError("line_family: node coordinates x must be strictly increasing")
    lo, hi = (x[0], x[-1]) if s_range is None else (float(s_range[0]), float(s_range[1]))
    if not x[0] - 1e-12 <= lo < hi <= x[-1] + 1e-12:
        raise ValueError(f"line_family: s_range = {s_range!r} must lie in the mesh [{x[0]:g}, {x[-1]:g}]")
    if s_nodes is None:
        s = x[(x >= lo - 1e-12) & (x <= hi + 1e-12)]
    elif isinstance(s_nodes, bool) or int(s_nodes) != s_nodes or s_nodes < 2:
        raise ValueError(f"line_family: s_nodes must be an integer >= 2, got {s_nodes!r}")
    else:
        s = np.linspace(lo, hi, int(s_nodes))
    free = np.asarray(free_dofs)
    fam = PointLoadFamily("line", sp.csr_matrix(K)[free][:, free], None, _trapezoid(s), s, None, free,
                          len(x), float(q), x)
    cols = [fam.load_at(sj) for sj in s]
    rows = np.concatenate([c[0] for c in cols])
    fam.loads = sp.csc_matrix((np.concatenate([c[1] for c in cols]),
                               (rows, np.repeat(np.arange(len(s)), [len(c[0]) for c in cols]))),
                              shape=(len(free), len(s)))
    return fam


def surface_family(K, points, free_dofs, nodes, weights, force) -> PointLoadFamily:
    """Point load ``force`` (3,) moving over the mesh ``nodes`` (accessible surface).

    ``K`` (ndof, ndof) linear stiffness on all dofs (node-major xyz), ``points`` (n_nodes, 3),
    ``weights`` (n_s,) the measure of each parameter node (e.g. :func:`nodal_areas`).
    """
    nodes, w = np.asarray(nodes, dtype=np.int64), np.asarray(weights, float)
    force = np.asarray(force, float)
    if force.shape != (3,) or not np.any(force):
        raise ValueError(f"surface_family: force must be a non-zero (3,) vector, got {force!r}")
    if w.shape != nodes.shape or np.any(w <= 0):
        raise ValueError("surface_family: weights must be positive, one per node")
    free = np.asarray(free_dofs)
    fam = PointLoadFamily("surface", sp.csr_matrix(K)[free][:, free], None, w, np.asarray(points)[nodes],
                          nodes, free, K.shape[0], force)
    cols = [fam.load_at(n) for n in nodes]
    if any(len(c[0]) == 0 for c in cols):
        raise ValueError("surface_family: a parameter node has all its dofs fixed (no load can act there)")
    rows = np.concatenate([c[0] for c in cols])
    fam.loads = sp.csc_matrix((np.concatenate([c[1] for c in cols]),
                               (rows, np.repeat(np.arange(len(nodes)), [len(c[0]) for c in cols]))),
                              shape=(len(free), len(nodes)))
    return fam


def anterior_nodes(mesh, info, free_dofs, who: str = "anterior_nodes") -> np.ndarray:
    """Nodes of the anterior (outer) surface of a ``cornea_dome`` mesh whose three dofs are
    free (the clamped base ring is not accessible), sorted by node id; ``who`` names the
    method in the error of a mesh without layers."""
    if "layers" not in info or "nodes_per_layer" not in info:
        raise ValueError(f"{who}: the parameter domain of the vademecum is the anterior surface of a layered shell "
                         f"mesh (builder 'cornea_dome'); this scene's mesh ({info.get('builder', 'a mesh file')}) "
                         "has no layers")
    start = info["layers"] * info["nodes_per_layer"]
    cand = np.arange(start, start + info["nodes_per_layer"])
    free = np.zeros(3 * mesh.n_vertices, bool)
    free[np.asarray(free_dofs)] = True
    return cand[free.reshape(-1, 3)[cand].all(axis=1)]


def nodal_areas(mesh, nodes) -> np.ndarray:
    """Lumped area (quarter of each boundary quad, third of each triangle) of ``nodes``
    over the boundary facets whose vertices are all in ``nodes`` [length^2]."""
    nodes = np.asarray(nodes)
    facets = mesh.boundary_facets
    on = np.isin(facets, nodes).all(axis=1)
    area = np.zeros(mesh.n_vertices)
    p = mesh.points
    for f in facets[on]:
        a = p[f[1]] - p[f[0]]
        b = p[f[2]] - p[f[0]]
        A = 0.5 * np.linalg.norm(np.cross(a, b))
        if len(f) == 4:
            A += 0.5 * np.linalg.norm(np.cross(p[f[2]] - p[f[0]], p[f[3]] - p[f[0]]))
        area[f] += A / len(f)
    out = area[nodes]
    if np.any(out <= 0):
        raise ValueError("nodal_areas: a node has no boundary facet among the given nodes")
    return out
