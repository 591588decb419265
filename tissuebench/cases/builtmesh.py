"""The result types of the mesh builders and helpers shared by them.

:class:`BuiltMesh` is what every builder of :mod:`.builders` returns; :class:`LineMesh`
is the mesh of the 1D models. Kept apart from the builders so that the organ builders
(:mod:`.builders_organs`) and the generic ones share them without an import cycle.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..refsolvers.mesh import Mesh

__all__ = ["LineMesh", "BuiltMesh", "scaled", "ngmesh_to_mesh"]


@dataclass(frozen=True, eq=False)
class LineMesh:
    """A 1D mesh along x: ``points`` (n, 3) with y = z = 0, ``cells`` (n - 1, 2)."""

    points: np.ndarray
    cells: np.ndarray
    cell_type: str = "line"

    @property
    def n_vertices(self) -> int:
        return len(self.points)

    @property
    def n_cells(self) -> int:
        return len(self.cells)

    @property
    def x(self) -> np.ndarray:
        return self.points[:, 0]


@dataclass(frozen=True, eq=False)
class BuiltMesh:
    """What a builder returns: the mesh and metadata (what was built, from which file ...)."""

    mesh: Mesh | LineMesh
    info: dict = field(default_factory=dict)


def scaled(mesh: Mesh, scale: float) -> Mesh:
    """``mesh`` with its coordinates multiplied by ``scale`` (the same object for 1)."""
    if scale == 1.0:
        return mesh
    out = Mesh(mesh.points * scale, mesh.cells, mesh.cell_type)
    # the cells were reoriented when ``mesh`` was built: keep the count for the mesh info
    object.__setattr__(out, "n_reoriented", mesh.n_reoriented)
    return out


def ngmesh_to_mesh(ngmesh) -> Mesh:
    """The tetrahedra of a netgen mesh, numbered over the points they use."""
    points = np.array([p.p for p in ngmesh.Points()], dtype=float)
    cells = np.array([[v.nr - 1 for v in el.vertices] for el in ngmesh.Elements3D()], dtype=np.int64)
    if len(cells) == 0:
        raise ValueError("netgen produced no tetrahedra")
    used = np.unique(cells)
    if len(used) != len(points):  # drop surface-only points
        renumber = np.full(len(points), -1, dtype=np.int64)
        renumber[used] = np.arange(len(used))
        points, cells = points[used], renumber[cells]
    return Mesh(points, cells, "tetra")
