"""The PGD-POD direct integrator ("pgd_direct"): exactness on the 2-DOF frame, the vademecum
step against the explicit update formula of its inner integrator, convergence with PGD modes
and parameter-mesh nodes, extrapolation and failure reporting, bad input."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.rom import METHODS, make_method
from tissuebench.rom.base import Training
from tissuebench.rom.pgd_direct import SCHEMES, StepVademecum, VectorAlgebra
from tissuebench.rom.pgd_direct.meshes import ParameterMesh, parameter_domain
from tissuebench.studies.trajectories import scene_system, trajectory_training


@pytest.fixture(scope="module")
def frame_fe():
    """Frame trained on its own forward-Euler run (so the run stays inside the intervals)."""
    return trajectory_training("frame_2dof", integrator="forward_euler", t_end=3.0)


@pytest.fixture(scope="module")
def beam():
    """The clamped beam at dt = 5e-4 s (omega_1 dt = 0.24: explicit schemes are meaningful).

    At the scene's dt = 5e-3 (omega_1 dt = 2.4, beyond the explicit stability limit) the
    velocity update of forward Euler has columns nearly parallel with weights 1e5 apart and
    the PGD reaches 2e-7 in 23 modes instead of 1e-14 in 10.
    """
    return trajectory_training("clamped_beam", dt=5e-4, t_end=0.3)


def _run(model, training, load_at_times=None):
    hist, times = training.history, training.parameter_values("time")
    model.start({"time": times[0], "load_factor": hist(times[0])}, None, training.dt)
    out = [model.step({"time": t, "load_factor": hist(t)}) for t in times[1:]]
    return out


def _random_params(vad, rng, n):
    lo = np.array([m.lo for m in vad.meshes])
    hi = np.array([m.hi for m in vad.meshes])
    return lo + (hi - lo) * rng.random((n, len(lo)))


def _state_of(model, p):
    """Full free-dof state fields of parameter vector p (coordinates on the model's bases)."""
    return {f: model.bases[f] @ p[model._slices[f]] for f in model.fields}


def test_registered():
    assert METHODS["pgd_direct"].kind == "trajectory" and "trajectory" in METHODS["pgd_direct"].training_kinds


def test_frame_all_modes_equals_full_forward_euler(frame_fe):
    model = make_method("pgd_direct", pod_modes=2, integrator="forward_euler", n_nodes=200).build(frame_fe)
    res = _run(model, frame_fe)
    assert all(r.status == "ok" for r in res) and model.extrapolations == 0
    U = np.array([model.reconstruct(r) for r in res])
    ref = integrate(frame_fe.system, None, None, frame_fe.dt, frame_fe.parameter_values("time")[-1],
                    method="forward_euler", store_every=1)
    err = np.abs(U - ref.u[1:]).max() / np.abs(ref.u).max()
    assert err < 1e-10, err  # measured 3e-12 over 300 steps
    # the velocity update has rank 5 (4 coordinates + the load): within the paper's 8 modes
    assert model.info["pgd_modes"]["update v"] <= 8
    # monitored outputs without the full field equal the functional of the reconstruction
    y = model.outputs(res[-1])
    assert y["u2"] == pytest.approx(frame_fe.outputs["u2"] @ U[-1], rel=1e-12)


@pytest.mark.parametrize("scheme, vbasis", [("forward_euler", "velocity"), ("central_difference", "velocity"),
                                            ("bathe", "velocity"), ("hht", "velocity"), ("bathe", "displacement"),
                                            ("hht", "displacement")])
def test_vademecum_step_matches_the_explicit_update_formula(beam, scheme, vbasis):
    model = make_method("pgd_direct", pod_modes=4, integrator=scheme, n_nodes=30,
                        velocity_basis=vbasis).build(beam)
    if vbasis == "displacement":
        assert model.bases["v"] is model.bases["u"]
    vad, alg = model.vademecum, VectorAlgebra(model.ops)
    rng = np.random.default_rng(7)
    for p in _random_params(vad, rng, 20):
        state = _state_of(model, p)
        ref = alg.step(SCHEMES[scheme], state, vad.dt, p[-1], alpha=-0.05)
        got = vad.evaluate(p)
        for k in SCHEMES[scheme].outputs:
            assert np.linalg.norm(got[k] - ref[k]) <= 1e-9 * np.linalg.norm(ref[k])
        # the online step: next reduced state = projection of the update, field = the update
        model.q = p[:-1].copy()
        r = model.step({"time": 0.0, "load_factor": p[-1]})
        assert r.status == "ok"
        q_ref = np.concatenate([model.bases[f].T @ (model.ops.M @ ref[f]) for f in model.fields])
        np.testing.assert_allclose(r.q, q_ref, rtol=0, atol=1e-9 * np.abs(q_ref).max())
        u = model.reconstruct(r)[beam.free_dofs]
        assert np.linalg.norm(u - ref["u"]) <= 1e-9 * np.linalg.norm(ref["u"])


def test_error_decreases_with_pgd_modes_to_exactness_at_the_rank(beam):
    """Forward Euler: one PGD solve (the velocity update, rank P = 9); greedy modes are nested."""
    errs, P = [], None
    samples = refs = None
    for n in range(1, 11):
        model = make_method("pgd_direct", pod_modes=4, integrator="forward_euler", n_nodes=20,
                            pgd_modes=n).build(beam)
        vad = model.vademecum
        if samples is None:
            alg, P = VectorAlgebra(model.ops), vad.n_params
            samples = _random_params(vad, np.random.default_rng(3), 400)
            refs = np.array([alg.step(SCHEMES["forward_euler"], _state_of(model, p), vad.dt, p[-1])["v"]
                             for p in samples])
        got = np.array([vad.evaluate(p)["v"] for p in samples])
        # the Galerkin PGD decreases the error in the L2 norm over the parameter box (M in space):
        # estimated on 400 fixed uniform samples
        err2 = np.einsum("si,ij,sj->", got - refs, model.ops.M.toarray(), got - refs)
        errs.append(np.sqrt(err2 / np.einsum("si,ij,sj->", refs, model.ops.M.toarray(), refs)))
    # exact at the rank (one mode per coordinate and the load), large with one mode
    assert errs[0] > 1e-1 and errs[P - 1] < 1e-10, errs
    assert all(b < a for a, b in itertools.pairwise(errs[:P])), errs


def test_linear_map_is_exact_on_the_coarsest_parameter_mesh(beam):
    """P1 interpolation of a function linear in each parameter is exact: 2 nodes suffice."""
    model = make_method("pgd_direct", pod_modes=3, integrator="bathe", n_nodes=2).build(beam)
    vad, alg = model.vademecum, VectorAlgebra(model.ops)
    for p in _random_params(vad, np.random.default_rng(5), 10):
        ref = alg.step(SCHEMES["bathe"], _state_of(model, p), vad.dt, p[-1])
        assert np.linalg.norm(vad.evaluate(p)["u"] - ref["u"]) <= 1e-9 * np.linalg.norm(ref["u"])


@pytest.fixture(scope="module")
def svk_block():
    """wave_block SVK at ci, trained on 40 HHT steps; snapshots scaled by 300 so that the
    intervals reach strains of a few percent, where the SVK step map is visibly nonlinear."""
    tr = trajectory_training("wave_block", variant="svk", t_end=0.05)
    tr.snapshots *= 300.0
    tr.velocities *= 300.0
    return tr


def test_nonlinear_step_converges_at_second_order_in_the_parameter_mesh(svk_block):
    errs, nodes = [], [5, 9, 17, 33]
    for n in nodes:
        model = make_method("pgd_direct", pod_modes=2, integrator="central_difference", n_nodes=n).build(svk_block)
        vad, alg = model.vademecum, VectorAlgebra(model.ops)
        num = den = 0.0
        for p in _random_params(vad, np.random.default_rng(11), 200):
            ref = alg.step(SCHEMES["central_difference"], _state_of(model, p), vad.dt, p[-1])["u"]
            num += np.sum((vad.evaluate(p)["u"] - ref) ** 2)
            den += np.sum(ref**2)
        errs.append(np.sqrt(num / den))  # L2 over the parameter box, 200 fixed uniform samples
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    # P1 interpolation of the quadratic and cubic terms in q: order 2 (measured 2.02, 2.00, 1.99)
    assert np.all((orders > 1.8) & (orders < 2.2)), (errs, orders)
    assert errs[0] > 1e-6  # the nonlinearity is visible at these amplitudes (measured 6.7e-6)


def test_implicit_scheme_refuses_a_nonlinear_system(svk_block):
    with pytest.raises(ValueError, match="implicit"):
        make_method("pgd_direct", pod_modes=2, integrator="bathe").build(svk_block)


def test_extrapolation_is_flagged_counted_and_exact_for_a_linear_map(frame_fe):
    model = make_method("pgd_direct", pod_modes=2, integrator="forward_euler").build(frame_fe)
    hi = model.vademecum.meshes[0].hi
    u0 = np.zeros(frame_fe.snapshots.shape[0])
    u0[frame_fe.free_dofs] = model.bases["u"][:, 0] * 3.0 * hi  # coordinate 0 three times its interval
    model.start({"time": 0.0, "load_factor": 1.0}, {"u": u0}, frame_fe.dt)
    r = model.step({"time": frame_fe.dt, "load_factor": 1.0})
    assert r.status == "extrapolation" and "u:0" in r.message and model.extrapolations == 1
    ref = VectorAlgebra(model.ops).step(SCHEMES["forward_euler"], {"u": u0[frame_fe.free_dofs],
                                                                    "v": np.zeros(2)}, frame_fe.dt, 1.0)
    np.testing.assert_allclose(model.reconstruct(r)[frame_fe.free_dofs], ref["u"], rtol=1e-9)
    r2 = model.step({"time": 2 * frame_fe.dt, "load_factor": 50.0})  # load beyond its interval
    assert r2.status == "extrapolation" and model.extrapolations == 2
    model.reset()  # the latency protocol restarts from the same state and counters
    assert model.extrapolations == 0 and model.step({"time": 0.01, "load_factor": 1.0}).status == "extrapolation"


def test_non_finite_state_is_a_failed_step(frame_fe):
    model = make_method("pgd_direct", pod_modes=2).build(frame_fe)
    model.start()
    model.q = np.full(model.n_reduced, 1e300)
    r = model.step({"time": 0.01, "load_factor": 1.0})
    assert r.status == "failed" and r.q is None and "non-finite" in r.message
    assert np.isnan(model.outputs(r)["u1"])
    with pytest.raises(ValueError, match="failed"):
        model.reconstruct(r)


@pytest.mark.parametrize("opts, match", [({"integrator": "rk4"}, "integrator"), ({"pod_modes": 0}, "pod_modes"),
                                         ({"n_nodes": 1}, "n_nodes"), ({"load_at": "middle"}, "load_at"),
                                         ({"alpha": -0.5}, "alpha"), ({"margin": -1.0}, "margin"),
                                         ({"mass": "diagonal"}, "mass"), ({"dt": 0.0}, "dt"),
                                         ({"velocity_basis": "acceleration"}, "velocity_basis"),
                                         ({"balance": "state"}, "balance"),
                                         ({"n_modes": 3}, "n_modes")])
def test_bad_options(opts, match):
    with pytest.raises(ValueError, match=match):
        make_method("pgd_direct", **opts)


def test_bad_start_and_step_input(frame_fe):
    model = make_method("pgd_direct", pod_modes=2).build(frame_fe)
    with pytest.raises(ValueError, match="dt"):
        model.start(None, None, 2 * frame_fe.dt)
    model.start()
    with pytest.raises(ValueError, match="load_factor"):
        model.step({"time": 0.01})
    with pytest.raises(ValueError, match="load_factor"):
        model.step({"time": 0.01, "load_factor": float("inf")})


def test_training_without_velocities_or_time_step_is_refused(frame_fe):
    tr = Training(snapshots=frame_fe.snapshots, parameters=frame_fe.parameters, free_dofs=frame_fe.free_dofs,
                  system=frame_fe.system, history=frame_fe.history, dt=frame_fe.dt)
    with pytest.raises(ValueError, match="velocities"):
        make_method("pgd_direct", integrator="bathe").build(tr)
    tr.velocities, tr.dt = frame_fe.velocities, None
    with pytest.raises(ValueError, match="time step"):
        make_method("pgd_direct").build(tr)


def test_vademecum_npz_roundtrip(tmp_path, frame_fe):
    vad = make_method("pgd_direct", pod_modes=2, integrator="hht").build(frame_fe).vademecum
    back = StepVademecum.load(vad.save(tmp_path / "vad.npz"))
    p = _random_params(vad, np.random.default_rng(0), 1)[0]
    assert back.param_names == vad.param_names and back.stats["pgd_modes"] == vad.stats["pgd_modes"]
    for k, x in vad.evaluate(p).items():
        np.testing.assert_array_equal(back.evaluate(p)[k], x)


def test_load_at_start_reproduces_forward_euler_with_a_time_varying_load():
    """The full forward Euler uses the load at the beginning of each step (the paper's convention)."""
    ss = scene_system("frame_2dof")
    f = ss.system.load(1.0)

    def hist(t):
        return np.sin(2 * np.pi * t)

    sysm = SecondOrderSystem.linear_system(ss.system.M, ss.system.tangent(None), lambda t: f * hist(t),
                                           free=ss.system.free)
    res = integrate(sysm, None, None, 0.01, 1.0, method="forward_euler", store_every=1)
    tr = Training(snapshots=res.u.T, parameters=[{"time": t, "load_factor": hist(t)} for t in res.t],
                  free_dofs=sysm.free, velocities=res.v.T, system=sysm, history=hist, dt=0.01)
    errs = {}
    for load_at in ("start", "end"):
        model = make_method("pgd_direct", pod_modes=2, load_at=load_at).build(tr)
        U = np.array([model.reconstruct(r) for r in _run(model, tr)])
        errs[load_at] = np.abs(U - res.u[1:]).max() / np.abs(res.u).max()
    assert errs["start"] < 1e-10 and errs["end"] > 1e-3, errs
    # "mid": the mean of the previous and the new load factor is held over the step
    model = make_method("pgd_direct", pod_modes=2, load_at="mid").build(tr)
    model.start({"time": 0.0, "load_factor": 0.2}, None, 0.01)
    r = model.step({"time": 0.01, "load_factor": 0.6})
    x = VectorAlgebra(model.ops).initial_state(SCHEMES["forward_euler"], np.zeros(2), np.zeros(2), 0.01, 0.2)
    ref = VectorAlgebra(model.ops).step(SCHEMES["forward_euler"], x, 0.01, 0.4)
    np.testing.assert_allclose(model.field(r, "v")[tr.free_dofs], ref["v"], rtol=0, atol=1e-10 * np.abs(ref["v"]).max())


def test_basis_floor_bounds_the_error_of_a_replayed_training(beam):
    """``basis_floor_rmse`` (info) is the error of the training displacements' best
    approximation in the POD span: it falls with the POD modes, and a run that replays the
    training trajectory (as the presets do) cannot go below it, whatever the inner scheme."""
    floors = []
    for k in (1, 2, 4):
        model = make_method("pgd_direct", pod_modes=k, integrator="bathe", n_nodes=20).build(beam)
        floors.append(model.info["basis_floor_rmse"])
        res = _run(model, beam)
        U = np.array([model.reconstruct(r)[beam.free_dofs] for r in res]).T
        ref = beam.snapshots[beam.free_dofs][:, 1:1 + U.shape[1]]
        rmse = np.linalg.norm(U - ref) / np.linalg.norm(ref)
        assert rmse >= 0.9 * floors[-1], (k, rmse, floors[-1])
    assert floors[0] > floors[1] > floors[2] and 0 < floors[2] < 0.2, floors


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
