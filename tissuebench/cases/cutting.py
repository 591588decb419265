"""Cut meshes: radial incisions (radial keratotomy) by node duplication.

The full-FE reference of the pgd-vademecum-cutting paper (§5) is the same cornea with
the cut made in the mesh: the mesh faces on the incision are split into two coincident
boundary faces by giving their nodes a copy, used by the cells on one side.

Semantics (the ``[cut]`` table of a scene, or :func:`cut_mesh`):

* An incision is the half-plane through the vertical axis of the shell centre at
  ``angle_deg`` (counter-clockwise from +x), from horizontal radius r0 to r1 (mm) on the
  anterior surface: ``radii = [r0, r1]``.
* Only mesh faces are cut: the interior faces on the anterior surface whose four vertices
  lie within ``tol`` (relative to the face diameter) of the half-plane and whose radial
  span has its middle in [r0, r1] (the ends snap to the nearest nodes), and below each
  the faces of the same strip down to the cut depth. An angle without a line of faces
  covering [r0, r1] is refused (ValueError listing the angles that have one), not
  snapped: snapping 45 deg to 0 or 90 would silently merge two spokes. On the cornea
  O-grid, 0, 90, 180 and 270 deg are the only face lines through the core (45 deg ones
  exist only in the ring, r > ~3.1 mm).
* Depth is quantised to element layers: the ``floor(depth_fraction * layers)`` anterior
  layers are cut (at least one); the fraction cut is reported. 1 is a through cut.
* Nodes of the cut faces get a copy, except crack-front nodes (on the edges of the cut
  surface inside the body: its radial ends and the bottom of a partial cut); nodes on
  the anterior (posterior, base) surface are copied. The cells on the counter-clockwise
  side of the plane (normal ``(-sin a, cos a, 0)``) switch to the copies. A cut one
  element long has only front nodes and is refused.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..refsolvers.mesh import HEX_FACES, Mesh
from .builtmesh import BuiltMesh
from .schema import c_any, c_num, c_numlist, c_str, check_table, fail, is_num

__all__ = ["CutInfo", "cut_mesh", "check_cut", "apply_cut", "cut_scene_mesh"]

_EDGES = np.array([[0, 1], [1, 2], [2, 3], [3, 0]])


@dataclass(frozen=True, eq=False)
class CutInfo:
    """What :func:`cut_mesh` did (node ids are those of the cut mesh).

    Attributes
    ----------
    pairs : (k, 2) int, the (original, copy) duplicated nodes; copies are numbered last
    faces_minus, faces_plus : (n_cut_faces, 4) int, outward boundary facets of the side
        keeping the originals and of the side using the copies (same faces, same order)
    face_incision : (n_cut_faces,) int, incision index of each face
    front_nodes : (m,) int, crack-front nodes (not duplicated)
    incisions : tuple of dict, per incision: requested and actual angle (deg) and anterior
        radii (mm), numbers of cut faces and duplicated nodes
    depth_fraction, depth_fraction_cut, layers_cut : requested and quantised depth
    """

    pairs: np.ndarray
    faces_minus: np.ndarray
    faces_plus: np.ndarray
    face_incision: np.ndarray
    front_nodes: np.ndarray
    incisions: tuple
    depth_fraction: float
    depth_fraction_cut: float
    layers_cut: int

    @property
    def n_cut_faces(self) -> int:
        return len(self.faces_minus)

    @property
    def angles_deg(self) -> list[float]:  # actual angles of the cut faces, deg
        return [inc["angle_deg"] for inc in self.incisions]

    def to_dict(self) -> dict:
        """A JSON-able summary (counts, actual angles and radii; no node arrays)."""
        return {"incisions": [dict(inc) for inc in self.incisions], "depth_fraction": self.depth_fraction,
                "depth_fraction_cut": self.depth_fraction_cut, "layers_cut": self.layers_cut,
                "n_cut_faces": self.n_cut_faces, "n_duplicated_nodes": len(self.pairs),
                "n_front_nodes": len(self.front_nodes)}


@dataclass(frozen=True, eq=False)
class _Faces:
    """Interior faces of a layered shell: vertex ids (f, 4), their two cells and local face
    numbers (f, 2), vertices about the centre (f, 4, 3), whether on the anterior surface
    (f,), horizontal radii of the upper edge (f, 2, mm), pair codes of the upper and lower
    edge (f,) (meaningful for the vertical faces, the only ones an incision cuts)."""

    verts: np.ndarray
    cells: np.ndarray
    local: np.ndarray
    X: np.ndarray
    anterior: np.ndarray
    rho: np.ndarray
    upper: np.ndarray
    lower: np.ndarray

    @classmethod
    def of(cls, mesh, centre, s):
        faces = mesh.cells[:, HEX_FACES].reshape(-1, 4)
        _, inv, counts = np.unique(np.sort(faces, axis=1), axis=0, return_inverse=True, return_counts=True)
        idx = np.flatnonzero(counts[inv.ravel()] == 2)
        idx = idx[np.argsort(inv.ravel()[idx], kind="stable")].reshape(-1, 2)  # the two cells side by side
        v, d, nv = faces[idx[:, 0]], mesh.points - centre, mesh.n_vertices
        by_s = np.take_along_axis(v, np.argsort(s[v], axis=1, kind="stable"), axis=1)
        return cls(v, idx // 6, idx % 6, d[v], s[v].max(axis=1) > 1 - 1e-6,
                   np.hypot(d[by_s[:, 2:], 0], d[by_s[:, 2:], 1]), _codes(by_s[:, 2:], nv), _codes(by_s[:, :2], nv))

    def select(self, angle, r0, r1, n_cut, tol):
        """Mask of the faces cut by one incision (deg, mm, layers): the anterior faces on the
        half-plane whose radial span has its middle in [r0, r1] (the ends snap to the nearest
        nodes), and the ``n_cut - 1`` faces below each, found through their shared edges."""
        a = math.radians(angle)
        n, e = np.array([-math.sin(a), math.cos(a), 0.0]), np.array([math.cos(a), math.sin(a), 0.0])
        h = np.linalg.norm(self.X[:, 0] - self.X[:, 2], axis=1, keepdims=True)
        on = (np.abs(self.X @ n) <= tol * h).all(axis=1) & ((self.X @ e).mean(axis=1) > 0)
        sel = layer = self.anterior & on & (self.rho.mean(axis=1) >= r0) & (self.rho.mean(axis=1) <= r1)
        for _ in range(n_cut - 1):
            layer = on & np.isin(self.upper, self.lower[layer])
            sel = sel | layer
        return sel

    def covers(self, sel, r0, r1, n_cut):
        """Whether the faces ``sel`` form one radial strip from r0 to r1, ``n_cut`` layers deep."""
        top = sel & self.anterior
        if not top.any() or sel.sum() != n_cut * top.sum():
            return False
        lo, hi = np.sort(self.rho[top].min(axis=1)), np.sort(self.rho[top].max(axis=1))
        if np.any(np.abs(lo[1:] - hi[:-1]) > 1e-6 * hi[-1]):
            return False  # a hole: part of the segment is not on a mesh line
        return bool(lo[0] - r0 <= 0.5 * (hi[0] - lo[0]) + 1e-9 and r1 - hi[-1] <= 0.5 * (hi[-1] - lo[-1]) + 1e-9)


def _codes(edges, nv):  # one integer per undirected edge (a, b)
    e = np.sort(edges, axis=1)
    return e[:, 0] * nv + e[:, 1]


def _depth(s, depth_fraction, path):
    """(layers cut, fraction of the thickness cut) from the thickness coordinates ``s``."""
    n_layers = len(np.unique(np.round(s, 6))) - 1
    if not 1 <= n_layers <= 100:
        raise ValueError(f"{path}: the mesh is not a layered shell about its centre ({n_layers} layers)")
    n_cut = max(1, int(math.floor(depth_fraction * n_layers + 1e-9)))
    return n_cut, n_cut / n_layers


def _split_nodes(fv, boundary_codes, nv):
    """(duplicated, crack-front) nodes of the cut faces ``fv`` (k, 4): the front is the
    edges used by one cut face that are not on the body's boundary surface."""
    code, counts = np.unique(_codes(fv[:, _EDGES].reshape(-1, 2), nv), return_counts=True)
    front_codes = code[(counts == 1) & ~np.isin(code, boundary_codes)]
    front = np.unique(np.concatenate([front_codes // nv, front_codes % nv]))
    return np.setdiff1d(np.unique(fv), front), front


def _plus(points, cells, centre, angle, path):
    """Side of ``cells`` (n, 8) about the incision plane (True: counter-clockwise)."""
    a = math.radians(angle)
    sd = (points[cells].mean(axis=1) - centre) @ np.array([-math.sin(a), math.cos(a), 0.0])
    if np.any(np.abs(sd) <= 1e-6 * np.ptp(points[cells], axis=1).max(axis=1)):
        raise ValueError(f"{path}: a cell next to the cut straddles the incision plane")
    return sd > 0


def _switch_side(cells, mesh, centre, angle, dup, copies, path):
    """Renumber in place the cells on the counter-clockwise side using a duplicated node."""
    near = np.flatnonzero(np.isin(mesh.cells, dup).any(axis=1))
    pos = near[_plus(mesh.points, mesh.cells[near], centre, angle, path)]
    sub = cells[pos]
    hit = np.isin(sub, dup)
    sub[hit] = copies[np.searchsorted(dup, sub[hit])]
    cells[pos] = sub


def _find(F, angle, radii, n_cut, tol, where, anterior_xy):
    """Indices of the faces of one incision, or a ValueError listing the usable angles
    (candidates: azimuths shared by two or more anterior nodes off the axis)."""
    r0, r1 = radii
    sel = F.select(angle, r0, r1, n_cut, tol)
    if F.covers(sel, r0, r1, n_cut):
        return np.flatnonzero(sel)
    xy = anterior_xy[np.hypot(*anterior_xy.T) > 1e-9 * np.abs(anterior_xy).max()]
    az, counts = np.unique(np.round(np.degrees(np.arctan2(xy[:, 1], xy[:, 0])) % 360.0, 3), return_counts=True)
    ok = [float(c) for c in az[counts >= 2] if F.covers(F.select(c, r0, r1, n_cut, tol), r0, r1, n_cut)]
    fail(f"{where}.angle_deg", angle, f"no line of mesh faces at this angle covers radii {list(radii)} mm "
         f"(angles are not snapped); angles with one: {ok}")


def _incision(mesh, F, inc, ctx, where):
    """Faces, duplicated nodes and crack front of one incision, and its CutInfo record."""
    a, radii = float(inc["angle_deg"]), [float(r) for r in inc["radii"]]
    if not (len(radii) == 2 and 0 <= radii[0] < radii[1] <= ctx["r_max"] + 1e-9):
        fail(f"{where}.radii", list(inc["radii"]), f"expected [r0, r1] with 0 <= r0 < r1 <= {ctx['r_max']:.4g} mm "
             "(the anterior base radius)")
    faces = _find(F, a, radii, ctx["n_cut"], ctx["tol"], where, ctx["anterior_xy"])
    fv = F.verts[faces]
    if ctx["used"][fv].any():
        fail(where, dict(inc), "shares mesh nodes with an earlier incision")
    ctx["used"][fv] = True
    dup, front = _split_nodes(fv, ctx["boundary_codes"], mesh.n_vertices)
    if not np.isin(fv, dup).any(axis=1).all():
        fail(f"{where}.radii", list(inc["radii"]), "the cut is one element long: its crack-front nodes hold it "
             "closed (cut at least two elements)")
    top = faces[F.anterior[faces]]
    xy = F.X[top][..., :2].reshape(-1, 2).mean(axis=0)
    record = {"angle_deg_requested": a, "angle_deg": round(math.degrees(math.atan2(xy[1], xy[0])) % 360, 9),
              "radii_requested": radii, "radii": [float(F.rho[top].min()), float(F.rho[top].max())],
              "n_cut_faces": len(faces), "n_duplicated": len(dup)}
    return faces, dup, front, record


def cut_mesh(mesh: Mesh, incisions, depth_fraction: float = 1.0, *, centre=(0.0, 0.0, 0.0),
             tol: float = 1e-3, path: str = "cut") -> tuple[Mesh, CutInfo]:
    """Cut radial incisions into a layered hexahedral shell by duplicating nodes.

    Parameters
    ----------
    mesh : Mesh
        Hexahedral shell whose nodes lie on spheres about ``centre`` (``cornea_dome``).
    incisions : non-empty sequence of ``{"angle_deg": a, "radii": [r0, r1]}`` (deg, mm)
    depth_fraction : float in (0, 1], from the anterior surface, quantised to element layers
    centre : array_like, shape (3,), mm; the incisions turn about the vertical through it
    tol : float, distance of a cut face's vertices from the plane relative to its diameter
    path : str, key path named in the errors (``cut.incisions[0].angle_deg = 45.0: ...``)

    Returns
    -------
    (Mesh, CutInfo)
        The cut mesh (the original nodes, then the copies at the same coordinates).
    """
    if mesh.cell_type != "hexahedron" or not len(incisions):
        raise ValueError(f"{path}: cutting needs a hexahedral mesh and at least one incision")
    if not (is_num(depth_fraction) and 0 < depth_fraction <= 1):
        fail(f"{path}.depth_fraction", depth_fraction, "expected a fraction of the thickness in (0, 1]")
    centre, nv = np.asarray(centre, float), mesh.n_vertices
    d = mesh.points - centre
    R = np.linalg.norm(d, axis=1)
    s = (R - R.min()) / np.ptp(R)  # thickness coordinate: 0 posterior .. 1 anterior
    n_cut, frac = _depth(s, depth_fraction, path)
    F = _Faces.of(mesh, centre, s)
    ctx = {"n_cut": n_cut, "tol": tol, "anterior_xy": d[s > 1 - 1e-6, :2], "used": np.zeros(nv, bool),
           "boundary_codes": np.unique(_codes(mesh.boundary_facets[:, _EDGES].reshape(-1, 2), nv))}
    ctx["r_max"] = np.hypot(*ctx["anterior_xy"].T).max()
    cells, faces, pairs, fronts, records, first_plus = mesh.cells.copy(), [], [], [], [], []
    for i, inc in enumerate(incisions):
        f, dup, front, rec = _incision(mesh, F, inc, ctx, f"{path}.incisions[{i}]")
        copies = nv + sum(map(len, pairs)) + np.arange(len(dup))
        _switch_side(cells, mesh, centre, rec["angle_deg"], dup, copies, path)
        first_plus.append(_plus(mesh.points, mesh.cells[F.cells[f, 0]], centre, rec["angle_deg"], path))
        faces.append(f), pairs.append(np.column_stack([dup, copies])), fronts.append(front), records.append(rec)
    pairs, p0, f = np.vstack(pairs), np.concatenate(first_plus)[:, None], np.concatenate(faces)
    # the geometry is unchanged, so no cell is reoriented and the local face numbers stay valid
    cut = Mesh(np.vstack([mesh.points, mesh.points[pairs[:, 0]]]), cells, "hexahedron", reorient=False)
    side = [np.take_along_axis(cut.cells[F.cells[f, j]], HEX_FACES[F.local[f, j]], axis=1) for j in (0, 1)]
    return cut, CutInfo(pairs, np.where(p0, side[1], side[0]), np.where(p0, side[0], side[1]),
                        np.repeat(np.arange(len(faces)), list(map(len, faces))), np.unique(np.concatenate(fronts)),
                        tuple(records), float(depth_fraction), frac, n_cut)


# ----------------------------------------------------------------------------- scene files
_CUT_SCHEMA = {"incisions": c_any, "depth_fraction": c_num, "note": c_str}
_INCISION_SCHEMA = {"angle_deg": c_num, "radii": c_numlist}
# what each key means (the scene-format reference of the documentation)
CUT_DOC = {"incisions": "an array of incision tables (below)",
           "depth_fraction": "the cut depth as a fraction of the thickness (quantised to element layers)",
           "note": "documentation"}
INCISION_DOC = {"angle_deg": "the incision's direction, counter-clockwise from +x [degrees]",
                "radii": "`[r0, r1]`: from horizontal radius r0 to r1 [mm]"}


def check_cut(path: str, table) -> dict:
    """Validate a ``[cut]`` table; returns ``{"incisions": [{"angle_deg", "radii"}], "depth_fraction"}``.

    ``incisions`` (required): array of ``{angle_deg in [0, 360), radii = [r0, r1]}`` with
    0 <= r0 < r1 (mm); ``depth_fraction`` in (0, 1] (default 1, a through cut); ``note``.
    Whether r1 is within the mesh is checked when the mesh is cut (:func:`cut_mesh`).
    """
    cut = check_table(path, table, _CUT_SCHEMA, required=("incisions",))
    if not (isinstance(cut["incisions"], list) and cut["incisions"]):
        fail(f"{path}.incisions", cut["incisions"], "expected a non-empty array of {angle_deg, radii} tables")
    incs = [check_table(f"{path}.incisions[{i}]", inc, _INCISION_SCHEMA, required=("angle_deg", "radii"))
            for i, inc in enumerate(cut["incisions"])]
    for i, inc in enumerate(incs):
        if not 0 <= inc["angle_deg"] < 360:
            fail(f"{path}.incisions[{i}].angle_deg", inc["angle_deg"], "expected an angle in [0, 360) deg")
        if not (len(inc["radii"]) == 2 and 0 <= inc["radii"][0] < inc["radii"][1]):
            fail(f"{path}.incisions[{i}].radii", inc["radii"], "expected [r0, r1] with 0 <= r0 < r1 (mm)")
    d = cut.get("depth_fraction", 1.0)
    if not 0 < d <= 1:
        fail(f"{path}.depth_fraction", d, "expected a fraction of the thickness in (0, 1]")
    return {"incisions": incs, "depth_fraction": float(d)}


def _cut_built(built: BuiltMesh, cut: dict, path: str = "cut") -> tuple[Mesh, CutInfo]:
    if "centre" not in built.info:
        raise ValueError(f"{path}: cuts need a layered shell with a centre (cornea_dome), "
                         f"not a {built.info.get('builder')!r} mesh")
    return cut_mesh(built.mesh, cut["incisions"], cut["depth_fraction"], centre=built.info["centre"], path=path)


def apply_cut(built: BuiltMesh, cut: dict) -> BuiltMesh:
    """``built`` cut by the validated ``[cut]`` table; ``info["cut"]`` = :meth:`CutInfo.to_dict`."""
    mesh, info = _cut_built(built, cut)
    return BuiltMesh(mesh, {**built.info, "cut": info.to_dict()})


def cut_scene_mesh(scene) -> tuple[Mesh, CutInfo | None]:
    """(cut mesh, CutInfo with its node arrays) of a scene with a ``[cut]`` table (the mesh
    equals ``scene.mesh``, same numbering), or (the builder's mesh, None) without one."""
    from .builders import build_mesh

    built = build_mesh(scene.mesh_spec["builder"], **scene.mesh_spec["params"])
    return (built.mesh, None) if getattr(scene, "cut", None) is None else _cut_built(built, scene.cut)
