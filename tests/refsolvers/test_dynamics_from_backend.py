"""``SecondOrderSystem.from_backend`` by its numbers (issue 41): what it asks a backend for (the
tangent at zero, the mass lumped or not, the load at the load factor of each time, the load's
tangent at the free dofs' displacement) and what the system it builds computes, on a 3-dof spring
backend written here whose operators are numpy arrays checkable by hand."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import SecondOrderSystem

M3 = np.array([[2.0, 0.5, 0.0], [0.5, 3.0, 0.25], [0.0, 0.25, 1.0]])
K3 = np.array([[50.0, -20.0, 0.0], [-20.0, 45.0, -25.0], [0.0, -25.0, 25.0]])
F3 = np.array([1.0, -2.0, 3.0])
KF = 4.0  # a follower load's stiffness: load = lam (F3 - KF u)


class SpringBackend:
    def __init__(self, follower=False, moving=False):
        self.follower, self.calls = follower, []
        self.problem = SimpleNamespace(ndof=3, free_dofs=np.array([0, 2]), fixed_dofs=np.array([1]), dirichlet=[],
                                       prescribed_values=lambda lam: np.array([0.01 * lam if moving else 0.0]))

    def mass(self, lumped=False):
        self.calls.append(("mass", lumped))
        return sp.diags(M3.sum(axis=1)) if lumped is True else sp.csr_matrix(M3)

    def tangent(self, u):
        self.calls.append(("tangent", np.array(u)))
        return sp.csr_matrix(K3 * (1.0 + float(u @ u)))  # stiffens away from 0: K at 0 is K3

    def internal_force(self, u):
        return (1.0 + float(u @ u) / 3.0) * (K3 @ u)

    def strain_energy(self, u):
        return 0.5 * float(u @ K3 @ u)

    def external_force(self, u, lam):
        self.calls.append(("force", np.array(u), lam))
        return lam * (F3 - KF * u) if self.follower else lam * F3

    def external_tangent(self, u, lam):
        self.calls.append(("load_tangent", np.array(u), lam))
        return sp.csr_matrix(-lam * KF * np.eye(3)) if self.follower else None


def history(t):
    return 0.5 + t


def test_a_linear_system_from_a_backend_with_dead_loads():
    be = SpringBackend()
    s = SecondOrderSystem.from_backend(be, history, alpha_m=0.3, beta_k=0.002, linear=True)
    assert s.linear is True and s.free.tolist() == [0, 2] and (s.alpha_m, s.beta_k) == (0.3, 0.002)
    assert ("load_tangent", [0.0] * 3, 0.5) in [(c[0], c[1].tolist(), c[2]) for c in be.calls if len(c) == 3]
    assert [c for c in be.calls if c[0] == "mass"] == [("mass", False)]
    tangents = [c[1].tolist() for c in be.calls if c[0] == "tangent"]
    assert tangents[0] == [0.0, 0.0, 0.0]
    u = np.array([0.1, -0.2])
    full = np.array([0.1, 0.0, -0.2])
    np.testing.assert_allclose(s.f_int(u), (K3 @ full)[[0, 2]], rtol=1e-14)  # K at 0, not the stiffened force
    np.testing.assert_allclose(s.M_ff.toarray(), M3[np.ix_([0, 2], [0, 2])])
    np.testing.assert_allclose(s.C_ff.toarray(), 0.3 * M3[np.ix_([0, 2], [0, 2])] + 0.002 * K3[np.ix_([0, 2], [0, 2])])
    np.testing.assert_allclose(s.f_ext(0.25, u), 0.75 * F3[[0, 2]], rtol=1e-14)
    assert be.calls[-1][0] == "force" and be.calls[-1][2] == 0.75 and be.calls[-1][1].tolist() == full.tolist()
    assert s.energy(u) == pytest.approx(0.5 * full @ K3 @ full, rel=1e-14)
    assert s.prescribed is None and not s.has_prescribed
    lumped = SecondOrderSystem.from_backend(SpringBackend(), history, lumped=True, linear=True)
    np.testing.assert_allclose(lumped.M_ff.toarray(), np.diag(M3.sum(axis=1)[[0, 2]]))


def test_linear_needs_dead_loads():
    with pytest.raises(ValueError) as err:
        SecondOrderSystem.from_backend(SpringBackend(follower=True), history, linear=True)
    assert str(err.value) == ("from_backend: linear=True needs dead loads (external_tangent is not None, "
                              "the effective matrix would not be constant)")


def test_a_nonlinear_system_with_a_follower_load_and_a_moving_support():
    be = SpringBackend(follower=True, moving=True)
    s = SecondOrderSystem.from_backend(be, history, alpha_m=0.1, beta_k=0.003)
    assert s.linear is False and (s.alpha_m, s.beta_k) == (0.1, 0.003) and s.has_prescribed
    u, uc = np.array([0.1, -0.2]), np.array([0.01 * 0.75])
    full = np.array([0.1, uc[0], -0.2])
    np.testing.assert_allclose(s.prescribed_values(0.25), uc, rtol=1e-15)
    np.testing.assert_allclose(s.f_int(u, uc), ((1 + full @ full / 3) * (K3 @ full))[[0, 2]], rtol=1e-14)
    np.testing.assert_allclose(s.f_ext(0.25, u, uc), (0.75 * (F3 - KF * full))[[0, 2]], rtol=1e-14)
    Kt = s.K_t(u, 0.25, uc).toarray()
    np.testing.assert_allclose(Kt, (K3 * (1 + full @ full) + 0.75 * KF * np.eye(3))[np.ix_([0, 2], [0, 2])],
                               rtol=1e-14)
    assert be.calls[-1][0] == "load_tangent" and be.calls[-1][1].tolist() == full.tolist()
    assert be.calls[-1][2] == 0.75
    assert s.energy(u, uc) == pytest.approx(0.5 * full @ K3 @ full, rel=1e-14)
    np.testing.assert_allclose(s.C_ff.toarray(), 0.1 * M3[np.ix_([0, 2], [0, 2])] + 0.003 * K3[np.ix_([0, 2], [0, 2])])


def test_the_round_off_floor_of_an_fe_system_is_the_static_newtons():
    """Issue 54: the step Newton's round-off floor is statics' (eps x the free rows of the tangent at rest times a
    unit dilation of the nodes about their centre); a linear system and a backend without nodes have none."""
    from tissuebench.cases.meshes import box_mesh
    from tissuebench.refsolvers import Dirichlet, PointLoad, Problem, make_backend, make_material
    from tissuebench.refsolvers.newton import _Equilibrium

    mesh = box_mesh((1.0, 0.1, 0.1), (4, 1, 1), "tetra")
    problem = Problem(mesh, make_material("neo_hookean", E=1e4, nu=0.45), "P1",
                      dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9)],
                      loads=[PointLoad(lambda x: x[:, 0] > 1 - 1e-9, np.array([0.0, -0.01, 0.0]))])
    be = make_backend("skfem", problem)
    s = SecondOrderSystem.from_backend(be, lambda t: 1.0)
    nodes = np.asarray(problem.nodes)
    np.testing.assert_array_equal(s.unit_strain, (nodes - nodes.mean(axis=0)).ravel())
    K_f = be.tangent(np.zeros(be.ndof))[problem.free_dofs]
    assert s.round_off_floor == pytest.approx(_Equilibrium(be, 1.0).round_off_floor(K_f), rel=1e-12)
    assert 0.0 < s.round_off_floor < 1e-9
    assert SecondOrderSystem.from_backend(be, lambda t: 1.0, linear=True).round_off_floor == 0.0
    spring = SecondOrderSystem.from_backend(SpringBackend(), history)
    assert spring.unit_strain is None and spring.round_off_floor == 0.0
