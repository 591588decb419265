"""Element quantities on cell subsets (Backend.cell_kernel): energies, element force
vectors and element tangents, checked against the assembled f_int / K_t / energy of the
same backend, against the other backend (independent implementation: NGSolve's symbolic
energy versus the NumPy material kernels), and against finite differences."""
import numpy as np
import pytest
import scipy.sparse as sp

from _fe_helpers import BACKEND_PARAMS, MATERIAL_NAMES, element_mesh, material_set
from tissuebench.refsolvers import Dirichlet, Guccione, MooneyRivlin, Problem
from tissuebench.refsolvers.backends import make_backend

# P2 tolerates less displacement before a jittered cell inverts
AMPLITUDE = {"P1": 0.05, "P2": 0.01, "Q1": 0.05}


def problem(element, material=None):
    mesh = element_mesh(element, (1.0, 1.0, 2.0), (2, 2, 3), jitter=0.2, seed=1)
    material = material or MooneyRivlin(1.0, 0.5, 10.0)
    return Problem(mesh, material, element, [Dirichlet(lambda x: x[:, 2] < 1e-9)])


def displacement(pb, element, seed=0):
    return AMPLITUDE[element] * np.random.default_rng(seed).standard_normal(pb.ndof)


def scatter(be, fe, Ke):
    dofs = be.element_dofs()
    n = dofs.shape[1]
    f = np.bincount(dofs.ravel(), fe.ravel(), minlength=be.ndof)
    K = sp.coo_matrix((Ke.ravel(), (np.repeat(dofs, n, 1).ravel(), np.tile(dofs, (1, n)).ravel())),
                      shape=(be.ndof, be.ndof)).tocsr()
    return f, K


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element", ["P1", "P2", "Q1"])
def test_all_cells_sum_to_the_assembled_operators(backend, element):
    pb = problem(element)
    be = make_backend(backend, pb)
    u = displacement(pb, element)
    fe, Ke = be.element_forces_and_tangents(u)
    W, fe2 = be.element_energies_and_forces(u)
    f, K = scatter(be, fe, Ke)
    assert np.abs(f - be.internal_force(u)).max() <= 1e-13 * np.abs(f).max()
    assert abs(K - be.tangent(u)).max() <= 1e-13 * abs(K).max()
    assert W.sum() == pytest.approx(be.strain_energy(u), rel=1e-13)
    assert np.abs(fe2 - fe).max() <= 1e-13 * np.abs(fe).max()
    assert np.allclose(W, be.element_strain_energies(u), rtol=1e-12, atol=0)
    # element tangents are symmetric (hyperelastic)
    assert np.abs(Ke - Ke.transpose(0, 2, 1)).max() <= 1e-12 * np.abs(Ke).max()


@pytest.mark.ngsolve
@pytest.mark.parametrize("element", ["P1", "P2", "Q1"])
def test_subset_kernels_agree_across_backends(element):
    pb = problem(element)
    u = displacement(pb, element, seed=3)
    cells = np.array([3, 0, 5, 3, pb.mesh.n_cells - 1])  # unsorted, one duplicate
    out = {}
    for name in ("skfem", "ngsolve"):
        k = make_backend(name, pb).cell_kernel(cells)
        assert k.dofs.shape == (5, 3 * pb.layout[1].shape[1])
        out[name] = (*k.forces_and_tangents(k.gather(u)), *k.energies_and_forces(k.gather(u)), k.volumes)
    (f1, K1, W1, _, V1), (f2, K2, W2, _, V2) = out["skfem"], out["ngsolve"]
    assert np.abs(f1 - f2).max() <= 1e-12 * np.abs(f1).max()
    assert np.abs(K1 - K2).max() <= 1e-12 * np.abs(K1).max()
    assert np.abs(W1 - W2).max() <= 1e-12 * np.abs(W1).max()
    assert np.allclose(V1, V2, rtol=1e-13)
    assert np.array_equal(f1[0], f1[3])  # the duplicate cell


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_subset_equals_rows_of_all_cells_and_finite_differences(backend):
    mesh = element_mesh("P1", (1.0, 1.0, 2.0), (2, 2, 3), jitter=0.2, seed=1)
    fib = np.random.default_rng(5).standard_normal((mesh.n_cells, 3))
    pb = problem("P1", Guccione(1.0, 2.0, 1.0, 1.5, 20.0, fibres=fib))  # per-cell data sliced per subset
    be = make_backend(backend, pb)
    u = displacement(pb, "P1", seed=2)
    cells = np.array([7, 2, 11])
    fe_all, Ke_all = be.element_forces_and_tangents(u)
    k = be.cell_kernel(cells)
    u_loc = k.gather(u)
    fe, Ke = k.forces_and_tangents(u_loc)
    assert np.allclose(fe, fe_all[cells], rtol=1e-13, atol=0) and np.allclose(Ke, Ke_all[cells], rtol=1e-13, atol=0)
    # d energy / d u_loc = f_e ; d f_e / d u_loc = K_e (central differences)
    h = 1e-6
    dW, dF = np.zeros_like(fe), np.zeros_like(Ke)
    for j in range(u_loc.shape[1]):
        e = np.zeros_like(u_loc)
        e[:, j] = h
        Wp, fp = k.energies_and_forces(u_loc + e)
        Wm, fm = k.energies_and_forces(u_loc - e)
        dW[:, j] = (Wp - Wm) / (2 * h)
        dF[:, :, j] = (fp - fm) / (2 * h)
    assert np.abs(dW - fe).max() <= 1e-7 * np.abs(fe).max()
    assert np.abs(dF - Ke).max() <= 1e-6 * np.abs(Ke).max()
    assert k.volumes == pytest.approx(np.abs(np.linalg.det(
        pb.mesh.points[pb.mesh.cells[cells, 1:]] - pb.mesh.points[pb.mesh.cells[cells, :1]])) / 6, rel=1e-12)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_bad_cells_and_local_shapes(backend):
    pb = problem("P1")
    be = make_backend(backend, pb)
    with pytest.raises(ValueError, match="cells: index out of range"):
        be.cell_kernel([0, pb.mesh.n_cells])
    with pytest.raises(ValueError, match="1D integer array"):
        be.cell_kernel(np.array([0.5, 1.0]))
    k = be.cell_kernel([1, 2])
    with pytest.raises(ValueError, match=r"u_loc must have shape \(2, 12\)"):
        k.energies_and_forces(np.zeros((3, 12)))


@pytest.mark.parametrize("name", MATERIAL_NAMES)
def test_fused_energy_and_stress_equals_the_separate_kernels(name):
    mat = material_set()[name]
    F = np.eye(3) + 0.2 * np.random.default_rng(7).standard_normal((50, 2, 3, 3))
    F = F[np.all(np.linalg.det(F) > 0.2, axis=1)]  # (cells, qp, 3, 3), no inverted point
    W, P = mat.energy_and_stress(F)
    assert np.allclose(W, mat.energy(F), rtol=1e-12, atol=1e-14)
    assert np.allclose(P, mat.stress(F), rtol=1e-11, atol=1e-13)
