"""Region selectors of the scene files: node sets chosen by their coordinates.

A region is a TOML table with exactly one primary key: ``plane = "x"`` + value [+ tol];
``box = [[lo], [hi]]``; ``nearest = [x, y, z]`` [+ count]; ``sphere = [x, y, z]`` +
radius; ``fraction = "y"`` + side ("min"|"max") + amount; ``ellipsoid = [a, b, c]``
[+ center, tol]; ``all = true``. Modifiers: ``boundary = true`` (boundary nodes only),
``frame = "bbox"`` (points/values as fractions of the mesh bounding box).

:func:`check_region` validates such a table; :func:`compile_region` turns it into a
predicate on node coordinates, so the same region can select vertices, P2 nodes or
facet centres.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .schema import (AXES, accepts, c_any, c_axis, c_bool, c_enum, c_frame, c_int1, c_num, c_pos, c_vec3,
                     check_table, fail, require)

__all__ = ["MeshGeometry", "check_region", "compile_region"]

_REGION_PRIMARY = ("plane", "box", "nearest", "sphere", "fraction", "ellipsoid", "all")
_REGION_SCHEMA = {
    "plane": c_axis, "value": c_num, "tol": c_pos,
    "box": c_any, "nearest": c_vec3, "count": c_int1, "sphere": c_vec3, "radius": c_pos,
    "fraction": c_axis, "side": c_enum("min", "max"), "amount": c_pos,
    "ellipsoid": c_vec3, "center": c_vec3, "all": c_bool, "boundary": c_bool,
    "frame": c_frame,
}
_REGION_NEEDS = {"plane": ("value",), "sphere": ("radius",), "fraction": ("side", "amount")}
# what each key means (the scene-format reference of the documentation is generated from these)
REGION_DOC = {
    "plane": "the nodes on the plane where this coordinate equals `value`",
    "value": "`plane`: the coordinate of the plane", "tol": "`plane`, `ellipsoid`: the distance tolerance",
    "box": "the nodes in the box `[[x0, y0, z0], [x1, y1, z1]]`",
    "nearest": "the `count` nodes nearest to this point", "count": "`nearest`: how many nodes (default 1)",
    "sphere": "the nodes within `radius` of this centre", "radius": "`sphere`: its radius",
    "fraction": "the nodes within `amount` (a fraction of the bounding box) of one `side` along this axis",
    "side": "`fraction`: `\"min\"` or `\"max\"`", "amount": "`fraction`: the fraction of the box's extent",
    "ellipsoid": "the nodes on the ellipsoid of these semi-axes", "center": "`ellipsoid`: its centre (default 0)",
    "all": "every node", "boundary": "modifier: boundary nodes only",
    "frame": "modifier: `\"bbox\"` states points and values as fractions of the mesh's bounding box "
             "(default `\"absolute\"`)",
}


@accepts("a region table (see Regions)")
def check_region(path, r):
    """Validate a region table (see the module docstring); returns the checked table."""
    r = check_table(path, r, _REGION_SCHEMA)
    prim = [k for k in _REGION_PRIMARY if k in r]
    if len(prim) != 1:
        fail(path, r, f"a region needs exactly one of {list(_REGION_PRIMARY)}")
    require(path, r, _REGION_NEEDS.get(prim[0], ()), f"for a {prim[0]!r} region")
    if "box" in r:
        _check_box(f"{path}.box", r["box"])
    if r.get("ellipsoid") is not None and min(r["ellipsoid"]) <= 0:
        fail(f"{path}.ellipsoid", r["ellipsoid"], "semi-axes must be > 0")
    if r.get("all") is False:
        fail(f"{path}.all", False, "only `all = true` is meaningful")
    return r


def _check_box(path, b):
    if not (isinstance(b, list) and len(b) == 2):
        fail(path, b, "expected [[x0, y0, z0], [x1, y1, z1]]")
    lo, hi = c_vec3(f"{path}[0]", b[0]), c_vec3(f"{path}[1]", b[1])
    if any(a > c for a, c in zip(lo, hi)):
        fail(path, b, "lower corner above upper corner")


@dataclass(frozen=True)
class MeshGeometry:
    """What region predicates need from a mesh: bounding box and boundary points."""

    lo: np.ndarray
    hi: np.ndarray
    boundary_points: np.ndarray

    @property
    def diag(self):
        # a degenerate (point) mesh still needs a nonzero length scale for tolerances
        return float(np.linalg.norm(self.hi - self.lo)) or 1.0

    @classmethod
    def of(cls, mesh):
        pts = mesh.points
        if getattr(mesh, "cell_type", "") == "line":
            bnd = pts[[0, -1]]
        else:
            # facet vertices plus edge midpoints, so that P2 mid-edge nodes on the
            # boundary are recognised as boundary nodes too
            f = mesh.boundary_facets
            nf = f.shape[1]
            mids = [(pts[f[:, i]] + pts[f[:, (i + 1) % nf]]) / 2 for i in range(nf)]
            bnd = np.vstack([pts[np.unique(f)]] + mids)
        return cls(pts.min(axis=0), pts.max(axis=0), bnd)


def compile_region(spec: dict, mesh, geometry: MeshGeometry | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """A predicate ``where(coords (n, 3)) -> bool mask`` for a validated region ``spec``."""
    g = geometry or MeshGeometry.of(mesh)
    bbox = spec.get("frame", "absolute") == "bbox"
    ext = g.hi - g.lo

    def point(p):
        p = np.asarray(p, float)
        return g.lo + p * ext if bbox else p

    def on_boundary(x):
        from scipy.spatial import cKDTree

        d, _ = cKDTree(g.boundary_points).query(x)
        return d <= 1e-9 * g.diag

    def where(x):
        x = np.asarray(x, float)
        allowed = on_boundary(x) if spec.get("boundary") else np.ones(len(x), bool)
        if "nearest" in spec:  # not a predicate per point: ranks the allowed points
            idx = np.flatnonzero(allowed)
            d = np.linalg.norm(x[idx] - point(spec["nearest"]), axis=1)
            mask = np.zeros(len(x), bool)
            mask[idx[np.argsort(d, kind="stable")[: spec.get("count", 1)]]] = True
            return mask
        return _primary_mask(spec, x, g, bbox, point) & allowed

    return where


def _primary_mask(spec, x, g, bbox, point):
    """Mask of the points ``x`` selected by the primary key of ``spec`` (not ``nearest``)."""
    ext = g.hi - g.lo
    if spec.get("all"):
        return np.ones(len(x), bool)
    if "plane" in spec:
        a = AXES[spec["plane"]]
        v = g.lo[a] + spec["value"] * ext[a] if bbox else spec["value"]
        return np.abs(x[:, a] - v) <= spec.get("tol", 1e-6 * g.diag)
    if "box" in spec:
        lo, hi = point(spec["box"][0]), point(spec["box"][1])
        tol = 1e-9 * g.diag
        return np.all((x >= lo - tol) & (x <= hi + tol), axis=1)
    if "sphere" in spec:
        return np.linalg.norm(x - point(spec["sphere"]), axis=1) <= spec["radius"]
    if "fraction" in spec:
        a = AXES[spec["fraction"]]
        if spec["side"] == "min":
            return x[:, a] <= g.lo[a] + spec["amount"] * ext[a]
        return x[:, a] >= g.hi[a] - spec["amount"] * ext[a]
    if "ellipsoid" in spec:
        c = np.asarray(spec.get("center", [0.0, 0.0, 0.0]))
        q = np.sqrt(np.sum(((x - c) / np.asarray(spec["ellipsoid"])) ** 2, axis=1))
        return np.abs(q - 1.0) <= spec.get("tol", 1e-3)
    raise AssertionError(spec)
