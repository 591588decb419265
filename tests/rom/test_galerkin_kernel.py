"""The element quantities of ``pod_galerkin`` (rom/galerkin/kernel.py, forces.py) against the backends.

The Voigt total-Lagrangian kernel must give the backends' cell-kernel energies, element force
vectors and tangents to round-off for every nonlinear material (invariant laws through their
derivatives, Saint Venant-Kirchhoff, Guccione's fibres through its own ``pk2``), on P1, P2 and Q1
cells (one and several quadrature points); the reduced force and tangent through the mode
gradients must be ``V^T f_int`` and ``V^T K_t V`` of the assembled operators, with a prescribed
displacement lifted onto the fixed dofs, and the tangent the force's derivative.
"""
from __future__ import annotations

import numpy as np
import pytest

from _fe_helpers import element_mesh, material_set
from tissuebench.refsolvers import Dirichlet, Problem, make_backend
from tissuebench.rom.galerkin.forces import element_forces
from tissuebench.rom.galerkin.kernel import ElementKernel, cell_geometry

NONLINEAR = ["svk", "neo_hookean", "neo_hookean_decoupled", "mooney_rivlin", "guccione"]
AMPLITUDE = {"P1": 0.05, "P2": 0.01, "Q1": 0.05}


def _problem(element, material, prescribed=False):
    mesh = element_mesh(element, (1.0, 1.0, 2.0), (2, 2, 3), jitter=0.2, seed=1)
    bcs = [Dirichlet(lambda x: x[:, 2] < 1e-9)]
    if prescribed:
        bcs.append(Dirichlet(lambda x: x[:, 2] > 2 - 1e-9, (0, 2), [0.05, -0.1]))
    return Problem(mesh, material, element, bcs)


@pytest.mark.parametrize("element", ["P1", "P2", "Q1"])
@pytest.mark.parametrize("name", NONLINEAR)
def test_the_kernel_gives_the_backend_cell_quantities(element, name):
    mesh = element_mesh(element, (1.0, 1.0, 2.0), (2, 2, 3), jitter=0.2, seed=1)
    fibres = np.random.default_rng(5).standard_normal((mesh.n_cells, 3))
    pb = _problem(element, material_set(fibres)[name])
    be = make_backend("skfem", pb)
    cells = np.array([4, 0, 7, 4, pb.mesh.n_cells - 1])  # unsorted, a duplicate
    ref = be.cell_kernel(cells)
    ours = ElementKernel(*cell_geometry(be, cells), pb.material, cells)
    u = AMPLITUDE[element] * np.random.default_rng(2).standard_normal(ref.dofs.shape)
    (W0, f0), (W1, f1) = ref.energies_and_forces(u), ours.energies_and_forces(u)
    (g0, K0), (g1, K1) = ref.forces_and_tangents(u), ours.forces_and_tangents(u)
    for a, b in ((W0, W1), (f0, f1), (g0, g1), (K0, K1)):
        assert np.abs(a - b).max() <= 1e-12 * np.abs(a).max()


@pytest.mark.parametrize("element", ["P1", "P2"])
@pytest.mark.parametrize("prescribed", [False, True])
def test_reduced_force_and_tangent_are_the_projected_assembled_ones(element, prescribed):
    pb = _problem(element, material_set()["mooney_rivlin"], prescribed)
    be = make_backend("skfem", pb)
    free, fixed = pb.free_dofs, np.sort(pb.fixed_dofs)
    rng = np.random.default_rng(3)
    r = 5
    V = np.zeros((pb.ndof, r))
    V[free] = np.linalg.qr(rng.standard_normal((len(free), r)))[0]
    forces = element_forces(be, np.arange(pb.mesh.n_cells), np.ones(pb.mesh.n_cells), V, fixed)
    q = 0.3 * rng.standard_normal(r)
    u = V @ q
    uc = None
    if prescribed:
        uc = np.asarray(pb.prescribed_values(0.7), float)[np.argsort(pb.fixed_dofs)]
        u[fixed] = uc
    f, K = forces.force_and_tangent(q, uc)
    f_ref = V.T @ be.internal_force(u)
    K_ref = V.T @ (be.tangent(u) @ V)
    assert np.abs(f - f_ref).max() <= 1e-12 * np.abs(f_ref).max()
    assert np.abs(forces.force(q, uc) - f_ref).max() <= 1e-12 * np.abs(f_ref).max()
    assert np.abs(K - K_ref).max() <= 1e-12 * np.abs(K_ref).max()
    assert forces.energy(q, uc) == pytest.approx(be.strain_energy(u), rel=1e-12)
    h = 1e-6
    fd = np.column_stack([(forces.force(q + h * e, uc) - forces.force(q - h * e, uc)) / (2 * h) for e in np.eye(r)])
    assert np.abs(fd - K).max() <= 1e-6 * np.abs(K).max()


def test_weights_scale_the_element_sums_and_contributions_add_up():
    pb = _problem("P1", material_set()["neo_hookean"])
    be = make_backend("skfem", pb)
    rng = np.random.default_rng(4)
    V = np.zeros((pb.ndof, 3))
    V[pb.free_dofs] = rng.standard_normal((len(pb.free_dofs), 3))
    cells = np.array([1, 5, 9])
    w = np.array([0.5, 2.0, 3.0])
    q = 0.05 * rng.standard_normal(3)
    weighted = element_forces(be, cells, w, V, np.sort(pb.fixed_dofs))
    single = [element_forces(be, [c], [1.0], V, np.sort(pb.fixed_dofs)) for c in cells]
    expected = sum(wi * s.force(q) for wi, s in zip(w, single))
    assert np.abs(weighted.force(q) - expected).max() <= 1e-13 * np.abs(expected).max()
    assert np.abs(weighted.contributions(q) - np.array([s.force(q) for s in single])).max() <= \
        1e-13 * np.abs(expected).max()


@pytest.mark.parametrize("element", ["P1", "P2"])
def test_deim_rows_are_the_assembled_force_and_tangent_at_the_sampled_dofs(element):
    """With the identity as its force 'basis' on the sampled dofs, DEIM's force and tangent are
    rows of the assembled ``f_int`` and ``K_t V``: the points' stresses mapped onto the dofs."""
    from tissuebench.rom.galerkin.deim import DeimForces, _select

    pb = _problem(element, material_set()["neo_hookean"], prescribed=True)
    be = make_backend("skfem", pb)
    free, fixed = pb.free_dofs, np.sort(pb.fixed_dofs)
    rng = np.random.default_rng(7)
    V = np.zeros((pb.ndof, 4))
    V[free] = 0.01 * rng.standard_normal((len(free), 4))
    sampled = free[[0, 5, len(free) // 2, len(free) - 1]]
    dofs = be.element_dofs()
    cells = np.flatnonzero(np.isin(dofs, sampled).any(axis=1))
    deim = element_forces(be, cells, np.ones(len(cells)), V, fixed, cls=DeimForces)
    deim.bind(_select(deim, dofs[cells], sampled), np.eye(len(sampled)), {})
    q = rng.standard_normal(4)
    uc = np.asarray(pb.prescribed_values(0.5), float)[np.argsort(pb.fixed_dofs)]
    u = V @ q
    u[fixed] = uc
    f, K = deim.force_and_tangent(q, uc)
    f_ref, K_ref = be.internal_force(u)[sampled], (be.tangent(u) @ V)[sampled]
    assert np.abs(f - f_ref).max() <= 1e-12 * np.abs(f_ref).max()
    assert np.abs(deim.force(q, uc) - f_ref).max() <= 1e-12 * np.abs(f_ref).max()
    assert np.abs(K - K_ref).max() <= 1e-12 * np.abs(K_ref).max()
