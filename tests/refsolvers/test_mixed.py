"""Verification of the mixed u-p (Taylor-Hood P2-P1) formulation of incompressible solids.

1. homogeneous incompressible uniaxial stretch against closed forms (u, p and the reaction);
2. consistent tangent against central finite differences (incompressible and perturbed
   Lagrangian, with a follower pressure);
3. the NGSolve (symbolic) and scikit-fem (hand-derived) forms agree on the same mesh;
4. the constraint holds: the deformed volume equals the reference volume to round-off,
   where the penalty formulation loses volume;
5. bad input.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from _fe_helpers import BACKEND_PARAMS, element_mesh, on_plane

from tissuebench.refsolvers import (
    Dirichlet,
    FollowerPressure,
    Guccione,
    MooneyRivlin,
    NeoHookean,
    NeoHookeanDecoupled,
    Problem,
    SaintVenantKirchhoff,
    SurfaceTraction,
)
from tissuebench.refsolvers.mixed import MixedBackend, solve_mixed
from tissuebench.refsolvers.newton import newton_solve

FIBRE_X = np.array([1.0, 0.0, 0.0])
MATERIALS = {
    "neo_hookean": NeoHookean(E=1.0, nu=0.3),
    "neo_hookean_decoupled": NeoHookeanDecoupled(E=1.0, nu=0.3),
    "mooney_rivlin": MooneyRivlin(mu1=0.5, mu2=0.6, kappa=10.0),
    "guccione": Guccione(C=0.2, bf=8.0, bt=2.0, bfs=4.0, kappa=2.0, fibres=FIBRE_X),
}


# =========================================================================== 1. closed form
def _deviatoric_dW(name, l):
    """d(W - U)/d l_i of F = diag(l) at J = 1, written by hand for each material."""
    m = MATERIALS[name]
    I1 = float(np.sum(l**2))
    if name == "neo_hookean":  # mu/2 (I1 - 3) - mu ln J
        mu = m.lame[1]
        return mu * (l - 1 / l)
    if name == "neo_hookean_decoupled":  # mu/2 (J^-2/3 I1 - 3)
        mu = m.lame[1]
        return mu * (l - I1 / (3 * l))
    if name == "mooney_rivlin":  # mu1/2 (J^-2/3 I1 - 3) + mu2/2 (J^-4/3 I2 - 3)
        I2 = 0.5 * (I1**2 - float(np.sum(l**4)))
        return m.mu1 * (l - I1 / (3 * l)) + m.mu2 * (l * (I1 - l**2) - 2 * I2 / (3 * l))
    # Guccione, fibres along x: Q = bf e1^2 + bt (e2^2 + e3^2), e_i = (l_i^2 - 1)/2
    e = 0.5 * (l**2 - 1)
    Q = m.bf * e[0] ** 2 + m.bt * (e[1] ** 2 + e[2] ** 2)
    b = np.array([m.bf, m.bt, m.bt])
    return m.C * math.exp(Q) * b * e * l


def _incompressible_uniaxial(name, l1):
    """(p, P11) for F = diag(l1, l1^-1/2, l1^-1/2), lateral faces traction-free:
    P = d(W - U)/dF + p cof F gives P22 = dW_2 + p / l2 = 0 and P11 = dW_1 + p / l1."""
    l = np.array([l1, l1**-0.5, l1**-0.5])
    dW = _deviatoric_dW(name, l)
    p = -l[1] * dW[1]
    return p, dW[0] + p / l1


def test_closed_form_matches_finite_differences_of_energy():
    """The hand-written dW_i are the derivatives of the package's W - U (central FD) at J = 1."""
    h, lj = 1e-6, np.array([1.3, 1.3**-0.5, 1.3**-0.5])  # a volume-preserving stretch
    for name, m in MATERIALS.items():
        def Wdev(v, m=m):
            F = np.diag(v)[None, None]
            return float(m.energy(F)[0, 0] - m.volumetric(np.array(np.prod(v)))[0])
        for i in range(3):
            e = np.eye(3)[i] * h
            fd = (Wdev(lj + e) - Wdev(lj - e)) / (2 * h)
            assert fd == pytest.approx(_deviatoric_dW(name, lj)[i], rel=1e-7), (name, i)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("name", list(MATERIALS))
def test_uniaxial_incompressible_stretch(name, backend):
    """Unit cube, symmetry planes, u_x = l1 - 1 on x = 1: the isochoric homogeneous state
    (lateral stretch l1^-1/2) and the constant p are in the P2-P1 space, so u, p and the
    reaction P11 match the closed form to 1e-9."""
    l1 = 1.3
    mesh = element_mesh("P2", divisions=(2, 1, 1))
    bcs = [Dirichlet(on_plane(0, 0.0), (0,)), Dirichlet(on_plane(1, 0.0), (1,)),
           Dirichlet(on_plane(2, 0.0), (2,)), Dirichlet(on_plane(0, 1.0), (0,), l1 - 1.0)]
    pb = Problem(mesh, MATERIALS[name], "P2", bcs)
    res = solve_mixed(pb, backend, n_increments=2, rtol=1e-12, strict=True)
    p_exact, P11 = _incompressible_uniaxial(name, l1)
    l2 = l1**-0.5
    x = pb.nodes
    assert np.abs(res.u.reshape(-1, 3) - x * (np.array([l1, l2, l2]) - 1)).max() <= 1e-9
    assert np.abs(res.p - p_exact).max() <= 1e-9 * max(1.0, abs(p_exact))
    mb = MixedBackend(pb, backend)
    f = mb.internal_force(np.concatenate([res.u, res.p]))[:pb.ndof].reshape(-1, 3)
    assert f[on_plane(0, 1.0)(x), 0].sum() == pytest.approx(P11, rel=1e-9)


# =========================================================================== 2. tangent
def _beam(divisions=(3, 1, 1), material="guccione", loads=None, seed=0):
    mesh = element_mesh("P2", lengths=(3.0, 1.0, 1.0), divisions=divisions)
    mat = MATERIALS[material]
    if material == "guccione":  # one random fibre per cell
        f = np.random.default_rng(seed).standard_normal((mesh.n_cells, 3))
        mat = Guccione(C=0.2, bf=8.0, bt=2.0, bfs=4.0, kappa=2.0, fibres=f)
    if loads is None:
        loads = [FollowerPressure(on_plane(2, 0.0), 0.01)]
    return Problem(mesh, mat, "P2", [Dirichlet(on_plane(0, 0.0))], loads)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("bulk_modulus,penalty_weight", [(None, 0.0), (5.0, 0.0), (None, 0.3)])
def test_mixed_tangent_matches_finite_differences(bulk_modulus, penalty_weight, backend):
    """K (internal, and internal minus the follower-pressure tangent) against central FD
    along random directions of (u, p): relative error <= 1e-6."""
    mb = MixedBackend(_beam(), backend, bulk_modulus, penalty_weight)
    rng = np.random.default_rng(1)
    z = np.concatenate([0.02 * rng.standard_normal(mb.n_u), 0.1 * rng.standard_normal(mb.n_p)])
    assert mb.min_jacobian(z) > 0.5
    lam, h = 0.8, 1e-6

    def residual(v):
        return mb.internal_force(v) - mb.external_force(v, lam)
    K = mb.tangent(z) - mb.external_tangent(z, lam)
    for _ in range(3):
        d = rng.standard_normal(mb.ndof)
        fd = (residual(z + h * d) - residual(z - h * d)) / (2 * h)
        assert np.linalg.norm(K @ d - fd) <= 1e-6 * np.linalg.norm(fd)
    Kint = mb.tangent(z)
    assert abs(Kint - Kint.T).max() <= 1e-12 * abs(Kint).max()  # a Lagrangian's Hessian


@pytest.mark.ngsolve
def test_ngsolve_mixed_tangent_keeps_one_pattern_and_the_newton_factorisation_is_reused(monkeypatch):
    """At u = 0 many tangent entries are exactly zero (SciPy's product would drop them): the
    NGSolve tangent comes on one structural pattern at every state, with the same values,
    and a load-stepped solve refactorises the LDL^T in place after its first tangents (the
    paper-mesh ventricle factorised anew at every iteration before)."""
    from tissuebench.refsolvers import saddle_solver

    mb = MixedBackend(_beam(), "ngsolve", None, 0.3)
    rng = np.random.default_rng(2)
    z = np.concatenate([0.02 * rng.standard_normal(mb.n_u), 0.1 * rng.standard_normal(mb.n_p)])
    K0, K1 = mb.tangent(np.zeros(mb.ndof)), mb.tangent(z)
    assert np.array_equal(K0.indptr, K1.indptr) and np.array_equal(K0.indices, K1.indices)
    assert (K0.data == 0).sum() > 0  # structural zeros kept at the reference state
    f, K = mb.internal_force_and_tangent(z)
    assert abs(K - K1).max() == 0 and np.array_equal(f, mb.internal_force(z))
    symbolic = []
    solve = saddle_solver.SaddlePointSolver.solve

    def recording(self, K, b):
        x, info = solve(self, K, b)
        symbolic.append(info.get("symbolic"))
        return x, info
    monkeypatch.setattr(saddle_solver.SaddlePointSolver, "solve", recording)
    res = solve_mixed(_beam(), "ngsolve", n_increments=3, penalty_weight=0.3)
    assert res.success and len(symbolic) >= 6
    assert symbolic.count("computed") <= 2 and symbolic[-3:] == ["reused"] * 3, symbolic


# =========================================================================== 3. backends
@pytest.mark.ngsolve
@pytest.mark.parametrize("penalty_weight", [0.0, 0.3])
def test_mixed_backends_agree(penalty_weight):
    """Follower pressure on a Guccione beam with a random fibre per cell, 2 increments:
    the symbolic (NGSolve) and hand-derived (scikit-fem) forms give the same u and p."""
    pb = _beam(loads=[FollowerPressure(on_plane(2, 0.0), 0.02)])
    a = solve_mixed(pb, "skfem", n_increments=2, rtol=1e-12, strict=True, penalty_weight=penalty_weight)
    b = solve_mixed(pb, "ngsolve", n_increments=2, rtol=1e-12, strict=True, penalty_weight=penalty_weight)
    assert np.abs(a.u).max() > 0.1  # clearly nonlinear: tip moves > 10 % of the height
    assert np.abs(a.u - b.u).max() <= 1e-9 * np.abs(a.u).max()
    assert np.abs(a.p - b.p).max() <= 1e-9 * np.abs(a.p).max()


# =========================================================================== 4. constraint
@pytest.mark.ngsolve
def test_volume_is_preserved_where_the_penalty_loses_it():
    """With p = 1 in the pressure space, int (J - 1) = 0 is one of the equations: the deformed
    volume (NGSolve's exact integral of det F, degree 6 < order 8) equals the reference volume
    to 1e-10. The displacement formulation with the penalty kappa = 10 C misses it by > 1e-4."""
    import ngsolve as ngs

    pb = _beam(material="guccione", loads=[SurfaceTraction(on_plane(0, 3.0), np.array([0.0, 0.0, 0.05]))])
    res = solve_mixed(pb, "ngsolve", n_increments=2, strict=True)
    be = MixedBackend(pb, "ngsolve").displacement_backend

    def volume(u):
        gfu = be._set_u(u)
        return ngs.Integrate(ngs.Det(ngs.Id(3) + ngs.Grad(gfu)), be.ngmesh, order=8)
    assert abs(volume(res.u) / 3.0 - 1) <= 1e-10
    pen = newton_solve(be, 1.0, n_increments=2, strict=True)
    assert abs(volume(pen.u) / 3.0 - 1) > 1e-4


# =========================================================================== 5. bad input
def test_bad_input():
    pb = _beam()
    with pytest.raises(ValueError, match="P2"):
        MixedBackend(Problem(element_mesh("P1"), MATERIALS["neo_hookean"], "P1", [Dirichlet(on_plane(0, 0.0))]))
    with pytest.raises(TypeError, match="svk"):
        MixedBackend(Problem(pb.mesh, SaintVenantKirchhoff(E=1.0, nu=0.3), "P2", pb.dirichlet), "skfem")
    with pytest.raises(ValueError, match="bulk_modulus"):
        MixedBackend(pb, "skfem", bulk_modulus=-1.0)
    with pytest.raises(ValueError, match="penalty_weight"):
        MixedBackend(pb, "skfem", penalty_weight=1.5)
    with pytest.raises(ValueError, match="linear_solver"):
        MixedBackend(pb, "skfem").make_linear_solver("amg-cg")
    with pytest.raises(NotImplementedError):
        MixedBackend(pb, "skfem").mass()


# =========================================================================== 6. linear solver
@pytest.mark.parametrize("use_ngsolve", [pytest.param(True, marks=pytest.mark.ngsolve), False])
@pytest.mark.parametrize("asymmetry", [0.0, 1e-3])
def test_saddle_point_solver(asymmetry, use_ngsolve):
    """[[A, B^T], [B, 0]] with A SPD (+ a small asymmetric part): the solution of the
    regularised-LDL^T + GMRES path (or the SuperLU fallback) has a relative residual <= 1e-10."""
    import scipy.sparse as sp

    from tissuebench.refsolvers.saddle_solver import SaddlePointSolver

    rng = np.random.default_rng(3)
    n_u, n_p = 60, 12
    R = sp.random(n_u, n_u, density=0.1, random_state=4)
    A = R @ R.T + sp.eye(n_u) + asymmetry * sp.random(n_u, n_u, density=0.05, random_state=5)
    B = sp.random(n_p, n_u, density=0.3, random_state=6) + sp.eye(n_p, n_u)
    K = sp.bmat([[A, B.T], [B, None]], format="csr")
    b = rng.standard_normal(n_u + n_p)
    solver = SaddlePointSolver(n_p, use_ngsolve=use_ngsolve)
    x, info = solver.solve(K, b)
    assert np.linalg.norm(K @ x - b) <= 1e-10 * np.linalg.norm(b), info
    assert info["solver"] == ("ldlt-gmres" if use_ngsolve else "scipy-splu-colamd")
    if use_ngsolve:
        # GMRES only polishes the regularised LDL^T solution (measured 4 and 8 iterations;
        # the ventricle's 17k-dof tangents take 3); the next tangent of the same pattern is
        # refactorised in place
        assert info["iterations"] <= (6 if asymmetry == 0 else 12), info
        K2 = K.copy()
        K2.data[:n_u] *= 1.01
        x2, info2 = solver.solve(K2, b)
        assert info2["symbolic"] == "reused" and np.linalg.norm(K2 @ x2 - b) <= 1e-10 * np.linalg.norm(b)


@pytest.mark.slow  # ~16 s; the u-p solver on both backends stays in the default run (test_mixed_backends_agree)
def test_catalogue_scene_with_mixed_formulation_runs_mixed_on_both_backends():
    """land_beam declares analysis.formulation = "mixed": the scene runner solves the u-p
    problem (not the penalty), the plan says so, and the two backends agree."""
    from tissuebench.reference import solve

    runs = {b: solve("land_beam", backend=b) for b in ("skfem", "ngsolve")}
    for r in runs.values():
        assert r.status == "success" and r.plan.algorithm == "newton_solve:mixed"
        assert r.info["formulation"].startswith("mixed u-p")
    tips = [r.table["tip_z"].iloc[-1] for r in runs.values()]
    assert tips[0] == pytest.approx(tips[1], rel=1e-8)
    assert 4.0 < tips[0] < 4.17  # ci mesh (10, 2, 2) is stiffer than the converged 4.151 .. 4.185 mm
