"""The cube bar of the skinning-cubature paper (wsc §3.1, App. B) in tension.

A 2 x 2 x 8 cm bar (SI units: m, Pa, N), compressible Mooney-Rivlin with
mu1 = 0.5 kPa, mu2 = 0.6 kPa. The paper gives no bulk modulus; we take
kappa = 2 (mu1 + mu2)(1 + nu0) / (3 (1 - 2 nu0)) with nu0 = 0.4, i.e. the small-strain
bulk modulus of a nu = 0.4 solid (the Poisson ratio the paper uses for its other
materials), 5.133 kPa. The end x = 0 is clamped, the end x = L is displaced by
``stretch * L`` along x (its transverse motion fixed), as in the paper's tension test.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..refsolvers import Dirichlet, Mesh, MooneyRivlin, Problem
from .meshes import box_mesh

LENGTHS = (0.08, 0.02, 0.02)  # m
MU1, MU2, NU0 = 500.0, 600.0, 0.4  # Pa, Pa, -
KAPPA = 2 * (MU1 + MU2) * (1 + NU0) / (3 * (1 - 2 * NU0))  # Pa
DENSITY = 500.0  # kg/m^3
# Reported by the paper (App. B) for the FE reference at 30 % strain.
PAPER = {"nominal_stress_kPa": (0.368, 0.371), "volume_ratio": (1.031, 1.032)}
RESOLUTIONS = {
    "ci": {"divisions": (12, 3, 3)},  # 208 vertices, 648 tetrahedra
    "paper": {"divisions": (63, 10, 10)},  # 7744 vertices, 37800 tetrahedra (paper: 7273 / 37592)
}


@dataclass(frozen=True)
class BarCase:
    problem: Problem
    stretch: float
    resolution: str

    def monitors(self, u: np.ndarray, f_int: np.ndarray) -> dict:
        """Nominal stress (kPa) on the pulled end and deformed/reference volume ratio."""
        pb = self.problem
        nodes = pb.nodes
        pulled = np.isclose(nodes[:, 0], LENGTHS[0])
        reaction = f_int.reshape(-1, 3)[pulled, 0].sum()
        mesh = pb.mesh
        nv = mesh.n_vertices
        deformed = Mesh(mesh.points + u.reshape(-1, 3)[:nv], mesh.cells, mesh.cell_type, reorient=False)
        ratio = deformed.cell_volumes().sum() / mesh.cell_volumes().sum()
        return {"nominal_stress_kPa": reaction / (LENGTHS[1] * LENGTHS[2]) / 1e3, "volume_ratio": ratio}


def bar_mesh(resolution: str = "ci") -> Mesh:
    if resolution not in RESOLUTIONS:
        raise ValueError(f"resolution={resolution!r} is not one of {sorted(RESOLUTIONS)}")
    return box_mesh(LENGTHS, RESOLUTIONS[resolution]["divisions"], "tetra")


def bar_tension(resolution: str = "ci", stretch: float = 0.3, element: str = "P1", mesh: Mesh | None = None) -> BarCase:
    """The bar pulled to ``stretch`` (engineering strain) at load factor 1."""
    if not (np.isfinite(stretch) and -1 < stretch):
        raise ValueError(f"stretch must be a finite number > -1, got {stretch!r}")
    mesh = mesh or bar_mesh(resolution)
    L = LENGTHS[0]
    tol = 1e-9 * L
    problem = Problem(
        mesh, MooneyRivlin(MU1, MU2, KAPPA), element,
        dirichlet=[Dirichlet(lambda x: x[:, 0] < tol),
                   Dirichlet(lambda x: x[:, 0] > L - tol, (0, 1, 2), (stretch * L, 0.0, 0.0))],
        density=DENSITY)
    return BarCase(problem, stretch, resolution)
