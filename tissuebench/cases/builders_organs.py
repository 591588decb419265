"""Organ-shaped mesh builders: cornea dome, left ventricle, liver.

``cornea_dome``  structured hexahedral spherical-cap shell (O-grid disc mapped on the cap)
``lv_ellipsoid`` truncated thick-walled ellipsoid of Land et al. 2015 problem 2 (netgen CSG)
``liver``        the SOFA liver shipped in tissuebench/data (VTU), any meshio volume mesh, an STL surface
                 tetrahedralised by netgen, or a built-in organ-like fallback shape

They are registered by name in :mod:`.builders` and importable from there.
"""
from __future__ import annotations

import math
import warnings
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..refsolvers.mesh import Mesh
from .builtmesh import BuiltMesh, ngmesh_to_mesh, scaled

__all__ = ["cornea_dome", "lv_ellipsoid", "truncated_spheroid_volume", "liver"]


# ----------------------------------------------------------------------------- cornea: O-grid disc
def _ogrid_disc(n_core: int, n_ring: int, core_fraction: float, roundness: float = 0.5):
    """Structured quadrilateral grid of the unit disc: square core + ring (O-grid).

    Returns (xy (n, 2), quads (m, 4) counter-clockwise, boundary node ids).
    ``n_core`` cells per core side (even or odd), ``n_ring`` cells across the ring.
    """
    if n_core < 1 or n_ring < 1:
        raise ValueError(f"core_cells and ring_cells must be >= 1, got {n_core}, {n_ring}")
    if not 0 < core_fraction < 1:
        raise ValueError(f"core_fraction must lie in (0, 1), got {core_fraction}")
    s = np.linspace(-1.0, 1.0, n_core + 1)
    U, V = np.meshgrid(s, s, indexing="ij")

    def core_map(u, v):  # blend of the square and the elliptical square-to-disc map
        sq = np.stack([u, v], -1) / math.sqrt(2.0)
        disc = np.stack([u * np.sqrt(1 - v ** 2 / 2), v * np.sqrt(1 - u ** 2 / 2)], -1)
        return core_fraction * ((1 - roundness) * sq + roundness * disc)

    core = core_map(U, V).reshape(-1, 2)
    cid = lambda i, j: i * (n_core + 1) + j  # noqa: E731
    quads = [[cid(i, j), cid(i + 1, j), cid(i + 1, j + 1), cid(i, j + 1)]
             for i in range(n_core) for j in range(n_core)]
    # boundary loop of the core, counter-clockwise, 4 n_core nodes
    loop = ([(i, 0) for i in range(n_core)] + [(n_core, j) for j in range(n_core)]
            + [(i, n_core) for i in range(n_core, 0, -1)] + [(0, j) for j in range(n_core, 0, -1)])
    loop_ids = np.array([cid(i, j) for i, j in loop])
    start = core[loop_ids]
    ang = np.arctan2(start[:, 1], start[:, 0])
    circle = np.stack([np.cos(ang), np.sin(ang)], -1)
    ring_pts, outer_ids = _ogrid_ring(start, circle, loop_ids, len(core), n_ring, quads)
    xy = np.vstack([core] + ring_pts)
    quads = np.array(quads, dtype=np.int64)
    # orient all quads counter-clockwise
    p = xy[quads]
    area = 0.5 * np.sum(p[:, :, 0] * np.roll(p[:, :, 1], -1, 1) - np.roll(p[:, :, 0], -1, 1) * p[:, :, 1], axis=1)
    quads[area < 0] = quads[area < 0][:, ::-1]
    return xy, quads, outer_ids


def _ogrid_ring(start, circle, loop_ids, next_id, n_ring, quads):
    """Layers of the O-grid ring from the core boundary ``start`` to the unit ``circle``:
    appends their quads to ``quads``; returns (layer points, outer boundary node ids)."""
    pts = []
    prev, nl = loop_ids, len(loop_ids)
    for k in range(1, n_ring + 1):
        t = k / n_ring
        pts.append((1 - t) * start + t * circle)
        ids = np.arange(next_id, next_id + nl)
        next_id += nl
        for a in range(nl):
            b = (a + 1) % nl
            quads.append([prev[a], prev[b], ids[b], ids[a]])
        prev = ids
    return pts, prev


def _extrude(xy, quads, n_layers, surface_map):
    """Stack ``n_layers + 1`` copies of the disc grid mapped by ``surface_map(xy, s)``,
    s in [0, 1] from the first to the last layer, into hexahedra."""
    nn = len(xy)
    pts = np.vstack([surface_map(xy, k / n_layers) for k in range(n_layers + 1)])
    hexes = np.vstack([np.hstack([quads + k * nn, quads + (k + 1) * nn]) for k in range(n_layers)])
    return pts, hexes


def cornea_dome(radius=7.8, thickness=0.55, base_diameter=11.5, core_cells=4, ring_cells=3, layers=2,
                core_fraction=0.5) -> BuiltMesh:
    """Hexahedral spherical-cap shell: the cornea of the anm-pod and pgd-cutting papers.

    The shell lies between the concentric spheres of radii ``radius -/+ thickness / 2``
    (centre ``(0, 0, -z_b)``), cut by the base plane ``z = 0``; ``z_b`` is chosen so that
    the mid-surface meets the base plane on a circle of diameter ``base_diameter``. The
    apex is on the +z axis. An O-grid of the unit disc (``core_cells`` per core side,
    ``ring_cells`` across the ring) is mapped on each of ``layers + 1`` spherical
    surfaces by polar angle proportional to the disc radius, so all base nodes lie in
    the plane z = 0 (clamped base). Nodes: ``(layers + 1) ((core_cells + 1)^2 +
    4 core_cells ring_cells)``; hexahedra: ``layers (core_cells^2 + 4 core_cells ring_cells)``.
    Units: those of the parameters (mm in the catalogue).
    """
    if not (radius > 0 and 0 < thickness < radius and 0 < base_diameter / 2 < radius - thickness / 2):
        raise ValueError(f"inconsistent cornea dimensions: radius={radius}, thickness={thickness}, "
                         f"base_diameter={base_diameter}")
    if layers < 1:
        raise ValueError(f"layers must be >= 1, got {layers}")
    z_b = math.sqrt(radius ** 2 - (base_diameter / 2) ** 2)
    xy, quads, _ = _ogrid_disc(int(core_cells), int(ring_cells), float(core_fraction))

    def surface(xy, s):
        r = radius + (s - 0.5) * thickness
        theta_max = math.acos(z_b / r)
        rho = np.linalg.norm(xy, axis=1)
        theta = rho * theta_max
        with np.errstate(invalid="ignore", divide="ignore"):
            f = np.where(rho > 1e-14, np.sin(theta) / np.where(rho > 1e-14, rho, 1.0), theta_max)
        return np.column_stack([r * f * xy[:, 0], r * f * xy[:, 1], r * np.cos(theta) - z_b])

    pts, hexes = _extrude(xy, quads, int(layers), surface)
    mesh = Mesh(pts, hexes, "hexahedron")
    info = {"builder": "cornea_dome", "centre": [0.0, 0.0, -z_b], "base_plane_z": 0.0,
            "apex_z_mid": radius - z_b, "apex_z_outer": radius + thickness / 2 - z_b,
            "nodes_per_layer": len(xy), "layers": int(layers)}
    return BuiltMesh(mesh, info)


# ----------------------------------------------------------------------------- left ventricle
def truncated_spheroid_volume(r_s: float, r_l: float, z_base: float) -> float:
    """Volume of the spheroid x^2/r_s^2 + y^2/r_s^2 + z^2/r_l^2 <= 1 below z = z_base."""
    c, h = r_l, z_base
    return math.pi * r_s ** 2 * ((h + c) - (h ** 3 + c ** 3) / (3 * c ** 2))


def lv_ellipsoid(endo=(7.0, 17.0), epi=(10.0, 20.0), z_base=5.0, maxh=2.0) -> BuiltMesh:
    """Truncated thick-walled ellipsoid (Land et al. 2015, problem 2), netgen CSG tetrahedra.

    Endocardium x^2/r_s^2 + y^2/r_s^2 + z^2/r_l^2 = 1 with (r_s, r_l) = ``endo``,
    epicardium likewise with ``epi``, base plane z = ``z_base``, apex at z = -r_l.
    """
    (a0, c0), (a1, c1) = (float(v) for v in endo), (float(v) for v in epi)
    if not (0 < a0 < a1 and 0 < c0 < c1):
        raise ValueError(f"mesh.params.endo = {list(endo)}, mesh.params.epi = {list(epi)}: inconsistent LV "
                         "dimensions: need 0 < endo < epi, radius by radius (the endocardium inside the epicardium)")
    if not -c0 < z_base < c0:
        raise ValueError(f"mesh.params.z_base = {z_base}: the base plane must cut the endocardium: "
                         f"-{c0:g} < z_base < {c0:g} (its long radius, mesh.params.endo[1])")
    mesh = _lv_mesh(a0, c0, a1, c1, float(z_base), float(maxh))
    exact = truncated_spheroid_volume(a1, c1, z_base) - truncated_spheroid_volume(a0, c0, z_base)
    return BuiltMesh(mesh, {"builder": "lv_ellipsoid", "maxh": maxh, "wall_volume_exact": exact})


@lru_cache(maxsize=8)
def _lv_mesh(a0, c0, a1, c1, z_base, maxh) -> Mesh:  # meshes are immutable: safe to share
    from netgen.csg import CSGeometry, Ellipsoid, Plane, Pnt, Vec

    geo = CSGeometry()
    outer = Ellipsoid(Pnt(0, 0, 0), Vec(a1, 0, 0), Vec(0, a1, 0), Vec(0, 0, c1))
    inner = Ellipsoid(Pnt(0, 0, 0), Vec(a0, 0, 0), Vec(0, a0, 0), Vec(0, 0, c0))
    geo.Add(outer * Plane(Pnt(0, 0, z_base), Vec(0, 0, 1)) - inner)
    return ngmesh_to_mesh(geo.GenerateMesh(maxh=maxh))


def half_ellipsoid(semi_axes=(60.0, 60.0, 120.0), maxh=20.0) -> BuiltMesh:
    """The half ellipsoid x^2/a^2 + y^2/b^2 + z^2/c^2 <= 1, z >= 0 (a dome on its flat base z = 0),
    netgen CSG tetrahedra: the nearly incompressible organ of the locking indicator's tests and
    of the ``extremes`` preset (``examples/nearly_incompressible_organ`` meshes it with gmsh)."""
    a, b, c = (float(v) for v in semi_axes)
    mesh = _half_ellipsoid_mesh(a, b, c, float(maxh))
    return BuiltMesh(mesh, {"builder": "half_ellipsoid", "maxh": maxh, "volume_exact": 2 * math.pi * a * b * c / 3})


@lru_cache(maxsize=8)
def _half_ellipsoid_mesh(a, b, c, maxh) -> Mesh:  # meshes are immutable: safe to share
    from netgen.csg import CSGeometry, Ellipsoid, Plane, Pnt, Vec

    geo = CSGeometry()
    geo.Add(Ellipsoid(Pnt(0, 0, 0), Vec(a, 0, 0), Vec(0, b, 0), Vec(0, 0, c)) * Plane(Pnt(0, 0, 0), Vec(0, 0, -1)))
    return ngmesh_to_mesh(geo.GenerateMesh(maxh=maxh))


# ----------------------------------------------------------------------------- liver
def _tetrahedralise_stl(path: Path, maxh: float, grading: float) -> Mesh:
    from netgen.meshing import MeshingParameters
    from netgen.stl import STLGeometry

    geo = STLGeometry(str(path))
    return ngmesh_to_mesh(geo.GenerateMesh(MeshingParameters(maxh=maxh, grading=grading)))


@lru_cache(maxsize=4)
def _fallback_organ(maxh: float) -> Mesh:
    """A liver-sized organ-like shape (mm): a flattened ellipsoid, bent and tapered."""
    from netgen.csg import CSGeometry, Ellipsoid, Pnt, Vec

    a, b, c = 95.0, 75.0, 60.0
    geo = CSGeometry()
    geo.Add(Ellipsoid(Pnt(0, 0, 0), Vec(a, 0, 0), Vec(0, b, 0), Vec(0, 0, c)))
    m = ngmesh_to_mesh(geo.GenerateMesh(maxh=maxh))
    x, y, z = m.points.T
    xi = x / a
    taper = 1.0 - 0.35 * xi  # the left lobe thins out
    pts = np.column_stack([x, y * taper + 12.0 * xi ** 2, z * (0.8 - 0.3 * xi) - 8.0 * xi ** 2])
    pts += np.array([125.0, 130.0, 130.0])  # roughly where the shipped liver sits
    return Mesh(pts, m.cells, "tetra")


def liver(path: str | None = None, scale: float = 1.0, maxh: float = 14.0, grading: float = 0.65,
          fallback_maxh: float = 14.0, allow_fallback: bool = True) -> BuiltMesh:
    """The liver: ``path`` (any meshio volume mesh, or an STL surface tetrahedralised by
    netgen with ``maxh``/``grading``), default ``<data folder>/liver/liver_tet.vtu`` (shipped with the package).

    Without ``path`` and without that file ($TISSUEBENCH_DATA pointing elsewhere), a built-in organ-like shape is meshed
    (with a warning; ``info["fallback"]`` is True). An explicit ``path`` that does not
    exist raises FileNotFoundError naming it. Coordinates are multiplied by ``scale``
    (the shipped files are in mm; ``scale = 0.001`` gives metres).
    """
    from .io import liver_mesh_path, read_mesh

    info = {"builder": "liver", "scale": scale, "fallback": False}
    if path is not None:
        p = Path(path).expanduser()
        if not p.is_file():
            raise FileNotFoundError(f"mesh.path: liver mesh file {p} does not exist")
    else:
        p = liver_mesh_path()
        if not p.is_file():
            if not allow_fallback:
                raise FileNotFoundError(f"liver mesh {p} does not exist (set $TISSUEBENCH_DATA)")
            msg = (f"liver mesh {p} not found: using the built-in organ-like fallback shape "
                   f"(unset $TISSUEBENCH_DATA to use the mesh shipped with the package)")
            warnings.warn(msg, stacklevel=2)
            info.update(fallback=True, source="built-in fallback (bent, tapered ellipsoid)", reason=msg)
            return BuiltMesh(scaled(_fallback_organ(fallback_maxh), scale), info)
    if p.suffix.lower() == ".stl":
        mesh = _tetrahedralise_stl(p, maxh, grading)
        info.update(source=str(p), tetrahedralised=True, maxh=maxh, grading=grading)
    else:
        mesh = read_mesh(p)
        info.update(source=str(p), tetrahedralised=False)
    return BuiltMesh(scaled(mesh, scale), info)
