"""pod_linear's online step on a linear-elastic bar whose supports prescribe displacements of
every kind (issue 41: the branches the mutation run found untested): scaled with the load
factor, imposed at every load factor (an offset at rest), and a motion (not affine in the load
factor). On a linear problem the free field is ``u_f(lam) = K_ff^-1 (lam f_f - K_fc u_D(lam))``;
a basis spanning it makes the Galerkin step exact, so the step is checked against that solve
(scipy, here) to round-off, at load factors no snapshot holds; the envelope's bounds on both
sides of their tolerance; the latency floor doing the step's arithmetic (a fair lower bound)."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse.linalg as spla

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import Dirichlet, LinearElastic, PointLoad, Problem, make_backend
from tissuebench.rom.base import Training, make_method


def _tilt(x, lam):
    """A motion: the end face's z grows as lam**2 (not affine in lam), zero at rest."""
    return np.full((len(x), 1), 0.05 * lam ** 2)


def _problem(kind: str) -> Problem:
    end = [Dirichlet(lambda x: x[:, 0] > 4.0 - 1e-9, (0,), 0.4)]  # pulled along x, scaled
    if kind == "offset":  # the end held 0.03 up at every load factor
        end.append(Dirichlet(lambda x: x[:, 0] > 4.0 - 1e-9, (2,), 0.03, scaled=False))
    elif kind == "motion":
        end.append(Dirichlet(lambda x: x[:, 0] > 4.0 - 1e-9, (2,), motion=_tilt))
    elif kind == "clamped":  # no prescribed value but zero: the outputs have no fixed share
        end = []
    mesh = box_mesh((4.0, 1.0, 1.0), (8, 2, 2), "tetra")
    return Problem(mesh, LinearElastic(1e3, 0.3), "P1", dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9), *end],
                   loads=[PointLoad(lambda x: np.isclose(x[:, 0], 2.0), np.array([0.0, -3.0, 0.0]) / 9)])


def _solve(be, lam: float) -> np.ndarray:
    """The full linear solution at ``lam`` (independent of the ROM: scipy's sparse LU)."""
    pb = be.problem
    free, fixed = pb.free_dofs, pb.fixed_dofs
    K = be.tangent(np.zeros(be.ndof)).tocsr()
    u = np.zeros(be.ndof)
    u[fixed] = pb.prescribed_values(lam)
    rhs = be.external_force(u, lam)[free] - K[free][:, fixed] @ u[fixed]
    u[free] = spla.spsolve(K[free][:, free].tocsc(), rhs)
    return u


def _model(kind: str, lams=(0.25, 0.5, 1.0)):
    be = make_backend("skfem", _problem(kind))
    S = np.column_stack([_solve(be, lam) for lam in lams])
    training = Training(snapshots=S, parameters=[{"load_factor": lam} for lam in lams], backend=be)
    return be, make_method("pod_linear", n_modes=len(lams)).build(training)


@pytest.mark.parametrize("kind", ["scaled", "offset", "motion"])
def test_the_step_is_the_linear_solution_between_and_inside_the_snapshots(kind):
    be, model = _model(kind)
    fixed = be.problem.fixed_dofs
    for lam in (0.3, 0.7, 1.0):
        res = model.step({"load_factor": lam})
        assert (res.status, res.message, res.mu) == ("ok", "", {"load_factor": lam})
        u, exact = model.reconstruct(res), _solve(be, lam)
        np.testing.assert_allclose(u[fixed], be.problem.prescribed_values(lam), rtol=0, atol=1e-15)
        assert np.linalg.norm(u - exact) <= 1e-9 * np.linalg.norm(exact), (kind, lam)
    if kind == "offset":  # the share of the values held at every load factor, at rest too
        res = model.step({"load_factor": 0.25})
        assert np.abs(model.reconstruct(res)[fixed]).max() == pytest.approx(0.4 * 0.25)
        assert np.abs(be.problem.prescribed_values(0.0)).max() == pytest.approx(0.03)


def test_the_envelope_bounds_on_both_sides_of_their_tolerance():
    _, model = _model("scaled")
    assert model.envelope == {"load_factor": (0.25, 1.0)}
    for lam in (0.25 * (1 - 1e-13), 1.0 + 1e-13):  # within 1e-12 of the bound: inside
        assert model.step({"load_factor": lam}).status == "ok"
    for lam in (0.25 * (1 - 1e-9), 1.0 + 1e-9, 0.0, 1.5):
        res = model.step({"load_factor": lam})
        assert res.status == "extrapolation" and res.mu == {"load_factor": lam}, lam
        assert res.q is not None and np.all(np.isfinite(res.q))


def _closure(fn) -> dict:
    return dict(zip(fn.__code__.co_freevars, (c.cell_contents for c in fn.__closure__)))


@pytest.mark.parametrize("kind", ["scaled", "offset", "clamped"])
def test_the_latency_floor_does_the_steps_arithmetic(kind):
    be, model = _model(kind)
    rng = np.random.default_rng(5)
    model.attach_outputs({"a": rng.standard_normal(be.ndof), "b": rng.standard_normal(be.ndof)})
    floor = model.floor_ops()
    floor()
    cells = _closure(floor)
    res = model.step({"load_factor": 0.5})  # the floor's load factor
    np.testing.assert_allclose(cells["q"], res.q, rtol=1e-14, atol=1e-300)
    out = model.outputs(res)
    np.testing.assert_allclose(cells["y"], [out["a"], out["b"]], rtol=1e-12)


# ---------------------------------------------------------------- pod_newton's iterations
@pytest.fixture(scope="module")
def svk_path():
    """An SVK cantilever bent by a tip load, its Newton path at lam = 1/4 ... 1 (training)."""
    from tissuebench.refsolvers import SaintVenantKirchhoff
    from tissuebench.refsolvers.newton import newton_solve

    mesh = box_mesh((4.0, 1.0, 1.0), (8, 2, 2), "tetra")
    pb = Problem(mesh, SaintVenantKirchhoff(1e3, 0.3), "P1", dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9)],
                 loads=[PointLoad(lambda x: np.isclose(x[:, 0], 4.0), np.array([0.0, 0.0, -12.0]) / 9)])
    be = make_backend("skfem", pb)
    ref = newton_solve(be, 1.0, n_increments=4, max_increment=0.25)
    assert ref.success
    lams = [inc.load_factor for inc in ref.increments if inc.converged]
    return be, np.column_stack(ref.states), lams


def _newton(svk_path, **options):
    be, S, lams = svk_path
    training = Training(snapshots=S, parameters=[{"load_factor": lam} for lam in lams], backend=be)
    return make_method("pod_newton", n_modes=S.shape[1], **options).build(training)


def test_pod_newton_stops_at_the_first_iterate_within_its_tolerance_and_starts_from_it(svk_path):
    be = svk_path[0]
    model = _newton(svk_path, rtol=1e-9)
    res = model.step({"load_factor": 0.5})
    norms = res.info["residual_norms"]
    assert (res.status, res.message, res.mu) == ("ok", "", {"load_factor": 0.5})
    assert res.info["iterations"] == len(norms) - 1 >= 2
    u = model.reconstruct(res)
    scale = max(np.linalg.norm(be.external_force(u, 0.5)), np.linalg.norm(be.internal_force(u)[be.problem.fixed_dofs]))
    tol = 1e-9 * scale + model._atol
    assert norms[-1] <= tol < min(norms[:-1])  # the first within the tolerance ends the iterations
    again = model.step({"load_factor": 0.5})  # the warm start: the converged q itself
    assert again.info["iterations"] == 0 and np.array_equal(again.q, res.q)
    model.start()  # forgets it: from q = 0 again
    assert model.step({"load_factor": 0.5}).info["iterations"] == res.info["iterations"]
    floor = model.floor_ops()
    assert floor() is None  # one iteration's work at the last converged state, no error
    with pytest.raises(ValueError, match="pod_newton"):
        model.step({})  # no load factor: the error names the model


def test_pod_newton_says_how_many_iterations_failed_and_keeps_its_warm_start(svk_path):
    model = _newton(svk_path, max_iterations=1)
    res = model.step({"load_factor": 1.0})  # from rest in one iteration: not converged
    norms = res.info["residual_norms"]
    assert res.status == "failed" and res.q is None and res.mu == {"load_factor": 1.0}
    assert res.info["iterations"] == 1 and len(norms) == 2
    assert res.message == f"pod_newton: no convergence at load factor 1 in 1 iterations (residual {norms[-1]:.3e})"
    assert np.array_equal(model._q, np.zeros(model.n_reduced))  # a failed step leaves the warm start


def test_pod_newton_outside_its_envelope_says_where(svk_path):
    model = _newton(svk_path)
    res = model.step({"load_factor": 1.25})
    assert res.status == "extrapolation" and res.q is not None
    assert res.message == "load factor 1.25 outside the training envelope [0.25, 1]"
    assert model.step({"load_factor": 1.0 + 1e-13}).status == "ok"
    assert model.step({"load_factor": 0.25 * (1 - 1e-13)}).status == "ok"
    assert model.step({"load_factor": 0.25 * (1 - 1e-9)}).status == "extrapolation"


# ---------------------------------------------------------------- options and the POD's inner product
@pytest.mark.parametrize("method", ["pod_linear", "pod_newton"])
def test_the_options_at_their_boundaries(method):
    assert make_method(method, n_modes=1).n_modes == 1
    for bad in (0, -1, True, 1.5):
        with pytest.raises(ValueError, match=method):
            make_method(method, n_modes=bad)
    with pytest.raises(ValueError, match=f"{method}: inner='energy'"):
        make_method(method, inner="energy")


def test_pod_newton_options_at_their_boundaries():
    model = make_method("pod_newton")
    assert (model.rtol, model.max_iterations) == (1e-10, 25)
    assert make_method("pod_newton", rtol=1e-30, max_iterations=1).max_iterations == 1
    for bad in ({"rtol": 0.0}, {"rtol": -1e-9}, {"max_iterations": 0}, {"rtol": 0.0, "max_iterations": 0}):
        with pytest.raises(ValueError, match="pod_newton: rtol > 0 and max_iterations >= 1"):
            make_method("pod_newton", **bad)


@pytest.mark.parametrize("inner", ["mass", "stiffness"])
def test_the_modes_are_orthonormal_in_the_inner_product_asked(inner):
    be = make_backend("skfem", _problem("scaled"))
    S = np.column_stack([_solve(be, lam) for lam in (0.25, 0.5, 1.0)])
    S[:, 1:] += 1e-2 * np.random.default_rng(2).standard_normal((be.ndof, 2))  # three independent snapshots
    training = Training(snapshots=S, parameters=[{"load_factor": lam} for lam in (0.25, 0.5, 1.0)], backend=be)
    free = be.problem.free_dofs
    W = (be.mass() if inner == "mass" else be.tangent(np.zeros(be.ndof)))[free][:, free]
    Phi = make_method("pod_linear", n_modes=3, inner=inner).build(training).basis
    np.testing.assert_allclose(Phi.T @ (W @ Phi), np.eye(3), atol=1e-10)
    assert not np.allclose(Phi.T @ Phi, np.eye(3), atol=1e-3)  # not the euclidean ones


@pytest.mark.parametrize("method", ["pod_linear", "pod_newton"])
def test_the_envelopes_tolerance_is_relative_to_its_largest_bound(method, svk_path):
    be, S, lams = svk_path
    if method == "pod_linear":
        be = make_backend("skfem", _problem("scaled"))
    # (lowest, highest, inside, outside): bounds below 1, above 1, and a pushed (negative) range
    # whose largest bound is its lowest
    for lo, top, inside, outside in ((0.25, 0.5, 0.75e-12, 1.5e-12), (2.0, 4.0, 3e-12, 5e-12),
                                     (-4.0, -2.0, 3e-12, 5e-12)):
        train = [lo, top]
        snaps = np.column_stack([_solve(be, t) if method == "pod_linear" else S[:, -1] * t for t in train])
        training = Training(snapshots=snaps, parameters=[{"load_factor": t} for t in train], backend=be)
        model = make_method(method, n_modes=1).build(training)
        assert model.step({"load_factor": top + inside}).status == "ok", (top, inside)
        assert model.step({"load_factor": top + outside}).status == "extrapolation", (top, outside)
        assert model.step({"load_factor": lo - inside}).status == "ok"
        assert model.step({"load_factor": lo - outside}).status == "extrapolation"
        model.start() if method == "pod_newton" else None


@pytest.mark.parametrize("kind", ["scaled", "motion", "clamped"])
def test_the_latency_floor_runs_without_outputs_and_on_a_motion(kind):
    """Without outputs attached (a scene without monitors) the floor is the reduced step alone; on
    a motion (no affine form) it is the loaded share ``lam q1``, the motion's solve left out."""
    be, model = _model(kind)
    floor = model.floor_ops()
    assert floor() is None
    cells = _closure(floor)
    if kind != "motion":
        np.testing.assert_allclose(cells["q"], model.step({"load_factor": 0.5}).q, rtol=1e-14, atol=1e-300)
    else:
        np.testing.assert_allclose(cells["q"], 0.5 * model._q1, rtol=1e-14, atol=1e-300)
    model.attach_outputs({"a": np.ones(be.ndof)})
    floor = model.floor_ops()
    assert floor() is None and _closure(floor)["y"].shape == (1,)
