"""The weighted-skinning + cubature ROM ("wsc"): weights, subspace, cubature, dynamics.

Verification (issue 13): partition of unity and weight 1 at the own handle; any affine
motion (rotation + stretch + translation) represented exactly; full cubature equals the
exact reduced force and tangent; NNLS fit error on held-out snapshots reported; with a
handle on every vertex and full cubature the ROM is the FE model (same trajectory);
bad input and numerical failures reported.
"""
import math

import numpy as np
import pytest

from tissuebench.cases.assembly import rotation_motion
from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import Dirichlet, FollowerPressure, MooneyRivlin, Problem
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.rom import METHODS, StepResult, Training, make_method
from tissuebench.rom.wsc import (Subspace, full_cubature, furthest_point_sampling, rbf_cubature, resolve_count,
                                 skinning_weights)
from tissuebench.rom.wsc.cubature import cell_centroids
from tissuebench.rom.wsc.reduced import CubatureForces

L, H = 0.08, 0.02
MAT = MooneyRivlin(500.0, 600.0, 5133.333333333333)


def bar_problem(divisions=(8, 2, 2), pull=(0.02, 0.0, 0.0), motion=None, loads=()):
    mesh = box_mesh((L, H, H), divisions, "tetra")
    right = Dirichlet(lambda x: x[:, 0] > L - 1e-12, value=np.asarray(pull, float), motion=motion)
    return Problem(mesh, MAT, "P1", [Dirichlet(lambda x: x[:, 0] < 1e-12), right], loads=loads, density=500.0)


def ramp(t):
    return min(max(t, 0.0), 1.0)


def run_rom(model, times):
    model.start()
    return [model.step({"time": t, "load_factor": ramp(t)}) for t in times]


# ------------------------------------------------------------------ handles, weights
def test_fps_is_seeded_spread_and_counts_are_checked():
    X = np.random.default_rng(0).uniform(size=(400, 3))
    a, b, c = (furthest_point_sampling(X, 20, seed=s) for s in (1, 1, 2))
    assert np.array_equal(a.indices, b.indices) and not np.array_equal(a.indices, c.indices)
    d = np.linalg.norm(X[:, None] - X[a.indices][None], axis=2).min(axis=1)
    assert d.max() == pytest.approx(a.covering_radius, rel=1e-12)
    assert a.separation >= 0.999 * a.covering_radius  # FPS picks are at least the covering radius apart
    assert resolve_count(0.05, 1000, "handles") == 50 and resolve_count(7, 1000, "handles") == 7
    with pytest.raises(ValueError, match="handles = 1001: more than the 1000 available"):
        resolve_count(1001, 1000, "handles")
    with pytest.raises(ValueError, match="count = 401 but 400 points are available"):
        furthest_point_sampling(X, 401)


def test_weights_are_a_partition_of_unity_with_weight_one_at_the_own_handle():
    pb = bar_problem()
    X = pb.nodes
    fps = furthest_point_sampling(X, 12, seed=3)
    W = skinning_weights(X, X[fps.indices], 2.0 * fps.covering_radius).toarray()
    assert np.abs(W.sum(axis=1) - 1).max() <= 1e-14
    assert np.all(W >= 0)
    assert np.allclose(W[fps.indices], np.eye(12), atol=0)  # exactly 1 on the own handle, 0 on the others
    assert (W > 0).sum(axis=1).min() >= 1
    assert np.count_nonzero(W) < W.size  # compact support
    with pytest.raises(ValueError, match="outside the support radius"):
        skinning_weights(X, X[fps.indices], 0.5 * fps.covering_radius)


def _affine_q(n_handles, A, t):
    """q with every handle's map equal to the displacement map u = (A - I) X + t."""
    D = np.zeros((4, 3))
    D[0], D[1:] = t, (A - np.eye(3)).T  # rows [1, x, y, z], columns = components
    return np.tile(D.ravel(), n_handles)


def test_subspace_reproduces_any_affine_motion_exactly():
    pb = bar_problem(divisions=(10, 3, 3))
    X = pb.nodes
    left = np.flatnonzero(X[:, 0] < 1e-12)
    fps = furthest_point_sampling(X, 15, seed=0, sources=[left])
    W = skinning_weights(X, X[fps.indices], 2.0 * fps.covering_radius, [left])
    sub = Subspace(X, W, 1, np.zeros(0, dtype=int))
    th = 0.7
    R = np.array([[1, 0, 0], [0, math.cos(th), -math.sin(th)], [0, math.sin(th), math.cos(th)]])
    A = R @ np.diag([1.3, 0.9, 1.1])  # rigid rotation plus stretch
    t = np.array([0.01, -0.02, 0.005])
    u = sub.displacement(_affine_q(sub.n_handles, A, t))
    exact = (X @ A.T + t - X).ravel()
    assert np.abs(u - exact).max() <= 1e-12 * np.abs(exact).max()
    assert np.abs(sub.U @ _affine_q(sub.n_handles, A, t) - exact).max() <= 1e-12 * np.abs(exact).max()


# ------------------------------------------------------------------ cubature
@pytest.fixture(scope="module")
def small_model():
    pb = bar_problem()
    be = make_backend("skfem", pb)
    model = make_method("wsc", handles=10, cubature="full").build(Training(backend=be, dt=0.01))
    return pb, be, model


def test_full_cubature_is_the_exact_reduced_force_and_tangent(small_model):
    pb, be, model = small_model
    sub = model.sub
    q = 1e-3 * np.random.default_rng(4).standard_normal(sub.n_q)
    forces = CubatureForces(sub, be, full_cubature(pb.mesh.n_cells))
    E, f = forces.energy_and_force(q)
    u = sub.displacement(q)
    exact = sub.U.T @ be.internal_force(u)
    assert np.abs(f - exact).max() <= 1e-12 * np.abs(exact).max()
    assert E == pytest.approx(be.strain_energy(u), rel=1e-12)
    f2, K = forces.force_and_tangent(q)
    K_exact = (sub.U.T @ be.tangent(u) @ sub.U).toarray()
    assert np.abs(K - K_exact).max() <= 1e-12 * np.abs(K_exact).max()
    assert np.abs(f2 - f).max() <= 1e-14 * np.abs(f).max()


def test_rbf_rule_integrates_volume_and_samples_are_spread(small_model):
    pb, be, _ = small_model
    vol = be.cell_kernel().volumes
    cen = cell_centroids(pb.mesh.points, pb.mesh.cells)
    cub = rbf_cubature(cen, vol, 40, seed=0)
    assert cub.size == 40 and len(np.unique(cub.cells)) == 40
    assert (cub.weights * vol[cub.cells]).sum() == pytest.approx(vol.sum(), rel=1e-12)  # int alpha_j sums to |Omega|
    exact = rbf_cubature(cen, vol, pb.mesh.n_cells)
    assert np.allclose(exact.weights, 1.0)


def test_nnls_fit_error_is_reported_and_a_tolerance_it_cannot_meet_is_refused():
    pb = bar_problem()
    be = make_backend("skfem", pb)
    res = integrate(SecondOrderSystem.from_backend(be, ramp), None, None, 0.05, 1.0, method="backward_euler")
    tr = Training(snapshots=res.u.T, parameters=[{"time": t, "load_factor": ramp(t)} for t in res.t],
                  backend=be, dt=0.05)
    model = make_method("wsc", handles=8, cubature="nnls", cubature_elements=120, nnls_tol=0.05).build(tr)
    info = model.info["cubature_info"]
    assert 0 <= info["heldout_error"] < 0.05 and info["snapshots_heldout"] >= 1
    assert model.info["cubature_elements"] <= 120
    print("NNLS held-out relative force error:", info["heldout_error"], "training:", info["train_error"])
    assert model.envelope == {"load_factor": (0.0, 1.0)}
    with pytest.raises(ValueError, match="held-out snapshots exceeds nnls_tol"):
        make_method("wsc", handles=8, cubature="nnls", cubature_elements=3, nnls_tol=1e-6).build(tr)
    with pytest.raises(ValueError, match="needs training snapshots"):
        make_method("wsc", handles=8, cubature="nnls").build(Training(backend=be, dt=0.05))


# ------------------------------------------------------------------ dynamics
@pytest.mark.parametrize("motion", [None, "twist"])
def test_all_vertices_as_handles_and_full_cubature_is_the_fe_model(motion):
    rot = rotation_motion({"axis": [1.0, 0.0, 0.0], "center": [L, H / 2, H / 2], "angle_deg": 60.0})
    pb = bar_problem(divisions=(3, 1, 1), motion=rot if motion else None)
    be = make_backend("skfem", pb)
    dt, n = 0.02, 15
    fe = integrate(SecondOrderSystem.from_backend(be, ramp), None, None, dt, n * dt, method="backward_euler",
                   newton_rtol=1e-12)
    n_free_vertices = int(np.sum((pb.nodes[:, 0] > 1e-12) & (pb.nodes[:, 0] < L - 1e-12)))
    model = make_method("wsc", handles=n_free_vertices, cubature="full", solver="newton",
                        rtol=1e-12).build(Training(backend=be, dt=dt))
    B = (model.sub.U @ model.sub.T).toarray()[pb.free_dofs]
    assert np.linalg.matrix_rank(B) == len(pb.free_dofs)  # the subspace is the full free space (redundantly)
    out = run_rom(model, fe.t[1:])
    assert all(r.ok for r in out), [r.message for r in out if not r.ok]
    U = np.array([model.reconstruct(r) for r in out])
    assert np.abs(U - fe.u[1:]).max() <= 1e-8 * np.abs(fe.u).max()


def test_rom_tracks_fe_and_reports_energy(small_model):
    pb, be, _ = small_model
    dt = 0.02
    fe = integrate(SecondOrderSystem.from_backend(be, ramp), None, None, dt, 0.6, method="newmark")
    model = make_method("wsc", handles=10, cubature="bgbc", cubature_elements=0.5, integrator="newmark",
                        track_energy=True).build(Training(backend=be, dt=dt))
    out = run_rom(model, fe.t[1:])
    assert all(r.ok for r in out)
    U = np.array([model.reconstruct(r) for r in out])
    rmse = np.sqrt(np.mean((U - fe.u[1:]) ** 2) / np.mean(fe.u[1:] ** 2))
    assert rmse < 0.1, rmse
    ke, ie, w = (np.array([r.info[k] for r in out]) for k in ("kinetic_energy", "strain_energy", "reaction_work"))
    # trapezoidal rule: the reduced energy balance closes up to the O(dt^2) rule error
    assert np.abs(ke + ie - w).max() < 0.02 * w.max()
    # prescribed values are exact in the reconstruction
    assert np.allclose(U[-1][pb.fixed_dofs], pb.prescribed_values(ramp(fe.t[-1])), atol=1e-14)


def test_outputs_follow_the_reduced_state(small_model):
    pb, be, model = small_model
    c = np.zeros(pb.ndof)
    c[3 * int(np.argmax(pb.nodes[:, 0] - pb.nodes[:, 1])) + 1] = 1.0
    model.attach_outputs({"tip_y": c})
    res = run_rom(model, [0.01, 0.02])[-1]
    assert model.outputs(res)["tip_y"] == pytest.approx(c @ model.reconstruct(res), rel=1e-12, abs=1e-18)


def test_follower_pressure_in_the_subspace_equals_the_backend_force():
    mesh = box_mesh((L, H, H), (6, 2, 2), "tetra")
    top = FollowerPressure(mesh.select_facets(lambda x: x[:, 2] > H - 1e-12), 50.0)
    pb = Problem(mesh, MAT, "P1", [Dirichlet(lambda x: x[:, 0] < 1e-12)], loads=[top], density=500.0)
    be = make_backend("skfem", pb)
    model = make_method("wsc", handles=6, cubature="full").build(Training(backend=be, dt=0.01))
    sub, loads = model.sub, model.stepper.loads
    q = 2e-3 * np.random.default_rng(2).standard_normal(sub.n_q)
    u = sub.displacement(q)
    exact = be.external_force(u, 1.0)
    assert np.abs(loads.follower_full(q) - exact).max() <= 1e-12 * np.abs(exact).max()
    assert np.abs(loads.follower_q(q) - sub.U.T @ exact).max() <= 1e-12 * np.abs(sub.U.T @ exact).max()


# ------------------------------------------------------------------ contract, bad input, failures
def test_registered_as_a_trajectory_method_with_checked_options():
    assert METHODS["wsc"].kind == "trajectory" and "operators" in METHODS["wsc"].training_kinds
    with pytest.raises(ValueError, match="a zero budget"):
        make_method("wsc", cubature_elements=0)
    with pytest.raises(ValueError, match="support = 0.8 must exceed 1"):
        make_method("wsc", support=0.8)
    with pytest.raises(ValueError, match="cubature = 'deim'"):
        make_method("wsc", cubature="deim")
    with pytest.raises(ValueError, match="integrator = 'rk4'"):
        make_method("wsc", integrator="rk4")
    with pytest.raises(ValueError, match="takes no option 'modes'"):
        make_method("wsc", modes=3)


def test_more_handles_than_vertices_and_non_affine_motion_are_refused(small_model):
    pb, be, _ = small_model
    with pytest.raises(ValueError, match="handles = 1000: more than the 81 available"):
        make_method("wsc", handles=1000).build(Training(backend=be))
    with pytest.raises(ValueError, match="exceeds the .* vertices outside the Dirichlet sets"):
        make_method("wsc", handles=80).build(Training(backend=be))
    bent = Problem(pb.mesh, MAT, "P1", [Dirichlet(lambda x: x[:, 0] < 1e-12),
                                        Dirichlet(lambda x: x[:, 0] > L - 1e-12,
                                                  value=lambda x: np.column_stack([x[:, 1] ** 2, 0 * x[:, 1:]]))])
    with pytest.raises(ValueError, match="not affine on its Dirichlet set"):
        make_method("wsc", handles=10).build(Training(backend=make_backend("skfem", bent)))


def test_a_step_the_reduced_solver_cannot_converge_is_a_failed_result(small_model):
    pb, be, _ = small_model
    model = make_method("wsc", handles=10, cubature="full", max_iter=1, rtol=1e-14).build(Training(backend=be))
    with pytest.raises(ValueError, match="dt must be a time step"):
        model.start()
    model.start(dt=0.05)
    res = model.step({"time": 0.05, "load_factor": 0.5})
    assert isinstance(res, StepResult) and res.status == "failed" and res.q is None
    assert "did not converge in 1 iterations" in res.message and "t=0.05" in res.message
    assert np.isnan(model.outputs(res).get("x", np.nan))
    with pytest.raises(ValueError, match="the step failed"):
        model.reconstruct(res)
    with pytest.raises(ValueError, match=r"parameter 'load_factor' missing"):
        model.step({"time": 0.1})
    # the paper's capped iteration keeps the step and says so
    capped = make_method("wsc", handles=10, cubature="full", max_iter=1, rtol=1e-14,
                         on_max_iter="accept").build(Training(backend=be))
    capped.start(dt=0.05)
    res = capped.step({"time": 0.05, "load_factor": 0.5})
    assert res.status == "ok" and res.q is not None and not res.info["converged"]
    assert "kept unconverged" in res.message and res.info["residual"] > 0


@pytest.mark.ngsolve
def test_the_rom_on_either_backend_is_the_same_model():
    pb = bar_problem(divisions=(6, 2, 2))
    out = []
    for name in ("skfem", "ngsolve"):
        model = make_method("wsc", handles=6, cubature="bgbc", cubature_elements=60, rtol=1e-10).build(
            Training(backend=make_backend(name, pb), dt=0.05))
        # fields, not q: a redundant direction of q (if any) moves no node and is arbitrary
        out.append(np.array([model.reconstruct(r) for r in run_rom(model, [0.05, 0.1, 0.15])]))
    assert np.abs(out[0] - out[1]).max() <= 1e-8 * np.abs(out[0]).max()
