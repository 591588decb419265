"""The NGSolve mesh of a tissuebench mesh and the integration rules equal to the shared ones
(:mod:`..quadrature`): what the NGSolve backend (:mod:`.ngsolve_backend`) and its cell kernels
(:mod:`.ngsolve_cells`) both build on, so it sits below both. The conventions are the backend's
(its module docstring): vertex numbers and cell order kept, netgen's tetrahedra of the opposite
orientation, the reference simplices mapped through barycentric coordinates.
"""
from __future__ import annotations

import netgen.meshing as nm
import ngsolve as ngs
import numpy as np

from ..quadrature import facet_rule, volume_rule

__all__ = ["TET_TO_NG", "simplex_rule_to_ng", "make_intrules", "build_ngsolve_mesh"]

TET_TO_NG = np.array([1, 0, 2, 3])  # netgen vertex k of a tet = VTK vertex TET_TO_NG[k]
_VOL_ET = {"tetra": ngs.ET.TET, "hexahedron": ngs.ET.HEX}
_BND_ET = {"tetra": ngs.ET.TRIG, "hexahedron": ngs.ET.QUAD}


def simplex_rule_to_ng(points, vertex_map):
    """Map unit-simplex points (vertex 0 at the origin) to NGSolve reference coordinates.

    Parameters
    ----------
    points : ndarray, shape (dim, n_qp)
        Points of the shared rule (barycentrics ``(1 - sum, x_1, ..., x_dim)``).
    vertex_map : ndarray of int, shape (dim + 1,)
        NGSolve local vertex k is local vertex ``vertex_map[k]`` of the shared ordering.

    Returns
    -------
    ndarray, shape (n_qp, dim)
        NGSolve reference coordinates ``(lambda_{map[0]}, ..., lambda_{map[dim-1]})``.
    """
    bary = np.vstack([1.0 - points.sum(axis=0), points])
    return bary[vertex_map[:-1]].T


def _intrule(points_ng, weights):
    return ngs.IntegrationRule([tuple(map(float, p)) for p in points_ng], [float(w) for w in weights])


def make_intrules(element, order, facet=False):
    """``{ET: IntegrationRule}`` equal to the shared rule of :mod:`..quadrature`."""
    cell = "hexahedron" if element == "Q1" else "tetra"
    if facet:
        pts, w = facet_rule(element, order)
        ng = pts.T if cell == "hexahedron" else simplex_rule_to_ng(pts, np.arange(3))
        return {_BND_ET[cell]: _intrule(ng, w)}
    pts, w = volume_rule(element, order)
    ng = pts.T if cell == "hexahedron" else simplex_rule_to_ng(pts, TET_TO_NG)
    return {_VOL_ET[cell]: _intrule(ng, w)}


def build_ngsolve_mesh(mesh, facet_sets=()):
    """NGSolve mesh with the vertices and cells of ``mesh`` in the same order.

    Parameters
    ----------
    mesh : tissuebench Mesh
    facet_sets : sequence of ndarray, shape (n_facets, 3 or 4)
        Outward-oriented facets; set k becomes boundary region ``"load{k}"``.
    """
    m = nm.Mesh(dim=3)
    m.AddPoints(np.ascontiguousarray(mesh.points, dtype=float))
    m.SetMaterial(1, "body")
    cells = mesh.cells[:, TET_TO_NG] if mesh.cell_type == "tetra" else mesh.cells
    m.AddElements(dim=3, index=1, data=np.ascontiguousarray(cells, dtype=np.int32), base=0)
    for k, facets in enumerate(facet_sets):
        m.Add(nm.FaceDescriptor(surfnr=k + 1, domin=1, domout=0, bc=k + 1))
        m.SetBCName(k, f"load{k}")
        m.AddElements(dim=2, index=k + 1, data=np.ascontiguousarray(facets, dtype=np.int32), base=0)
    return ngs.Mesh(m)
