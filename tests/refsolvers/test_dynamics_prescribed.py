"""Prescribed (non-zero) motion of Dirichlet dofs in the full-order dynamics.

* A linear bar (nu = 0) pulled at constant velocity V from the homogeneous initial
  velocity field V x / L is exactly u = V t x / L (zero acceleration everywhere, the
  quasi-static solution at every instant): every implicit scheme reproduces it to
  round-off, on both backends, and the energy balance closes with the work of the
  reaction.
* A Mooney-Rivlin bar pulled slowly from rest ends near the quasi-static (Newton) state
  of the same end displacement; pulled fast, the trapezoidal rule's energy balance
  (reaction work included) closes to O(dt^2), exactly for a linear material.
"""
import numpy as np
import pytest

from _fe_helpers import BACKEND_PARAMS
from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import Dirichlet, LinearElastic, MooneyRivlin, Problem
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.refsolvers.newton import newton_solve

L, H = 0.08, 0.02           # bar length and side [m]
RHO = 500.0                 # kg/m^3
CUBE_MR = MooneyRivlin(500.0, 600.0, 5133.333333333333)  # the cube_tension_twist material [Pa]


def bar(material, pull, divisions=(6, 2, 2), backend="skfem"):
    """Bar along x, end x = 0 clamped, end x = L moved by ``pull`` (3,) at load factor 1."""
    mesh = box_mesh((L, H, H), divisions, "tetra")
    pb = Problem(mesh, material, "P1", [Dirichlet(lambda x: x[:, 0] < 1e-12),
                                        Dirichlet(lambda x: x[:, 0] > L - 1e-12, value=np.asarray(pull, float))],
                 density=RHO)
    return make_backend(backend, pb)


def ramp(T):
    return lambda t: min(max(t / T, 0.0), 1.0)


@pytest.mark.parametrize("backend", BACKEND_PARAMS)
@pytest.mark.parametrize("method", ["newmark", "hht", "bathe", "backward_euler"])
def test_constant_velocity_pull_is_the_quasi_static_solution(backend, method):
    D, T = 0.01, 1.0                      # end displacement [m] reached at T [s]: V = 1 cm/s
    be = bar(LinearElastic(3000.0, 0.0), [D, 0.0, 0.0], backend=backend)
    system = SecondOrderSystem.from_backend(be, ramp(T), linear=True)
    X = be.problem.nodes
    exact = lambda t: np.column_stack([D * t / T * X[:, 0] / L, 0 * X[:, 1:]]).ravel()  # noqa: E731
    v0 = np.column_stack([D / T * X[:, 0] / L, 0 * X[:, 1:]]).ravel()
    res = integrate(system, None, v0, 0.05, 0.8, method=method)
    assert res.success, res.message
    err = max(np.abs(res.u[i] - exact(res.t[k])).max() for i, k in enumerate(res.stored_steps))
    assert err <= 1e-10 * D
    assert np.abs(res.a).max() <= 1e-7 * D / T ** 2 * 1e3
    # energy: strain energy 1/2 E eps^2 V_bar; kinetic energy constant; the reaction pays the strain energy
    eps = D * res.t / T / L
    assert res.strain_energy == pytest.approx(0.5 * 3000.0 * eps ** 2 * L * H * H, rel=1e-9, abs=1e-15)
    assert res.kinetic_energy == pytest.approx(np.full_like(eps, res.kinetic_energy[0]), rel=1e-9)
    assert res.reaction_work[-1] == pytest.approx(res.strain_energy[-1], rel=1e-9)
    assert np.abs(res.energy_error).max() <= 1e-9 * res.strain_energy[-1]


def test_slow_mooney_rivlin_pull_ends_near_the_quasi_static_state():
    D = 0.1 * L                           # 10 % strain
    be = bar(CUBE_MR, [D, 0.0, 0.0])
    system = SecondOrderSystem.from_backend(be, ramp(2.0))
    res = integrate(system, None, None, 0.02, 2.4, method="backward_euler")
    assert res.success, res.message
    for lam in (0.5, 1.0):  # mid-pull (moving at 4 mm/s) and after the hold
        static = newton_solve(be, lam)
        assert static.success
        i = int(np.argmin(np.abs(res.t_stored - (2.0 * lam if lam < 1 else 2.4))))
        diff = np.linalg.norm(res.u[i] - static.u) / np.linalg.norm(static.u)
        # the pulling speed is 1.5e-3 of the wave speed: inertia is a small perturbation
        assert diff < 5e-3, (lam, diff)
        print(f"slow pull at load factor {lam}: |u_dyn - u_static| / |u_static| = {diff:.2e}")
    # the end moved as prescribed, and the whole history stayed in the quasi-static regime
    fixed = system.fixed
    assert np.allclose(res.u[-1][fixed], system.prescribed_values(2.4), atol=1e-15)
    assert res.kinetic_energy.max() < 1e-3 * res.strain_energy[-1]


def test_energy_balance_counts_the_reaction_work():
    T = 0.1                               # fast pull: the fundamental period is about 0.06 s
    errors = []
    for dt in (2e-3, 1e-3):
        be = bar(CUBE_MR, [0.05 * L, 0.0, 0.0])
        res = integrate(SecondOrderSystem.from_backend(be, ramp(T)), None, None, dt, 2 * T, method="newmark")
        assert res.success, res.message
        assert res.kinetic_energy.max() > 0.05 * res.strain_energy.max()  # really dynamic
        scale = np.abs(res.reaction_work).max()
        assert res.external_work[-1] == pytest.approx(res.reaction_work[-1], rel=1e-12)  # no other load
        errors.append(np.abs(res.energy_error).max() / scale)
    assert errors[1] < 1e-3 and errors[0] / errors[1] > 3.0, errors  # second order in dt
    # the same pull on a linear material closes the balance to round-off
    be = bar(LinearElastic(3000.0, 0.3), [0.1 * L, 0.0, 0.0])
    res = integrate(SecondOrderSystem.from_backend(be, ramp(T), linear=True), None, None, 2e-3, 2 * T,
                    method="newmark")
    assert np.abs(res.energy_error).max() <= 1e-10 * np.abs(res.reaction_work).max()
    # backward Euler dissipates: the balance shows a loss
    res = integrate(SecondOrderSystem.from_backend(be, ramp(T), linear=True), None, None, 2e-3, 2 * T,
                    method="backward_euler")
    assert res.energy_error[-1] < -0.01 * np.abs(res.reaction_work).max()


@pytest.mark.ngsolve
def test_backends_follow_the_same_twisting_trajectory():
    from tissuebench.cases.assembly import rotation_motion

    motion = rotation_motion({"axis": [1.0, 0.0, 0.0], "center": [L, H / 2, H / 2], "angle_deg": 60.0})
    out = []
    for name in ("skfem", "ngsolve"):
        mesh = box_mesh((L, H, H), (6, 2, 2), "tetra")
        pb = Problem(mesh, CUBE_MR, "P1", [Dirichlet(lambda x: x[:, 0] < 1e-12),
                                           Dirichlet(lambda x: x[:, 0] > L - 1e-12, motion=motion)], density=RHO)
        res = integrate(SecondOrderSystem.from_backend(make_backend(name, pb), ramp(0.2)), None, None, 0.01, 0.25,
                        method="hht", alpha=-0.1)
        assert res.success, res.message
        out.append(res)
    assert np.abs(out[0].u - out[1].u).max() <= 1e-9 * np.abs(out[0].u).max()
    assert out[0].reaction_work[-1] == pytest.approx(out[1].reaction_work[-1], rel=1e-8)


def test_prescribed_motion_bad_input():
    be = bar(LinearElastic(3000.0, 0.0), [0.01, 0.0, 0.0])
    system = SecondOrderSystem.from_backend(be, lambda t: 1.0, linear=True)  # end already displaced at t0
    assert system.has_prescribed
    with pytest.raises(ValueError, match="u0 on the constrained dofs differs from the prescribed displacement"):
        integrate(system, np.zeros(be.ndof), None, 0.01, 0.1)
    res = integrate(system, None, None, 0.01, 0.02)  # None: the prescribed values are filled in
    assert np.allclose(res.u[0][system.fixed], system.prescribed_values(0.0))
    with pytest.raises(ValueError, match="forward_euler: a prescribed motion needs lumped=True"):
        integrate(system, None, None, 1e-4, 1e-3, method="forward_euler")
    clamped = bar(LinearElastic(3000.0, 0.0), [0.0, 0.0, 0.0])
    assert not SecondOrderSystem.from_backend(clamped, ramp(1.0)).has_prescribed
