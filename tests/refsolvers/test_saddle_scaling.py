"""The saddle-point solver of the mixed formulation does not depend on the units (issue 43).

Its pressure-block regularisation was relative to the displacement block's diagonal; with SI
units on a soft organ (E = 3 kPa, cells of centimetres) that swamps the pressure Schur complement
(diag(A) ~ 10, Schur diagonal ~ 1e-8) and GMRES took 86-118 iterations per solve, some falling to
SuperLU. Relative to the Schur complement's own scale it takes 2, in any unit.
"""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.refsolvers import Dirichlet, NeoHookean, Problem, SurfaceTraction
from tissuebench.refsolvers.anp import volumetric_modulus
from tissuebench.refsolvers.mixed import MixedBackend
from tissuebench.refsolvers.saddle_solver import SaddlePointSolver, schur_scale
from _fe_helpers import element_mesh


@pytest.mark.ngsolve
@pytest.mark.parametrize("length, E", [(1.0, 1.0), (0.05, 3000.0)], ids=["unit", "SI-organ"])
def test_gmres_iterations_do_not_depend_on_the_units(length, E):
    mesh = element_mesh("P2", (length, length / 2, length / 2), (4, 2, 2), jitter=0.1, seed=2)
    material = NeoHookean(E=E, nu=0.499)
    top = lambda x: np.abs(x[:, 2] - length / 2) <= 1e-9 * length  # noqa: E731
    pb = Problem(mesh, material, "P2", dirichlet=[Dirichlet(lambda x: x[:, 0] <= 1e-9 * length)],
                 loads=[SurfaceTraction(lambda x: top(x), np.array([0.0, 0.0, -0.01 * E]))])
    mb = MixedBackend(pb, "skfem", bulk_modulus=volumetric_modulus(material))
    z = np.zeros(mb.ndof)
    K = mb.tangent(z)
    free = mb.problem.free_dofs
    Kff = K[free][:, free].tocsr()
    b = mb.external_force(z, 1.0)[free]
    assert schur_scale(Kff, mb.n_p) < 1e-3 * np.abs(Kff.diagonal()[:-mb.n_p]).mean() or length == 1.0
    x, info = SaddlePointSolver(mb.n_p).solve(Kff, b)
    assert info["solver"] == "ldlt-gmres" and info["iterations"] <= 5, info
    assert np.linalg.norm(Kff @ x - b) <= 1e-9 * np.linalg.norm(b)
