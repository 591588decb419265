"""Corotational elasticity through inverted cells (issue 52, 4; refsolvers/corotational.py).

Under a point load the corotational equilibrium inverts the cells under the load (its energy
has no barrier as J -> 0), and the material is defined there (the Irving flip keeps R a
rotation): the static Newton goes there for it, and still refuses an inverted state for a
material that is not defined there (neo-Hookean, log J). The tangent, in the frame of the signed
SVD, is the consistent one on inverted cells too, and stays finite where R is not
differentiable (an inverted cell whose two smallest stretches are equal: the inverse the
previous tangent took was singular there, LinAlgError)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import Dirichlet, NeoHookean, PointLoad, Problem, make_backend
from tissuebench.refsolvers.corotational import Corotational, polar_decomposition
from tissuebench.refsolvers.newton import newton_solve

E, NU = 1.0e3, 0.49


def _probe_block(material, load):
    """A block 1 x 1 x 0.5 clamped at its base, ``load`` [N] down on the top face's centre node."""
    mesh = box_mesh((1.0, 1.0, 0.5), (6, 6, 3), "tetra", jitter=0.1, seed=3)
    top = lambda x: (np.abs(x[:, 0] - 0.5) < 1e-9) & (np.abs(x[:, 1] - 0.5) < 1e-9) & (x[:, 2] > 0.5 - 1e-9)  # noqa: E731
    return Problem(mesh, material, "P1", dirichlet=[Dirichlet(lambda x: x[:, 2] < 1e-9)],
                   loads=[PointLoad(top, np.array([0.0, 0.0, -load]))])


def _inverted(n, seed):
    """``n`` deformation gradients with det F < 0, their two smallest stretches at least 0.2 apart."""
    rng = np.random.default_rng(seed)
    U, V = Rotation.random(n, random_state=seed).as_matrix(), Rotation.random(n, random_state=seed + 1).as_matrix()
    s = np.sort(rng.uniform(0.3, 2.0, (n, 3)), axis=1)[:, ::-1]
    s[:, 2] = np.minimum(s[:, 2], s[:, 1] - 0.2)
    return U @ (s[:, :, None] * np.eye(3) * np.array([1.0, 1.0, -1.0])) @ np.swapaxes(V, 1, 2)


def test_the_tangent_is_the_derivative_of_the_stress_on_inverted_cells():
    m = Corotational(E, NU)
    F = _inverted(40, 0)
    assert np.all(np.linalg.det(F) < 0)
    _, A = m.stress_and_tangent(F)
    h = 1e-6
    for k in range(3):
        for L in range(3):
            dF = np.zeros_like(F)
            dF[:, k, L] = h
            fd = (m.stress(F + dF) - m.stress(F - dF)) / (2 * h)
            assert np.abs(fd - A[..., k, L]).max() <= 1e-6 * np.abs(A).max()
    assert np.abs(A - np.transpose(A, (0, 3, 4, 1, 2))).max() <= 1e-12 * np.abs(A).max()  # a Hessian


def test_the_tangent_stays_finite_where_the_rotation_of_an_inverted_cell_is_not_differentiable():
    """F = Q diag(3, 0.2, -0.2) Q'^T: which of the two equal stretches carries the sign is arbitrary, so
    R jumps there (the energy has a kink). Measured on the organ of issue 52: a cell at (3.11, 0.206,
    -0.206) where Newton stalled. The tangent is finite and symmetric; the previous one raised."""
    Q = Rotation.random(5, random_state=3).as_matrix()
    F = Q @ np.diag([3.0, 0.2, -0.2]) @ np.swapaxes(Q[::-1], 1, 2)
    P, A = Corotational(E, NU).stress_and_tangent(F)
    assert np.all(np.isfinite(P)) and np.all(np.isfinite(A))
    assert np.abs(A - np.transpose(A, (0, 3, 4, 1, 2))).max() <= 1e-12 * np.abs(A).max()
    s = polar_decomposition(F)[2]
    assert np.allclose(s[:, 1] + s[:, 2], 0.0, atol=1e-12)  # on the kink indeed


def test_newton_goes_through_inverted_cells_only_where_the_material_is_defined():
    """One load increment, 100 N on the block's top centre: the corotational equilibrium has cells
    inverted (det F down to -0.35), and Newton reaches it (the previous Newton refused every inverted
    trial state: stalled, 'inverted element'). A neo-Hookean block under 150 N in one increment is still
    refused at its first, inverted, iterate."""
    cor = make_backend("skfem", _probe_block(Corotational(E, NU), 100.0))
    assert Corotational(E, NU).invertible and not getattr(NeoHookean(E, NU), "invertible", False)
    res = newton_solve(cor, 1.0, n_increments=1, min_increment=1.0, max_iterations=25)
    assert res.success, res.message
    assert cor.min_jacobian(res.u) < -0.2
    f = cor.internal_force(res.u) - cor.external_force(res.u, 1.0)
    assert np.linalg.norm(f[cor.problem.free_dofs]) <= 1e-8 * 100.0  # the model's equilibrium, inverted cells and all
    nh = make_backend("skfem", _probe_block(NeoHookean(E, NU), 150.0))
    res = newton_solve(nh, 1.0, n_increments=1, min_increment=1.0, max_iterations=25)
    assert res.status == "stalled" and "inverted element" in res.increments[0].message
    assert np.all(res.u == 0.0)


@pytest.mark.parametrize("nu", [0.45, 0.49])
def test_the_reference_newton_of_the_same_block_keeps_its_cells_upright(nu):
    """The neo-Hookean reference under the same 150 N converges in ten increments with its cells upright
    (its J -> 0 barrier; min det F 0.44 at nu = 0.45, 0.72 at 0.49): the inversion is the corotational
    model's, not the scene's."""
    nh = make_backend("skfem", _probe_block(NeoHookean(E, nu), 150.0))
    res = newton_solve(nh, 1.0, n_increments=10, max_increment=0.1)
    assert res.success and nh.min_jacobian(res.u) > 0.4
