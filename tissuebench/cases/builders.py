"""Mesh builders referenced by name from the scene files (``[mesh] builder = "..."``).

Every builder takes keyword parameters only (the merged ``[mesh.params]`` and
``[mesh.<resolution>]`` tables of a scene) and returns a :class:`BuiltMesh`: the mesh
(a :class:`~tissuebench.refsolvers.mesh.Mesh` for the finite-element cases, a
:class:`LineMesh` for the 1D models) and a metadata dict (what was built, from which
file, whether a fallback shape was used ...).

Builders
--------
``box``          structured box, tetrahedra or hexahedra (wraps :func:`box_mesh`)
``netgen_box``   unstructured netgen box
``cornea_dome``  structured hexahedral spherical-cap shell (O-grid disc mapped on the cap)
``lv_ellipsoid`` truncated thick-walled ellipsoid of Land et al. 2015 problem 2 (netgen CSG)
``half_ellipsoid`` a dome (half ellipsoid on its flat base, netgen CSG): a nearly incompressible organ
``liver``        the SOFA liver shipped in tissuebench/data (VTU), any meshio volume mesh, an STL surface
                 tetrahedralised by netgen, or a built-in organ-like fallback shape
``file``         a user's volume mesh file (any meshio format), coordinates scaled: what a scene's
                 ``[mesh] file = "kidney.msh"`` builds (see :mod:`.scene`)
``interval``     1D interval [0, length] split into equal elements (Poisson 1D)
``beam1d``       1D beam/column axis [0, length] split into equal elements
"""
from __future__ import annotations

import numpy as np

from ..refsolvers.mesh import Mesh
from ..refsolvers.mesh import hex_corner_jacobians as corner_jacobians
from .builders_organs import cornea_dome, half_ellipsoid, liver, lv_ellipsoid, truncated_spheroid_volume
from .builtmesh import BuiltMesh, LineMesh

__all__ = ["BuiltMesh", "LineMesh", "BUILDERS", "build_mesh", "box", "netgen_box", "cornea_dome", "mesh_file",
           "lv_ellipsoid", "half_ellipsoid", "truncated_spheroid_volume", "liver", "interval", "beam1d",
           "hex_corner_jacobians"]


# ----------------------------------------------------------------------------- boxes
def box(lengths, divisions, cell_type="tetra", origin=(0.0, 0.0, 0.0)) -> BuiltMesh:
    """Structured box (see :func:`tissuebench.cases.meshes.box_mesh`)."""
    from .meshes import box_mesh

    mesh = box_mesh(tuple(lengths), tuple(divisions), cell_type, tuple(origin))
    return BuiltMesh(mesh, {"builder": "box", "divisions": list(divisions), "cell_type": cell_type})


def netgen_box(lengths, maxh, origin=(0.0, 0.0, 0.0)) -> BuiltMesh:
    """A box of ``lengths`` from ``origin``, tetrahedra of size about ``maxh`` meshed by netgen."""
    from .meshes import netgen_box_mesh

    return BuiltMesh(netgen_box_mesh(tuple(lengths), maxh, tuple(origin)), {"builder": "netgen_box", "maxh": maxh})


def hex_corner_jacobians(mesh: Mesh) -> np.ndarray:
    """Corner Jacobian determinants of every hexahedron, shape (n_cells, 8)."""
    return corner_jacobians(mesh.points, mesh.cells)


# ----------------------------------------------------------------------------- 1D
def _line(length, n_elements, name) -> BuiltMesh:
    if not (length > 0 and int(n_elements) >= 1):
        raise ValueError(f"{name}: length must be > 0 and n_elements >= 1, got {length}, {n_elements}")
    n = int(n_elements)
    x = np.linspace(0.0, float(length), n + 1)
    pts = np.column_stack([x, np.zeros_like(x), np.zeros_like(x)])
    cells = np.column_stack([np.arange(n), np.arange(1, n + 1)])
    return BuiltMesh(LineMesh(pts, cells), {"builder": name, "n_elements": n, "length": float(length)})


def interval(length=1.0, n_elements=50) -> BuiltMesh:
    """The interval [0, length] in ``n_elements`` equal linear elements."""
    return _line(length, n_elements, "interval")


def beam1d(length=1.0, n_elements=10) -> BuiltMesh:
    """A beam (or column) axis [0, length] in ``n_elements`` equal elements."""
    return _line(length, n_elements, "beam1d")


def mesh_file(path, scale: float = 1.0) -> BuiltMesh:
    """The volume mesh in file ``path`` (tetrahedra or hexahedra, any format meshio reads),
    coordinates multiplied by ``scale`` (the file's unit to the scene's length unit)."""
    from pathlib import Path

    from .builtmesh import scaled
    from .io import read_mesh

    p = Path(path)
    mesh = read_mesh(p)
    return BuiltMesh(scaled(mesh, scale), {"builder": "file", "source": str(p), "file": p.name, "scale": scale})


BUILDERS = {"box": box, "netgen_box": netgen_box, "cornea_dome": cornea_dome, "lv_ellipsoid": lv_ellipsoid,
            "half_ellipsoid": half_ellipsoid, "liver": liver, "interval": interval, "beam1d": beam1d, "file": mesh_file}


def mesh_sources(builder: str, params: dict) -> list:
    """The files a builder reads for ``params`` (their content is part of a scene's identity):
    the liver's VTU/STL (explicit ``path`` or the data folder's); none for meshes built from
    parameters alone."""
    if builder == "file":
        from pathlib import Path

        return [Path(params["path"])]
    if builder != "liver":
        return []
    from pathlib import Path

    from .io import liver_mesh_path

    p = Path(params["path"]).expanduser() if params.get("path") else liver_mesh_path()
    return [p] if p.is_file() else []


def build_mesh(builder: str, **params) -> BuiltMesh:
    """Call the builder registered as ``builder`` with ``params``."""
    if builder not in BUILDERS:
        raise ValueError(f"mesh.builder: unknown builder {builder!r}; valid: {sorted(BUILDERS)}")
    try:
        built = BUILDERS[builder](**params)
    except TypeError as exc:
        raise ValueError(f"mesh: builder {builder!r}: {exc}") from None
    n = getattr(built.mesh, "n_reoriented", 0)
    if n:  # said in the run's manifest (mesh info): the file's node order was changed
        built.info.update(reoriented_cells=n, orientation_note=(
            f"{n} of {built.mesh.n_cells} cells had negative orientation (node order) and were reoriented"
            + (" (all of them: a node-order convention of the source)" if n == built.mesh.n_cells else "")))
    return built
