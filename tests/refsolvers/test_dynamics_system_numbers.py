"""The dynamics' system blocks, input checks, start/step contract and energy bookkeeping by hand
(issue 41): tiny numpy arrays, each rule at its boundary on both sides."""
from __future__ import annotations

import re
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import DynamicsResult, SecondOrderSystem, StepReport, check_dt, integrate
from tissuebench.refsolvers.dynamics.base import Integrator
from tissuebench.refsolvers.dynamics.implicit import Newmark
from tissuebench.refsolvers.dynamics.result import Recorder
from tissuebench.refsolvers.dynamics.system import _prescribed_motion

# 3 dofs, dof 1 fixed; K is not symmetric so a transposed block shows
M3 = np.array([[4.0, 1.0, 0.0], [1.0, 5.0, 2.0], [0.0, 2.0, 6.0]])
K3 = np.array([[10.0, -3.0, 1.0], [-4.0, 8.0, -2.0], [1.0, -5.0, 7.0]])
F, C = [0, 2], [1]
AM, BK = 0.3, 0.02
C3 = AM * M3 + BK * K3
CUB = 2.0  # cubic spring coefficient of the nonlinear system


def _ix(A, rows, cols):
    return A[np.ix_(rows, cols)]


def _msg(text):
    return "^" + re.escape(text) + "$"


def _sys3(damped=True, prescribed=lambda t: np.array([2.0 * t]), **kw):
    am, bk = (AM, BK) if damped else (0.0, 0.0)
    return SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=[2, 0, 2], alpha_m=am, beta_k=bk,
                                           prescribed=prescribed, **kw)


def _nonlinear(load=None, **kw):
    return SecondOrderSystem(M=M3, internal_force=lambda u: K3 @ u + CUB * u ** 3,
                             tangent=lambda u: sp.csr_matrix(K3 + np.diag(3.0 * CUB * u ** 2)),
                             load=np.zeros(3) if load is None else load, free=F, **kw)


# ---------------------------------------------------------------- system blocks
def test_free_and_fixed_blocks_are_numpy_slices():
    s = _sys3()
    assert list(s.free) == F and s.free.dtype == np.int64 and list(s.fixed) == C and s.n == 3
    for got, want in ((s.M_ff, _ix(M3, F, F)), (s.M_fc, _ix(M3, F, C)), (s.K0_ff, _ix(K3, F, F)),
                      (s.K0_fc, _ix(K3, F, C))):
        assert sp.issparse(got) and np.array_equal(got.toarray(), want)
    np.testing.assert_allclose(s.C_ff.toarray(), _ix(C3, F, F), rtol=1e-15)
    np.testing.assert_allclose(s.C_fc.toarray(), _ix(C3, F, C), rtol=1e-15)
    np.testing.assert_allclose(s.C_full.toarray(), C3, rtol=1e-15)
    assert s.damped and s.has_prescribed and s.linear is True
    np.testing.assert_allclose(s.damping_force(np.array([1.0, -2.0])), _ix(C3, F, F) @ [1.0, -2.0], rtol=1e-15)


@pytest.mark.parametrize("am, bk, damped", [(0.0, 0.0, False), (0.5, 0.0, True), (0.0, 0.5, True)])
def test_damped_when_either_rayleigh_coefficient_is_nonzero(am, bk, damped):
    s = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=F, alpha_m=am, beta_k=bk)
    assert s.damped is damped
    if not damped:
        assert s.C_ff is None and s.C_fc is None and s.C_full is None
        v = np.array([1.0, 2.0])
        assert np.array_equal(s.damping_force(v), [0.0, 0.0])
    else:
        np.testing.assert_allclose(s.C_full.toarray(), am * M3 + bk * K3, rtol=1e-15)
        np.testing.assert_allclose(s.C_fc.toarray(), _ix(am * M3 + bk * K3, F, C), rtol=1e-15)


def test_couplings_with_and_without_a_prescribed_motion():
    s = _sys3()
    ac, vc = np.array([2.0]), np.array([3.0])
    np.testing.assert_array_equal(s.mass_coupling(ac), [2.0, 4.0])
    np.testing.assert_allclose(s.damping_coupling(vc), _ix(C3, F, C) @ vc, rtol=1e-15)
    np.testing.assert_allclose(s.coupling_force(vc, ac), [2.0, 4.0] + _ix(C3, F, C) @ vc, rtol=1e-15)
    undamped = _sys3(damped=False)
    np.testing.assert_array_equal(undamped.mass_coupling(ac), [2.0, 4.0])
    assert undamped.damping_coupling(vc) == 0.0
    np.testing.assert_array_equal(undamped.coupling_force(vc, ac), [2.0, 4.0])
    still = _sys3(prescribed=None)
    assert not still.has_prescribed
    assert still.mass_coupling(ac) == 0.0 and still.damping_coupling(vc) == 0.0
    assert still.coupling_force(vc, ac) == 0.0
    # a motion given but nothing fixed: no prescribed motion at all
    allfree = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), prescribed=lambda t: np.zeros(0))
    assert not allfree.has_prescribed and allfree.prescribed_values(1.0).shape == (0,)
    assert allfree.mass_coupling(np.zeros(0)) == 0.0


def test_support_force_by_hand():
    u_f, u_c = np.array([0.1, -0.2]), np.array([0.3])
    v, a = np.array([1.0, 2.0, 3.0]), np.array([-1.0, 0.5, 2.0])
    u = np.array([0.1, 0.3, -0.2])
    s = _sys3()
    np.testing.assert_allclose(s.support_force(u_f, u_c, v, a), (M3 @ a + C3 @ v + K3 @ u)[C], rtol=1e-14)
    Md = np.diag([1.0, 2.0, 3.0])
    np.testing.assert_allclose(s.support_force(u_f, u_c, v, a, mass=sp.csr_matrix(Md)),
                               (Md @ a + C3 @ v + K3 @ u)[C], rtol=1e-14)
    np.testing.assert_allclose(_sys3(damped=False).support_force(u_f, u_c, v, a), (M3 @ a + K3 @ u)[C], rtol=1e-14)
    # the scheme's own damping (a lumped scheme's C_L) replaces C_full
    Cd = np.diag([0.5, 0.25, 2.0]) + BK * K3
    np.testing.assert_allclose(s.support_force(u_f, u_c, v, a, mass=sp.csr_matrix(Md), damping=sp.csr_matrix(Cd)),
                               (Md @ a + Cd @ v + K3 @ u)[C], rtol=1e-14)


def _loaded3(load, **kw):
    return SecondOrderSystem.linear_system(M3, K3, load, free=F, alpha_m=AM, beta_k=BK,
                                           prescribed=lambda t: np.array([2.0 * t]), **kw)


def test_reactions_by_hand():
    # (M a + C v + K u - f)[C] on the fixed dof 1, zero on the free ones: f = (1, 7, -2) + t (0, 1, 0)
    u, v, a = np.array([0.1, 0.3, -0.2]), np.array([1.0, 2.0, 3.0]), np.array([-1.0, 0.5, 2.0])
    f = np.array([1.0, 7.5, -2.0])
    load = _loaded3(lambda t: np.array([1.0, 7.0 + t, -2.0]))
    want = np.zeros(3)
    want[C] = (M3 @ a + C3 @ v + K3 @ u - f)[C]
    np.testing.assert_allclose(load.reactions(0.5, u, v, a), want, rtol=1e-14, atol=0)
    assert load.reactions(0.5, u, v, a)[F].tolist() == [0.0, 0.0]
    # at rest: f_int - f_ext, as the static path (Problem.support_reactions)
    rest = load.reactions(0.5, u, np.zeros(3), np.zeros(3))
    assert rest[1] == pytest.approx((K3 @ u - f)[1], rel=1e-14)
    # a follower load is called with (t, u); the scheme's mass and damping replace M and C_full
    follower = _loaded3(lambda t, x: np.array([0.0, 2.0 * x[1] + t, 0.0]), load_depends_on_u=True)
    Md, Cd = np.diag([1.0, 2.0, 3.0]), np.diag([0.5, 0.25, 2.0])
    got = follower.reactions(0.5, u, v, a, mass=sp.csr_matrix(Md), damping=sp.csr_matrix(Cd))
    assert got[1] == pytest.approx((Md @ a + Cd @ v + K3 @ u)[1] - (0.6 + 0.5), rel=1e-14)
    with pytest.raises(ValueError, match=_msg("a must have shape (3,), got (2,)")):
        load.reactions(0.5, u, v, a[:2])
    with pytest.raises(ValueError, match=_msg("load(t) at t=0.5 must have shape (3,), got (2,)")):
        _loaded3(lambda t: np.zeros(2)).reactions(0.5, u, v, a)


def test_expand_f_int_and_energy_with_the_fixed_values():
    s = _nonlinear()
    np.testing.assert_array_equal(s.expand(np.array([1.0, 2.0])), [1.0, 0.0, 2.0])
    np.testing.assert_array_equal(s.expand(np.array([1.0, 2.0]), np.array([5.0])), [1.0, 5.0, 2.0])
    u = np.array([0.1, 0.3, -0.2])
    np.testing.assert_allclose(s.f_int([0.1, -0.2], [0.3]), (K3 @ u + CUB * u ** 3)[F], rtol=1e-15)
    u0 = np.array([0.1, 0.0, -0.2])
    np.testing.assert_allclose(s.f_int([0.1, -0.2]), (K3 @ u0 + CUB * u0 ** 3)[F], rtol=1e-15)
    assert s.energy([1.0, 2.0], [3.0]) is None
    e = _nonlinear(strain_energy=lambda x: float(x @ [1.0, 10.0, 100.0]))
    assert e.energy(np.array([1.0, 2.0]), np.array([3.0])) == 231.0
    assert e.energy(np.array([1.0, 2.0])) == 201.0


def _load_tangent(t, u):
    return sp.csr_matrix(np.array([[1.0 + t, 0.5, u[1]], [0.0, 9.0, 0.0], [2.0 * u[1], 0.0, 3.0 - t]]))


@pytest.mark.parametrize("t", [0.0, 0.5])
def test_tangent_subtracts_the_follower_load_tangent(t):
    s = _nonlinear(load_tangent=_load_tangent)
    u = np.array([0.1, 0.3, -0.2])
    Kt = K3 + np.diag(3.0 * CUB * u ** 2)
    Ke = np.array([[1.0 + t, 0.3], [0.6, 3.0 - t]])
    got = s.K_t(np.array([0.1, -0.2]), t, np.array([0.3]))
    assert isinstance(got, sp.csr_matrix)
    np.testing.assert_allclose(got.toarray(), _ix(Kt, F, F) - Ke, rtol=1e-15)
    # t=None ignores the load tangent; so does a load tangent returning None
    np.testing.assert_allclose(s.K_t(np.array([0.1, -0.2]), None, np.array([0.3])).toarray(), _ix(Kt, F, F),
                               rtol=1e-15)
    dead = _nonlinear(load_tangent=lambda t, u: None)
    np.testing.assert_allclose(dead.K_t(np.array([0.1, -0.2]), t, np.array([0.3])).toarray(), _ix(Kt, F, F),
                               rtol=1e-15)
    u0 = np.array([0.1, 0.0, -0.2])  # default u_c = 0
    np.testing.assert_allclose(s.K_t(np.array([0.1, -0.2])).toarray(),
                               _ix(K3 + np.diag(3.0 * CUB * u0 ** 2), F, F), rtol=1e-15)


def test_follower_load_receives_the_full_displacement():
    seen = []

    def load(t, u):
        seen.append(u.copy())
        return t * u + np.array([1.0, 2.0, 3.0])

    s = _nonlinear(load=load, load_depends_on_u=True)
    np.testing.assert_allclose(s.f_ext(0.5, np.array([0.1, -0.2]), np.array([0.3])), [1.05, 2.9], rtol=1e-15)
    np.testing.assert_array_equal(seen[-1], [0.1, 0.3, -0.2])
    np.testing.assert_allclose(s.f_ext(0.5, np.array([0.1, -0.2])), [1.05, 2.9], rtol=1e-15)
    np.testing.assert_array_equal(seen[-1], [0.1, 0.0, -0.2])
    dead = _nonlinear(load=lambda t: np.array([t, 2.0 * t, 3.0 * t]))
    np.testing.assert_array_equal(dead.f_ext(2.0, np.array([0.1, -0.2]), np.array([0.3])), [2.0, 6.0])


@pytest.mark.parametrize("value, text", [
    (np.zeros(2), "load(t) at t=0.5 must have shape (3,), got (2,)"),
    (np.zeros((3, 1)), "load(t) at t=0.5 must have shape (3,), got (3, 1)"),
    (np.array([0.0, np.nan, 1.0]), "load(t) at t=0.5 contains a non-finite value nan at index 1"),
    (np.array([0.0, 1.0, -np.inf]), "load(t) at t=0.5 contains a non-finite value -inf at index 2"),
])
def test_bad_load_values_are_refused_naming_the_time(value, text):
    s = _nonlinear(load=lambda t, u: value, load_depends_on_u=True)
    with pytest.raises(ValueError, match=_msg(text)):
        s.f_ext(0.5, np.zeros(2))


def test_prescribed_values():
    assert np.array_equal(_sys3(prescribed=None).prescribed_values(0.25), [0.0])
    calls = []

    def g(t):
        calls.append(t)
        return [2.0 * t]

    s = _sys3(prescribed=g)
    np.testing.assert_array_equal(s.prescribed_values(0.25), [0.5])
    assert s.prescribed_values(1).dtype == float and type(calls[-1]) is float
    bad = _sys3(prescribed=lambda t: [t, t])
    with pytest.raises(ValueError, match=_msg("prescribed(t) at t=0.25 must have shape (1,), got (2,)")):
        bad.prescribed_values(0.25)
    with pytest.raises(ValueError, match=_msg("prescribed(t) at t=0.25 contains a non-finite value inf at index 0")):
        _sys3(prescribed=lambda t: [np.inf]).prescribed_values(0.25)


# ---------------------------------------------------------------- construction checks
@pytest.mark.parametrize("free", [[-1, 0], [0, 3]])
def test_free_index_out_of_range(free):
    with pytest.raises(ValueError, match=_msg("free: dof index out of range 0..2")):
        SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=free)


def test_free_indices_at_the_ends_are_accepted():
    s = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=[2, 0])
    assert list(s.free) == [0, 2]
    with pytest.raises(ValueError, match=_msg("M has no free dofs")):
        SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=[])


@pytest.mark.parametrize("name, value, shown", [
    ("alpha_m", -1e-300, "-1e-300"), ("alpha_m", np.nan, "nan"), ("alpha_m", np.inf, "inf"),
    ("beta_k", -0.5, "-0.5"), ("beta_k", np.nan, "nan"), ("beta_k", np.inf, "inf"),
])
def test_bad_rayleigh_coefficients(name, value, shown):
    with pytest.raises(ValueError, match=_msg(f"{name} must be finite and >= 0, got {shown}")):
        SecondOrderSystem.linear_system(M3, K3, np.zeros(3), **{name: value})


def test_rayleigh_coefficients_zero_accepted_and_made_float():
    s = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), alpha_m=0, beta_k=1)
    assert type(s.alpha_m) is float and s.alpha_m == 0.0 and type(s.beta_k) is float and s.beta_k == 1.0


def test_prescribed_must_be_callable():
    with pytest.raises(TypeError, match=_msg("prescribed must be a callable t -> (n_fixed,), got list")):
        SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=F, prescribed=[1.0])


def test_constant_load_vector_is_checked_and_copied():
    f = np.array([1.0, 2.0, 3.0])
    s = SecondOrderSystem.linear_system(M3, K3, f)
    f[0] = 99.0
    np.testing.assert_array_equal(s.load(7.0), [1.0, 2.0, 3.0])
    assert callable(s.load) and s.load(7.0).dtype == float
    with pytest.raises(ValueError, match=_msg("load must have shape (3,), got (2,)")):
        SecondOrderSystem.linear_system(M3, K3, [1.0, 2.0])
    with pytest.raises(ValueError, match=_msg("load contains a non-finite value inf at index 2")):
        SecondOrderSystem.linear_system(M3, K3, [1.0, 2.0, np.inf])


def test_mass_is_converted_to_float_csr():
    s = SecondOrderSystem.linear_system([[4, 1], [1, 5]], np.eye(2), np.zeros(2))
    assert isinstance(s.M, sp.csr_matrix) and s.M.dtype == float
    np.testing.assert_array_equal(s.M.toarray(), [[4.0, 1.0], [1.0, 5.0]])
    s = SecondOrderSystem.linear_system(sp.csc_matrix(M3), K3, np.zeros(3))
    assert isinstance(s.M, sp.csr_matrix) and np.array_equal(s.M.toarray(), M3)
    one = SecondOrderSystem(M=5.0, internal_force=lambda u: u, tangent=lambda u: sp.eye(1), load=[0.0])
    assert one.n == 1 and one.M.toarray().tolist() == [[5.0]]


def test_linear_system_checks_the_stiffness_shape():
    with pytest.raises(ValueError, match=_msg("K must have shape (3, 3) like M, got (2, 2)")):
        SecondOrderSystem.linear_system(M3, np.eye(2), np.zeros(3))


def test_linear_is_the_constructor_on_the_class_and_the_flag_on_an_instance():
    assert SecondOrderSystem.linear == SecondOrderSystem.linear_system
    s = SecondOrderSystem.linear(M3, K3, np.zeros(3))
    assert s.linear is True
    u = np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(s.internal_force(u), K3 @ u)
    assert s.strain_energy(u) == 0.5 * float(u @ (K3 @ u))
    assert _nonlinear().linear is False
    s.linear = 0
    assert s.linear is False
    s.linear = "yes"
    assert s.linear is True


# ---------------------------------------------------------------- _prescribed_motion of a backend's problem
class _Problem:
    def __init__(self, values, dirichlet=()):
        self.values, self.dirichlet, self.lams = np.asarray(values, float), list(dirichlet), []
        self.fixed_dofs = np.array([5, 1, 3])

    def prescribed_values(self, lam):
        self.lams.append(lam)
        return lam * self.values


def test_no_motion_and_zero_values_at_one_is_none():
    pb = _Problem([0.0, 0.0, 0.0], [SimpleNamespace(motion=None), SimpleNamespace()])
    assert _prescribed_motion(pb, lambda t: 2.0 * t) is None and pb.lams == [1.0]
    bare = _Problem([0.0, 0.0, 0.0])
    del bare.dirichlet
    assert _prescribed_motion(bare, lambda t: t) is None


def test_values_are_reordered_to_the_sorted_fixed_dofs():
    pb = _Problem([10.0, 20.0, 30.0], [SimpleNamespace(motion=None)])
    g = _prescribed_motion(pb, lambda t: np.float64(2.0 * t))
    # fixed_dofs [5, 1, 3]: sorted order is dofs 1, 3, 5 -> values 20, 30, 10, scaled by lam = 2 t
    np.testing.assert_array_equal(g(0.25), [10.0, 15.0, 5.0])
    assert pb.lams[-1] == 0.5 and type(pb.lams[-1]) is float
    for tiny in (1e-300, -1e-300):
        assert _prescribed_motion(_Problem([0.0, 0.0, tiny]), lambda t: t) is not None


def test_a_motion_makes_it_prescribed_even_with_zero_values():
    pb = _Problem([0.0, 0.0, 0.0], [SimpleNamespace(motion=None), SimpleNamespace(motion=lambda x, t: x)])
    g = _prescribed_motion(pb, lambda t: t)
    assert g is not None
    np.testing.assert_array_equal(g(0.7), [0.0, 0.0, 0.0])


# ---------------------------------------------------------------- recorder and result
M2 = np.array([[2.0, 0.5], [0.5, 1.0]])
K2 = np.array([[3.0, -1.0], [-1.0, 2.0]])
AM2, BK2 = 0.1, 0.02
C2 = AM2 * M2 + BK2 * K2


def _g2(t):
    return np.array([0.1 * t * t + 0.05 * t])


def _sys2(**kw):
    return SecondOrderSystem.linear_system(M2, K2, lambda t: np.array([1.0 + t, 7.0]), free=[0], alpha_m=AM2,
                                           beta_k=BK2, prescribed=_g2, **kw)


def _trapezoid(f, x):
    """Cumulative sum over steps of 1/2 (f_k + f_k+1) . (x_k+1 - x_k); f, x: (steps, m)."""
    inc = 0.5 * np.einsum("ij,ij->i", f[1:] + f[:-1], np.diff(x, axis=0))
    return np.concatenate([[0.0], np.cumsum(inc)])


def test_prescribed_run_energy_bookkeeping_by_hand():
    res = integrate(_sys2(), [0.3, 0.0], [-0.2, 0.05], 0.1, 0.5, method="newmark")
    assert res.success and res.n_steps == 5 and list(res.stored_steps) == [0, 1, 2, 3, 4, 5]
    u, v, a, t = res.u, res.v, res.a, res.t
    np.testing.assert_allclose(u[:, 1], [_g2(x)[0] for x in t], rtol=1e-14)
    ke = 0.5 * np.einsum("ij,jk,ik->i", v, M2, v)
    ie = 0.5 * np.einsum("ij,jk,ik->i", u, K2, u)
    support = (a @ M2.T + v @ C2.T + u @ K2.T)[:, 1:]
    rw = _trapezoid(support, u[:, 1:])
    w = _trapezoid((1.0 + t)[:, None], u[:, :1]) + rw
    d = _trapezoid(v @ C2.T, u)
    np.testing.assert_allclose(res.kinetic_energy, ke, rtol=1e-13)
    np.testing.assert_allclose(res.strain_energy, ie, rtol=1e-13)
    np.testing.assert_allclose(res.reaction_work, rw, rtol=1e-12, atol=1e-16)
    np.testing.assert_allclose(res.external_work, w, rtol=1e-12, atol=1e-16)
    np.testing.assert_allclose(res.damping_dissipation, d, rtol=1e-12, atol=1e-16)
    err = ke + ie + d - w - (ke[0] + ie[0])
    np.testing.assert_allclose(res.energy_error, err, rtol=0, atol=1e-14)
    assert np.abs(res.energy_error).max() < 1e-14 < np.abs(rw).max() * 1e-10  # trapezoidal rule: exact
    mech, supplied = ke + ie + d, ke[0] + ie[0] + w
    assert res.energy_growth_ratio == pytest.approx(mech.max() / supplied.max(), rel=1e-13)
    scale = max(np.abs(ke + ie).max(), np.abs(w).max())
    np.testing.assert_allclose(res.relative_energy_error, res.energy_error / scale, rtol=1e-13)
    assert res.newton_iterations.tolist() == [0, 1, 1, 1, 1, 1] and res.converged.all()
    assert res.wall_time[0] == 0.0 and np.all(res.wall_time >= 0)


def test_internal_work_without_strain_energy_counts_the_prescribed_dofs():
    s = SecondOrderSystem(M=M2, internal_force=lambda u: K2 @ u, tangent=lambda u: sp.csr_matrix(K2),
                          load=lambda t: np.array([1.0 + t, 7.0]), free=[0], linear=True, prescribed=_g2)
    res = integrate(s, None, [-0.2, 0.05], 0.1, 0.5, method="newmark")
    # the trapezoidal rule integrates the linear symmetric force K u exactly: 1/2 u.K u on all dofs
    np.testing.assert_allclose(res.strain_energy, 0.5 * np.einsum("ij,jk,ik->i", res.u, K2, res.u), rtol=1e-12)


@pytest.mark.parametrize("t_end, stored", [(0.5, [0, 2, 4, 5]), (0.4, [0, 2, 4])])
def test_store_every_keeps_the_multiples_and_the_last(t_end, stored):
    full = integrate(_sys2(), [0.3, 0.0], [-0.2, 0.05], 0.1, t_end)
    res = integrate(_sys2(), [0.3, 0.0], [-0.2, 0.05], 0.1, t_end, store_every=2, dofs=[1, 0])
    assert res.stored_steps.tolist() == stored and res.dofs.tolist() == [1, 0]
    for name in ("u", "v", "a"):
        np.testing.assert_array_equal(getattr(res, name), getattr(full, name)[stored][:, [1, 0]])
    np.testing.assert_array_equal(res.t_stored, full.t[stored])
    np.testing.assert_array_equal(res.energy_error, full.energy_error)
    only = integrate(_sys2(), [0.3, 0.0], [-0.2, 0.05], 0.1, t_end, dofs=[1])
    assert only.u.shape == (len(full.t), 1)
    np.testing.assert_array_equal(only.u[:, 0], full.u[:, 1])


@pytest.mark.parametrize("kw, text", [
    (dict(dofs=[2]), "dofs: index out of range 0..1"), (dict(dofs=[-1]), "dofs: index out of range 0..1"),
    (dict(store_every=0), "store_every must be an integer >= 1, got 0"),
    (dict(store_every=1.5), "store_every must be an integer >= 1, got 1.5"),
])
def test_recorder_refuses_bad_storage_options(kw, text):
    s = _sys2()
    with pytest.raises(ValueError, match=_msg(text)):
        Recorder(s, s.M_ff, 3, **kw)


def test_recorder_accepts_the_boundary_storage_options():
    s = _sys2()
    rec = Recorder(s, s.M_ff, 3, dofs=[0, 1], store_every=2.0)
    assert rec.store_every == 2 and type(rec.store_every) is int
    assert Recorder(s, s.M_ff, 3, store_every=1).store_every == 1


def test_recorder_with_a_prescribed_motion_and_its_own_mass_by_hand():
    s = _sys2()
    Md = np.diag([3.0, 1.5])
    rec = Recorder(s, sp.csr_matrix([[3.0]]), 1, mass_full=sp.csr_matrix(Md))
    states = [(0.0, [0.1], [0.2], [0.3], [1.0], (np.array([0.05]), np.array([0.4]), np.array([0.6]))),
              (0.1, [0.15], [-0.1], [0.5], [2.0], (np.array([0.09]), np.array([0.5]), np.array([-0.2])))]
    for t, u, v, a, f, c in states:
        rec.record(t, np.array(u), np.array(v), np.array(a), np.array(f), constrained=c)
    res = rec.finish("hand", 0.1, "success", "", None, {"x": 1})
    uf = np.array([[0.1, 0.05], [0.15, 0.09]])
    vf = np.array([[0.2, 0.4], [-0.1, 0.5]])
    af = np.array([[0.3, 0.6], [0.5, -0.2]])
    ke = 0.5 * np.einsum("ij,jk,ik->i", vf, Md, vf)
    r = (af @ Md.T + vf @ C2.T + uf @ K2.T)[:, 1]
    rw = 0.5 * (r[0] + r[1]) * (0.09 - 0.05)
    d = 0.5 * float((C2 @ (vf[0] + vf[1])) @ (uf[1] - uf[0]))
    np.testing.assert_allclose(res.kinetic_energy, ke, rtol=1e-15)
    np.testing.assert_allclose(res.strain_energy, 0.5 * np.einsum("ij,jk,ik->i", uf, K2, uf), rtol=1e-15)
    np.testing.assert_allclose(res.reaction_work, [0.0, rw], rtol=1e-14)
    np.testing.assert_allclose(res.external_work, [0.0, 0.5 * 3.0 * 0.05 + rw], rtol=1e-14)
    np.testing.assert_allclose(res.damping_dissipation, [0.0, d], rtol=1e-14)
    np.testing.assert_allclose(res.u, uf, rtol=0)
    assert res.options == {"x": 1} and res.method == "hand" and res.dt == 0.1
    # the scheme's own damping on all dofs: in the support force and in the dissipation (issue 54)
    Cd = np.array([[0.6, -0.02], [-0.02, 0.19]])
    rec = Recorder(s, sp.csr_matrix([[3.0]]), 1, mass_full=sp.csr_matrix(Md), damping_full=sp.csr_matrix(Cd))
    for t, u, v, a, f, c in states:
        rec.record(t, np.array(u), np.array(v), np.array(a), np.array(f), constrained=c)
    res = rec.finish("hand", 0.1, "success", "", None, {})
    r = (af @ Md.T + vf @ Cd.T + uf @ K2.T)[:, 1]
    np.testing.assert_allclose(res.reaction_work, [0.0, 0.5 * (r[0] + r[1]) * (0.09 - 0.05)], rtol=1e-14)
    np.testing.assert_allclose(res.damping_dissipation,
                               [0.0, 0.5 * float((Cd @ (vf[0] + vf[1])) @ (uf[1] - uf[0]))], rtol=1e-14)


def _one_dof_recorder(damping_force=None, store_every=1):
    s = SecondOrderSystem(M=[[2.0]], internal_force=lambda u: u ** 3, tangent=lambda u: sp.csr_matrix(3 * u ** 2),
                          load=[0.0])
    return Recorder(s, s.M_ff, 3, damping_force=damping_force, store_every=store_every)


def test_recorder_without_strain_energy_accumulates_the_internal_work():
    rec = _one_dof_recorder(damping_force=lambda v: 3.0 * v)
    z = np.zeros(1)
    rec.record(0.0, np.array([0.5]), z, z, z)  # no strain energy: IE_0 = 0
    rec.record(0.1, np.array([1.0]), np.array([1.0]), z, np.array([4.0]), iterations=2, wall=0.25)
    rec.record(0.2, np.array([2.0]), np.array([0.0]), z, np.array([4.0]), f_int=np.array([7.0]), converged=False)
    res = rec.finish("hand", 0.1, "newton_failed", "m", 2, {})
    # f_int recomputed as u^3 when not given: 0.125, 1.0; then the given 7
    np.testing.assert_allclose(res.strain_energy, [0.0, 0.5 * 1.125 * 0.5, 0.5 * 1.125 * 0.5 + 0.5 * 8.0],
                               rtol=1e-15)
    np.testing.assert_allclose(res.external_work, [0.0, 0.5 * 4.0 * 0.5, 1.0 + 4.0], rtol=1e-15)
    np.testing.assert_allclose(res.damping_dissipation, [0.0, 0.5 * 3.0 * 0.5, 0.75 + 0.5 * 3.0], rtol=1e-15)
    np.testing.assert_allclose(res.kinetic_energy, [0.0, 1.0, 0.0], rtol=0)
    assert res.newton_iterations.tolist() == [0, 2, 0] and res.converged.tolist() == [True, True, False]
    assert res.wall_time.tolist() == [0.0, 0.25, 0.0] and res.reaction_work is None
    assert res.status == "newton_failed" and res.failed_step == 2 and not res.success and res.n_steps == 2
    assert res.rejected_step == 2 and res.blow_up_step is None    # blown_up=False: the step was rejected
    blown = _one_dof_recorder()
    blown.record(0.0, np.array([0.5]), z, z, z)
    out = blown.finish("hand", 0.1, "blow_up", "m", 0, {}, blown_up=True)
    assert (out.failed_step, out.rejected_step, out.blow_up_step) == (0, None, 0)
    mech = np.array([0.0, 1.0 + 0.28125 + 0.75, 4.28125 + 2.25])
    supplied = np.array([0.0, 1.0, 5.0])
    np.testing.assert_allclose(res.energy_error, mech - supplied, rtol=1e-15)
    assert res.energy_growth_ratio == pytest.approx(mech.max() / 5.0, rel=1e-15)


def test_growth_ratio_when_nothing_was_supplied():
    z = np.zeros(1)
    rec = _one_dof_recorder()
    rec.record(0.0, z, z, z, z)
    rec.record(0.1, z, z, z, z)
    assert rec.growth_ratio() == 1.0
    rec.record(0.2, z, np.array([1e-3]), z, z)  # energy from nowhere
    assert rec.growth_ratio() == np.inf
    decay = _one_dof_recorder()
    decay.record(0.0, z, np.array([2.0]), z, z)  # KE_0 = 4 J, the largest of the run
    decay.record(0.1, z, np.array([1.0]), z, z)
    assert decay.growth_ratio() == 1.0


def test_store_keeps_forced_steps_once():
    z = np.zeros(1)
    rec = _one_dof_recorder(store_every=5)
    for k in range(3):
        rec.record(0.1 * k, np.array([float(k)]), z, z, z, force_store=(k == 1))
    rec.store(2, np.array([2.0]), z, z)
    rec.store(2, np.array([9.0]), z, z)
    res = rec.finish("hand", 0.1, "success", "", None, {})
    assert res.stored_steps.tolist() == [0, 1, 2] and res.u[:, 0].tolist() == [0.0, 1.0, 2.0]


def _result(ke, ie, w, err):
    n = len(ke)
    z = np.zeros(n)
    return DynamicsResult(method="m", dt=0.1, t=0.1 * np.arange(n), stored_steps=np.array([0, n - 1]),
                          dofs=np.array([0]), u=np.zeros((2, 1)), v=np.zeros((2, 1)), a=np.zeros((2, 1)),
                          newton_iterations=np.zeros(n, int), converged=np.ones(n, bool),
                          kinetic_energy=np.array(ke), strain_energy=np.array(ie), external_work=np.array(w),
                          damping_dissipation=z, energy_error=np.array(err), wall_time=z)


def test_relative_energy_error_scale():
    r = _result([1.0, 2.0], [0.5, -4.0], [0.0, 1.0], [0.2, -0.4])  # total energy [1.5, -2]: scale 2
    np.testing.assert_array_equal(r.relative_energy_error, [0.1, -0.2])
    np.testing.assert_array_equal(r.total_energy, [1.5, -2.0])
    r = _result([1.0, 2.0], [0.0, 0.0], [0.0, -8.0], [0.2, -0.4])  # external work dominates: scale 8
    np.testing.assert_array_equal(r.relative_energy_error, [0.025, -0.05])
    r = _result([0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [0.0, 1e-310])  # floor 1e-300
    np.testing.assert_allclose(r.relative_energy_error, [0.0, 1e-10], rtol=1e-12)
    assert r.success and r.n_steps == 1 and r.t_stored.tolist() == [0.0, 0.1]
    assert r.energy_growth_ratio == 1.0 and r.reaction_work is None and r.observations == []
    r.status = "blow_up"
    assert not r.success


# ---------------------------------------------------------------- integrator start / state / step
@pytest.mark.parametrize("dt, shown", [(0.0, "0.0"), (-1, "-1.0"), (np.nan, "nan"), (np.inf, "inf")])
def test_check_dt_refuses(dt, shown):
    with pytest.raises(ValueError, match=_msg(f"dt must be a finite time step > 0, got {shown}")):
        check_dt(dt)


def test_check_dt_accepts_the_tiniest_step():
    assert check_dt(1e-300) == 1e-300 and type(check_dt("0.5")) is float


def _clamped():  # dof 0 free, dofs 1 and 2 held at zero
    return SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=[0])


@pytest.mark.parametrize("name, x, shown", [("u0", [0.0, -0.25, 0.1], "2.500e-01"),
                                            ("v0", [0.0, 0.0, -1e-300], "1.000e-300")])
def test_nonzero_initial_values_on_held_dofs_are_refused(name, x, shown):
    kw = {name: np.array(x)}
    with pytest.raises(ValueError, match=_msg(f"{name} must be zero on the constrained dofs (the system prescribes "
                                              f"no motion), max |{name}| there = {shown}")):
        Newmark().start(_clamped(), dt=0.1, **kw)


def test_held_dofs_at_zero_are_accepted():
    integ = Newmark().start(_clamped(), [7.0, 0.0, 0.0], [-1.0, 0.0, 0.0], 0.1)
    assert integ.u.tolist() == [7.0] and integ.v.tolist() == [-1.0] and integ.uc.tolist() == [0.0, 0.0]
    np.testing.assert_allclose(integ.a, [-K3[0, 0] * 7.0 / M3[0, 0]], rtol=1e-15)


def _moving(G, damped=False):
    return _sys3(damped=damped, prescribed=lambda t: np.array([G + 3.0 * (t - 0.5)]))


@pytest.mark.parametrize("G, gap, ok", [
    (1.0, 0.9e-12, True), (1.0, 2e-12, False),
    (1000.0, 0.9e-9, True), (1000.0, 1.1e-9, False),
    (-1000.0, 0.9e-9, True), (-1000.0, 1.1e-9, False),
    (1e-3, 0.9e-12, True), (1e-3, 1.1e-12, False),
])
def test_initial_displacement_must_match_the_motion(G, gap, ok):
    u0 = np.array([0.0, G + gap, 0.0])
    if ok:
        integ = Newmark().start(_moving(G), u0, None, 0.1, t0=0.5)
        assert integ.uc.tolist() == [G + gap] and integ.t == 0.5
        return
    shown = f"{abs((G + gap) - G):.3e}"
    with pytest.raises(ValueError, match=_msg("u0 on the constrained dofs differs from the prescribed displacement "
                                              f"at t0 by {shown}")):
        Newmark().start(_moving(G), u0, None, 0.1, t0=0.5)


def test_start_fills_the_motion_and_takes_the_fixed_velocity():
    s = _moving(0.4, damped=True)
    integ = Newmark()
    assert integ.start(s, None, [0.1, 0.7, -0.2], 0.1, t0=0.5) is integ
    assert integ.uc.tolist() == [0.4] and integ.vc.tolist() == [0.7] and integ.ac.tolist() == [0.0]
    assert integ.u.tolist() == [0.0, 0.0] and integ.v.tolist() == [0.1, -0.2] and integ.dt == 0.1
    np.testing.assert_array_equal(integ.full_u(), [0.0, 0.4, 0.0])
    np.testing.assert_array_equal(integ.full([1.0, 2.0], [3.0]), [1.0, 3.0, 2.0])
    u = np.array([0.0, 0.4, 0.0])
    rhs = -(K3 @ u)[F] - _ix(C3, F, F) @ [0.1, -0.2] - _ix(C3, F, C) @ [0.7]
    np.testing.assert_allclose(integ.a, np.linalg.solve(_ix(M3, F, F), rhs), rtol=1e-13)
    assert integ.mass_full is s.M and integ.mass_ff is s.M_ff
    np.testing.assert_allclose(integ.damping_force(np.array([1.0, 2.0])), _ix(C3, F, F) @ [1.0, 2.0], rtol=1e-15)


@pytest.mark.parametrize("t0, shown", [(np.nan, "nan"), (np.inf, "inf"), (-np.inf, "-inf")])
def test_start_refuses_a_non_finite_t0(t0, shown):
    with pytest.raises(ValueError, match=_msg(f"t0 must be finite, got {shown}")):
        Newmark().start(_clamped(), None, None, 0.1, t0=t0)


def test_start_needs_a_system_and_step_needs_start():
    with pytest.raises(TypeError, match=_msg("system must be a SecondOrderSystem, got dict")):
        Newmark().start({}, None, None, 0.1)
    with pytest.raises(RuntimeError, match=_msg("call start(system, u0, v0, dt) before step()")):
        Newmark().step()
    with pytest.raises(ValueError, match=_msg("dt must be a finite time step > 0, got 0.0")):
        Newmark().start(_clamped(), None, None, 0.0)


def _time_load(t):
    return np.array([1.0 + t, 2.0, 3.0 - t])


def test_set_state_solves_the_equation_of_motion_by_hand():
    s = SecondOrderSystem.linear_system(M3, K3, _time_load, free=F, alpha_m=AM, beta_k=BK,
                                        prescribed=lambda t: np.array([2.0 * t]))
    integ = Newmark().start(s, None, None, 0.1)
    u_f, v_f = np.array([0.1, -0.2]), np.array([0.3, 0.4])
    integ.set_state(0.2, u_f, v_f, None, [0.5], [0.6], [0.7])
    u = np.array([0.1, 0.5, -0.2])
    rhs = _time_load(0.2)[F] - (K3 @ u)[F] - _ix(C3, F, F) @ v_f - _ix(M3, F, C) @ [0.7] - _ix(C3, F, C) @ [0.6]
    np.testing.assert_allclose(integ.a, np.linalg.solve(_ix(M3, F, F), rhs), rtol=1e-13)
    np.testing.assert_allclose(integ.f_ext, _time_load(0.2)[F], rtol=1e-15)
    np.testing.assert_allclose(integ.f_int, (K3 @ u)[F], rtol=1e-15)
    assert integ.t == 0.2 and integ.uc.tolist() == [0.5] and integ.vc.tolist() == [0.6]
    assert integ.ac.tolist() == [0.7]
    # defaults: uc = prescribed(t), vc = ac = 0; a given is kept
    integ.set_state(0.25, u_f, v_f, [9.0, 8.0])
    assert integ.uc.tolist() == [0.5] and integ.vc.tolist() == [0.0] and integ.ac.tolist() == [0.0]
    assert integ.a.tolist() == [9.0, 8.0]
    with pytest.raises(ValueError, match=_msg("a must have shape (2,), got (3,)")):
        integ.set_state(0.25, u_f, v_f, [1.0, 2.0, 3.0])


def test_the_mass_factorisation_follows_the_system():
    integ = Newmark()
    f = np.array([6.0, 0.0, 12.0])
    integ.start(SecondOrderSystem.linear_system(M3, K3, f, free=F), None, None, 0.1)
    np.testing.assert_allclose(integ.a, np.linalg.solve(_ix(M3, F, F), f[F]), rtol=1e-14)
    M_other = np.diag([2.0, 1.0, 3.0])
    integ.start(SecondOrderSystem.linear_system(M_other, K3, f, free=F), None, None, 0.1)
    np.testing.assert_allclose(integ.a, [3.0, 4.0], rtol=1e-14)


class _Scripted(Integrator):
    """Returns what it is told from _advance."""

    def __init__(self):
        super().__init__()
        self.out = None

    def _advance(self):
        return self.out


def _scripted():
    s = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=F, prescribed=lambda t: np.array([0.0]))
    return _Scripted().start(s, None, None, 0.1)


@pytest.mark.parametrize("bad", [0, 1, 2])
def test_step_refuses_a_non_finite_state_and_keeps_the_old_one(bad):
    integ = _scripted()
    new = [np.zeros(2), np.zeros(2), np.zeros(2)]
    new[bad] = np.array([0.0, np.nan if bad != 1 else np.inf])
    integ.out = (StepReport(iterations=4), (0.1234567, *new, np.ones(2), np.ones(2)))
    rep = integ.step()
    assert not rep.converged and rep.message == "non-finite state at t=0.123457" and rep.iterations == 4
    assert integ.t == 0.0 and integ.f_ext.tolist() == [0.0, 0.0]


def test_step_passes_a_failure_through_and_takes_a_good_state():
    integ = _scripted()
    failed = StepReport(False, 3, "boom")
    integ.out = failed
    assert integ.step() is failed and integ.t == 0.0
    one, two = np.array([1.0, 2.0]), np.array([3.0, 4.0])
    integ.out = (StepReport(iterations=1), (0.1, one, two, one, two, one))
    rep = integ.step()
    assert rep.converged and integ.t == 0.1 and integ.u is one and integ.v is two and integ.f_int is one
    assert integ.uc.tolist() == [0.0]  # a six-tuple leaves the fixed dofs alone
    integ.out = (StepReport(), (0.2, one, two, one, two, one, np.array([5.0]), np.array([6.0]), np.array([7.0])))
    integ.step()
    assert integ.uc.tolist() == [5.0] and integ.vc.tolist() == [6.0] and integ.ac.tolist() == [7.0]


@pytest.mark.parametrize("name, index", [("u", 1), ("v", 2), ("uc", 4), ("vc", 5), ("ac", 6)])
def test_set_state_names_the_vector_of_a_wrong_shape(name, index):
    from tissuebench.refsolvers.dynamics.implicit import Newmark
    s = SecondOrderSystem.linear_system(np.diag([2.0, 1.0]), np.array([[60.0, -20.0], [-20.0, 30.0]]),
                                        np.array([1.0, 0.0]), free=[0], prescribed=lambda t: np.array([0.1 * t]))
    integ = Newmark().start(s, None, None, 0.1)
    args = [0.0, np.zeros(1), np.zeros(1), None, np.zeros(1), np.zeros(1), np.zeros(1)]
    args[index] = np.zeros(3)
    with pytest.raises(ValueError) as err:
        integ.set_state(*args)
    assert str(err.value) == f"{name} must have shape (1,), got (3,)"


# ---------------------------------------------------------------- round-off floor, tiny loads (issue 54)
EPS = np.finfo(float).eps


def test_round_off_floor_by_hand():
    # K0 = K3 at u = 0; its free rows (0, 2) times X = (1, -2, 0.5): 10 + 6 + 0.5 = 16.5 and 1 + 10 + 3.5 = 14.5
    X = np.array([1.0, -2.0, 0.5])
    assert _nonlinear(unit_strain=X).round_off_floor == pytest.approx(EPS * np.sqrt(16.5 ** 2 + 14.5 ** 2), rel=1e-15)
    assert _nonlinear().round_off_floor == 0.0                       # no unit strain: no floor
    linear = SecondOrderSystem.linear_system(M3, K3, np.zeros(3), free=F, unit_strain=X)
    assert linear.round_off_floor == 0.0                             # K u: its round-off shrinks with u
    with pytest.raises(ValueError, match=_msg("unit_strain must have shape (3,), got (2,)")):
        _nonlinear(unit_strain=[1.0, 2.0])


def _cubic(load, unit_strain=None):
    """M = 1, f_int = 4 u + u^3: a 1-dof nonlinear spring (Newton iterates, no single linear solve)."""
    return SecondOrderSystem(M=[[1.0]], internal_force=lambda u: 4.0 * u + u ** 3,
                             tangent=lambda u: sp.csr_matrix([[4.0 + 3.0 * u[0] ** 2]]), load=load,
                             unit_strain=unit_strain)


def test_a_load_below_the_round_off_floor_fails_the_step_saying_so():
    # X = 0.5: floor = eps |4 x 0.5| = 2 eps. Newmark from rest under a constant f: r_ref = max(|f|, |M a0| = f) = f
    floor = 2.0 * EPS
    assert _cubic([1.0], [0.5]).round_off_floor == floor
    below = integrate(_cubic([0.5 * floor], [0.5]), None, None, 0.5, 1.0, method="newmark")
    assert below.status == "newton_failed" and below.rejected_step == 1 and below.n_steps == 0
    assert below.message == (f"step 1: t=0.5: the step's forces are below round-off: the largest, {0.5 * floor:.3e} "
                             f"N, is under the round-off floor {floor:.3e} N of the internal force (machine epsilon x "
                             "the force of a unit strain of the body), so the strains they cause are below double "
                             "precision: a load far too small for the body's stiffness (is its length or load unit "
                             "right?)")
    above = integrate(_cubic([4.0 * floor], [0.5]), None, None, 0.5, 1.0, method="newmark")
    assert above.success and above.n_steps == 2 and np.all(above.newton_iterations[1:] >= 1)
    # without a unit strain (no floor) the tiny load is solved as any other
    assert integrate(_cubic([0.5 * floor]), None, None, 0.5, 1.0, method="newmark").success


@pytest.mark.parametrize("method", ["newmark", "hht", "bathe"])
def test_a_1e_200_n_load_is_solved_exactly_as_a_1_n_one_scaled(method):
    """A linear spring (M = 1, K = 4) under 2^-664 N = 1e-200 N: every number of the run is the 1 N run's times
    2^-664, exactly (binary scaling). a24e7fa: ||r|| underflowed to 0 and each step "converged" at its predictor."""
    tiny = 2.0 ** -664
    one = integrate(SecondOrderSystem.linear_system([[1.0]], [[4.0]], [1.0]), None, None, 0.5, 2.0, method=method)
    small = integrate(SecondOrderSystem.linear_system([[1.0]], [[4.0]], [tiny]), None, None, 0.5, 2.0, method=method)
    assert one.success and small.success and small.n_steps == 4
    np.testing.assert_array_equal(small.u, one.u * tiny)
    np.testing.assert_array_equal(small.a, one.a * tiny)
    assert np.all(small.newton_iterations[1:] >= 1) and small.u[-1, 0] != 0.0


@pytest.mark.parametrize("method", ["newmark", "bathe"])
def test_a_motion_that_decays_below_the_floor_goes_on(method):
    """A damped nonlinear spring from u0 = 1e-10 (forces 4e-10 N, 900 x the floor eps |4 x 500| = 4.4e-13 N) decays
    below the floor within the run: those steps converge at the floor and the run succeeds; a run that starts
    there (its load below round-off, as in test_a_load_below_the_round_off_floor_fails_the_step_saying_so) is
    refused at its first step."""
    spring = SecondOrderSystem(M=[[1.0]], internal_force=lambda u: 4.0 * u + u ** 3,
                               tangent=lambda u: sp.csr_matrix([[4.0 + 3.0 * u[0] ** 2]]), load=[0.0],
                               alpha_m=3.0, unit_strain=[500.0])
    floor = spring.round_off_floor
    assert floor == 2000.0 * EPS
    res = integrate(spring, [1e-10], None, 0.25, 10.0, method=method)
    assert res.success, res.message
    forces = np.maximum(np.abs(4.0 * res.u[:, 0] + res.u[:, 0] ** 3), np.abs(res.a[:, 0]))   # |f_int|, |M a|
    assert forces[0] > 100 * floor and np.sum(forces[1:-1] <= floor) >= 5
    late = integrate(spring, [res.u[-1, 0]], [res.v[-1, 0]], 0.25, 0.5, method=method)
    assert late.status == "newton_failed" and late.rejected_step == 1 and "below round-off" in late.message
