"""Measurements of the direct-integrator study against closed forms."""
import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.rom.direct.diagnostics import (
    energy_history,
    relative_rmse,
    spectrum_peaks,
)
from tissuebench.rom.direct.meshes import ParameterMesh, parameter_domain


def test_energy_balance_of_the_exact_forced_oscillator_is_zero():
    """u = (f/k)(1 - cos w t) under a constant load: KE + SE - W = 0 (W = f u exactly)."""
    m, k, f = 2.0, 50.0, 3.0
    w = np.sqrt(k / m)
    t = np.linspace(0.0, 3.0, 301)
    u = (f / k) * (1 - np.cos(w * t))
    v = (f / k) * w * np.sin(w * t)
    e = energy_history(u[:, None], v[:, None], sp.identity(1) * m, np.array([f]), np.ones_like(t),
                       lambda x: 0.5 * k * float(x @ x))
    assert np.max(np.abs(e["relative_error"])) < 1e-13
    assert e["work"][-1] == pytest.approx(f * u[-1], rel=1e-13)
    # a 1 % amplitude error shows up in the balance
    e2 = energy_history(1.01 * u[:, None], v[:, None], sp.identity(1) * m, np.array([f]), np.ones_like(t),
                        lambda x: 0.5 * k * float(x @ x))
    assert np.max(np.abs(e2["relative_error"])) > 1e-3


def test_spectrum_peaks_of_two_sines():
    dt = 1e-3
    t = np.arange(0.0, 2.0, dt)
    y = 0.7 + np.sin(2 * np.pi * 10 * t) + 0.3 * np.sin(2 * np.pi * 25 * t)
    f, a = spectrum_peaks(y, dt, n_peaks=2)
    assert f[0] == pytest.approx(10.0, abs=0.5) and f[1] == pytest.approx(25.0, abs=0.5)
    assert a[1] / a[0] == pytest.approx(0.3, rel=0.05)


def test_relative_rmse():
    ref = np.array([[1.0, 0.0], [0.0, 2.0]])
    assert relative_rmse(ref, ref) == 0.0
    assert relative_rmse(1.1 * ref, ref) == pytest.approx(0.1)
    with pytest.raises(ValueError, match="shapes"):
        relative_rmse(ref[:1], ref)


def test_parameter_domain_and_mesh():
    assert parameter_domain([0.0, 2.0, -1.0], 0.25) == (-2.5, 2.5)
    assert parameter_domain([0.0, 2.0, -1.0], 0.25, min_radius=4.0) == (-4.0, 4.0)
    assert parameter_domain([1.0, 1.0], 0.25, symmetric=False) == (0.75, 1.25)
    with pytest.raises(ValueError, match="zero"):
        parameter_domain([0.0, 0.0], 0.25)
    with pytest.raises(ValueError, match="margin"):
        parameter_domain([1.0], -0.1)
    mesh = ParameterMesh(-1.0, 1.0, 5)
    # the P1 mass matrix integrates: 1^T W 1 = length, x^T W x = int x^2 = 2/3
    W = mesh.mass()
    assert np.ones(5) @ W @ np.ones(5) == pytest.approx(2.0)
    assert mesh.nodes @ W @ mesh.nodes == pytest.approx(2.0 / 3.0)
    # interpolation of a linear function is exact, also beyond the ends (extrapolation flagged)
    _, _, inside = mesh.locate(np.array([-1.0, 0.3, 1.0, 1.7]))
    assert list(inside) == [True, True, True, False]
    assert mesh.interpolate(3 * mesh.nodes + 1, np.array([0.3, 1.7])) == pytest.approx([1.9, 6.1])
    with pytest.raises(ValueError, match="n_nodes"):
        ParameterMesh(0.0, 1.0, 1)


def test_full_run_is_the_full_order_inner_integrator():
    """full_run (no reduction) of central difference on the frame = refsolvers' central difference."""
    from tissuebench.refsolvers.dynamics import integrate
    from tissuebench.rom import make_method
    from tissuebench.rom.direct.diagnostics import full_run, simulate
    from tissuebench.studies.trajectories import trajectory_training

    tr = trajectory_training("frame_2dof", t_end=1.0)
    model = make_method("pgd_direct", pod_modes=2, integrator="central_difference").build(tr)
    times = tr.parameter_values("time")
    full = full_run(model, times, tr.history)
    ref = integrate(tr.system, None, None, tr.dt, times[-1], method="central_difference", store_every=1)
    np.testing.assert_allclose(full.u, ref.u, rtol=0, atol=1e-12 * np.abs(ref.u).max())
    red = simulate(model, times, tr.history)  # all modes: the reduced run is the full one
    assert relative_rmse(red.u, full.u) < 1e-10 and red.extrapolations == 0
    assert set(red.outputs) == {"u1", "u2"} and len(red.outputs["u1"]) == len(times) - 1
