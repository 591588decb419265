"""Verification of ``pod_galerkin`` (POD-Galerkin dynamics with ECSW / DEIM hyper-reduction).

A neo-Hookean bar (4 x 1 x 1, 48 free dofs) clamped at x = 0 is bent by a tip load ramped on
over 0.2 s, held, and released from 0.3 s to 0.4 s (then free vibration), HHT at dt = 0.01 s; a second
bar is bent by a prescribed displacement of its far end instead (a motion through the
Dirichlet data). What must hold:

* with every mode (the basis spans the free space) and full assembly the reduced trajectory is
  the full one to round-off (the integrator's own update formulas run on the reduced system);
* the error decreases with the number of modes;
* ECSW approaches full assembly as its tolerance goes to 0; its weights are non-negative and its
  force is the gradient of its energy, its tangent symmetric;
* the energy balance of the reduced HHT and trapezoidal runs, and the drift of the free
  vibration's energy, are the full runs'.
"""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import Dirichlet, PointLoad, Problem, make_backend
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.refsolvers.materials import NeoHookean
from tissuebench.rom import Training, make_method

DT, T_END, RELEASED = 0.01, 0.7, 0.4


def _history(t):
    """Ramp on over 0.2 s, hold, release over 0.1 s from 0.3 s: free vibration from RELEASED."""
    return float(np.clip(t / 0.2, 0.0, 1.0) - np.clip((t - 0.3) / 0.1, 0.0, 1.0))


def _bar(prescribed: bool):
    mesh = box_mesh((4.0, 1.0, 1.0), (4, 1, 1), "tetra")
    clamp = Dirichlet(lambda x: x[:, 0] < 1e-9)
    if prescribed:  # the far end pushed down 0.8 (a large bend) through its Dirichlet data
        bcs, loads = [clamp, Dirichlet(lambda x: x[:, 0] > 4 - 1e-9, (2,), -0.8)], []
    else:
        bcs, loads = [clamp], [PointLoad(lambda x: np.isclose(x[:, 0], 4.0), np.array([0.0, 0.0, -15.0]))]
    return make_backend("skfem", Problem(mesh, NeoHookean(1e3, 0.3), "P1", dirichlet=bcs, loads=loads, density=1.0))


def _training(prescribed: bool, method="hht", **opts):
    be = _bar(prescribed)
    system = SecondOrderSystem.from_backend(be, _history)
    res = integrate(system, None, None, DT, T_END, method=method, newton_rtol=1e-12, **opts)
    assert res.success, res.message
    return Training(res.u.T.copy(), [{"time": float(t), "load_factor": _history(t)} for t in res.t], be,
                    velocities=res.v.T.copy(), trajectories=np.zeros(len(res.t), int), system=system,
                    history=_history, dt=DT, info={"integrator": method, "options": opts}), res


@pytest.fixture(scope="module")
def point_load():
    return _training(False, alpha=-0.05)


def _run(training, **options):
    model = make_method("pod_galerkin", **options).build(training)
    mus = [{"time": float(k * DT), "load_factor": _history(k * DT)} for k in range(1, round(T_END / DT) + 1)]
    results = model.solve(mus, dt=DT)
    assert all(r.ok for r in results), [r.message for r in results if not r.ok][:1]
    return model, np.array([model.reconstruct(r) for r in results])


def _error(U, res):
    return float(np.linalg.norm(U - res.u[1:]) / np.linalg.norm(res.u[1:]))


@pytest.mark.parametrize("prescribed", [False, True])
def test_every_mode_and_full_assembly_reproduce_the_full_hht_trajectory(prescribed, point_load):
    training, res = point_load if not prescribed else _training(True, alpha=-0.05)
    n_free = len(training.system.free)
    model, U = _run(training, n_modes=n_free, hyper="none", rtol=1e-12)
    assert model.n_reduced == n_free
    assert np.abs(U).max() > 0.5  # a large deformation of a 1 x 1 section
    assert _error(U, res) <= 1e-10


def test_the_error_decreases_with_the_modes(point_load):
    training, res = point_load
    errors = [_error(_run(training, n_modes=n, hyper="none")[1], res) for n in (2, 4, 8)]
    assert errors[0] > errors[1] > errors[2] and errors[2] < 0.01, errors


def test_ecsw_approaches_full_assembly_as_its_tolerance_goes_to_zero(point_load):
    training, _ = point_load
    _, U_none = _run(training, n_modes=8, hyper="none")
    gaps, sizes = [], []
    for tol in (3e-1, 3e-2, 1e-8):
        model, U = _run(training, n_modes=8, hyper="ecsw", ecsw_tol=tol)
        gaps.append(float(np.linalg.norm(U - U_none) / np.linalg.norm(U_none)))
        sizes.append(model.info["hyper"]["elements"])
        assert model.info["hyper"]["train_residual"] <= tol
    assert gaps[0] > gaps[1] > gaps[2] and gaps[2] <= 1e-6, gaps
    assert sizes[0] < sizes[2] <= training.backend.problem.mesh.n_cells, sizes


def test_ecsw_force_is_the_gradient_of_its_energy_and_its_tangent_is_symmetric(point_load):
    training, _ = point_load
    forces = make_method("pod_galerkin", n_modes=6, hyper="ecsw", ecsw_tol=1e-2).build(training).system.forces
    assert np.all(forces.weights > 0) and forces.size < training.backend.problem.mesh.n_cells
    q = np.random.default_rng(0).standard_normal(6) * 0.3
    f, K = forces.force_and_tangent(q)
    h = 1e-6
    grad = np.array([(forces.energy(q + h * e) - forces.energy(q - h * e)) / (2 * h) for e in np.eye(6)])
    np.testing.assert_allclose(grad, f, rtol=1e-6, atol=1e-8 * np.abs(f).max())
    np.testing.assert_allclose(K, K.T, rtol=0, atol=1e-10 * np.abs(K).max())


@pytest.mark.parametrize("method, opts", [("hht", {"alpha": -0.3}), ("newmark", {})])
def test_reduced_energy_behaves_like_the_full_one(method, opts):
    """The energy balance of the integrator (``DynamicsResult.relative_energy_error``: HHT's numerical
    dissipation, the trapezoidal rule's round-trip) and the drift of the free vibration's energy:
    the reduced run's (ECSW: a weighted energy) within 20 % of the full run's."""
    training, res = _training(False, method, **opts)
    model = make_method("pod_galerkin", n_modes=10, hyper="ecsw", ecsw_tol=1e-4).build(training)
    red = integrate(model.system, None, None, DT, T_END, method=method, newton_rtol=1e-12, **opts)
    assert red.success, red.message
    free = red.t >= RELEASED + 1e-9  # the load released: free vibration
    balance, drift = {}, {}
    for name, run in (("full", res), ("reduced", red)):
        balance[name] = float(np.abs(run.relative_energy_error).max())
        E = run.total_energy[free]
        drift[name] = (E[-1] - E[0]) / E[0]
    assert abs(balance["reduced"] - balance["full"]) <= 0.2 * balance["full"], balance
    assert abs(drift["reduced"] - drift["full"]) <= 0.2 * abs(drift["full"]), drift
    if method == "hht":  # dissipative: the energy never exceeds what was supplied, the balance error is HHT's
        assert res.energy_growth_ratio < 1 and red.energy_growth_ratio < 1 and balance["full"] > 5e-4
    else:  # the trapezoidal rule: a balance error several times smaller
        assert balance["full"] < 3e-4


def test_deim_interpolates_the_training_forces_with_the_rank_of_their_snapshots(point_load):
    training, _ = point_load
    model = make_method("pod_galerkin", n_modes=6, hyper="deim", deim_modes=8, hyper_states=8).build(training)
    exact = make_method("pod_galerkin", n_modes=6, hyper="none").build(training).system.forces
    deim = model.system.forces
    assert model.info["hyper"]["force_modes"] == model.info["hyper"]["force_rank"] >= 6
    assert deim.energy(np.zeros(6)) is None
    from tissuebench.rom.galerkin.basis import training_states

    states = training_states(training, training.system.free, training.system.fixed, model.projector, False, 8)
    for q, _ in states:
        np.testing.assert_allclose(deim.force(q), exact.force(q), rtol=0, atol=1e-8 * np.abs(exact.force(q)).max()
                                   + 1e-12)


@pytest.mark.parametrize("options, match", [
    ({"hyper": "gappy"}, "hyper = 'gappy'"), ({"ecsw_tol": 0.0}, "ecsw_tol"), ({"n_modes": 2.5}, "n_modes"),
    ({"integrator": "central_difference"}, "integrator = 'central_difference'"), ({"energy": 1.5}, "energy"),
    ({"inner": "stiffness"}, "inner = 'stiffness'"), ({"deim_modes": 0}, "deim_modes"),
    ({"newton_iterations": 0}, "newton_iterations"), ({"newton_iterations": 2.5}, "newton_iterations")])
def test_bad_options_are_refused_naming_them(options, match):
    with pytest.raises(ValueError, match=match):
        make_method("pod_galerkin", **options)



# ------------------------------------------------------------------ the run's start is not its first step
def _steps(model, mus, mu0, counts=None):
    """q of every step of a run started at ``mu0``; ``counts`` collects the tangents each step formed."""
    forces, tangent = model.system.forces, type(model.system.forces).tangent
    formed = [0]

    def counting(q, uc=None):
        formed[0] += 1
        return tangent(forces, q, uc)

    forces.tangent = counting
    try:
        model.start(mu0, dt=DT)
        qs = []
        for mu in mus:
            formed[0] = 0
            res = model.step(mu)
            assert res.ok, res.message
            qs.append(res.q.copy())
            if counts is not None:
                counts.append(formed[0])
    finally:
        del forces.tangent
    return np.array(qs)


def test_start_forms_the_first_newton_matrix_and_the_steps_give_the_same_numbers(point_load, monkeypatch):
    """Issue 52 (5): the first step formed and factorised the Newton matrix (modified Newton
    keeps it after): 10 of the 20 samples beyond a 2000-step p99. start() binds the integrator and
    primes the matrix at the first step's predictor, bit for bit the matrix the step would form."""
    from tissuebench.refsolvers.dynamics.implicit import NewmarkFamily

    model = make_method("pod_galerkin", n_modes=4).build(point_load[0])
    mus = [{"time": float(k * DT), "load_factor": _history(k * DT)} for k in range(1, 31)]
    primed_counts, lazy_counts = [], []
    primed = _steps(model, mus, {"time": 0.0, "load_factor": 0.0}, primed_counts)
    monkeypatch.setattr(NewmarkFamily, "prime", lambda self: None)  # the step forms its first matrix itself
    lazy = _steps(model, mus, None, lazy_counts)
    assert np.array_equal(primed, lazy)
    assert primed_counts[0] == 0 and lazy_counts[0] >= 1
    assert primed_counts[1:] == lazy_counts[1:]


def test_a_first_step_other_than_foreseen_binds_again_and_gives_the_same_numbers(point_load):
    """The other side: started at t0 = 0.25 s (the history at 1) and driven at half the load,
    the start's binding (scale 1) is not the step's: the step binds again, as without a start."""
    model = make_method("pod_galerkin", n_modes=4).build(point_load[0])
    mus = [{"time": 0.25 + k * DT, "load_factor": 0.5 * _history(0.25 + k * DT)} for k in range(1, 11)]
    again = _steps(model, mus, {"time": 0.25, "load_factor": 1.0})
    assert model._bound_for is None
    assert np.array_equal(again, _steps(model, mus, None))


@pytest.mark.parametrize("method", ["linear_fe", "corotational_fe"])
def test_the_fe_baselines_in_time_start_their_integrator_in_start_too(point_load, monkeypatch, method):
    """The practitioners' models in time (fe_baselines.stepping.TrajectoryModel): the same start,
    the same numbers; the linear model's constant matrix factorised by start, not by its first step."""
    from tissuebench.refsolvers.dynamics.implicit import NewmarkFamily

    model = make_method(method).build(point_load[0])
    mus = [{"time": float(k * DT), "load_factor": _history(k * DT)} for k in range(1, 21)]
    system, K_t = model.system, type(model.system).K_t
    formed = []

    def run(mu0):
        formed[:] = [0]  # the start's own
        model.start(mu0, dt=DT)
        formed.pop()
        qs = []
        for mu in mus:
            formed.append(0)
            res = model.step(mu)
            assert res.ok, res.message
            qs.append(np.array(res.q, copy=True))
        return np.array(qs)

    def counting(*args, **kwargs):
        formed[-1] += 1
        return K_t(system, *args, **kwargs)

    monkeypatch.setattr(system, "K_t", counting, raising=False)
    started = run({"time": 0.0, "load_factor": 0.0})
    first_started = formed[0]
    monkeypatch.setattr(NewmarkFamily, "prime", lambda self: None)
    lazy = run(None)
    assert np.array_equal(started, lazy)
    if method == "linear_fe":  # one matrix for the run: formed by start, by the first step without it
        assert first_started == 0 and formed[0] >= 1


# ------------------------------------------------------------------ a fixed Newton budget (issue 52, item 5)
def test_a_fixed_newton_budget_steps_with_k_iterations_and_counts_the_steps_left_above_rtol(point_load):
    """``newton_iterations = k``: every step does k iterations (a haptic frame's fixed cost); with
    one, the large bend leaves steps above rtol, each said in its message and counted, and the
    trajectory stays near the converged one; with enough, none is left and the numbers are the
    converged run's to its tolerance."""
    training, res = point_load
    mus = [{"time": float(k * DT), "load_factor": _history(k * DT)} for k in range(1, round(T_END / DT) + 1)]
    converged, U = _run(training, n_modes=8, hyper="none", rtol=1e-10)
    for k, above in ((1, True), (8, False)):
        model = make_method("pod_galerkin", n_modes=8, hyper="none", rtol=1e-10, newton_iterations=k).build(training)
        results = model.solve(mus, dt=DT)
        assert all(r.ok for r in results)
        assert {r.info["iterations"] for r in results if r.info["iterations"]} == {k}
        flagged = [r for r in results if r.info.get("within_tolerance") is False]
        assert (model.steps_above_tolerance > 0) is above and len(flagged) == model.steps_above_tolerance
        assert all(f"fixed budget of {k} Newton iterations" in r.message for r in flagged)
        V = np.array([model.reconstruct(r) for r in results])
        gap = float(np.linalg.norm(V - U) / np.linalg.norm(U))
        assert gap <= (0.05 if above else 1e-8), gap
