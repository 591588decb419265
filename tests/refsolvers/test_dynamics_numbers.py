"""The dynamics' bookkeeping and machinery by hand (issue 41): the energy balance of a run from its
states, the Newton loop's tolerances and counts, the system's free/fixed blocks and couplings,
the front door's step count, blow-up and growth rules, each at its boundary on both sides."""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate

M, K, C_M, C_K = 2.0, 50.0, 0.3, 0.004
DT = 0.05


def _load(t):
    return np.array([3.0 + 4.0 * t])


def _one_dof(**kw):
    return SecondOrderSystem.linear_system(np.array([[M]]), np.array([[K]]), _load, alpha_m=C_M, beta_k=C_K, **kw)


def _trapezoid(f, u):
    """sum of 1/2 (f_k + f_k+1) (u_k+1 - u_k), accumulated per step, from 0."""
    return np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(u))])


@pytest.mark.parametrize("method", ["newmark", "hht", "central_difference", "forward_euler", "bathe"])
def test_the_energy_balance_of_one_dof_from_its_states(method):
    res = integrate(_one_dof(), [0.1], [-0.2], DT, 4 * DT, method=method)
    u, v, t = res.u[:, 0], res.v[:, 0], res.t
    c = C_M * M + C_K * K
    ke, ie = 0.5 * M * v ** 2, 0.5 * K * u ** 2
    work, damping = _trapezoid(3.0 + 4.0 * t, u), _trapezoid(c * v, u)
    np.testing.assert_allclose(res.kinetic_energy, ke, rtol=1e-13)
    np.testing.assert_allclose(res.strain_energy, ie, rtol=1e-13)
    np.testing.assert_allclose(res.external_work, work, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res.damping_dissipation, damping, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(res.energy_error, ke + ie + damping - work - (ke[0] + ie[0]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(res.total_energy, ke + ie, rtol=1e-13)
    mech, supplied = ke + ie + damping, ke[0] + ie[0] + work
    assert res.energy_growth_ratio == pytest.approx(mech.max() / supplied.max(), rel=1e-12)
    scale = max(np.abs(ke + ie).max(), np.abs(work).max())
    np.testing.assert_allclose(res.relative_energy_error, res.energy_error / scale, rtol=1e-13)
    assert res.reaction_work is None and res.n_steps == 4 and res.success
