"""Cook's membrane and the published numbers it is checked against.

The trapezoid (0,0), (48,44), (48,60), (0,44) mm, 1 mm thick (one element through the
thickness), left edge clamped, a dead shear traction of 1/16 MPa on the right edge (1 N
total), units mm, N, MPa. Two neo-Hookean energies with mu = 0.4225 MPa, nu = 0.3:

* the coupled one (this project's ``neo_hookean``), W = mu/2 (I1 - 3) - mu ln J + lambda/2 (ln J)^2
  (:class:`~tissuebench.refsolvers.NeoHookean`): plane strain, corner u_y 13.57 mm
  (our converged P2 16x16 / Q1 32x32 value, no external source);
* the decoupled one of the deal.II code gallery (``Quasi_static_Finite_strain_Compressible_
  Elasticity``, J-P. Pelteret and A. McBride 2016, doi:10.5281/zenodo.1228964;
  :class:`~tissuebench.refsolvers.NeoHookeanDecoupled`), whose README tables are
  reproduced here to the printed digit with the gallery's element (Q1, 2x2x2 Gauss):

  - since commit 7f3b249 (2021): plane strain, midpoint (48, 52) of the loaded edge,
    Q2 limit 14.74 mm;
  - 2015-2021: top corner (48, 60) of a free slab: the code meant to fix u_z on both
    faces but tagged them with ``center()[0]`` instead of ``center()[2]`` (fixed in
    a587098), so the faces were traction-free. Q2 limit 14.33 mm, the figure usually
    quoted for this benchmark. A free 1 mm slab meshed with tetrahedra buckles out of
    plane (u_z ~ 16 mm at 4x4 P2); the single hexahedron layer stays in plane.
"""
from __future__ import annotations

import numpy as np

from ..refsolvers import (
    Dirichlet,
    LinearElastic,
    Mesh,
    NeoHookean,
    NeoHookeanDecoupled,
    Problem,
    SurfaceTraction,
    make_backend,
)
from ..refsolvers.newton import newton_solve
from .meshes import box_mesh

__all__ = [
    "CORNER",
    "COUPLED_LIMIT",
    "DEALII_PLANE_STRAIN_LIMIT",
    "DEALII_PLANE_STRAIN_Q1",
    "DEALII_SLAB_LIMIT",
    "DEALII_SLAB_Q1",
    "MIDPOINT",
    "MU",
    "NU",
    "E",
    "cook_problem",
    "cook_tip",
    "printed_half_unit",
]

MU, NU = 0.4225, 0.3  # MPa, -
E = 2 * MU * (1 + NU)
CORNER, MIDPOINT = (48.0, 60.0, 0.0), (48.0, 52.0, 0.0)
#: deal.II gallery README (2021-), Q1 column, plane strain, midpoint; entries as printed (mm)
DEALII_PLANE_STRAIN_Q1 = {2: "8.638", 4: "12.07", 8: "13.86", 16: "14.49", 32: "14.67", 64: "14.72"}
DEALII_PLANE_STRAIN_LIMIT = 14.74  # Q2 32x32 and 64x64
#: deal.II gallery README (2015-2021), Q1 column, free slab, corner; entries as printed (mm)
DEALII_SLAB_Q1 = {1: "5.15", 2: "8.72", 4: "12.02", 8: "13.61", 16: "14.13", 32: "14.28", 64: "14.32"}
DEALII_SLAB_LIMIT = 14.33  # Q2 32x32 and 64x64
COUPLED_LIMIT = 13.57  # ours: coupled energy, plane strain, corner


def printed_half_unit(text: str) -> float:
    """Half a unit of the last printed digit of a table entry (its rounding interval)."""
    return 0.5 * 10.0 ** -len(text.split(".")[1])


def cook_problem(n: int, element: str = "P2", material="coupled", traction: float = 1.0 / 16.0,
                 plane_strain: bool = True) -> Problem:
    """Cook's membrane on an n x n x 1 mesh.

    Parameters
    ----------
    n : int
        Cells along each in-plane edge (>= 1).
    element : {"P1", "P2", "Q1"}
    material : "coupled" | "decoupled" | "linear" | Material
        Our (coupled) neo-Hookean, the gallery's decoupled one (both mu = 0.4225 MPa, nu = 0.3),
        linear E = 70 MPa, nu = 1/3 (the linear benchmark), or any material.
    traction : float
        Shear traction on the right edge [MPa] (1/16: 1 N on the 16 mm x 1 mm face).
    plane_strain : bool
        u_z = 0 everywhere; False leaves both faces free (the gallery's 2015 slab).
    """
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise ValueError(f"n must be an integer >= 1, got {n!r}")
    if element not in ("P1", "P2", "Q1"):
        raise ValueError(f"element must be 'P1', 'P2' or 'Q1', got {element!r}")
    named = {"coupled": lambda: NeoHookean(E=E, nu=NU), "decoupled": lambda: NeoHookeanDecoupled(E=E, nu=NU),
             "linear": lambda: LinearElastic(E=70.0, nu=1 / 3)}
    if isinstance(material, str):
        if material not in named:
            raise ValueError(f"material must be one of {sorted(named)} or a Material, got {material!r}")
        material = named[material]()
    m = box_mesh((1.0, 1.0, 1.0), (n, n, 1), "hexahedron" if element == "Q1" else "tetra")
    xi, eta, z = m.points.T
    pts = np.stack([48 * xi, 44 * xi + 44 * eta - 28 * xi * eta, z], axis=1)
    mesh = Mesh(pts, m.cells, m.cell_type)
    clamp = Dirichlet(lambda x: np.abs(x[:, 0]) <= 1e-9)
    bcs = [clamp] + ([Dirichlet(lambda x: np.ones(len(x), bool), (2,))] if plane_strain else [])
    load = SurfaceTraction(lambda x: np.abs(x[:, 0] - 48.0) <= 1e-9, np.array([0.0, traction, 0.0]))
    return Problem(mesh, material, element, bcs, [load])


def cook_tip(problem: Problem, backend: str = "skfem", point=CORNER, **newton_options):
    """(u_y at the node ``point`` [mm], Newton result) after a load-stepped Newton solve.

    The value is NaN when Newton does not reach the full load (see ``result.message``).
    """

    hit = np.flatnonzero(np.all(np.abs(problem.nodes - np.asarray(point, float)) < 1e-9, axis=1))
    if hit.size == 0:
        raise ValueError(f"point={point!r} is not a node of this mesh (use an even n for the midpoint)")
    res = newton_solve(make_backend(backend, problem), 1.0, **newton_options)
    return (float(res.u[3 * hit[0] + 1]) if res.success else float("nan")), res
