"""Long-run energy drift (studies/energy.py) on trajectories whose energy is known in closed form."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tissuebench.refsolvers.dynamics import SecondOrderSystem
from tissuebench.studies.energy import conservative_window, model_drift, reference_drift

K, M, F = 4.0, 1.0, 2.0  # omega = 2 rad/s; static deflection F / K = 0.5
OMEGA = np.sqrt(K / M)


def _system(damped=False):
    return SecondOrderSystem.linear_system(np.array([[M]]), np.array([[K]]), np.array([F]),
                                           alpha_m=0.1 if damped else 0.0)


def _fields(decay=0.0, dt=1e-3, t_end=20.0):
    """Exact response to a step load from rest, its oscillation scaled by exp(-decay t)."""
    k = np.arange(int(round(t_end / dt)) + 1)
    t = k * dt
    u = F / K * (1.0 - np.exp(-decay * t) * np.cos(OMEGA * t))
    return {int(i): np.array([x]) for i, x in zip(k, u)}, dt, t_end


def test_window_of_a_step_load_and_of_a_release():
    assert conservative_window(lambda t: 1.0, 0.01, 5.0) == pytest.approx(0.01)
    released = lambda t: max(0.0, 1.0 - t)  # noqa: E731  (constant 0 from t = 1 s)
    assert conservative_window(released, 0.01, 5.0) == pytest.approx(1.0)
    assert conservative_window(lambda t: np.sin(t), 0.01, 5.0) is None  # never constant


def test_exact_conservative_trajectory_has_no_drift():
    """The exact undamped response conserves KE + K u^2 / 2 - F u: |drift| < 1e-6 (central
    differences at dt = 1 ms: the velocity error is O((omega dt)^2) and oscillates)."""
    fields, dt, t_end = _fields()
    scale = 0.5 * K * (2 * F / K) ** 2  # the largest KE + W of the motion
    d = model_drift(_system(), dt, dt, t_end, fields, scale)
    assert abs(d.drift) < 1e-6 and d.spread < 1e-5 and d.message == ""


def test_decaying_oscillation_drifts_by_the_energy_it_lost():
    """Amplitude exp(-c t): the oscillation energy K a^2 / 2 falls from 0.5 to 0.5 exp(-2 c T);
    the fitted trend over [0, T] is negative and of that order."""
    c = 0.02
    fields, dt, t_end = _fields(decay=c)
    scale = 0.5 * K * (2 * F / K) ** 2
    d = model_drift(_system(), dt, dt, t_end, fields, scale)
    lost = 0.5 * K * (F / K) ** 2 * (1 - np.exp(-2 * c * t_end)) / scale
    assert -1.6 * lost < d.drift < -0.6 * lost


def test_reference_drift_from_the_energy_table():
    t = np.linspace(0.0, 10.0, 1001)
    table = pd.DataFrame({"time": t, "kinetic_energy": 1.0 + 0 * t, "strain_energy": 1.0 - 0.01 * t,
                          "external_work": 0 * t})
    d = reference_drift(table, 0.0, 10.0)
    assert d.drift == pytest.approx(-0.1 / 2.0, rel=1e-9)  # 0.1 J lost over a 2 J scale


def test_undefined_cases_say_why():
    fields, dt, t_end = _fields()
    assert "damped" in model_drift(_system(damped=True), dt, dt, t_end, fields, 1.0).message
    missing = {k: v for k, v in fields.items() if k < 4}  # the model failed at its 4th step
    assert model_drift(_system(), dt, dt, t_end, missing, 1.0).drift == np.inf
