"""Verification of the average nodal pressure (ANP) tetrahedra of :mod:`tissuebench.refsolvers.anp`.

1. force = d energy / du and tangent = d force / du (central differences), symmetric tangent;
2. the scikit-fem and NGSolve wrappings agree to round-off (the correction is shared NumPy);
3. convergence order against the closed-form bar under its own weight (Timoshenko & Goodier),
   nearly incompressible (nu = 0.4999): order 2 in the nodal displacement; bending of a
   cantilever at nu = 0.4999, where P1 locks and ANP does not;
4. the linear material is exactly the linearisation of the neo-Hookean one at rest;
5. bad input: P2, SVK.
"""
from __future__ import annotations

import numpy as np
import pytest
from _fe_helpers import BACKEND_PARAMS, element_mesh, on_box_boundary

from tissuebench.refsolvers import BodyForce, Dirichlet, NeoHookean, PointLoad, Problem, SaintVenantKirchhoff
from tissuebench.refsolvers.anp import AnpBackend, anp_applies, volumetric_modulus
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.materials import LinearElastic, NeoHookeanDecoupled
from tissuebench.refsolvers.sparse_direct import factorized


def _problem(material, divisions=(3, 2, 2), element="P1", loads=()):
    mesh = element_mesh(element, (1.0, 0.5, 0.5), divisions, jitter=0.15, seed=1)
    return Problem(mesh, material, element, dirichlet=[Dirichlet(lambda x: x[:, 0] <= 1e-9)], loads=loads)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("material", [NeoHookean(E=3.0, nu=0.49), NeoHookeanDecoupled(E=3.0, nu=0.45),
                                      LinearElastic(E=3.0, nu=0.499)], ids=lambda m: m.name)
def test_force_and_tangent_are_the_energy_derivatives(material, backend):
    be = AnpBackend(_problem(material), backend)
    rng = np.random.default_rng(0)
    u = 0.02 * rng.standard_normal(be.ndof)
    f, K = be.internal_force_and_tangent(u)
    du = 1e-6 * rng.standard_normal(be.ndof)
    dE = be.strain_energy(u + du) - be.strain_energy(u - du)
    assert dE == pytest.approx(2 * f @ du, rel=1e-6)
    df = be.internal_force(u + du) - be.internal_force(u - du)
    assert np.linalg.norm(df - 2 * K @ du) <= 1e-6 * np.linalg.norm(2 * K @ du)
    assert abs(K - K.T).max() <= 1e-12 * abs(K).max()
    assert np.allclose(be.tangent(u).toarray(), K.toarray(), rtol=0, atol=1e-12 * abs(K).max())


@pytest.mark.ngsolve
def test_backends_agree():
    pb = _problem(NeoHookean(E=3.0, nu=0.499))
    a, b = AnpBackend(pb, "skfem"), AnpBackend(pb, "ngsolve")
    u = 0.02 * np.random.default_rng(1).standard_normal(a.ndof)
    fa, Ka = a.internal_force_and_tangent(u)
    fb, Kb = b.internal_force_and_tangent(u)
    assert np.linalg.norm(fa - fb) <= 1e-12 * np.linalg.norm(fa)
    assert abs(Ka - Kb).max() <= 1e-12 * abs(Ka).max()
    assert a.strain_energy(u) == pytest.approx(b.strain_energy(u), rel=1e-12)


def test_linear_material_is_the_neo_hookean_at_rest():
    """The linear ANP (volume ratio linearised) has the tangent of the neo-Hookean ANP at u = 0."""
    lin, nh = AnpBackend(_problem(LinearElastic(3.0, 0.49))), AnpBackend(_problem(NeoHookean(3.0, 0.49)))
    Kl, Kn = lin.tangent(np.zeros(lin.ndof)), nh.tangent(np.zeros(nh.ndof))
    assert abs(Kl - Kn).max() <= 1e-12 * abs(Kn).max()
    assert volumetric_modulus(LinearElastic(3.0, 0.49)) == pytest.approx(NeoHookean(3.0, 0.49).lame[0])
    assert volumetric_modulus(NeoHookeanDecoupled(3.0, 0.49)) == pytest.approx(3.0 / (3 * (1 - 2 * 0.49)))


# ------------------------------------------------------------------ convergence order
RHO_G, E, NU = 1.0, 1.0, 0.4999
L = (1.0, 0.5, 0.5)


def _exact(x):
    """Bar under its own weight (body force -rho g along z), sigma_zz = rho g z, the rest zero."""
    X, Y, Z = x.T
    return np.column_stack([-NU * RHO_G * X * Z / E, -NU * RHO_G * Y * Z / E,
                            RHO_G * Z**2 / (2 * E) + NU * RHO_G * (X**2 + Y**2) / (2 * E)])


def _bar_error(n, anp):
    """Max nodal error / max |u| of the linear solution on an (2n, n, n) box, the exact
    displacement prescribed on the whole boundary."""
    mesh = element_mesh("P1", L, (2 * n, n, n))
    pb = Problem(mesh, LinearElastic(E, NU), "P1", dirichlet=[Dirichlet(on_box_boundary(L), value=_exact)],
                 loads=[BodyForce(np.array([0.0, 0.0, -RHO_G]))])
    be = AnpBackend(pb) if anp else make_backend("skfem", pb)
    u = np.zeros(pb.ndof)
    fixed, free = pb.fixed_dofs, pb.free_dofs
    u[fixed] = pb.prescribed_values(1.0)
    K = be.tangent(u)
    u[free] = factorized(K[free][:, free])(be.external_force(u, 1.0)[free] - K[free][:, fixed] @ u[fixed])
    exact = _exact(pb.nodes).ravel()
    return float(np.abs(u - exact).max() / np.abs(exact).max())


def test_convergence_order():
    ns = (2, 4, 8)
    errors = [_bar_error(n, anp=True) for n in ns]
    slope = np.polyfit(np.log(1.0 / np.array(ns)), np.log(errors), 1)[0]
    assert 1.6 <= slope <= 2.6, (errors, slope)
    assert errors[-1] <= 0.01


def _tip_deflection(anp, nu):
    """Tip deflection of a clamped 6 x 1 x 1 cantilever (24 x 4 x 4 boxes of 6 tetrahedra) under a
    unit end load, linear material E = 1, relative to Euler-Bernoulli F L^3 / (3 E I) = 864."""
    mesh = element_mesh("P1", (6.0, 1.0, 1.0), (24, 4, 4))
    end = np.flatnonzero(np.abs(mesh.points[:, 0] - 6.0) <= 1e-9)
    pb = Problem(mesh, LinearElastic(1.0, nu), "P1", dirichlet=[Dirichlet(lambda x: x[:, 0] <= 1e-9)],
                 loads=[PointLoad(end, np.array([0.0, 0.0, -1.0 / len(end)]))])
    be = AnpBackend(pb) if anp else make_backend("skfem", pb)
    free = pb.free_dofs
    u = np.zeros(pb.ndof)
    u[free] = factorized(be.tangent(u)[free][:, free])(be.external_force(u, 1.0)[free])
    return float(-u.reshape(-1, 3)[end, 2].mean() / 864.0)


@pytest.mark.parametrize("nu", [0.3, 0.4999])
def test_bending_does_not_lock(nu):
    """Bending of a nearly incompressible cantilever: at nu = 0.4999 P1 locks (3 % of the beam's
    deflection on this mesh) and ANP does not (76 %; 86 % at nu = 0.3, where P1 has 80 %;
    P2 on 12 x 2 x 2 boxes: 93 % and 100 %)."""
    anp, p1 = _tip_deflection(True, nu), _tip_deflection(False, nu)
    assert 0.7 <= anp <= 1.1, anp
    if nu < 0.45:
        assert p1 >= 0.6 * anp, (p1, anp)
    else:
        assert p1 <= 0.5 * anp, (p1, anp)


# ------------------------------------------------------------------ bad input
def test_refuses_what_it_cannot_model():
    with pytest.raises(ValueError, match="linear tetrahedra"):
        AnpBackend(_problem(NeoHookean(3.0, 0.49), element="P2"))
    svk = _problem(SaintVenantKirchhoff(3.0, 0.49))
    assert "no volumetric part" in anp_applies(svk)
    with pytest.raises(ValueError, match="Saint Venant-Kirchhoff"):
        AnpBackend(svk)
    be = AnpBackend(_problem(NeoHookean(3.0, 0.49)))
    with pytest.raises(NotImplementedError, match="does not split into cell"):
        be.element_strain_energies(np.zeros(be.ndof))
