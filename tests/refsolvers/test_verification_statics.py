"""Verification of the static reference solvers against analytical and independent references.

Every test asserts a number with its tolerance stated next to it:

1. linear patch tests on distorted meshes (Dirichlet and traction versions), P1/P2/Q1;
2. L2 convergence orders for a manufactured (harmonic-gradient) linear-elastic solution;
3. homogeneous uniaxial stretch against closed forms (SVK, neo-Hookean, Mooney-Rivlin);
4. cross-verification scikit-fem vs NGSolve on the same mesh for every material/element;
5. consistent tangents against central finite differences (f_int and follower pressure);
6. quadratic convergence of Newton on a large-rotation SVK cantilever;
7. Cook's membrane under refinement: the coupled neo-Hookean (13.57 mm) and the deal.II code
   gallery's decoupled neo-Hookean (plane strain 14.74 mm, free slab 14.33 mm), same numbers as
   the gallery's own Q1 tables.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from _closed_forms import lame_from, principal_stress, uniaxial_closed_form
from _fe_helpers import (BACKEND_PARAMS, ELEMENTS, MATERIAL_NAMES, element_mesh, fitted_order,
                         l2_error, material_set, on_box_boundary, on_plane, solve)

from tissuebench.cases.cook import (
    CORNER,
    COUPLED_LIMIT,
    DEALII_PLANE_STRAIN_LIMIT,
    DEALII_PLANE_STRAIN_Q1,
    DEALII_SLAB_LIMIT,
    DEALII_SLAB_Q1,
    MIDPOINT,
    printed_half_unit,
)
from tissuebench.cases.cook import cook_problem as _cook_problem
from tissuebench.cases.cook import cook_tip as _cook_tip
from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.materials import (
    LinearElastic,
    MooneyRivlin,
    NeoHookean,
    NeoHookeanDecoupled,
    SaintVenantKirchhoff,
)
from tissuebench.refsolvers.problem import (
    Dirichlet,
    FollowerPressure,
    Problem,
    SurfaceTraction,
)

# A fixed non-symmetric displacement gradient of size ~1e-3 and a translation.
A_PATCH = 1e-3 * np.array([[1.0, 0.4, -0.3],
                           [-0.7, 0.5, 0.2],
                           [0.6, -0.9, -0.8]])
B_PATCH = 1e-3 * np.array([0.3, -0.2, 0.5])


def u_affine(x):
    return x @ A_PATCH.T + B_PATCH


# =========================================================================== 1. patch tests
@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element", ELEMENTS)
def test_patch_test_dirichlet(backend, element):
    """u = A x + b on all boundary nodes of a distorted mesh is reproduced to 1e-10 (relative)."""
    mesh = element_mesh(element, divisions=(3, 3, 3), jitter=0.25, seed=3)
    pb = Problem(mesh, LinearElastic(E=1.0, nu=0.3), element,
                 [Dirichlet(on_box_boundary(), value=u_affine)])
    # the mesh really is distorted: some interior vertex moved off the lattice
    assert np.abs(mesh.points * 3 - np.round(mesh.points * 3)).max() > 0.1
    _, res = solve(pb, backend)
    ue = u_affine(pb.nodes).ravel()
    err = np.abs(res.u - ue).max() / np.abs(ue).max()
    assert err <= 1e-10, err


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element", ELEMENTS)
def test_patch_test_traction(backend, element):
    """Constant stress sigma(A) imposed by tractions on the six faces, six Dirichlet dofs
    consistent with u = A x + b: the exact affine field is reproduced to 1e-10."""
    mesh = element_mesh(element, divisions=(3, 3, 3), jitter=0.25, seed=4)
    mat = LinearElastic(E=2.0, nu=0.3)
    lam, mu = lame_from(2.0, 0.3)
    assert (lam, mu) == pytest.approx((15 / 13, 10 / 13), rel=1e-14)
    eps = 0.5 * (A_PATCH + A_PATCH.T)
    sigma = lam * np.trace(eps) * np.eye(3) + 2 * mu * eps
    loads = []
    for axis in range(3):
        for value, sign in ((0.0, -1.0), (1.0, 1.0)):
            n = sign * np.eye(3)[axis]
            loads.append(SurfaceTraction(on_plane(axis, value), sigma @ n))
    nodes = element_mesh(element, divisions=(3, 3, 3), jitter=0.25, seed=4).points
    i0 = int(np.flatnonzero(np.all(np.abs(nodes - [0, 0, 0]) < 1e-12, axis=1))[0])
    ix = int(np.flatnonzero(np.all(np.abs(nodes - [1, 0, 0]) < 1e-12, axis=1))[0])
    iy = int(np.flatnonzero(np.all(np.abs(nodes - [0, 1, 0]) < 1e-12, axis=1))[0])
    val = lambda comps: (lambda x: u_affine(x)[:, comps])  # noqa: E731
    bcs = [Dirichlet([i0], (0, 1, 2), val([0, 1, 2])),
           Dirichlet([ix], (1, 2), val([1, 2])),
           Dirichlet([iy], (2,), val([2]))]
    pb = Problem(mesh, mat, element, bcs, loads)
    assert len(pb.fixed_dofs) == 6
    _, res = solve(pb, backend)
    ue = u_affine(pb.nodes).ravel()
    err = np.abs(res.u - ue).max() / np.abs(ue).max()
    assert err <= 1e-10, err


# =========================================================================== 2. convergence
def u_harmonic(x):
    """u = grad(phi), phi = exp(x) sin(y) + exp(z) cos(y): div u = 0 and lap u = 0, so u
    solves Navier's equation with zero body force for any lambda, mu."""
    X, Y, Z = x[:, 0], x[:, 1], x[:, 2]
    return 1e-2 * np.stack([np.exp(X) * np.sin(Y),
                            np.exp(X) * np.cos(Y) - np.exp(Z) * np.sin(Y),
                            np.exp(Z) * np.cos(Y)], axis=1)


# element: (divisions per side, expected order, caps on the relative L2 error at each mesh,
# set ~20 % above the measured 3.94e-2 9.92e-3 2.49e-3 6.23e-4 (P1), 1.52e-2 3.71e-3 9.23e-4
# 2.30e-4 (Q1), 1.38e-2 1.89e-3 2.38e-4 2.96e-5 (P2))
CONVERGENCE = {"P1": ((2, 4, 8, 16), 2.0, (4.8e-2, 1.2e-2, 3.0e-3, 7.5e-4)),
               "Q1": ((2, 4, 8, 16), 2.0, (1.8e-2, 4.5e-3, 1.1e-3, 2.8e-4)),
               "P2": ((1, 2, 4, 8), 3.0, (1.7e-2, 2.3e-3, 2.9e-4, 3.6e-5))}
_convergence_cache: dict = {}


def _convergence_run(element, backend, levels):
    errs, sols = [], []
    for n in CONVERGENCE[element][0][:levels]:
        key = (element, backend, n)
        if key not in _convergence_cache:
            mesh = element_mesh(element, divisions=(n, n, n))
            pb = Problem(mesh, LinearElastic(E=1.0, nu=0.3), element, [Dirichlet(on_box_boundary(), value=u_harmonic)])
            _, res = solve(pb, backend)
            e, ref = l2_error(mesh, element, res.u, u_harmonic, order=6)
            _convergence_cache[key] = (e / ref, res.u)
        errs.append(_convergence_cache[key][0])
        sols.append(_convergence_cache[key][1])
    return np.array(errs), sols


def _check_convergence(element, backend, levels):
    ns, order, caps = CONVERGENCE[element]
    errs, _ = _convergence_run(element, backend, levels)
    h = 1.0 / np.asarray(ns[:levels], float)
    slope = fitted_order(h, errs)
    assert abs(slope - order) <= 0.2, (slope, errs)
    # the rate on the last refinement alone too
    assert abs(math.log(errs[-2] / errs[-1]) / math.log(2.0) - order) <= 0.2, errs
    assert np.all(errs <= np.asarray(caps[:levels])), errs


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element", ["P1", "Q1", "P2"])
def test_l2_convergence_order(element, backend):
    """Three meshes (h = 1/2..1/8, P2 1..1/4): fitted slope 2 (P1, Q1) / 3 (P2) +- 0.2."""
    _check_convergence(element, backend, 3)


@pytest.mark.slow
@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element", ["P1", "Q1", "P2"])
def test_l2_convergence_order_fine(element, backend):
    """Four meshes (down to h = 1/16, P2 1/8)."""
    _check_convergence(element, backend, 4)


@pytest.mark.ngsolve
@pytest.mark.parametrize("element", ["P1", "Q1", "P2"])
def test_l2_convergence_same_nodal_solution_on_both_backends(element):
    _, a = _convergence_run(element, "skfem", 3)
    _, b = _convergence_run(element, "ngsolve", 3)
    for ua, ub in zip(a, b):
        assert np.abs(ua - ub).max() <= 1e-8 * np.abs(ua).max()


# =========================================================================== 3. uniaxial stretch
def test_uniaxial_closed_forms_independent_numbers():
    """The hand-written stresses agree with the materials' strain energies (central FD of W)
    and with the published neo-Hookean numbers (E=1, nu=0.3, lambda1=1.5)."""
    nh = NeoHookean(E=1.0, nu=0.3)
    l2, P11 = uniaxial_closed_form(nh, 1.5)
    assert round(l2, 6) == 0.880175 and round(P11, 6) == 0.378280
    # SVK: P11 = E l (l^2 - 1)/2 and E22 = -nu E11
    svk = SaintVenantKirchhoff(E=1.0, nu=0.3)
    l2, P11 = uniaxial_closed_form(svk, 1.2)
    assert P11 == pytest.approx(1.2 * (1.2**2 - 1) / 2, rel=1e-12)
    assert 0.5 * (l2**2 - 1) == pytest.approx(-0.3 * 0.5 * (1.2**2 - 1), rel=1e-12)
    # d W(diag(l1, l2, l3)) / d l_i from the package's energy vs the hand derivation
    for mat in (svk, nh, MooneyRivlin(mu1=0.5, mu2=0.6, kappa=10.0), NeoHookeanDecoupled(E=1.0, nu=0.3)):
        l1, s, h = 1.3, 0.9, 1e-6
        W = lambda a, b, c, m=mat: float(m.energy(np.diag([a, b, c])[None, None])[0, 0])  # noqa: E731
        dW1 = (W(l1 + h, s, s) - W(l1 - h, s, s)) / (2 * h)
        dW2 = (W(l1, s + h, s) - W(l1, s - h, s)) / (2 * h)
        P11, P22 = principal_stress(mat, l1, s)
        assert dW1 == pytest.approx(P11, rel=1e-8) and dW2 == pytest.approx(P22, rel=1e-8)


UNIAXIAL = [("svk", SaintVenantKirchhoff(E=1.0, nu=0.3), 1.2),
            ("neo_hookean", NeoHookean(E=1.0, nu=0.3), 1.5),
            ("mooney_rivlin", MooneyRivlin(mu1=0.5, mu2=0.6, kappa=10.0), 1.3),
            ("neo_hookean_decoupled", NeoHookeanDecoupled(E=1.0, nu=0.3), 1.5)]


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element,divisions", [("Q1", (1, 1, 1)), ("P1", (2, 1, 1))])
@pytest.mark.parametrize("name,material,l1", UNIAXIAL, ids=[u[0] for u in UNIAXIAL])
def test_uniaxial_stretch(name, material, l1, element, divisions, backend):
    """Unit cube, symmetry planes x=0, y=0, z=0, u_x = l1 - 1 on x=1: the homogeneous state
    is in the FE space, so lateral stretch and P11 (reaction / area) match to 1e-8."""
    mesh = element_mesh(element, divisions=divisions)
    bcs = [Dirichlet(on_plane(0, 0.0), (0,)), Dirichlet(on_plane(1, 0.0), (1,)),
           Dirichlet(on_plane(2, 0.0), (2,)), Dirichlet(on_plane(0, 1.0), (0,), l1 - 1.0)]
    pb = Problem(mesh, material, element, bcs)
    b, res = solve(pb, backend, n_increments=2, rtol=1e-12)
    l2, P11 = uniaxial_closed_form(material, l1)
    x = pb.nodes
    u = res.u.reshape(-1, 3)
    # the displacement field is the homogeneous one everywhere
    expected = x * (np.array([l1, l2, l2]) - 1)
    assert np.abs(u - expected).max() <= 1e-8 * (l1 - 1)
    f = b.internal_force(res.u).reshape(-1, 3)
    face = on_plane(0, 1.0)(x)
    assert f[face, 0].sum() / 1.0 == pytest.approx(P11, rel=1e-8)
    assert f[on_plane(0, 0.0)(x), 0].sum() == pytest.approx(-P11, rel=1e-8)


# =========================================================================== 4. cross-verification
def _cross_problem(material_name, element):
    div = (2, 1, 1) if element == "P2" else (4, 2, 2)
    mesh = element_mesh(element, lengths=(2.0, 1.0, 1.0), divisions=div)
    mat = material_set()[material_name]
    loads = [SurfaceTraction(on_plane(0, 2.0), np.array([0.0, 0.004, -0.008]))]
    if material_name != "linear":
        loads.append(FollowerPressure(on_plane(2, 1.0), 0.004))
    return Problem(mesh, mat, element, [Dirichlet(on_plane(0, 0.0))], loads)


_cross_cache: dict = {}


def _cross_solution(material_name, element, backend):
    key = (material_name, element, backend)
    if key not in _cross_cache:
        pb = _cross_problem(material_name, element)
        _, res = solve(pb, backend, n_increments=2, rtol=1e-12)
        _cross_cache[key] = res.u
    return _cross_cache[key]


@pytest.mark.parametrize("element", ELEMENTS)
@pytest.mark.parametrize("material_name", MATERIAL_NAMES)
def test_cross_problem_is_nonlinear(material_name, element):
    """The load makes the response clearly nonlinear: max |u| between 5 % and 25 % of the length 2."""
    u = _cross_solution(material_name, element, "skfem")
    umax = np.abs(u).max()
    assert 0.1 <= umax <= 0.5, umax


@pytest.mark.ngsolve
@pytest.mark.parametrize("element", ELEMENTS)
@pytest.mark.parametrize("material_name", MATERIAL_NAMES)
def test_backends_agree(material_name, element):
    """scikit-fem and NGSolve on the same mesh and loads: <= 1e-8 (linear) / 1e-6 (nonlinear)."""
    ua = _cross_solution(material_name, element, "skfem")
    ub = _cross_solution(material_name, element, "ngsolve")
    tol = 1e-8 if material_name == "linear" else 1e-6
    diff = np.abs(ua - ub).max() / np.abs(ua).max()
    assert diff <= tol, diff


# =========================================================================== 5. tangents
def _fd_columns(fun, u, h, cols):
    """Central finite differences of ``fun`` along the unit vectors ``cols``."""
    out = []
    for j in cols:
        e = np.zeros_like(u)
        e[j] = h
        out.append((fun(u + e) - fun(u - e)) / (2 * h))
    return np.array(out).T


def _check_jacobian(K, fun, u, h=1e-6, max_cols=24, seed=0):
    """max |K - K_fd| / max |K_fd| over up to ``max_cols`` sampled columns (all for small
    systems) plus one random full direction (K v against the FD directional derivative)."""
    rng = np.random.default_rng(seed)
    n = len(u)
    cols = np.arange(n) if n <= max_cols else np.sort(rng.choice(n, max_cols, replace=False))
    K_fd = _fd_columns(fun, u, h, cols)
    scale = np.abs(K_fd).max()
    err_cols = np.abs(K[:, cols] - K_fd).max() / scale
    v = rng.standard_normal(n)
    v /= np.abs(v).max()
    d_fd = (fun(u + h * v) - fun(u - h * v)) / (2 * h)
    err_dir = np.abs(K @ v - d_fd).max() / np.abs(d_fd).max()
    return max(err_cols, err_dir)


def _tangent_problem(material_name, element, loads=()):
    div = (1, 1, 1) if element == "P2" else (2, 1, 1)
    mesh = element_mesh(element, lengths=(1.5, 1.0, 1.0), divisions=div)
    return Problem(mesh, material_set()[material_name], element, [Dirichlet(on_plane(0, 0.0))], loads)


def _random_u(pb, element, seed=0):
    scale = 0.01 if element == "P2" else 0.05
    return scale * np.random.default_rng(seed).standard_normal(pb.ndof)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element", ELEMENTS)
@pytest.mark.parametrize("material_name", MATERIAL_NAMES)
def test_tangent_matches_finite_differences(material_name, element, backend):
    pb = _tangent_problem(material_name, element)
    b = make_backend(backend, pb)
    u = _random_u(pb, element)
    assert b.min_jacobian(u) > 0.5
    K = b.tangent(u).toarray()
    err = _check_jacobian(K, b.internal_force, u)
    assert err <= 1e-6, err
    # and the combined call returns the same operators
    f2, K2 = b.internal_force_and_tangent(u)
    assert np.allclose(f2, b.internal_force(u), rtol=0, atol=1e-13 * np.abs(f2).max())
    assert np.abs(K2.toarray() - K).max() <= 1e-12 * np.abs(K).max()


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("element", ELEMENTS)
def test_follower_pressure_tangent_matches_finite_differences(element, backend):
    loads = [FollowerPressure(on_plane(2, 1.0), 0.3), FollowerPressure(on_plane(0, 1.5), 0.2)]
    pb = _tangent_problem("neo_hookean", element, loads)
    b = make_backend(backend, pb)
    u = _random_u(pb, element, seed=1)
    lam = 0.7
    K = b.external_tangent(u, lam).toarray()
    # sample the columns of the loaded faces' dofs (all other columns are zero)
    err = _check_jacobian(K, lambda v: b.external_force(v, lam), u, max_cols=24)
    assert err <= 1e-6, err
    assert np.abs(K - K.T).max() > 1e-3 * np.abs(K).max()  # follower load: non-symmetric
    # dead loads only: no external tangent
    pb_dead = _tangent_problem("neo_hookean", element, [SurfaceTraction(on_plane(2, 1.0), np.ones(3))])
    assert make_backend(backend, pb_dead).external_tangent(u, lam) is None


# =========================================================================== 6. Newton order
def _observed_orders(r):
    r = np.asarray(r, float)
    return np.array([math.log(r[k + 1] / r[k]) / math.log(r[k] / r[k - 1]) for k in range(1, len(r) - 1)])


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_newton_converges_quadratically(backend):
    """SVK cantilever 4x1x1 with an end load giving a large rotation, one increment."""
    mesh = box_mesh((4.0, 1.0, 1.0), (8, 2, 2), "hexahedron")
    mat = SaintVenantKirchhoff(E=1.0, nu=0.3)
    pb = Problem(mesh, mat, "Q1", [Dirichlet(on_plane(0, 0.0))],
                 [SurfaceTraction(on_plane(0, 4.0), np.array([0.0, 0.0, -0.02]))])
    b, res = solve(pb, backend, n_increments=1, rtol=1e-13, max_iterations=30)
    assert len(res.increments) == 1
    # large rotation: tip deflection above 50 % of the length
    tip = res.u.reshape(-1, 3)[on_plane(0, 4.0)(pb.nodes), 2].mean()
    assert tip < -2.0, tip
    r = np.asarray(res.increments[-1].residual_norms)
    # iterated into round-off (rtol=1e-13); keep the iterates clearly above that floor
    assert r[-1] <= 1e-13 * r.max(), r
    r = r[r > 10 * r[-1]]
    orders = _observed_orders(r)
    assert len(orders) >= 2, r
    assert orders[-1] >= 1.8, (orders, r)


# =========================================================================== 7. Cook's membrane
# Geometry, load and the deal.II code gallery's tables (with their provenance): tissuebench.cases.cook
COOK_REFERENCE = DEALII_SLAB_LIMIT  # 14.33 mm, the figure quoted for this benchmark
_printed_half_unit = printed_half_unit


def cook_problem(n, element, material=None, traction=1.0 / 16.0, plane_strain=True):
    return _cook_problem(n, element, material or "coupled", traction, plane_strain)


def cook_tip(pb, backend, point=CORNER):
    """u_y (mm) of the node at ``point`` after one strict Newton solve."""
    tip, res = _cook_tip(pb, backend, point, strict=True)
    return tip


def _richardson(coarse, fine, order=2):
    """Limit of a sequence converging as h^order from values at h and h/2."""
    return fine + (fine - coarse) / (2**order - 1)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("n,rel", [(8, 0.025), pytest.param(16, 0.01, marks=pytest.mark.slow)])
def test_cook_linear_plane_strain_matches_published_codes(n, rel, backend):
    """Setup check (geometry, load, clamping, plane strain): linear Cook, E = 70 MPa,
    nu = 1/3, traction 6.25 MPa; CalculiX / Code_Aster / Elmer very fine quadratic
    meshes give 32.20-32.28 mm (solids4foam tutorial). P2 8x8 within 2.5 %, 16x16 within 1 %."""
    pb = cook_problem(n, "P2", LinearElastic(E=70.0, nu=1 / 3), traction=6.25)
    tip = cook_tip(pb, backend)
    assert tip == pytest.approx(32.25, rel=rel), tip
    assert tip < 32.25  # P2 converges from below (stiffer than the limit)


_cook_cache: dict = {}


def _cook(n, element, backend, material="coupled", plane_strain=True, point=CORNER):
    key = (n, element, backend, material, plane_strain, point)
    if key not in _cook_cache:
        _cook_cache[key] = cook_tip(cook_problem(n, element, material, plane_strain=plane_strain), backend, point)
    return _cook_cache[key]


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_cook_neo_hookean_converges(backend):
    """Coupled energy, P2 2x2, 4x4, 8x8: monotone increase, last two within 2 %."""
    tips = [_cook(n, "P2", backend) for n in (2, 4, 8)]
    assert all(b > a for a, b in zip(tips, tips[1:])), tips
    assert abs(tips[-1] - tips[-2]) <= 0.02 * tips[-1], tips
    assert 13.0 <= tips[-1] <= 14.0, tips


@pytest.mark.slow
@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_cook_neo_hookean_converges_fine(backend):
    """Coupled energy, P2 up to 16x16 and Q1 up to 32x32: monotone from below, last two within
    0.5 % (P2) and 1.5 % (Q1), P2 and Q1 finest meshes within 0.5 % of each other, and the
    P2 16x16 corner value is the documented 13.57 mm to 0.1 %: 5.3 % below the 14.33 mm of the
    decoupled energy on the free slab, the coupled energy's own plane-strain figure."""
    p2 = [_cook(n, "P2", backend) for n in (2, 4, 8, 16)]
    q1 = [_cook(n, "Q1", backend) for n in (4, 8, 16, 32)]
    for seq, tol in ((p2, 0.005), (q1, 0.015)):
        assert all(b > a for a, b in zip(seq, seq[1:])), seq
        assert abs(seq[-1] - seq[-2]) <= tol * seq[-1], seq
    assert abs(p2[-1] - q1[-1]) <= 0.005 * p2[-1], (p2, q1)
    assert p2[-1] == pytest.approx(COUPLED_LIMIT, rel=1e-3), p2


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_cook_decoupled_plane_strain_matches_dealii_q1_column(backend):
    """Decoupled neo-Hookean, plane strain, midpoint of the loaded edge, Q1 with 2x2x2 Gauss
    (the gallery's element and rule) on 2x2 .. 16x16: every value rounds to the gallery's
    printed digits (an independent code on the same mesh)."""
    for n in (2, 4, 8, 16):
        ref = DEALII_PLANE_STRAIN_Q1[n]
        tip = _cook(n, "Q1", backend, "decoupled", point=MIDPOINT)
        assert abs(tip - float(ref)) <= _printed_half_unit(ref), (n, tip, ref)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_cook_decoupled_plane_strain_p2_converges_to_dealii_limit(backend):
    """P2 2x2, 4x4, 8x8 at the midpoint: monotone from below, 8x8 within 0.6 % of the
    gallery's converged Q2 value 14.74 mm (measured 14.670, -0.47 %)."""
    tips = [_cook(n, "P2", backend, "decoupled", point=MIDPOINT) for n in (2, 4, 8)]
    assert all(b > a for a, b in zip(tips, tips[1:])), tips
    assert tips[-1] < DEALII_PLANE_STRAIN_LIMIT
    assert tips[-1] == pytest.approx(DEALII_PLANE_STRAIN_LIMIT, rel=6e-3), tips


@pytest.mark.slow
@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_cook_decoupled_plane_strain_fine(backend):
    """P2 16x16 within 0.2 % of 14.74 mm (measured 14.718); Q1 32x32 rounds to 14.67."""
    tip = _cook(16, "P2", backend, "decoupled", point=MIDPOINT)
    assert tip == pytest.approx(DEALII_PLANE_STRAIN_LIMIT, rel=2e-3), tip
    q1 = _cook(32, "Q1", backend, "decoupled", point=MIDPOINT)
    assert abs(q1 - 14.67) <= _printed_half_unit(DEALII_PLANE_STRAIN_Q1[32]), q1


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_cook_neo_hookean_reference_value(backend):
    """The 14.33 mm: decoupled neo-Hookean on the free 1 mm slab (faces z = 0, 1 traction-free),
    top corner, Q1 (one hexahedron through the thickness, as the gallery). 1x1 .. 16x16 round
    to the gallery's 2015 Q1 column, and the Richardson limit (h^2) of 8x8 and 16x16 is within
    0.5 % of 14.33 mm (measured 14.303). P2 tetrahedra are not used on the free slab: their
    asymmetric layer triggers out-of-plane buckling of the thin plate (u_z ~ 16 mm at 4x4)."""
    tips = {}
    for n in (1, 2, 4, 8, 16):
        ref = DEALII_SLAB_Q1[n]
        tips[n] = _cook(n, "Q1", backend, "decoupled", plane_strain=False)
        assert abs(tips[n] - float(ref)) <= _printed_half_unit(ref), (n, tips[n], ref)
    assert _richardson(tips[8], tips[16]) == pytest.approx(COOK_REFERENCE, rel=5e-3), tips


@pytest.mark.slow
@pytest.mark.parametrize("backend", BACKEND_PARAMS)
def test_cook_neo_hookean_reference_value_fine(backend):
    """Q1 32x32 on the free slab rounds to 14.28, and the Richardson limit of 16x16 and 32x32
    is 14.33 mm to 0.1 % (measured 14.327; adding 64x64, 14.3182 -> 14.32, gives 14.332)."""
    q1 = {n: _cook(n, "Q1", backend, "decoupled", plane_strain=False) for n in (16, 32)}
    for n, tip in q1.items():
        assert abs(tip - float(DEALII_SLAB_Q1[n])) <= _printed_half_unit(DEALII_SLAB_Q1[n]), (n, tip)
    assert _richardson(q1[16], q1[32]) == pytest.approx(COOK_REFERENCE, rel=1e-3), q1
