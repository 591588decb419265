"""POD basis extraction and the POD-Galerkin statics ROMs (pod_linear, pod_newton)."""
import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import (Dirichlet, LinearElastic, PointLoad, Problem, SaintVenantKirchhoff,
                                    make_backend)
from tissuebench.refsolvers.newton import newton_solve
from tissuebench.rom.base import METHODS, OnlineModel, StepResult, Training, make_method
from tissuebench.rom.pod import PodBasis, PodLinear, PodNewton, pod_basis


def _cantilever(material, force=(0.0, 0.0, -12.0), dirichlet_value=0.0):
    mesh = box_mesh((4.0, 1.0, 1.0), (8, 2, 2), "tetra")
    return Problem(mesh, material, "P1",
                   dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9, value=dirichlet_value)],
                   loads=[PointLoad(lambda x: np.isclose(x[:, 0], 4.0), np.asarray(force, float) / 9)])


@pytest.fixture(scope="module")
def svk():
    """SVK cantilever, tip load with a large deflection; Newton path lam = 1/8 ... 1."""
    be = make_backend("skfem", _cantilever(SaintVenantKirchhoff(1e3, 0.3)))
    ref = newton_solve(be, 1.0, n_increments=8, max_increment=1 / 8)
    assert ref.success
    lams = [inc.load_factor for inc in ref.increments if inc.converged]
    S = np.column_stack(ref.states)
    return be, S, lams


def _training(be, S, lams):
    return Training(snapshots=S, parameters=[{"load_factor": lam} for lam in lams], backend=be)


def _synthetic(s, n_dof=60, seed=0):
    rng = np.random.default_rng(seed)
    U = np.linalg.qr(rng.standard_normal((n_dof, len(s))))[0]
    V = np.linalg.qr(rng.standard_normal((len(s), len(s))))[0]
    return (U * s) @ V.T


# ---------------------------------------------------------------- pod_basis
@pytest.mark.parametrize("energy, n", [(0.9, 1), (0.99, 2), (0.999, 3), (0.99999, 4), (1.0, 5)])
def test_energy_criterion_picks_the_smallest_sufficient_n(energy, n):
    s = np.array([10.0, 3.0, 1.0, 0.1, 0.01])  # cumulative energy 0.909, 0.9908, 0.99991, 0.999999, 1
    b = pod_basis(_synthetic(s), energy=energy)
    assert b.n_modes == n and not b.rank_deficient and b.rank == 5
    np.testing.assert_allclose(b.singular_values, s, rtol=1e-12)
    np.testing.assert_allclose(b.eigenvalues, s**2, rtol=1e-12)  # paper eq. 7: eigenvalues of Q Q^T
    assert b.energy_captured == pytest.approx(np.sum(s[:n] ** 2) / np.sum(s**2))
    np.testing.assert_allclose(b.modes.T @ b.modes, np.eye(n), atol=1e-12)


def test_mass_inner_product_gives_w_orthonormal_modes_spanning_the_snapshots():
    rng = np.random.default_rng(1)
    be = make_backend("skfem", _cantilever(LinearElastic(1e3, 0.3)))
    M = be.mass()
    S = rng.standard_normal((be.ndof, 6)) @ np.diag([1, 1e-1, 1e-2, 1e-3, 1e-4, 1e-5])
    b = pod_basis(S, n_modes=4, inner=M)
    assert sp.issparse(M) and b.n_modes == 4
    np.testing.assert_allclose(b.modes.T @ (M @ b.modes), np.eye(4), atol=1e-10)
    full = pod_basis(S, n_modes=6, inner=M)  # all modes: the snapshots are reproduced
    P = full.modes @ (full.modes.T @ (M @ S))
    assert np.linalg.norm(P - S) <= 1e-8 * np.linalg.norm(S)
    # the W singular values are the Euclidean ones of M^(1/2) S
    w = np.linalg.eigvalsh(S.T @ (M @ S))[::-1]
    np.testing.assert_allclose(full.singular_values, np.sqrt(w), rtol=1e-8)


def test_rank_deficient_snapshots_are_reported_not_raised():
    rng = np.random.default_rng(2)
    S = rng.standard_normal((50, 3)) @ rng.standard_normal((3, 12))  # 12 snapshots of rank 3
    b = pod_basis(S, n_modes=9)
    assert isinstance(b, PodBasis)
    assert b.rank == 3 and b.n_modes == 3 and b.rank_deficient
    assert "rank 3 < requested 9 modes: 3 returned" in b.message
    assert b.energy_captured == pytest.approx(1.0)


@pytest.mark.parametrize("bad", [np.zeros((0, 3)), np.full((4, 2), np.nan), np.zeros((5, 3)), np.ones(4)])
def test_empty_nan_or_zero_snapshots_raise(bad):
    with pytest.raises(ValueError):
        pod_basis(bad)


def test_bad_options_raise():
    S = _synthetic(np.array([1.0, 0.5]))
    for kwargs in ({"energy": 0.0}, {"energy": 1.5}, {"n_modes": 0}, {"n_modes": 2.5}):
        with pytest.raises(ValueError):
            pod_basis(S, **kwargs)
    with pytest.raises(ValueError, match="inner"):
        PodNewton(inner="h1")


# ---------------------------------------------------------------- ROMs
def test_unknown_method_lists_the_valid_ones():
    with pytest.raises(ValueError, match="pod_linear") as info:
        make_method("nope")
    assert "pod_newton" in str(info.value)
    assert METHODS["pod_linear"] is PodLinear and METHODS["pod_newton"] is PodNewton


def test_pod_linear_is_exact_when_the_basis_contains_the_linear_solution():
    be = make_backend("skfem", _cantilever(LinearElastic(1e3, 0.3)))
    free = be.problem.free_dofs
    K = be.tangent(np.zeros(be.ndof))[free][:, free].tocsc()
    u = np.zeros(be.ndof)
    u[free] = sp.linalg.spsolve(K, be.external_force(u, 1.0)[free])
    rng = np.random.default_rng(3)
    other = np.zeros((be.ndof, 2))
    other[free] = rng.standard_normal((len(free), 2))  # unrelated directions: Galerkin must ignore them
    tr = Training(snapshots=np.column_stack([0.4 * u, other]), parameters=[{"load_factor": 0.0}, {"load_factor": 2.0},
                                                                            {"load_factor": 1.0}], backend=be)
    model = make_method("pod_linear", n_modes=3).build(tr)
    for lam in (0.25, 1.0, 1.7):
        res = model.step({"load_factor": lam})
        assert res.ok
        assert np.linalg.norm(model.reconstruct(res) - lam * u) <= 1e-10 * np.linalg.norm(lam * u)
    assert model.envelope == {"load_factor": (0.0, 2.0)}
    assert model.step({"load_factor": 2.5}).status == "extrapolation"


def _stretched(material, loaded=True):
    """Bar clamped at x = 0, its end x = 4 pulled by 0.4 along x (prescribed, scaled), loaded
    sideways or (``loaded=False``) driven by the prescribed motion alone."""
    mesh = box_mesh((4.0, 1.0, 1.0), (8, 2, 2), "tetra")
    loads = [PointLoad(lambda x: np.isclose(x[:, 0], 2.0), np.array([0.0, 0.0, -3.0]) / 9)] if loaded else []
    return Problem(mesh, material, "P1",
                   dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9),
                              Dirichlet(lambda x: x[:, 0] > 4.0 - 1e-9, (0,), 0.4)], loads=loads)


@pytest.mark.parametrize("loaded", [True, False])
@pytest.mark.parametrize("method, material", [("pod_linear", LinearElastic(1e3, 0.3)),
                                              ("pod_newton", SaintVenantKirchhoff(1e3, 0.3))])
def test_prescribed_displacements_are_lifted_on_the_fixed_dofs(method, material, loaded):
    """Non-zero Dirichlet data: the basis spans the free part, the fixed dofs take u_D(lam);
    without any load the residual's scale is the reaction (Newton must still converge)."""
    be = make_backend("skfem", _stretched(material, loaded))
    ref = newton_solve(be, 1.0, n_increments=4, max_increment=0.25)
    assert ref.success
    lams = [inc.load_factor for inc in ref.increments if inc.converged]
    S = np.column_stack(ref.states)
    model = make_method(method, n_modes=len(lams)).build(_training(be, S, lams))
    fixed = be.problem.fixed_dofs
    for k, lam in enumerate(lams):
        res = model.step({"load_factor": lam})
        assert res.ok, res.message
        u = model.reconstruct(res)
        np.testing.assert_allclose(u[fixed], be.problem.prescribed_values(lam), rtol=0, atol=1e-15)
        assert np.abs(u[fixed]).max() == pytest.approx(0.4 * lam)
        assert np.linalg.norm(u - S[:, k]) <= 1e-8 * np.linalg.norm(S[:, k])


@pytest.mark.parametrize("inner", ["euclidean", "mass", "stiffness"])
def test_pod_newton_reproduces_the_reference_path(svk, inner):
    be, S, lams = svk
    model = PodNewton(n_modes=S.shape[1], inner=inner, rtol=1e-11).build(_training(be, S, lams))
    assert model.n_reduced == S.shape[1]
    for k, lam in enumerate(lams):  # increasing: each step warm-starts from the previous one
        res = model.step({"load_factor": lam})
        assert res.ok, res.message
        err = np.linalg.norm(model.reconstruct(res) - S[:, k]) / np.linalg.norm(S[:, k])
        assert err < 1e-6
    tip = S[:, -1].reshape(-1, 3)[np.isclose(be.problem.nodes[:, 0], 4.0), 2].mean()
    assert tip < -1.0  # a large deflection, far from the linear regime


def test_pod_newton_between_training_states_and_outside_the_envelope(svk):
    be, S, lams = svk
    train = list(range(1, len(lams), 2))  # every other state: lam = 1/4, 1/2, 3/4, 1
    model = PodNewton(n_modes=len(train)).build(_training(be, S[:, train], [lams[k] for k in train]))
    lo, hi = model.envelope["load_factor"]
    assert (lo, hi) == pytest.approx((0.25, 1.0))
    for k in range(2, len(lams) - 1, 2):  # held-out states between training ones
        res = model.step({"load_factor": lams[k]})
        assert res.ok
        err = np.linalg.norm(model.reconstruct(res) - S[:, k]) / np.linalg.norm(S[:, k])
        assert 1e-9 < err < 1e-2
    assert model.step({"load_factor": 1.1}).status == "extrapolation"
    model.reset()
    assert model.step({"load_factor": 0.125}).status == "extrapolation"


def test_pod_newton_reports_a_failure_and_keeps_the_warm_start(svk):
    be, S, lams = svk
    model = PodNewton(n_modes=S.shape[1], max_iterations=1).build(_training(be, S, lams))
    res = model.step({"load_factor": 1.0})  # one iteration from q = 0 cannot converge
    assert res.status == "failed" and res.q is None and "no convergence" in res.message
    with pytest.raises(ValueError, match="failed"):
        model.reconstruct(res)
    assert np.all(model._q == 0.0)


@pytest.mark.parametrize("cls", [PodLinear, PodNewton])
def test_online_contract(svk, cls):
    be, S, lams = svk
    model = make_method(cls, n_modes=3).build(_training(be, S, lams))
    assert isinstance(model, OnlineModel) and model.name == cls.name
    res = model.step({"load_factor": 0.5})
    assert isinstance(res, StepResult) and res.q.shape == (model.n_reduced,) == (3,)
    u = model.reconstruct(res)
    assert u.shape == (be.ndof,) and np.all(u[be.problem.fixed_dofs] == 0.0)
    with pytest.raises(ValueError, match="load_factor"):
        model.step({"time": 0.5})
    model.reset()


@pytest.mark.parametrize("lam, ok", [(1.0 / 5120, True), (0.05, True)])
def test_pod_newton_converges_at_a_paths_near_rest_point_on_the_round_off_floor(lam, ok):
    """Issue 54: on the mean-dilatation cornea the reduced residual at load factor 1/5120 (a path's
    near-rest evaluation point) stalled at 3.6e-16 above rtol x its load: 25 iterations, a failed
    step, an infinite error. The tolerance now never goes below the residual's round-off floor
    (eps x the reduced forces of a unit dilation, as the full Newton's); the step at 0.05, far
    above the floor, converges as before. Both are checked against the reference's own states."""
    from tissuebench.studies.case_entry import CaseEntry
    from tissuebench.studies.training import build_training, case_scene

    case = CaseEntry(id="c", name="cornea_pinch", resolution="ci", backend="skfem", training={"kind": "path"})
    training = build_training(case, case_scene(case))
    model = make_method("pod_newton", n_modes=9).build(training)
    assert model._atol > 1e-14 * np.linalg.norm(model.basis.T @ training.backend.external_force(
        np.zeros(training.backend.ndof), 1.0)[model.free_dofs])  # the floor, not the load's 1e-14, decides
    model.start()
    res = model.step({"load_factor": lam})
    assert res.ok is ok, res.message
    assert res.info["iterations"] <= 5
