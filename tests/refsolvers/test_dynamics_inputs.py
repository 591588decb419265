"""Bad input raises ValueError naming the field and value; registry, storage options,
and the backend adapter (with a duck-typed fake backend, no FE library needed)."""
import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import (INTEGRATORS, HHT, DynamicsResult, SecondOrderSystem,
                                             integrate, make_integrator)

M2 = np.diag([2.0, 1.0])
K2 = np.array([[3.0, -1.0], [-1.0, 1.0]])


def sys2(load=None):
    return SecondOrderSystem.linear(M2, K2, np.zeros(2) if load is None else load)


@pytest.mark.parametrize("dt", [0.0, -0.1, np.nan])
def test_bad_dt(dt):
    with pytest.raises(ValueError, match=r"dt must be .*got (0\.0|-0\.1|nan)"):
        integrate(sys2(), None, None, dt, 1.0)


def test_bad_total_time():
    with pytest.raises(ValueError, match="total time.*t_end=0.0"):
        integrate(sys2(), None, None, 0.1, 0.0)


@pytest.mark.parametrize("alpha", [-0.5, 0.1])
def test_bad_alpha(alpha):
    with pytest.raises(ValueError, match=rf"alpha must lie in \[-1/3, 0\], got {alpha}"):
        make_integrator("hht", alpha=alpha)
    with pytest.raises(ValueError, match="alpha"):
        integrate(sys2(), None, None, 0.1, 1.0, method="hht", alpha=alpha)


@pytest.mark.parametrize("M, pattern", [
    (np.diag([1.0, 0.0]), r"M is not positive definite: diagonal entry M\[1,1\] = 0.0"),
    (np.array([[1.0, 1.0], [1.0, 1.0]]), "M is not positive definite: smallest eigenvalue"),
    (np.array([[1.0, 0.5], [0.0, 1.0]]), "M is not symmetric"),
    (np.ones((2, 3)), r"M must be square, got shape \(2, 3\)"),
])
def test_bad_mass(M, pattern):
    with pytest.raises(ValueError, match=pattern):
        SecondOrderSystem.linear(M, np.eye(M.shape[0]), np.zeros(M.shape[0]))


def test_size_mismatch():
    with pytest.raises(ValueError, match=r"K must have shape \(2, 2\)"):
        SecondOrderSystem.linear(M2, np.eye(3), np.zeros(2))


def test_bad_load_shape_and_values():
    with pytest.raises(ValueError, match=r"load\(t\) at t=0.0 must have shape \(2,\), got \(3,\)"):
        integrate(sys2(lambda t: np.zeros(3)), None, None, 0.1, 1.0)
    with pytest.raises(ValueError, match=r"load\(t\) at t=0.0 contains a non-finite value nan"):
        integrate(sys2(lambda t: np.array([np.nan, 0.0])), None, None, 0.1, 1.0)
    # a load that turns bad during the run is caught at that step, naming the time
    late = sys2(lambda t: np.array([0.0, np.inf if t > 0.45 else 1.0]))
    for method in INTEGRATORS:
        with pytest.raises(ValueError, match=r"load\(t\) at t=0.5.* non-finite value inf"):
            integrate(late, None, None, 0.1, 1.0, method=method)


def test_bad_initial_state():
    with pytest.raises(ValueError, match=r"u0 must have shape \(2,\), got \(3,\)"):
        integrate(sys2(), np.zeros(3), None, 0.1, 1.0)
    with pytest.raises(ValueError, match="v0 contains a non-finite value nan at index 1"):
        integrate(sys2(), None, [0.0, np.nan], 0.1, 1.0)
    constrained = SecondOrderSystem.linear(M2, K2, np.zeros(2), free=[1])
    with pytest.raises(ValueError, match="u0 must be zero on the constrained dofs"):
        integrate(constrained, [1.0, 0.0], None, 0.1, 1.0)


def test_bad_damping_and_options():
    with pytest.raises(ValueError, match="alpha_m must be finite and >= 0, got -1.0"):
        SecondOrderSystem.linear(M2, K2, np.zeros(2), alpha_m=-1.0)
    with pytest.raises(ValueError, match="newton max_iter"):
        make_integrator("bathe", newton_max_iter=0)
    with pytest.raises(ValueError, match="store_every"):
        integrate(sys2(), None, None, 0.1, 1.0, store_every=0)


def test_registry():
    assert set(INTEGRATORS) == {"hht", "bathe", "newmark", "backward_euler", "central_difference", "forward_euler"}
    with pytest.raises(ValueError, match=r"unknown integrator 'rk4'; valid: \['backward_euler', 'bathe', "):
        make_integrator("rk4")
    assert isinstance(make_integrator(HHT, alpha=-0.2), HHT)
    integ = make_integrator("hht", alpha=-0.2)
    assert make_integrator(integ) is integ and integ.alpha == -0.2


def test_storage_options():
    res = integrate(sys2(np.array([0.0, 1.0])), None, None, 0.01, 1.0, store_every=7, dofs=[1])
    assert isinstance(res, DynamicsResult) and res.success
    assert res.n_steps == 100 and res.t.shape == (101,) and res.kinetic_energy.shape == (101,)
    assert list(res.stored_steps) == list(range(0, 100, 7)) + [100]
    assert res.u.shape == (len(res.stored_steps), 1) and list(res.dofs) == [1]
    full = integrate(sys2(np.array([0.0, 1.0])), None, None, 0.01, 1.0)
    assert res.u[:, 0] == pytest.approx(full.u[res.stored_steps, 1], abs=0)
    assert res.t_stored[-1] == pytest.approx(1.0, abs=1e-12)
    assert np.all(res.wall_time[1:] > 0) and res.newton_iterations[0] == 0


class FakeProblem:
    """Minimal stand-in of tissuebench Problem: 3 dofs, dof 0 fixed."""

    fixed_dofs = np.array([0])
    free_dofs = np.array([1, 2])

    def prescribed_values(self, lam):
        return np.zeros(1)


class FakeBackend:
    """Linear springs 0-1-2 (k = 4 N/m) with a follower-like load f = lam (1 + 0.1 u)."""

    problem = FakeProblem()
    K = sp.csr_matrix(4.0 * np.array([[1.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]]))

    def mass(self, lumped=False):
        return sp.identity(3, format="csr")

    def internal_force(self, u):
        return self.K @ u

    def tangent(self, u):
        return self.K

    def external_force(self, u, lam):
        return lam * (np.array([0.0, 0.0, 1.0]) + 0.1 * u)

    def external_tangent(self, u, lam):
        return sp.identity(3, format="csr") * (0.1 * lam)

    def strain_energy(self, u):
        return 0.5 * u @ (self.K @ u)


def test_from_backend_follower_load():
    sys = SecondOrderSystem.from_backend(FakeBackend(), lambda t: 1.0)
    assert list(sys.free) == [1, 2] and not sys.linear and sys.load_depends_on_u
    res = integrate(sys, None, None, 0.01, 2.0, method="hht", alpha=-0.05)
    assert res.success and res.newton_iterations.max() <= 3
    assert np.all(res.u[:, 0] == 0)
    # reference: at load factor 1 the follower term is a stiffness -0.1 I, so the free
    # dofs obey the linear system a + (K_ff - 0.1 I) u = e_2
    K_eff = FakeBackend.K.toarray()[1:, 1:] - 0.1 * np.eye(2)
    lin = SecondOrderSystem.linear(np.eye(2), K_eff, np.array([0.0, 1.0]))
    ref = integrate(lin, None, None, 0.01, 2.0, method="hht", alpha=-0.05)
    assert res.u[:, 1:] == pytest.approx(ref.u, abs=1e-10)


def test_unknown_options():
    with pytest.raises(ValueError, match=r"Bathe: unknown option\(s\) \['alpha'\]"):
        make_integrator("bathe", alpha=-0.1)
    with pytest.raises(ValueError, match="CentralDifference: got an unexpected keyword argument 'alpha'"):
        integrate(sys2(), None, None, 0.01, 1.0, method="central_difference", alpha=-0.1)
