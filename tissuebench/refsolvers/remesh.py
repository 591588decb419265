"""A coarser tetrahedral mesh of the same body, by remeshing its boundary surface with gmsh.

For meshes that come from a file (the liver) there are no builder parameters to coarsen;
:func:`remesh` takes the boundary triangles of the tetrahedral mesh, lets gmsh classify
them into smooth patches and build a parametrisation of each (``classifySurfaces`` +
``createGeometry``, the procedure of gmsh's tutorial t13, "remeshing an STL file without
an underlying CAD model"), and tetrahedralises the enclosed volume at the target element
size. gmsh (https://gmsh.info, GPL, pip wheel ``gmsh``) is a dependency of tissuebench; where
it cannot be imported (a wheel missing a system library), :func:`gmsh_import_error` says why,
the methods that remesh do not apply (``coarse_fe`` on a mesh file) and :func:`remesh` raises
ImportError saying so.
"""
from __future__ import annotations

import math

import numpy as np

from .mesh import Mesh

__all__ = ["remesh", "mean_edge_length", "gmsh_available", "gmsh_import_error"]


def gmsh_import_error() -> str:
    """``""`` when gmsh imports, else why it does not (the ImportError's text and the fix)."""
    try:
        import gmsh  # noqa: F401
    except ImportError as exc:  # OSError of a missing shared library surfaces as ImportError too
        return f"gmsh cannot be imported here ({exc}); install it with: pip install gmsh"
    return ""


def gmsh_available() -> bool:
    return not gmsh_import_error()


def mean_edge_length(mesh: Mesh) -> float:
    """Mean length of the cells' vertex-to-vertex edges (tetrahedra) or of the hexahedra's 12 edges."""
    if mesh.cell_type == "tetra":
        e = mesh.edges
    else:
        local = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [4, 5], [5, 6], [6, 7], [7, 4],
                          [0, 4], [1, 5], [2, 6], [3, 7]])
        e = np.unique(np.sort(mesh.cells[:, local].reshape(-1, 2), axis=1), axis=0)
    return float(np.linalg.norm(mesh.points[e[:, 0]] - mesh.points[e[:, 1]], axis=1).mean())


def remesh(mesh: Mesh, size: float, angle_deg: float = 80.0) -> Mesh:
    """A tetrahedral mesh of the body bounded by ``mesh``'s boundary surface, elements of size ``size``.

    Parameters
    ----------
    mesh : Mesh
        A tetrahedral mesh with one closed boundary surface.
    size : float
        Target element size (length unit of the mesh), gmsh's ``Mesh.MeshSizeMax``; the
        surface is remeshed at that size too.
    angle_deg : float
        Dihedral angle above which two boundary triangles belong to different patches. 80 degrees
        keeps the liver in 8 patches; at 40 degrees (21 patches) the reparametrised patches
        intersected each other at half of the coarse sizes tried ("PLC Error: a segment and a facet
        intersect"), with their small patches holding the edges short. A failed attempt is retried
        once at 1.5 x the angle.

    Raises
    ------
    ImportError
        gmsh cannot be imported (``pip install gmsh``).
    ValueError
        Not a tetrahedral mesh, ``size`` not > 0, or gmsh produced no tetrahedron.
    """
    if mesh.cell_type != "tetra":
        raise ValueError(f"remesh: needs a tetrahedral mesh, got {mesh.cell_type!r}")
    if not (isinstance(size, (int, float)) and math.isfinite(size) and size > 0):
        raise ValueError(f"remesh: size must be a finite number > 0, got {size!r}")
    why = gmsh_import_error()
    if why:
        raise ImportError(f"remesh: {why}")
    import gmsh
    try:
        return _remesh(gmsh, mesh, float(size), angle_deg)
    except Exception as first:  # gmsh raises plain Exception with its last error
        try:
            return _remesh(gmsh, mesh, float(size), 1.5 * angle_deg)
        except Exception:
            raise ValueError(f"remesh: gmsh failed at size {size:g} ({first}), also at angle "
                             f"{1.5 * angle_deg:g} deg") from None


def _remesh(gmsh, mesh, size, angle_deg):
    tri = mesh.boundary_facets
    used = np.unique(tri)
    local = np.full(mesh.n_vertices, -1)
    local[used] = np.arange(len(used))
    gmsh.initialize(interruptible=False)
    try:
        gmsh.option.setNumber("General.Terminal", 0)
        gmsh.model.add("remesh")
        surf = gmsh.model.addDiscreteEntity(2)
        gmsh.model.mesh.addNodes(2, surf, (np.arange(len(used)) + 1).tolist(), mesh.points[used].ravel().tolist())
        gmsh.model.mesh.addElementsByType(surf, 2, [], (local[tri] + 1).ravel().tolist())
        gmsh.model.mesh.classifySurfaces(math.radians(angle_deg), True, True, math.pi)
        gmsh.model.mesh.createGeometry()
        loop = gmsh.model.geo.addSurfaceLoop([s[1] for s in gmsh.model.getEntities(2)])
        gmsh.model.geo.addVolume([loop])
        gmsh.model.geo.synchronize()
        for key, value in (("Mesh.MeshSizeMax", size), ("Mesh.MeshSizeMin", size), ("Mesh.MeshSizeFromPoints", 0),
                           ("Mesh.MeshSizeExtendFromBoundary", 0), ("Mesh.MeshSizeFromCurvature", 0),
                           ("Mesh.Algorithm3D", 1)):  # uniform size; Delaunay
            gmsh.option.setNumber(key, value)
        gmsh.model.mesh.generate(3)
        tags, coords, _ = gmsh.model.mesh.getNodes()
        _, cell_nodes = gmsh.model.mesh.getElementsByType(4)
    finally:
        gmsh.finalize()
    if len(cell_nodes) == 0:
        raise ValueError(f"remesh: gmsh made no tetrahedron at size {size:g}")
    index = np.full(int(np.max(tags)) + 1, -1)
    index[np.asarray(tags, dtype=np.int64)] = np.arange(len(tags))
    cells = index[np.asarray(cell_nodes, dtype=np.int64).reshape(-1, 4)]
    keep = np.unique(cells)  # nodes of the surface's discrete entity that no tetrahedron uses
    renum = np.full(len(tags), -1)
    renum[keep] = np.arange(len(keep))
    return Mesh(np.asarray(coords, float).reshape(-1, 3)[keep], renum[cells], "tetra")
