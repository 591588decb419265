"""NGSolve backend: derivatives, patch tests, exactness, mass, loads, element data, solver."""
import numpy as np
import pytest
import scipy.sparse as sp

ngs = pytest.importorskip("ngsolve")

from _fe_helpers import element_mesh, material_set  # noqa: E402
from tissuebench.refsolvers.backends.ngsolve_backend import NgsolveBackend, make_intrules  # noqa: E402
from tissuebench.refsolvers.materials import LinearElastic, NeoHookean  # noqa: E402
from tissuebench.refsolvers.problem import (BodyForce, Dirichlet, FollowerPressure, Problem,  # noqa: E402
                                            SurfaceTraction)
from tissuebench.refsolvers.quadrature import facet_rule, volume_rule  # noqa: E402

pytestmark = pytest.mark.ngsolve

ELEMENTS = ["P1", "P2", "Q1"]


def mesh_for(element, n=(2, 2, 2), L=(1.0, 1.0, 1.0), distort=0.0, seed=0):
    """Structured box [0, L] for ``element``; interior vertices moved by up to ``distort`` * h."""
    return element_mesh(element, lengths=L, divisions=n, jitter=distort, seed=seed)


def clamp_x0():
    return [Dirichlet(lambda x: x[:, 0] < 1e-9)]


def materials(n_cells, seed=1):
    """The five materials, the Guccione one with a random fibre direction per cell."""
    return material_set(fibres=np.random.default_rng(seed).standard_normal((n_cells, 3)))


def backend(element, material="neo_hookean", loads=(), distort=0.2, **kw):
    mesh = mesh_for(element, distort=distort, **kw)
    mat = materials(mesh.n_cells)[material] if isinstance(material, str) else material
    return NgsolveBackend(Problem(mesh, mat, element, dirichlet=clamp_x0(), loads=list(loads)))


def random_u(b, amp=0.02, seed=0):
    """Moderate random displacement (smaller for P2, whose edge nodes are closer)."""
    scale = 0.4 if b.problem.element == "P2" else 1.0
    return scale * amp * np.random.default_rng(seed).standard_normal(b.ndof)


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


# ---------------------------------------------------------------- derivatives
@pytest.mark.parametrize("element", ELEMENTS)
@pytest.mark.parametrize("material", ["linear", "svk", "neo_hookean", "neo_hookean_decoupled", "mooney_rivlin",
                                      "guccione"])
def test_tangent_matches_fd_of_internal_force(element, material):
    b = backend(element, material)
    u = random_u(b)
    assert b.min_jacobian(u) > 0.5
    d = np.random.default_rng(5).standard_normal(b.ndof)
    h = 1e-6
    fd = (b.internal_force(u + h * d) - b.internal_force(u - h * d)) / (2 * h)
    K = b.tangent(u)
    assert isinstance(K, sp.csr_matrix) and K.shape == (b.ndof, b.ndof)
    assert rel(K @ d, fd) <= 1e-6
    f2, K2 = b.internal_force_and_tangent(u)
    np.testing.assert_allclose(f2, b.internal_force(u), rtol=0, atol=1e-14)
    assert abs(K2 - K).max() == 0.0


@pytest.mark.parametrize("element", ELEMENTS)
@pytest.mark.parametrize("material", ["mooney_rivlin", "guccione", "svk", "neo_hookean_decoupled"])
def test_internal_force_matches_fd_of_energy(element, material):
    b = backend(element, material)
    u = random_u(b)
    f = b.internal_force(u)
    h = 1e-6
    for seed in range(3):
        d = np.random.default_rng(seed + 10).standard_normal(b.ndof)
        fd = (b.strain_energy(u + h * d) - b.strain_energy(u - h * d)) / (2 * h)
        assert abs(fd - f @ d) <= 1e-6 * abs(f @ d)


def test_energies_match_spec_definitions_on_p1():
    """P1: F is constant per cell, so element energy = volume * W(F) of the NumPy kernels
    (checks the symbolic energies and the per-cell fibre order)."""
    mesh = mesh_for("P1", distort=0.2)
    vol = mesh.cell_volumes()
    for mat in materials(mesh.n_cells).values():
        b = NgsolveBackend(Problem(mesh, mat, "P1", dirichlet=clamp_x0()))
        u = random_u(b, amp=0.05, seed=3)
        X = mesh.points[mesh.cells]  # (n, 4, 3)
        x = X + u.reshape(-1, 3)[mesh.cells]
        dX = (X[:, 1:] - X[:, :1]).transpose(0, 2, 1)
        dx = (x[:, 1:] - x[:, :1]).transpose(0, 2, 1)
        F = dx @ np.linalg.inv(dX)
        expected = vol * mat.energy(F[:, None])[:, 0]
        np.testing.assert_allclose(b.element_strain_energies(u), expected, rtol=1e-11, atol=0)
        assert b.min_jacobian(u) == pytest.approx(np.linalg.det(F).min(), rel=1e-12)


# ---------------------------------------------------------------- patch and exactness
@pytest.mark.parametrize("element", ELEMENTS)
def test_linear_patch_test(element):
    mat = LinearElastic(E=3.0, nu=0.3)
    b = backend(element, mat, distort=0.25, n=(3, 3, 3))
    A = np.array([[0.01, 0.02, -0.03], [0.005, -0.01, 0.02], [0.03, 0.01, 0.015]])
    nodes = b.problem.nodes
    u = (nodes @ A.T + [0.1, -0.2, 0.3]).ravel()
    f = b.internal_force(u).reshape(-1, 3)
    interior = np.all((nodes > 1e-9) & (nodes < 1 - 1e-9), axis=1)
    assert interior.sum() > 0
    assert np.abs(f[interior]).max() <= 1e-10
    lam, mu = mat.lame
    eps = 0.5 * (A + A.T)
    W = 0.5 * lam * np.trace(eps) ** 2 + mu * np.sum(eps * eps)
    assert b.element_strain_energies(u).sum() == pytest.approx(W * 1.0, rel=1e-10)
    assert b.strain_energy(u) == pytest.approx(W, rel=1e-10)


def _box_integral(fun, L, n=3):
    """Tensor Gauss-Legendre integral over [0, L] (exact for degree <= 2n - 1 per axis)."""
    g, w = np.polynomial.legendre.leggauss(n)
    pts = [0.5 * l * (g + 1) for l in L]
    wts = [0.5 * l * w for l in L]
    X = np.stack(np.meshgrid(*pts, indexing="ij"), -1).reshape(-1, 3)
    Wt = np.einsum("i,j,k->ijk", *wts).ravel()
    return float(Wt @ fun(X))


@pytest.mark.parametrize("element", ["P2", "Q1"])
def test_higher_order_field_energy_is_exact(element):
    """P2 reproduces u = (a x^2, b y z, 0) and Q1 u = (a x y, 0, b x z): the linear-elastic
    energy is integrated exactly, which checks edge numbering and hexahedron vertex order."""
    L = (1.0, 2.0, 3.0)
    mat = LinearElastic(E=3.0, nu=0.3)
    b = backend(element, mat, distort=0.0, L=L)
    a, c = 0.02, 0.03
    x, y, z = b.problem.nodes.T
    if element == "P2":
        u = np.stack([a * x**2, c * y * z, 0 * x], 1).ravel()

        def grad(X):
            G = np.zeros((len(X), 3, 3))
            G[:, 0, 0] = 2 * a * X[:, 0]
            G[:, 1, 1], G[:, 1, 2] = c * X[:, 2], c * X[:, 1]
            return G
    else:
        u = np.stack([a * x * y, 0 * x, c * x * z], 1).ravel()

        def grad(X):
            G = np.zeros((len(X), 3, 3))
            G[:, 0, 0], G[:, 0, 1] = a * X[:, 1], a * X[:, 0]
            G[:, 2, 0], G[:, 2, 2] = c * X[:, 2], c * X[:, 0]
            return G
    exact = _box_integral(lambda X: mat.energy(np.eye(3) + grad(X)), L)
    assert b.strain_energy(u) == pytest.approx(exact, rel=1e-12)


@pytest.mark.parametrize("element", ELEMENTS)
def test_nodal_values_round_trip(element):
    """The NGSolve field built from a tissuebench vector takes the nodal values at the nodes."""
    b = backend(element)
    u = random_u(b, amp=1.0, seed=7)
    gfu = b._set_u(u)
    vals = np.array([gfu(b.ngmesh(*x)) for x in b.problem.nodes])
    np.testing.assert_allclose(vals, u.reshape(-1, 3), rtol=0, atol=1e-12)


@pytest.mark.parametrize("element", ELEMENTS)
def test_quadrature_points_match_shared_rule(element):
    """NGSolve maps the shared rule to the same physical points as the VTK/skfem convention
    (reference tet: vertex 0 at the origin; netgen reorders tets) with positive Jacobians."""
    b = backend(element)
    mesh = b.problem.mesh
    et, ir = next(iter(make_intrules(element, b._order).items()))
    mips = b.ngmesh.MapToAllElements({et: ir}, ngs.VOL)
    xyz = np.array(ngs.CF((ngs.x, ngs.y, ngs.z))(mips)).reshape(mesh.n_cells, -1, 3)
    det = np.array(ngs.Det(ngs.specialcf.JacobianMatrix(3))(mips)).ravel()
    assert det.min() > 0
    pts, _ = volume_rule(element, b._order)
    X = mesh.points[mesh.cells]
    if element == "Q1":
        s, t, r = pts
        N = np.stack([(1 - s) * (1 - t) * (1 - r), s * (1 - t) * (1 - r), s * t * (1 - r), (1 - s) * t * (1 - r),
                      (1 - s) * (1 - t) * r, s * (1 - t) * r, s * t * r, (1 - s) * t * r])
    else:
        N = np.vstack([1 - pts.sum(0), pts])
    np.testing.assert_allclose(xyz, np.einsum("ak,nai->nki", N, X), atol=1e-13)


def test_facet_quadrature_points_match_shared_rule():
    b = backend("P1", loads=[SurfaceTraction(lambda x: x[:, 2] > 1 - 1e-9, np.ones(3))])
    facets = b.problem.facets_of(b.problem.loads[0])
    et, ir = next(iter(make_intrules("P1", b._order, facet=True).items()))
    mips = b.ngmesh.MapToAllElements({et: ir}, b.ngmesh.Boundaries("load0"))
    xyz = np.array(ngs.CF((ngs.x, ngs.y, ngs.z))(mips)).reshape(len(facets), -1, 3)
    pts, _ = facet_rule("P1", b._order)
    N = np.vstack([1 - pts.sum(0), pts])
    np.testing.assert_allclose(xyz, np.einsum("ak,nai->nki", N, b.problem.mesh.points[facets]), atol=1e-13)


# ---------------------------------------------------------------- mass and element data
@pytest.mark.parametrize("element", ELEMENTS)
def test_mass_totals(element):
    mesh = mesh_for(element, distort=0.2, L=(1.0, 2.0, 0.5))
    b = NgsolveBackend(Problem(mesh, NeoHookean(1.0, 0.3), element, dirichlet=clamp_x0(), density=7.5))
    M, Ml = b.mass(), b.mass(lumped=True)
    assert isinstance(M, sp.csr_matrix) and M.shape == (b.ndof, b.ndof)
    assert abs(M - M.T).max() <= 1e-15
    total = 7.5 * 1.0
    for c in range(3):
        assert M[c::3, c::3].sum() == pytest.approx(total, rel=1e-12)
        assert Ml.diagonal()[c::3].sum() == pytest.approx(total, rel=1e-12)
        assert abs(M[c::3, (c + 1) % 3::3]).max() == 0.0
    assert Ml.nnz == b.ndof


@pytest.mark.parametrize("element", ELEMENTS)
def test_element_quantities_assemble_to_global(element):
    b = backend(element, "guccione")
    u = random_u(b)
    fe, ee = b.element_internal_forces(u), b.element_strain_energies(u)
    n_local = b.problem.layout[1].shape[1]
    assert fe.shape == (b.problem.mesh.n_cells, 3 * n_local) and ee.shape == (b.problem.mesh.n_cells,)
    g = np.zeros(b.ndof)
    np.add.at(g, b.element_dofs(), fe)
    f = b.internal_force(u)
    assert np.abs(g - f).max() <= 1e-12 * np.abs(f).max()
    assert ee.sum() == pytest.approx(b.strain_energy(u), rel=1e-12)


# ---------------------------------------------------------------- loads
FACES = [(0, 0.0, -1), (0, 1.0, 1), (1, 0.0, -1), (1, 1.0, 1), (2, 0.0, -1), (2, 1.0, 1)]


def _face(axis, value):
    return lambda x: np.abs(x[:, axis] - value) < 1e-9


@pytest.mark.parametrize("element", ELEMENTS)
def test_follower_pressure_resultants(element):
    p = 0.7
    # one face at u = 0: resultant -p * A * n
    b = backend(element, loads=[FollowerPressure(_face(0, 1.0), p)])
    f = b.external_force(np.zeros(b.ndof), 2.0).reshape(-1, 3)
    np.testing.assert_allclose(f.sum(0), [-2.0 * p, 0, 0], atol=1e-13)
    # all faces: zero resultant, at u = 0 and for an affine deformation
    b = backend(element, loads=[FollowerPressure(_face(a, v), p) for a, v, _ in FACES])
    assert np.abs(b.external_force(np.zeros(b.ndof), 1.0).reshape(-1, 3).sum(0)).max() <= 1e-13
    A = np.array([[0.1, 0.02, -0.03], [0.01, -0.05, 0.02], [0.03, 0.01, 0.08]])
    u = (b.problem.nodes @ A.T).ravel()
    assert np.abs(b.external_force(u, 1.0).reshape(-1, 3).sum(0)).max() <= 1e-13
    # single face, affine deformation: resultant -p cof(F) N A
    b = backend(element, loads=[FollowerPressure(_face(2, 1.0), p)])
    F = np.eye(3) + A
    cofN = np.linalg.det(F) * np.linalg.inv(F).T @ [0, 0, 1.0]
    np.testing.assert_allclose(b.external_force(u, 1.0).reshape(-1, 3).sum(0), -p * cofN, atol=1e-13)


@pytest.mark.parametrize("element", ELEMENTS)
def test_external_tangent_matches_fd(element):
    loads = [FollowerPressure(_face(0, 1.0), 0.7), FollowerPressure(_face(2, 0.0), -0.3),
             SurfaceTraction(_face(1, 1.0), [0.1, 0.2, 0.3]), BodyForce([0, 0, -1.0])]
    b = backend(element, loads=loads)
    u = random_u(b)
    d = np.random.default_rng(4).standard_normal(b.ndof)
    h = 1e-6
    fd = (b.external_force(u + h * d, 0.6) - b.external_force(u - h * d, 0.6)) / (2 * h)
    Ke = b.external_tangent(u, 0.6)
    assert isinstance(Ke, sp.csr_matrix) and Ke.shape == (b.ndof, b.ndof)
    assert rel(Ke @ d, fd) <= 1e-6


@pytest.mark.parametrize("element", ELEMENTS)
def test_dead_loads(element):
    loads = [SurfaceTraction(_face(1, 1.0), [0.1, 0.2, 0.3]), BodyForce([0, 0, -1.5])]
    b = backend(element, loads=loads, L=(1.0, 1.0, 1.0))
    assert b.external_tangent(np.zeros(b.ndof), 1.0) is None
    u = random_u(b)
    f = b.external_force(u, 0.5)
    np.testing.assert_allclose(f.reshape(-1, 3).sum(0), 0.5 * np.array([0.1, 0.2, 0.3 - 1.5]), atol=1e-13)
    np.testing.assert_array_equal(f, b.external_force(np.zeros(b.ndof), 0.5))
    if element == "P2":  # consistent P2 loads: no force on the vertices of a loaded triangle
        nv = b.problem.mesh.n_vertices
        f = b.external_force(u, 1.0).reshape(-1, 3)  # body force: -V/20 per vertex, V/5 per edge
        assert f[nv:].sum(0)[2] == pytest.approx(0.3 - 1.5 * 6 / 5, rel=1e-12)
        traction = NgsolveBackend(Problem(b.problem.mesh, b.problem.material, "P2", dirichlet=clamp_x0(),
                                          loads=[SurfaceTraction(_face(1, 1.0), [1.0, 0, 0])]))
        assert np.abs(traction.external_force(u, 1.0).reshape(-1, 3)[:nv]).max() <= 1e-14


# ---------------------------------------------------------------- linear solver
def test_direct_solver_spd_and_nonsymmetric():
    b = backend("P1", LinearElastic(E=1.0, nu=0.3), n=(3, 3, 3))
    free = b.problem.free_dofs
    K = b.tangent(np.zeros(b.ndof))[free][:, free].tocsr()
    x0 = np.random.default_rng(2).standard_normal(len(free))
    rhs = K @ x0
    solver = b.make_linear_solver("direct")
    x, info = solver.solve(K, rhs)
    assert np.linalg.norm(x - x0) <= 1e-10 * np.linalg.norm(x0)
    assert info["solver"] == "ngsolve-direct" and info["iterations"] == 1 and info["factor_s"] >= 0
    assert info["inverse"] == "sparsecholesky"
    N = (K + sp.random(K.shape[0], K.shape[1], density=0.002, random_state=3) * 0.1).tocsr()
    x, info = solver.solve(N, N @ x0)
    assert info["inverse"] == "umfpack"
    assert np.linalg.norm(x - x0) <= 1e-10 * np.linalg.norm(x0)
    X, _ = solver.solve(K, np.stack([rhs, 2 * rhs], 1))
    np.testing.assert_allclose(X[:, 1], 2 * x0, rtol=0, atol=1e-9)


# ---------------------------------------------------------------- compiled energy
@pytest.mark.slow
def test_realcompiled_energy_gives_the_interpreted_operators():
    """C++-compiled energy (realcompile): f_int and K_t equal the interpreted ones to round-off."""
    from tissuebench.refsolvers.backends.ngsolve_backend import compiler_available

    if not compiler_available():
        pytest.skip("no C++ compiler / ngscxx")
    plain = backend("P1", "mooney_rivlin", n=(3, 2, 2))
    compiled = NgsolveBackend(plain.problem, realcompile=True)
    assert compiled.compiled and not plain.compiled
    u = random_u(plain, seed=7)
    f0, f1 = plain.internal_force(u), compiled.internal_force(u)
    assert np.abs(f1 - f0).max() <= 1e-13 * np.abs(f0).max()
    K0, K1 = plain.tangent(u), compiled.tangent(u)
    assert abs(K1 - K0).max() <= 1e-13 * abs(K0).max()


def test_realcompile_failure_is_a_warning_and_falls_back(monkeypatch):
    from tissuebench.refsolvers.backends import ngsolve_backend as nb

    monkeypatch.setattr(nb.sys, "executable", "/nonexistent/bin/python")
    monkeypatch.setenv("PATH", "/nonexistent")
    assert not nb.compiler_available()
    plain = backend("P1", "mooney_rivlin", n=(2, 1, 1))
    with pytest.warns(RuntimeWarning, match="realcompile failed"):
        b = NgsolveBackend(plain.problem, realcompile=True)
    assert not b.compiled
    u = random_u(b, seed=8)
    np.testing.assert_allclose(b.internal_force(u), plain.internal_force(u), rtol=0, atol=1e-14)
