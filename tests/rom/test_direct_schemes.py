"""The one-step formulas of the direct integrator against the independent refsolvers integrators."""
import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.refsolvers.dynamics import SecondOrderSystem, make_integrator
from tissuebench.rom.pgd_direct.schemes import SCHEMES, StepOperators, VectorAlgebra


def _system(n=6, seed=0, alpha_m=0.0, beta_k=0.0, lumped=False):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    K = A @ A.T + n * np.eye(n)
    B = rng.standard_normal((n, n))
    M = np.diag(rng.uniform(1.0, 2.0, n)) if lumped else B @ B.T / n + np.eye(n)
    f = rng.standard_normal(n)
    C = alpha_m * M + beta_k * K if (alpha_m or beta_k) else None
    ops = StepOperators(sp.csr_matrix(M), sp.csr_matrix(K), f, None if C is None else sp.csr_matrix(C))
    return ops, M, K, f, rng


@pytest.mark.parametrize("scheme, opts", [("forward_euler", {}), ("bathe", {}), ("hht", {"alpha": -0.05}),
                                          ("hht", {"alpha": -0.3})])
@pytest.mark.parametrize("damping", [(0.0, 0.0), (0.3, 0.002)])
def test_one_step_matches_refsolvers(scheme, opts, damping):
    ops, M, K, f, rng = _system(alpha_m=damping[0], beta_k=damping[1])
    lam, dt = 0.7, 0.05
    u0, v0 = rng.standard_normal(6), rng.standard_normal(6)
    sosys = SecondOrderSystem.linear_system(M, K, lam * f, alpha_m=damping[0], beta_k=damping[1])
    integ = make_integrator(scheme, **opts).start(sosys, u0, v0, dt)
    alg = VectorAlgebra(ops)
    state = alg.initial_state(SCHEMES[scheme], u0, v0, dt, lam)
    for _ in range(5):  # HHT: from the second step on, its acceleration comes from u_prev, v_prev
        assert integ.step().converged
        state = alg.step(SCHEMES[scheme], state, dt, lam, **opts)
        for k in ("u", "v"):
            np.testing.assert_allclose(state[k], getattr(integ, k), rtol=1e-9,
                                       atol=1e-9 * np.abs(getattr(integ, k)).max())


@pytest.mark.parametrize("beta_k", [0.0, 0.002])
def test_central_difference_matches_refsolvers_over_steps(beta_k):
    ops, M, K, f, rng = _system(beta_k=beta_k, lumped=True)
    lam, dt = -1.3, 0.02
    u0, v0 = rng.standard_normal(6), rng.standard_normal(6)
    sosys = SecondOrderSystem.linear_system(M, K, lam * f, beta_k=beta_k)
    integ = make_integrator("central_difference").start(sosys, u0, v0, dt)
    alg = VectorAlgebra(ops)
    if beta_k == 0.0:  # the Taylor start is the half-step velocity start of refsolvers (undamped)
        x = alg.initial_state(SCHEMES["central_difference"], u0, v0, dt, lam)
        integ.step()
        np.testing.assert_allclose(alg.step(SCHEMES["central_difference"], x, dt, lam)["u"], integ.u, rtol=1e-10)
    else:
        integ.step()
    prev, cur = u0, integ.u.copy()  # from the first step on, the two-step form is exact
    for _ in range(10):
        integ.step()
        nxt = alg.step(SCHEMES["central_difference"], {"u": cur, "u_prev": prev}, dt, lam)
        np.testing.assert_array_equal(nxt["u_prev"], cur)
        prev, cur = cur, nxt["u"]
        np.testing.assert_allclose(cur, integ.u, rtol=1e-10, atol=1e-12)
