"""Newton's convergence test is scale-free (issue 37, item 4): a bar meshed in metres and scaled
by 1e2 ... 1e12 stalled at load factor 2.4e-4 (1/4096) with a residual it could not lower,
round-off of stresses that cancel near the reference state, while the same bar at scale 10
converged in 3 iterations. Now: converged to the residual's round-off floor (said), or, where
the whole load lies below that floor, a failure saying so at once."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import Dirichlet, PointLoad, Problem, make_backend, make_material
from tissuebench.refsolvers.newton import newton_solve


def _bar(scale, force=0.01, cell="tetra", element="P1", E=1e4):
    """A neo-Hookean 1 x 0.1 x 0.1 bar scaled by ``scale``, clamped at x = 0, a point load at its tip."""
    mesh = box_mesh((scale, 0.1 * scale, 0.1 * scale), (8, 2, 2), cell)
    problem = Problem(mesh, make_material("neo_hookean", E=E, nu=0.45), element,
                      dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9 * scale)],
                      loads=[PointLoad(lambda x: x[:, 0] > scale * (1 - 1e-9), np.array([0.0, -force, 0.0]))])
    return make_backend("skfem", problem)


def _linear(be):
    """The small-strain solution K0^-1 f (the nonlinear one tends to it as the strain vanishes)."""
    free = be.problem.free_dofs
    u = np.zeros(be.ndof)
    u[free] = spla.spsolve(be.tangent(u)[free][:, free].tocsc(), be.external_force(u, 1.0)[free])
    return u


@pytest.mark.parametrize("scale, cell, element, rel", [
    (1e2, "tetra", "P1", 1e-5), (1e3, "tetra", "P1", 1e-6), (1e4, "tetra", "P1", 1e-6),
    (1e3, "tetra", "P2", 1e-6), (1e3, "hexahedron", "Q1", 1e-6)])
def test_a_bar_scaled_far_up_converges_to_its_round_off_floor_and_says_so(scale, cell, element, rel):
    be = _bar(scale, cell=cell, element=element)
    res = newton_solve(be, 1.0, n_increments=2)
    assert res.success and res.load_factor == 1.0 and len(res.increments) == 2, res.message
    assert all(inc.iterations <= 3 for inc in res.increments)
    assert "increments only to the round-off floor of the residual" in res.message
    u = _linear(be)
    # strains of 1e-8 and less: the solution is the linear one, to round-off
    assert np.linalg.norm(res.u - u) <= rel * np.linalg.norm(u)


@pytest.mark.parametrize("scale", [1.0, 10.0])
def test_an_ordinary_bar_converges_on_rtol_as_before(scale):
    """The other side: where rtol * f_ref is above the floor, nothing changes (4 and 3 iterations,
    as before the floor existed), and no note."""
    res = newton_solve(_bar(scale), 1.0, n_increments=2)
    assert res.success and res.message == "converged"
    assert [inc.iterations for inc in res.increments] == ([4, 4] if scale == 1.0 else [3, 3])
    assert all(0 < inc.round_off_floor < 1e-9 * inc.force_scale and not inc.round_off_limited
               for inc in res.increments)


@pytest.mark.parametrize("scale", [1e6, 1e12])
def test_a_load_below_round_off_fails_at_once_saying_why(scale):
    res = newton_solve(_bar(scale), 1.0, n_increments=2)
    assert res.status == "stalled" and res.load_factor == 0.0
    assert len(res.increments) == 1 and res.increments[0].iterations == 0  # no halving: it cannot help
    assert res.increments[0].below_round_off
    assert "the load is below round-off" in res.message and "is its length unit right?" in res.message


def test_the_floor_does_not_depend_on_the_unit_of_force():
    """Floor and load scale together: the same bar with its modulus and load x 1e6 (N -> uN)."""
    a = newton_solve(_bar(1e3), 1.0, n_increments=2)
    b = newton_solve(_bar(1e3, force=0.01e6, E=1e10), 1.0, n_increments=2)
    assert b.success and [i.iterations for i in a.increments] == [i.iterations for i in b.increments]
    assert b.increments[0].round_off_floor == pytest.approx(1e6 * a.increments[0].round_off_floor, rel=1e-9)


def test_a_load_below_the_norms_underflow_is_refused_as_below_round_off():
    """Issue 54: np.linalg.norm squares the entries, so a 1e-200 N load had norm 0: its increment
    "converged" at once and newton_solve divided by that zero force (ZeroDivisionError on a24e7fa).
    With a scaled norm it is a load below round-off, said, exactly as 1e-150 N (above the
    underflow, ~1e-154 N) was and is; the force scale is the same multiple of the load on both sides."""
    runs = {force: newton_solve(_bar(1.0, force=force), 1.0, n_increments=2) for force in (1e-150, 1e-200)}
    for res in runs.values():
        inc = res.increments[0]
        assert res.status == "stalled" and res.load_factor == 0.0 and inc.below_round_off and inc.iterations == 0
        assert f"the load is below round-off: its force {inc.force_scale:.3g} is under" in res.message
    assert runs[1e-200].increments[0].force_scale / 1e-200 == pytest.approx(
        runs[1e-150].increments[0].force_scale / 1e-150, rel=1e-12)
