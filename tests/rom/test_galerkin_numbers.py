"""POD-Galerkin's offline pieces by hand (issue 50, item 10: the mutation testing of rom/galerkin/*):
the greedy NNLS of ECSW and the DEIM indices on small matrices worked out by hand, the training
states the hyper-reduction fits, the element kernel's dispatch and its edges (a quadrature of two
points, a flat or inverted element), the reduced forces of every law with a prescribed motion, the
ECSW rule and the DEIM forces on scripted contributions, and the POD basis of the snapshots. The
trajectories: test_pod_galerkin.py; the kernels against the assembled operators:
test_galerkin_kernel.py; the online model and the method: test_galerkin_model_numbers.py."""
from __future__ import annotations

import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from _fe_helpers import element_mesh, material_set
from tissuebench.refsolvers import Dirichlet, Problem, make_backend
from tissuebench.refsolvers.materials import NeoHookean
from tissuebench.rom.galerkin.basis import snapshot_basis, training_states
from tissuebench.rom.galerkin.deim import (deim_forces, deim_indices, least_squares_coefficients,
                                            oversampled_indices)
from tissuebench.rom.galerkin.ecsw import ecsw_rule, greedy_nnls
from tissuebench.rom.galerkin.forces import LinearForces, element_forces
from tissuebench.rom.galerkin.kernel import ElementKernel, cell_geometry


# ---------------------------------------------------------------- ECSW's NNLS and DEIM's indices
def test_greedy_nnls_by_hand():
    """b = 2 a0 + 1 a2 with orthonormal columns: the largest correlation enters first (a0: 2), then a2
    (1); a1 (correlation 0) never; at tol 0.5 the first column alone leaves |b - 2 a0| / |b| = 1 / 5 ** 0.5."""
    A = np.eye(3)
    b = np.array([2.0, 0.0, 1.0])
    cols, w, res = greedy_nnls(A, b, 1e-12, 3)
    assert cols.tolist() == [0, 2] and w.tolist() == [2.0, 1.0] and res == 0.0
    cols, w, res = greedy_nnls(A, b, 0.5, 3)
    assert cols.tolist() == [0] and w.tolist() == [2.0] and res == pytest.approx(5 ** -0.5, rel=1e-15)
    cols, w, res = greedy_nnls(A, b, 1e-12, 1)  # at most one element
    assert cols.tolist() == [0] and res == pytest.approx(5 ** -0.5, rel=1e-15)
    # tol exactly the residual of one column: stops there (|r| <= tol |b|)
    assert greedy_nnls(A, b, 5 ** -0.5, 3)[0].tolist() == [0]
    # relative to |b| however small b is: b / 10 stops at the same relative residual
    cols, w, res = greedy_nnls(A, b / 10, 0.5, 3)
    assert cols.tolist() == [0] and w == pytest.approx([0.2], rel=1e-15) and res == pytest.approx(5 ** -0.5)
    # a b no non-negative combination can reduce: no column enters
    cols, w, res = greedy_nnls(A, -b, 1e-12, 3)
    assert cols.tolist() == [] and w.tolist() == [] and res == 1.0


def test_greedy_nnls_refits_every_column_in():
    """A = [(1, 1), (1, -1)]. b = (1, 1): a0 alone fits it (weight 1). b = (1, 0): the correlations tie
    (1, 1), a0 enters first with the least-squares weight 1/2, leaving r = (1/2, -1/2), whose correlation
    with a1 is 1: a1 enters and the refit of both gives 1/2 each, exactly b."""
    A = np.array([[1.0, 1.0], [1.0, -1.0]])
    cols, w, res = greedy_nnls(A, np.array([1.0, 1.0]), 1e-12, 2)
    assert cols.tolist() == [0] and w == pytest.approx([1.0], rel=1e-15) and res < 1e-15
    cols, w, res = greedy_nnls(A, np.array([1.0, 0.0]), 1e-12, 2)
    assert cols.tolist() == [0, 1] and w == pytest.approx([0.5, 0.5], rel=1e-15) and res < 1e-15
    cols, w, res = greedy_nnls(A, np.array([1.0, 0.0]), 1e-12, 1)  # one element at most: a0's 1/2
    assert cols.tolist() == [0] and w == pytest.approx([0.5], rel=1e-15) and res == pytest.approx(0.5 ** 0.5)


def test_zero_b_has_a_zero_residual_and_no_column():
    cols, w, res = greedy_nnls(np.eye(2), np.zeros(2), 1e-3, 2)
    assert cols.tolist() == [] and res == 0.0


def test_deim_indices_by_hand():
    """Column 0's largest entry (|-3| at row 1); column 1's residual after interpolating it at row 1
    (c = u1[1] / u0[1] = 2 / -3): u1 - c u0 = (1 + 2/3, 0, 4 - 2/3 * 0.5) = (5/3, 0, 11/3): row 2."""
    U = np.array([[1.0, 1.0], [-3.0, 2.0], [0.5, 4.0]])
    idx = deim_indices(U)
    assert idx.tolist() == [1, 2] and idx.dtype == np.int64
    assert deim_indices([[0.0], [2.0], [-1.0]]).tolist() == [1]  # a list: read as an array


def test_oversampled_indices_by_hand():
    """U = [(4, 0), (0, 1), (3, 0), (0, 0.5)]: DEIM takes rows 0 and 1 (P^T U = diag(4, 1): s = (4, 1), the
    smallest's right vector w = (0, 1), g = 16 - 1 = 15). Row 2 = (3, 0): a = 15 + 9, gain 24 - sqrt(24^2 - 0) = 0;
    row 3 = (0, 0.5): a = 15.25, gain 15.25 - sqrt(15.25^2 - 4 15 0.25) = 15.25 - 14.75 = 0.5. Row 3 comes next,
    although row 2 is the larger (the largest-norm rule would take it): it raises s_min^2 from 1 to 1.25 (half the
    gain: exact for two modes), row 2 leaves it at 1."""
    U = np.array([[4.0, 0.0], [0.0, 1.0], [3.0, 0.0], [0.0, 0.5]])
    assert oversampled_indices(U, 2).tolist() == deim_indices(U).tolist() == [0, 1]  # p = m: DEIM's
    idx = oversampled_indices(U, 3)
    assert idx.tolist() == [0, 1, 3] and idx.dtype == np.int64
    assert np.linalg.svd(U[idx], compute_uv=False)[-1] ** 2 == pytest.approx(1.25, rel=1e-14)
    assert np.linalg.svd(U[[0, 1, 2]], compute_uv=False)[-1] ** 2 == pytest.approx(1.0, rel=1e-14)
    assert oversampled_indices(U, 4).tolist() == [0, 1, 3, 2]
    # one mode: the largest u_i^2 after DEIM's row (1): rows 2 (1) then 3 (0.25)
    assert oversampled_indices([[0.0], [2.0], [-1.0], [0.5]], 3).tolist() == [1, 2, 3]
    for samples in (1, 5):  # below the modes, above the rows
        with pytest.raises(ValueError) as err:
            oversampled_indices(U, samples)
        assert str(err.value) == ("oversampled_indices: samples must lie in [2, 4] (the force modes, the rows), "
                                  f"got {samples}")


def test_least_squares_coefficients_interpolate_when_square_and_fit_the_pseudo_inverse_when_oversampled():
    rng = np.random.default_rng(11)
    VtU = rng.standard_normal((3, 2))
    square = np.array([[2.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(least_squares_coefficients(VtU, square), VtU @ np.linalg.inv(square), rtol=1e-14)
    tall = np.array([[2.0, 1.0], [0.0, 1.0], [1.0, -1.0]])
    D = least_squares_coefficients(VtU, tall)
    np.testing.assert_allclose(D, VtU @ np.linalg.pinv(tall), rtol=1e-13)
    # exact on the span of the force modes: a force U c sampled at the dofs gives V^T U c
    c = np.array([0.3, -1.7])
    np.testing.assert_allclose(D @ (tall @ c), VtU @ c, rtol=1e-13)
    # but not an interpolation: a sample off the span is fitted, not met (residual orthogonal to the span)
    b = np.array([1.0, 0.0, 0.0])
    fit = tall @ (np.linalg.pinv(tall) @ b)
    assert not np.allclose(fit, b) and abs(tall.T @ (b - fit)).max() < 1e-14


@pytest.mark.parametrize("PtU, refused", [
    (np.array([[1.0, 2.0], [2.0, 4.0], [0.0, 0.0]]), True),  # rank 1 of 2 modes
    (np.array([[1.0, 2.0], [2.0, 4.0 + 1e-6], [0.0, 0.0]]), False),  # rank 2, barely (s_min / s_max ~ 1e-7)
])
def test_least_squares_coefficients_refuse_sampled_rows_that_cannot_tell_the_modes_apart(PtU, refused):
    if not refused:
        assert np.all(np.isfinite(least_squares_coefficients(np.eye(2), PtU)))
        return
    with pytest.raises(ValueError, match=r"^pod_galerkin DEIM: the sampled rows of the force basis have rank below "
                                         r"its 2 modes \(singular values of P\^T U from 5\.000e\+00 to .*\): fewer "
                                         r"deim_modes$"):
        least_squares_coefficients(np.eye(2), PtU)


# ---------------------------------------------------------------- training states
def test_training_states_evenly_through_the_snapshots():
    S = np.arange(4 * 9, dtype=float).reshape(4, 9)  # 4 dofs, 9 snapshot columns
    free, fixed = np.array([0, 2]), np.array([1, 3])
    P = np.array([[1.0, 0.0], [0.0, 2.0]])
    training = SimpleNamespace(snapshots=S)
    states = training_states(training, free, fixed, P, True, 3)  # columns 0, 4, 8
    assert [s[0].tolist() for s in states] == [[S[0, c], 2 * S[2, c]] for c in (0, 4, 8)]
    assert [s[1].tolist() for s in states] == [[S[1, c], S[3, c]] for c in (0, 4, 8)]
    states[0][1][0] = -1.0
    assert S[1, 0] == 9.0  # a copy of the prescribed values
    assert [s[1] for s in training_states(training, free, fixed, P, False, 2)] == [None, None]
    assert len(training_states(training, free, fixed, P, False, 20)) == 9  # at most every column
    cols = [s[0][0] for s in training_states(training, free, fixed, P, False, 4)]
    assert cols == [S[0, c] for c in (0, 3, 5, 8)]  # linspace(0, 8, 4) = 0, 2.67, 5.33, 8 rounded


# ---------------------------------------------------------------- the element kernel's dispatch and its edges
def _kernel_problem(name="neo_hookean"):
    mesh = element_mesh("P1", (1.0, 1.0, 1.0), (1, 1, 1), jitter=0.1, seed=3)
    fibres = np.random.default_rng(5).standard_normal((mesh.n_cells, 3))
    return Problem(mesh, material_set(fibres)[name], "P1", [Dirichlet(lambda x: x[:, 2] < 1e-9)])


def test_cell_geometry_takes_the_backends_own_or_else_scikit_fems():
    own = SimpleNamespace(grad=np.ones((1, 1, 4, 3), int), dx=np.full((1, 1), 2, int))
    backend = SimpleNamespace(problem=None, cell_kernel=lambda cells: own if cells.dtype == np.int64 else None)
    grad, dx = cell_geometry(backend, [0])  # its own (the problem is never read)
    assert grad.dtype == dx.dtype == float and grad.shape == (1, 1, 4, 3) and dx.tolist() == [[2.0]]
    pb = _kernel_problem()
    skfem = make_backend("skfem", pb).cell_kernel(np.array([2, 0]))
    for partial in (SimpleNamespace(), SimpleNamespace(grad=own.grad), SimpleNamespace(dx=own.dx)):  # as NGSolve's
        backend = SimpleNamespace(problem=pb, cell_kernel=lambda cells, k=partial: k)
        grad, dx = cell_geometry(backend, [2, 0])
        np.testing.assert_array_equal(grad, skfem.grad)
        np.testing.assert_array_equal(dx, skfem.dx)


def test_the_kernel_takes_the_invariant_path_only_for_an_unchanged_invariant_law_and_the_lame_tensor_for_svk():
    class OwnStress(NeoHookean):  # its own pk2 (an energy of the base): the general path, through its pk2
        def pk2(self, F, tangent=True):
            return super().pk2(F, tangent)

    class OwnEnergy(NeoHookean):
        def energy(self, F):
            return super().energy(F)

    grad, dx = np.zeros((1, 1, 4, 3)), np.ones((1, 1))
    mats = material_set(np.ones((1, 3)))
    flags = {name: (k._invariant, k._svk) for name, k in (
        (name, ElementKernel(grad, dx, m)) for name, m in {**mats, "own_stress": OwnStress(1.0, 0.3),
                                                            "own_energy": OwnEnergy(1.0, 0.3)}.items())}
    assert flags == {"linear": (False, False), "svk": (False, True), "neo_hookean": (True, False),
                     "neo_hookean_decoupled": (True, False), "mooney_rivlin": (True, False),
                     "guccione": (False, False), "own_stress": (False, False), "own_energy": (False, False)}


def test_a_material_already_on_the_cells_is_kept_as_given():
    guccione = material_set(np.eye(3))["guccione"]  # fibres of 3 cells
    grad, dx = np.zeros((3, 1, 4, 3)), np.ones((3, 1))
    assert ElementKernel(grad, dx, guccione).material is guccione
    np.testing.assert_array_equal(ElementKernel(grad[:2], dx[:2], guccione, [2, 0]).material.fibres, np.eye(3)[[2, 0]])


def test_a_rule_of_two_points_is_the_sum_of_its_points():
    """The kernel is generic in its quadrature: two points of one cell are the sums of two one-point
    kernels (energies, force vectors, tangents); no element of the package has a 2-point rule."""
    for name in ("neo_hookean", "svk", "guccione"):
        pb = _kernel_problem(name)
        k = make_backend("skfem", pb).cell_kernel(np.array([0, 1]))
        grad = np.concatenate([k.grad[:1], k.grad[1:2]], axis=1)  # (1, 2, 4, 3): cell 1's point as a second point
        dx = np.array([[k.dx[0, 0], 0.5 * k.dx[1, 0]]])
        mat = pb.material if name != "guccione" else type(pb.material)(**{**vars(pb.material), "fibres":
                                                                             np.array([0.6, 0.8, 0.0])})
        two = ElementKernel(grad, dx, mat)
        ones = [ElementKernel(grad[:, i:i + 1], dx[:, i:i + 1], mat) for i in range(2)]
        u = 0.05 * np.random.default_rng(1).standard_normal((1, 12))
        (W, f), (_, K) = two.energies_and_forces(u), two.forces_and_tangents(u)
        parts = [(o.energies_and_forces(u), o.forces_and_tangents(u)) for o in ones]
        assert W.shape == (1,) and f.shape == (1, 12) and K.shape == (1, 12, 12)
        np.testing.assert_allclose(W, sum(p[0][0] for p in parts), rtol=1e-13)
        np.testing.assert_allclose(f, sum(p[0][1] for p in parts), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(K, sum(p[1][1] for p in parts), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("scale", [0.0, -1.0])  # a flat element (J = 0) and an inverted one (J < 0)
def test_a_degenerate_element_gives_non_finite_numbers_without_a_warning(scale):
    """A haptic step over an element squashed flat or inverted: the invariant kernel's numbers are
    not finite (the step fails on them), and no RuntimeWarning per call floods the user's output."""
    pb = _kernel_problem()
    k = make_backend("skfem", pb).cell_kernel(np.array([0]))
    kernel = ElementKernel(k.grad, k.dx, pb.material)
    X = pb.mesh.points[pb.mesh.cells[0]]
    u = ((X * [1.0, 1.0, scale]) - X).reshape(1, -1)  # z scaled by 0 (flat) or -1 (mirrored)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        W, f = kernel.energies_and_forces(u)
        _, K = kernel.forces_and_tangents(u)
    assert not np.isfinite(W).all() or not np.isfinite(f).all() or not np.isfinite(K).all()


# ---------------------------------------------------------------- reduced forces
def test_linear_forces_by_hand():
    """K_r = [[2, 1], [1, 3]] (given as integers), K_rc = [[1], [0]]: f = K_r q + K_rc u_c; the energy
    q.K_r q / 2 where nothing is prescribed (with a prescribed motion the work of the coupling is not
    an energy of q alone: None)."""
    forces = LinearForces([[2, 1], [1, 3]], np.array([[1.0], [0.0]]))
    q, uc = np.array([1.0, -2.0]), np.array([0.5])
    assert forces.force(q).tolist() == [0.0, -5.0] and forces.force(q, uc).tolist() == [0.5, -5.0]
    f, K = forces.force_and_tangent(q, uc)
    assert f.tolist() == [0.5, -5.0] and K is forces.tangent(q, uc) and K.dtype == float
    assert K.tolist() == [[2.0, 1.0], [1.0, 3.0]]
    assert forces.energy(q) == 5.0 and forces.energy(q, uc) is None  # (0 * 1 + (-5) * (-2)) / 2
    free = LinearForces(np.diag([2.0, 4.0]))  # no prescribed motion: u_c is not read
    assert free.force(q, uc).tolist() == [2.0, -8.0] and free.energy(q, uc) == 9.0  # (2 + 16) / 2
    assert free.force_and_tangent(q)[0].tolist() == [2.0, -8.0] and LinearForces.size == 0


def _reduced(name, cells=None, prescribed=True):
    """(problem, backend, V (ndof, 3), fixed sorted, forces of ``cells`` with weight 1, q, uc, u)."""
    mesh = element_mesh("P1", (1.0, 1.0, 2.0), (2, 2, 3), jitter=0.2, seed=1)
    fibres = np.random.default_rng(5).standard_normal((mesh.n_cells, 3))
    bcs = [Dirichlet(lambda x: x[:, 2] < 1e-9)]
    if prescribed:
        bcs.append(Dirichlet(lambda x: x[:, 2] > 2 - 1e-9, (0, 2), [0.05, -0.1]))
    pb = Problem(mesh, material_set(fibres)[name], "P1", bcs)
    be = make_backend("skfem", pb)
    free, fixed = pb.free_dofs, np.sort(pb.fixed_dofs)
    rng = np.random.default_rng(3)
    V = np.zeros((pb.ndof, 3))
    V[free] = np.linalg.qr(rng.standard_normal((len(free), 3)))[0]
    cells = np.arange(mesh.n_cells) if cells is None else np.asarray(cells)
    forces = element_forces(be, cells, np.ones(len(cells)), V, fixed)
    q = 0.2 * rng.standard_normal(3)
    uc = np.asarray(pb.prescribed_values(0.7), float)[np.argsort(pb.fixed_dofs)]
    u = V @ q
    u[fixed] = uc
    return pb, be, V, fixed, forces, q, uc, u


@pytest.mark.parametrize("name", ["svk", "guccione"])
def test_reduced_forces_of_laws_off_the_invariant_path_with_a_prescribed_motion(name):
    """Saint Venant-Kirchhoff and Guccione go through the material's own stress (W, S) rather than the
    invariant first Piola-Kirchhoff: V^T f_int, V^T K V and the energy of the assembled operators,
    the prescribed values lifted into every evaluation (the tangent's and the contributions' too)."""
    pb, be, V, fixed, forces, q, uc, u = _reduced(name)
    f_ref, K_ref = V.T @ be.internal_force(u), V.T @ (be.tangent(u) @ V)
    assert np.abs(forces.force(q, uc) - f_ref).max() <= 1e-12 * np.abs(f_ref).max()
    assert np.abs(forces.tangent(q, uc) - K_ref).max() <= 1e-12 * np.abs(K_ref).max()
    assert np.abs(forces.contributions(q, uc).sum(axis=0) - f_ref).max() <= 1e-12 * np.abs(f_ref).max()
    assert forces.energy(q, uc) == pytest.approx(be.strain_energy(u), rel=1e-12)
    assert np.abs(forces.force(q) - forces.force(q, uc)).max() > 1e-3 * np.abs(f_ref).max()  # uc matters


def test_a_subset_of_cells_takes_their_own_fibres_and_no_fixed_dof_needs_no_lift():
    cells = np.array([4, 0, 7])
    pb, be, V, fixed, forces, q, uc, u = _reduced("guccione", cells)
    k = be.cell_kernel(cells)
    dofs = be.element_dofs()[cells]
    _, fe = k.energies_and_forces(u[dofs])
    expected = np.einsum("ek,ekr->er", fe, V[dofs])  # V_e^T f_e of each cell, its own fibres
    assert np.abs(forces.contributions(q, uc) - expected).max() <= 1e-12 * np.abs(expected).max()
    # nothing fixed: no lift of prescribed values (a body held by its inertia or its loads only)
    pb, be, V, _, _, q, _, _ = _reduced("neo_hookean", prescribed=False)
    loose = element_forces(be, np.arange(pb.mesh.n_cells), np.ones(pb.mesh.n_cells), V, np.zeros(0, int))
    assert loose._lift is None
    f_ref = V.T @ be.internal_force(V @ q)
    assert np.abs(loose.force(q) - f_ref).max() <= 1e-12 * np.abs(f_ref).max()


# ---------------------------------------------------------------- the ECSW rule
class _Elements:
    """``full`` for ecsw_rule: ``m`` elements of an ``r``-mode basis whose contributions at training state
    ``k`` (``q[0] = k``) are ``table[k]`` (m, r) times the state's ``uc[0]`` (1 without a prescribed value)."""

    def __init__(self, table, cells=None):
        self.table = {k: np.asarray(v, float) for k, v in table.items()}
        self.m, self.r = next(iter(self.table.values())).shape
        self.cells = np.arange(self.m) if cells is None else cells
        self.asked = []

    def contributions(self, q, uc=None):
        self.asked.append(uc)
        return self.table[int(q[0])] * (1.0 if uc is None else uc[0])


def _states(n, uc=None):
    return [(np.array([float(k)]), None if uc is None else np.array([uc])) for k in range(n)]


#: training pattern: elements (1, 0), (0, 1), (1, 1), whose sum (2, 2) is element 2 twice
TRAIN = np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])
#: a held-out state's: (2, 0), (0, 1), (1, 1), sum (3, 2): element 2 twice misses it by (-1, 0)
HELD = np.array([[2.0, 0.0], [0.0, 1.0], [1.0, 1.0]])


def test_ecsw_rule_by_hand_with_a_held_out_state():
    full = _Elements({0: TRAIN, 1: 2 * TRAIN, 2: 3 * TRAIN, 3: HELD})
    elements, w, info = ecsw_rule(full, _states(4, uc=0.5), 1e-6)
    assert elements.tolist() == [2] and w == pytest.approx([2.0], rel=1e-12)
    assert full.asked == [np.array([0.5])] * 4  # the prescribed values reach the contributions
    offline = info.pop("offline_s")
    assert 0.0 <= offline < 100.0
    assert info == {"elements": 1, "candidates": 3, "training_states": 3, "heldout_states": 1,
                    "train_residual": pytest.approx(0.0, abs=1e-15), "tol": 1e-6,
                    "heldout_force_error": pytest.approx(13 ** -0.5, rel=1e-12)}  # |(-1, 0)| / |(3, 2)|


@pytest.mark.parametrize("n, train, held", [(2, 2, 0), (3, 3, 0), (4, 3, 1), (5, 4, 1), (8, 6, 2)])
def test_every_fourth_training_state_is_held_out(n, train, held):
    full = _Elements({k: (k + 1) * TRAIN for k in range(n)})
    _, _, info = ecsw_rule(full, _states(n), 1e-6)
    assert (info["training_states"], info["heldout_states"]) == (train, held)
    assert np.isnan(info["heldout_force_error"]) if held == 0 else info["heldout_force_error"] < 1e-12


@pytest.mark.parametrize("scale, tiny, used", [
    (0.5, 5e-13, 2),  # forces of norm 1 and 1e-12: exactly 1e-12 of the largest is no force
    (1.0, 7.5e-13, 2),  # 1.5e-12 below 1e-12 of the largest (2): no force
    (5e-4, 5e-14, 3),  # norm 1e-13 against 1e-3: above 1e-12 of the largest, a force however small
])
def test_a_state_without_force_relative_to_the_largest_is_skipped(scale, tiny, used):
    one = np.array([[1.0], [1.0]])  # one mode, two elements: |b| = 2 a
    full = _Elements({0: scale * one, 1: scale * one, 2: tiny * one})
    assert ecsw_rule(full, _states(3), 1e-6)[2]["training_states"] == used


@pytest.mark.parametrize("n, message", [(0, "0 training state"), (1, "1 training state")])
def test_fewer_than_two_states_with_a_force_are_refused(n, message):
    full = _Elements({0: TRAIN, 1: 0 * TRAIN})
    states = [] if n == 0 else _states(2)  # none, or one with a force and one without
    with pytest.raises(ValueError) as err:
        ecsw_rule(full, states, 1e-6)
    assert str(err.value) == f"pod_galerkin hyper='ecsw': {message}(s) with a force; needs at least 2"


def test_the_fit_gets_the_scaled_rows_and_is_refused_above_the_tolerance_accepted_at_it(monkeypatch):
    """Each state's rows scaled by 1 / |b_s| (small motions count as much as large ones); at most as
    many elements as rows; a fit stopping above ecsw_tol is refused naming both, exactly at it kept."""
    from tissuebench.rom.galerkin import ecsw

    seen = []

    def fit(A, b, tol, most, residual):
        seen.append((A, b, tol, most))
        return np.array([2]), np.array([2.0]), residual

    full = _Elements({0: TRAIN, 1: 4 * TRAIN})
    monkeypatch.setattr(ecsw, "greedy_nnls", lambda A, b, tol, most: fit(A, b, tol, most, 0.25))
    with pytest.raises(ValueError) as err:
        ecsw_rule(full, _states(2), 0.1)
    assert str(err.value) == ("pod_galerkin hyper='ecsw': the NNLS fit over 3 elements stops at a relative residual "
                              "0.25 > ecsw_tol = 0.1 (1 elements); raise ecsw_tol")
    A, b, tol, most = seen[0]
    scale = 1 / np.sqrt(8.0)  # |b| = |(2, 2)| for the first state, 4 times it for the second
    np.testing.assert_allclose(A, np.vstack([TRAIN.T * scale, TRAIN.T * scale]), rtol=1e-15)
    np.testing.assert_allclose(b, [2 * scale] * 4, rtol=1e-15)
    assert tol == 0.1 and most == 3  # 3 candidates, 4 rows
    monkeypatch.setattr(ecsw, "greedy_nnls", lambda A, b, tol, most: fit(A, b, tol, most, 0.1))
    assert ecsw_rule(full, _states(2), 0.1)[2]["train_residual"] == 0.1  # exactly at the tolerance: kept
    one = _Elements({0: np.ones((3, 1)), 1: 2 * np.ones((3, 1))})  # one mode: 2 rows for 3 candidates
    ecsw_rule(one, _states(2), 0.1)
    assert seen[-1][3] == 2


def test_a_large_fit_samples_its_candidates_by_furthest_points(monkeypatch):
    """rows x elements past MAX_ENTRIES: the candidates are a furthest-point sample of the element
    centroids (seed 0 unless given), max(MAX_ENTRIES // rows, 4 r) of them (max(28 // 4, 8) = 8 of 12)."""
    from tissuebench.rom.galerkin import ecsw
    from tissuebench.rom.wsc.cubature import cell_centroids
    from tissuebench.rom.wsc.handles import furthest_point_sampling

    rng = np.random.default_rng(0)
    points = rng.random((30, 3))
    cells = rng.integers(0, 30, (20, 4))
    own = np.arange(3, 15)  # the 12 elements are mesh cells 3..14
    table = {k: (k + 1) * np.abs(rng.standard_normal((12, 2))) for k in range(2)}
    fitted = []
    real = ecsw.greedy_nnls
    monkeypatch.setattr(ecsw, "greedy_nnls", lambda A, b, tol, most: fitted.append(A) or real(A, b, tol, most))
    monkeypatch.setattr(ecsw, "MAX_ENTRIES", 28)  # 2 states x 2 modes = 4 rows, x 12 elements = 48

    def sample(seed):
        return np.sort(furthest_point_sampling(cell_centroids(points, cells[own]), 8, seed).indices)

    assert set(sample(3)) != set(sample(0))  # the seed matters on this mesh
    for seed, kwargs in ((3, {"seed": 3}), (0, {})):
        fitted.clear()
        chosen, _, info = ecsw_rule(_Elements(table, own), _states(2), 1e-12, points, cells, **kwargs)
        expected = sample(seed)
        assert info["candidates"] == 8 and set(chosen) <= set(expected)
        columns = np.vstack([table[k][expected].T / np.linalg.norm(table[k].sum(axis=0)) for k in range(2)])
        np.testing.assert_allclose(fitted[0], columns, rtol=1e-15)
    monkeypatch.setattr(ecsw, "MAX_ENTRIES", 48)  # not past it: every element
    assert ecsw_rule(_Elements(table, own), _states(2), 0.9, points, cells)[2]["candidates"] == 12
    monkeypatch.setattr(ecsw, "MAX_ENTRIES", 28)
    assert ecsw_rule(_Elements(table, own), _states(2), 0.9)[2]["candidates"] == 12  # no mesh: every element


def _deim_training():
    """The neo-Hookean reduced problem and four scaled states (prescribed values with them) DEIM learns."""
    pb, be, V, fixed, _, q, uc, _ = _reduced("neo_hookean")
    states = []
    for s in (0.5, 1.0, -0.7, 0.3):
        u = V @ (s * q)
        u[fixed] = s * uc
        states.append(u)
    return pb, be, V, fixed, q, uc, states


def test_deim_forces_record_what_they_sample_and_their_tangent_is_the_force_derivative():
    pb, be, V, fixed, q, uc, states = _deim_training()
    free = pb.free_dofs
    deim = deim_forces(be, V[free], free, V, fixed, states, 3)
    info = dict(deim.info)
    assert 0.0 <= info.pop("offline_s") < 100.0 and np.isfinite(info.pop("condition_PtU"))
    K0 = be.tangent(np.zeros(pb.ndof))  # the snapshots: the force less its linear part at rest
    sampled = free[deim_indices(np.linalg.svd(np.column_stack([(be.internal_force(u) - K0 @ u)[free] for u in states]),
                                              full_matrices=False)[0][:, :3])]
    touching = int(np.isin(be.element_dofs(), sampled).any(axis=1).sum())
    assert info == {"force_modes": 3, "force_rank": 4, "elements": touching, "interpolation_dofs": 3,
                    "force_energy_captured": pytest.approx(info["force_energy_captured"])}
    assert 0.9 < info["force_energy_captured"] < 1.0  # 3 of 4 force modes
    f, K = deim.force_and_tangent(q, uc)
    np.testing.assert_array_equal(deim.tangent(q, uc), K)
    assert not np.allclose(deim.tangent(q), K)  # the prescribed values enter the tangent


@pytest.mark.parametrize("oversampling, samples", [(1.0, 3), (1.5, 5), (100.0, None)])
def test_deim_reduces_the_linear_part_exactly_and_samples_as_many_dofs_as_asked(oversampling, samples):
    """Issue 52 (3): the force less its linear part at rest is what DEIM fits; V^T K_0 V and V^T K_0fc are exact.
    At rest the tangent is V^T K_0 V to round-off, and a small state (prescribed values included) gets the
    linearised force V^T K_0 u to first order, whatever the three force modes miss (the whole-force DEIM of
    commit a24e7fa was off there by the interpolation's error of the linear part). p = ceil(oversampling m),
    at most the free dofs."""
    pb, be, V, fixed, q, uc, states = _deim_training()
    free = pb.free_dofs
    deim = deim_forces(be, V[free], free, V, fixed, states, 3, oversampling)
    assert deim.info["interpolation_dofs"] == (samples or len(free))
    K0 = be.tangent(np.zeros(pb.ndof))
    K_r0 = V.T @ (K0 @ V)
    np.testing.assert_allclose(deim.tangent(np.zeros(3), np.zeros(len(fixed))), K_r0, rtol=0,
                               atol=1e-10 * np.abs(K_r0).max())
    eps = 1e-7
    u = V @ (eps * q)
    u[fixed] = eps * uc
    lin = V.T @ (K0 @ u)
    np.testing.assert_allclose(deim.force(eps * q, eps * uc), lin, rtol=0, atol=1e-5 * np.abs(lin).max())


# ---------------------------------------------------------------- the POD basis of the snapshots
def _snapshot_training(velocities=None, trajectories=None, M_ff=None):
    """Three dofs, dof 1 fixed; the free rows of the two snapshots are diag(0.4, 0.3) (|U| = 0.5)."""
    U = np.zeros((3, 2))
    U[0, 0], U[2, 1] = 0.4, 0.3
    return SimpleNamespace(snapshots=U, velocities=velocities, trajectories=trajectories,
                           system=SimpleNamespace(M_ff=M_ff))


OPTIONS = {"velocities": False, "inner": "euclidean", "energy": 0.99999, "n_modes": 1}


def test_snapshot_basis_by_hand():
    """One mode of diag(0.4, 0.3): e_0, leaving 0.3 of |U| = 0.5: a projection error 0.6."""
    free = np.array([0, 2])
    pod, projector, info = snapshot_basis(_snapshot_training(trajectories=np.array([0, 1])), free, OPTIONS)
    np.testing.assert_allclose(np.abs(pod.modes), [[1.0], [0.0]], atol=1e-15)
    np.testing.assert_array_equal(projector, pod.modes.T)
    assert info == {"n_modes": 1, "energy_captured": pod.energy_captured, "rank": 2, "basis_message": pod.message,
                    "singular_values": pytest.approx([0.4, 0.3], rel=1e-15), "snapshots": 2, "runs": 2,
                    "with_velocities": False, "training_projection_error": pytest.approx(0.6, rel=1e-14)}
    assert snapshot_basis(_snapshot_training(), free, OPTIONS)[2]["runs"] == 1  # no trajectory ids: one run


def test_velocity_snapshots_join_scaled_to_the_displacements_norm():
    """Velocities (0, 2) on dof 2 scaled by |U| / |V| = 0.5 / 2: the column (0, 0.5) joins, the first
    mode is then e_2 (singular values sqrt(0.3^2 + 0.5^2) and 0.4); the projection error is U's (0.8)."""
    free = np.array([0, 2])
    vel = np.zeros((3, 2))
    vel[2, 0] = 2.0
    pod, _, info = snapshot_basis(_snapshot_training(vel), free, {**OPTIONS, "velocities": True})
    np.testing.assert_allclose(np.abs(pod.modes), [[0.0], [1.0]], atol=1e-15)
    assert info["with_velocities"] is True and info["snapshots"] == 2
    assert info["singular_values"] == pytest.approx([0.34 ** 0.5, 0.4], rel=1e-14)
    assert info["training_projection_error"] == pytest.approx(0.8, rel=1e-14)
    for training, on in ((_snapshot_training(vel), False), (_snapshot_training(np.zeros((3, 2))), True),
                         (_snapshot_training(None), True)):  # asked without any, or not asked: U alone
        assert snapshot_basis(training, free, {**OPTIONS, "velocities": on})[2]["with_velocities"] is False


def test_mass_inner_product_makes_the_basis_mass_orthonormal():
    free = np.array([0, 2])
    W = np.diag([1.0, 4.0])
    pod, projector, _ = snapshot_basis(_snapshot_training(M_ff=W), free, {**OPTIONS, "inner": "mass", "n_modes": 2})
    V = pod.modes
    np.testing.assert_allclose(V.T @ W @ V, np.eye(2), atol=1e-14)
    np.testing.assert_allclose(projector, (W @ V).T, rtol=1e-15)
    np.testing.assert_allclose(projector @ V, np.eye(2), atol=1e-14)


def test_at_most_sixty_singular_values_are_recorded():
    S = np.random.default_rng(0).standard_normal((62, 62))
    info = snapshot_basis(SimpleNamespace(snapshots=S, velocities=None, trajectories=None, system=None),
                          np.arange(62), {**OPTIONS, "n_modes": 2})[2]
    assert len(info["singular_values"]) == 60
