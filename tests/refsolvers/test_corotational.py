"""Corotational linear elasticity (refsolvers/corotational.py): the element force against the
textbook form R K_e (R^T x - X), objectivity under rigid rotations of the whole body, the linear
limit, and the consistent tangent by central finite differences (observed order 2)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from _fe_helpers import element_mesh
from tissuebench.refsolvers import (Dirichlet, Guccione, LinearElastic, MooneyRivlin, NeoHookean, Problem,
                                    SaintVenantKirchhoff, make_backend)
from tissuebench.refsolvers.corotational import Corotational, polar_decomposition, small_strain_moduli

E, NU = 3.0e3, 0.35


def _problem(element="P1", material=None, jitter=0.15):
    mesh = element_mesh(element, (1.0, 1.0, 2.0), (2, 2, 3), jitter=jitter, seed=2)
    return Problem(mesh, material or Corotational(E, NU), element, [Dirichlet(lambda x: x[:, 2] < 1e-9)])


def _rigid(pb, Q, shift=(0.1, -0.2, 0.3)):
    """Displacement of the rigid motion x = Q X + shift."""
    X = pb.nodes
    return (X @ Q.T + np.asarray(shift) - X).ravel()


def test_polar_decomposition_is_a_rotation_times_a_symmetric_stretch():
    rng = np.random.default_rng(0)
    F = np.eye(3) + 0.4 * rng.standard_normal((50, 3, 3))
    F[:5] = F[:5] @ np.diag([1.0, 1.0, -1.0])  # inverted: R stays proper
    R, S, s, _ = polar_decomposition(F)
    assert np.abs(R @ S - F).max() < 1e-13
    assert np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() < 1e-13
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-13)
    assert np.abs(S - np.swapaxes(S, -1, -2)).max() < 1e-13
    assert np.all((np.prod(s, axis=-1) < 0) == (np.linalg.det(F) < 0))


def test_stress_is_the_energy_gradient_and_vanishes_at_any_rotation():
    m = Corotational(E, NU)
    rng = np.random.default_rng(1)
    F = np.eye(3) + 0.3 * rng.standard_normal((20, 3, 3))
    P = m.stress(F)
    h = 1e-6
    for k in range(3):
        for L in range(3):
            dF = np.zeros_like(F)
            dF[:, k, L] = h
            fd = (m.energy(F + dF) - m.energy(F - dF)) / (2 * h)
            assert np.abs(fd - P[:, k, L]).max() <= 1e-7 * np.abs(P).max()
    Q = Rotation.random(30, random_state=3).as_matrix()
    Q[0] = Rotation.from_rotvec([0.0, 0.0, np.pi]).as_matrix()  # half a turn
    assert np.abs(m.stress(Q)).max() < 1e-10 * E
    assert np.abs(m.energy(Q)).max() < 1e-20 * E


def test_element_force_is_the_rotated_linear_element_force():
    """On P1 tetrahedra the corotated material's element force equals R K_e (R^T x_e - X_e) with
    R the polar rotation of the cell's F and K_e the linear element (SOFA's 'polar' method)."""
    pb = _problem()
    rng = np.random.default_rng(4)
    Q = Rotation.from_rotvec([0.3, -1.1, 0.7]).as_matrix()
    u = _rigid(pb, Q) + 0.05 * rng.standard_normal(pb.ndof)
    corot = make_backend("skfem", pb)
    linear = make_backend("skfem", Problem(pb.mesh, LinearElastic(E, NU), "P1", pb.dirichlet))
    f_e = corot.element_internal_forces(u)
    _, K_e = linear.element_forces_and_tangents(np.zeros(pb.ndof))
    cells = pb.layout[1]
    X = pb.nodes[cells]  # (e, 4, 3)
    x = X + u.reshape(-1, 3)[cells]
    # F = sum_a x_a (x) grad N_a, grad N from the reference cell
    D = np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], axis=-1)
    d = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0], x[:, 3] - x[:, 0]], axis=-1)
    R = polar_decomposition(d @ np.linalg.inv(D))[0]
    local = np.einsum("eji,eaj->eai", R, x) - X  # R^T x_a - X_a
    expected = np.einsum("eij,eaj->eai", R, np.einsum("eij,ej->ei", K_e, local.reshape(len(X), -1))
                         .reshape(len(X), 4, 3))
    assert np.abs(f_e - expected.reshape(len(X), -1)).max() <= 1e-11 * np.abs(f_e).max()


@pytest.mark.parametrize("element", ["P1", "Q1"])
@pytest.mark.parametrize("angle_deg", [1.0, 37.0, 90.0, 180.0, 300.0])
def test_objective_under_a_rigid_rotation_of_the_whole_body(element, angle_deg):
    pb = _problem(element)
    be = make_backend("skfem", pb)
    Q = Rotation.from_rotvec(np.radians(angle_deg) * np.array([1.0, 2.0, -0.5]) / np.sqrt(5.25)).as_matrix()
    u_rigid = _rigid(pb, Q)
    scale = np.abs(be.internal_force(0.01 * np.random.default_rng(0).standard_normal(pb.ndof))).max()
    assert np.abs(be.internal_force(u_rigid)).max() <= 1e-11 * scale
    assert abs(be.strain_energy(u_rigid)) <= 1e-20 * E
    # a deformed state rotated rigidly: forces rotate with it, the energy does not change
    w = 0.03 * np.random.default_rng(5).standard_normal(pb.ndof)
    X = pb.nodes
    u_rot = ((X + w.reshape(-1, 3)) @ Q.T - X).ravel()
    f, f_rot = be.internal_force(w).reshape(-1, 3), be.internal_force(u_rot).reshape(-1, 3)
    assert np.abs(f_rot - f @ Q.T).max() <= 1e-10 * np.abs(f).max()
    assert be.strain_energy(u_rot) == pytest.approx(be.strain_energy(w), rel=1e-10)


@pytest.mark.parametrize("element", ["P1", "Q1"])
def test_linear_limit_tangent_at_rest_and_first_order_difference(element):
    """K(0) is the linear elastic stiffness to round-off; f_int(eps u) - eps K u = O(eps^2)."""
    pb = _problem(element)
    corot = make_backend("skfem", pb)
    linear = make_backend("skfem", Problem(pb.mesh, LinearElastic(E, NU), element, pb.dirichlet))
    K0, K_lin = corot.tangent(np.zeros(pb.ndof)), linear.tangent(np.zeros(pb.ndof))
    assert abs(K0 - K_lin).max() <= 1e-12 * abs(K_lin).max()
    u = np.random.default_rng(6).standard_normal(pb.ndof)
    gaps = []
    for eps in (1e-2, 1e-3, 1e-4):
        fu = K_lin @ (eps * u)
        gaps.append(np.linalg.norm(corot.internal_force(eps * u) - fu) / np.linalg.norm(fu))
    slopes = np.diff(np.log10(gaps)) / np.diff(np.log10([1e-2, 1e-3, 1e-4]))
    assert np.all(np.abs(slopes - 1.0) < 0.1), (gaps, slopes)  # relative gap O(eps): force gap O(eps^2)
    assert gaps[-1] < 1e-3


@pytest.mark.parametrize("element", ["P1", "Q1"])
def test_tangent_by_central_differences_converges_at_order_two(element):
    pb = _problem(element)
    be = make_backend("skfem", pb)
    rng = np.random.default_rng(7)
    Q = Rotation.from_rotvec([0.4, 0.9, -0.3]).as_matrix()
    u = _rigid(pb, Q) + 0.08 * rng.standard_normal(pb.ndof)
    d = rng.standard_normal(pb.ndof)
    Kd = be.tangent(u) @ d
    hs = np.array([2e-2, 1e-2, 5e-3, 2.5e-3])
    err = [np.linalg.norm((be.internal_force(u + h * d) - be.internal_force(u - h * d)) / (2 * h) - Kd)
           / np.linalg.norm(Kd) for h in hs]
    slope = np.polyfit(np.log(hs), np.log(err), 1)[0]
    assert abs(slope - 2.0) < 0.15, (err, slope)
    assert err[-1] < 1e-3
    # and the tangent is symmetric (a hyperelastic energy)
    K = be.tangent(u)
    assert abs(K - K.T).max() <= 1e-11 * abs(K).max()


def test_small_strain_moduli_give_the_tangent_at_rest():
    mesh = element_mesh("P1", (1.0, 1.0, 2.0), (2, 2, 3), jitter=0.1, seed=0)
    bc = [Dirichlet(lambda x: x[:, 2] < 1e-9)]
    for mat in (MooneyRivlin(500.0, 600.0, 5133.333), SaintVenantKirchhoff(E, NU), NeoHookean(E, NU)):
        K = make_backend("skfem", Problem(mesh, mat, "P1", bc)).tangent(np.zeros(3 * mesh.n_vertices))
        K_lin = make_backend("skfem", Problem(mesh, LinearElastic(*small_strain_moduli(mat)), "P1", bc)).tangent(
            np.zeros(3 * mesh.n_vertices))
        assert abs(K - K_lin).max() <= 1e-12 * abs(K_lin).max(), mat
    with pytest.raises(ValueError, match="anisotropic"):
        small_strain_moduli(Guccione(1.0, 10.0, 2.0, 4.0, 100.0))
    with pytest.raises(ValueError, match="nu must lie"):
        Corotational(E, 0.5)
