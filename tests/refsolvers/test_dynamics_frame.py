"""2-DOF shear frame of pgd-pod-direct-integration §4.2 against its modal solution.

Assumption (the paper's Fig. 1 is not in the text): u1 is the lower slab, u2 the top
slab, with masses m1 = 2000 kg and m2 = 2 m1 = 4000 kg as the paper writes
("m2 = 2 m1 = 4000 kg"); each storey has stiffness k = 12 EI / L^3 = 1e5 N/m, so
K = [[2k, -k], [-k, k]]. The step load h(t) = 1e4 N acts on the top slab (u2) for
t >= 0, from rest. Periods: 1.898 s and 0.588 s.
"""
import numpy as np
import pytest
from scipy.linalg import eigh

from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate

k = 1e5
M = np.diag([2000.0, 4000.0])
K = np.array([[2 * k, -k], [-k, k]])
F = np.array([0.0, 1e4])
FRAME = SecondOrderSystem.linear(M, K, F)
T_END = 6.0  # about 3 fundamental periods
DTS = [0.02 / 2 ** i for i in range(5)]


def exact(t):
    """Modal solution u(t) = u_st - sum_j phi_j q_j cos(w_j t), shape (len(t), 2) [m]."""
    lam, phi = eigh(K, M)  # mass-normalised modes
    w = np.sqrt(lam)
    u_st = np.linalg.solve(K, F)
    q = phi.T @ M @ u_st
    return u_st - (np.cos(np.outer(t, w)) * q) @ phi.T


def errors(method, **opts):
    """Max-norm relative global error over [0, T_END] for each dt, and the results."""
    out, results = [], []
    for dt in DTS:
        res = integrate(FRAME, None, None, dt, T_END, method=method, **opts)
        ref = exact(res.t)
        out.append(np.max(np.abs(res.u - ref)) / np.max(np.abs(ref)))
        results.append(res)
    return np.array(out), results


def fitted_order(errs):
    return np.polyfit(np.log(DTS), np.log(errs), 1)[0]


def test_modal_solution_sanity():
    lam = eigh(K, M, eigvals_only=True)
    assert 2 * np.pi / np.sqrt(lam) == pytest.approx([1.8978034, 0.58837405], rel=1e-6)
    assert exact(np.array([0.0])) == pytest.approx(np.zeros((1, 2)), abs=1e-15)


@pytest.mark.parametrize("method, opts", [("hht", {"alpha": -0.05}), ("hht", {"alpha": 0.0}),
                                          ("bathe", {}), ("newmark", {})])
def test_second_order_convergence(method, opts):
    errs, results = errors(method, **opts)
    p = fitted_order(errs)
    print(method, opts, "errors", errs, "order", p)
    assert p == pytest.approx(2.0, abs=0.2)
    assert errs[-1] < 1e-4
    assert all(r.success for r in results)


def test_forward_euler_grows():
    errs, results = errors("forward_euler")
    growth = [r.energy_growth_ratio for r in results]
    print("forward Euler errors", errs, "energy growth", growth)
    for r in results:
        assert r.status == "energy_growth" and r.energy_growth_ratio > 1.0
        assert r.energy_error[-1] > 0
    # the growth shrinks with dt but never vanishes (amplification sqrt(1 + (w dt)^2) > 1)
    assert np.all(np.diff(growth) < 0)
    assert errs[0] > 1.0  # at dt = 0.02 s the response has grown past the solution itself
