"""Geometry of one radial incision on the cornea for the cutting model: the nodes along it,
the cut lengths, the enriched (cracking) nodes and the accessible strip around it.

Cut length (the cutting parameter): the incision of ``[cut]`` snaps to the anterior
nodes ``n_0 .. n_M`` on its half-plane (radii r_0 < ... < r_M, the ends nearest to the
requested radii). A cut of length ``c`` is the incision from r_0 to r_(c+1): the
scalpel has gone past the anterior nodes ``n_1 .. n_c`` (the *cut nodes along the
incision*), which are cracked (duplicated in the full FE mesh, enriched in the reduced
model) at every node level down to the cut depth except the bottom one (crack front);
``n_0`` and ``n_(c+1)`` are its crack-front ends. ``c = 0`` is the intact cornea;
``c`` ranges over ``0 .. M - 1`` (a cut of one element has only front nodes and opens
nothing: :func:`~tissuebench.cases.cutting.cut_mesh` refuses it). The scalpel tip
(contact position of the study) is ``n_0`` for ``c = 0`` and ``n_(c+1)`` for a cut.

The accessible strip (the vademecum's parameter domain of the cutting model, the
paper's "strip of 3 x 18 nodes around the zone where the incision is made") is the
incision's anterior nodes ``n_0 .. n_M`` and their neighbours on the anterior surface
(``rings`` rings of quad neighbours), without the nodes that continue the line beyond
its ends.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...cases.cutting import cut_mesh

__all__ = ["IncisionStrip", "incision_strip"]

_QUAD_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])


@dataclass(eq=False)
class IncisionStrip:
    """One incision and its cut lengths (module docstring).

    Attributes
    ----------
    angle_deg : float; radii : (M+1,) anterior radii of n_0 .. n_M [mm]
    line : (M+1,) int, the anterior nodes n_0 .. n_M
    depth_fraction : float (requested); layers_cut : int
    enriched : (n_enr,) int, cracked nodes of the longest cut, in cut order (the nodes
        cracked at length c come first: ``enriched[:n_enriched[c]]``)
    n_enriched : (M,) int, number of cracked nodes at each cut length 0 .. M-1
    copies : list over c of (n_enriched[c],) int, the cut mesh's copy node of each
        cracked node (in the order of ``enriched``); copies are numbered after the
        original nodes, as :func:`~tissuebench.cases.cutting.cut_mesh` does
    accessible : (n_s,) int, the strip's anterior nodes (sorted)
    normals : dict node -> (3,) outward unit normal of the anterior surface
    """

    angle_deg: float
    radii: np.ndarray
    line: np.ndarray
    depth_fraction: float
    layers_cut: int
    enriched: np.ndarray
    n_enriched: np.ndarray
    copies: list
    accessible: np.ndarray
    centre: np.ndarray

    @property
    def max_cut_length(self) -> int:
        return len(self.n_enriched) - 1

    def incision(self, c: int) -> dict:
        """The ``[cut]`` incision of cut length ``c >= 1``."""
        self.check_length(c)
        if c == 0:
            raise ValueError("cut_length = 0 is the intact cornea: no incision")
        return {"angle_deg": self.angle_deg, "radii": [float(self.radii[0]), float(self.radii[c + 1])]}

    def tip(self, c: int) -> int:
        """Scalpel node at cut length ``c`` (n_0 uncut, else the advancing front n_(c+1))."""
        self.check_length(c)
        return int(self.line[0] if c == 0 else self.line[c + 1])

    def check_length(self, c) -> int:
        if isinstance(c, bool) or float(c) != int(c) or not 0 <= int(c) <= self.max_cut_length:
            raise ValueError(f"cut_length = {c!r}: expected an integer in 0..{self.max_cut_length} (the cut "
                             f"nodes along the incision at {self.angle_deg:g} deg, radii {self.radii[0]:.4g}.."
                             f"{self.radii[-1]:.4g} mm; a longer cut leaves the strip)")
        return int(c)

    def normal(self, points, node) -> np.ndarray:
        """Outward unit normal of the spherical anterior surface at ``node``."""
        d = points[node] - self.centre
        return d / np.linalg.norm(d)


def _line_nodes(points, anterior, centre, angle, radii, tol=1e-6):
    a = math.radians(angle)
    d = points[anterior] - centre
    n, e = np.array([-math.sin(a), math.cos(a), 0.0]), np.array([math.cos(a), math.sin(a), 0.0])
    scale = np.abs(d[:, :2]).max()
    on = (np.abs(d @ n) <= tol * scale) & (d @ e > tol * scale)
    nodes = anterior[on]
    rho = np.hypot(d[on, 0], d[on, 1])
    order = np.argsort(rho)
    nodes, rho = nodes[order], rho[order]
    if len(nodes) < 3:
        raise ValueError(f"incision angle_deg = {angle!r}: fewer than three anterior nodes on its half-plane "
                         "(the mesh has no line of nodes there)")
    i0, i1 = (int(np.argmin(np.abs(rho - r))) for r in radii)
    if i1 - i0 < 2:
        raise ValueError(f"incision radii = {list(radii)!r}: snap to {i1 - i0 + 1} node(s) on the line; "
                         "a cut needs at least three (two elements)")
    return nodes[i0:i1 + 1], rho[i0:i1 + 1], np.setdiff1d(nodes, nodes[i0:i1 + 1])


def _strip(mesh, layer, line, beyond, rings, free_nodes):
    facets = mesh.boundary_facets
    quads = facets[np.isin(facets, layer).all(axis=1)]
    e = np.sort(quads[:, _QUAD_EDGES].reshape(-1, 2), axis=1)
    sel = set(line.tolist())
    for _ in range(rings):
        nb = e[np.isin(e, list(sel)).any(axis=1)].ravel()
        sel |= set(nb.tolist()) - set(beyond.tolist())
    out = np.array(sorted(sel), dtype=np.int64)
    return out[np.isin(out, free_nodes)]


def incision_strip(mesh, mesh_info, incision: dict, depth_fraction: float, free_dofs, rings: int = 1
                   ) -> IncisionStrip:
    """The :class:`IncisionStrip` of ``incision`` (``{"angle_deg", "radii"}``) on an intact
    ``cornea_dome`` mesh; ValueError for an angle without a line of mesh faces (from
    :func:`~tissuebench.cases.cutting.cut_mesh`) or radii that leave fewer than 3 nodes."""
    centre = np.asarray(mesh_info["centre"], float)
    # the requested incision first: an angle without a line of faces is refused with the
    # scene loader's message (the usable angles listed), before any snapping
    cut_mesh(mesh, [incision], depth_fraction, centre=centre, path="cut")
    start = mesh_info["layers"] * mesh_info["nodes_per_layer"]
    layer = np.arange(start, start + mesh_info["nodes_per_layer"])
    line, rho, beyond = _line_nodes(mesh.points, layer, centre, float(incision["angle_deg"]), incision["radii"])
    M = len(line) - 1
    enriched, n_enr, copies_pos, layers_cut = [], [0], [np.zeros(0, np.int64)], None
    for c in range(1, M):
        inc = {"angle_deg": float(incision["angle_deg"]), "radii": [float(rho[0]), float(rho[c + 1])]}
        _, info = cut_mesh(mesh, [inc], depth_fraction, centre=centre, path="cut")
        layers_cut = info.layers_cut
        dup = info.pairs[:, 0]
        new = np.setdiff1d(dup, enriched)
        if not np.isin(enriched, dup).all():
            raise RuntimeError(f"cut length {c}: the cracked nodes of a shorter cut are not all cracked")
        # new nodes from the anterior surface down (by distance from the centre, decreasing)
        enriched.extend(new[np.argsort(-np.linalg.norm(mesh.points[new] - centre, axis=1))].tolist())
        n_enr.append(len(enriched))
        copy_of = dict(zip(info.pairs[:, 0].tolist(), info.pairs[:, 1].tolist()))
        copies_pos.append(np.array([copy_of[n] for n in enriched], dtype=np.int64))
    free_nodes = np.flatnonzero(np.bincount(np.asarray(free_dofs) // 3, minlength=mesh.n_vertices) == 3)
    strip = _strip(mesh, layer, line, beyond, rings, free_nodes)
    return IncisionStrip(float(incision["angle_deg"]), rho, line, float(depth_fraction),
                         layers_cut or 0, np.array(enriched, dtype=np.int64), np.array(n_enr), copies_pos,
                         strip, centre)
