"""Contract tests, parametrised over every entry of ``rom.METHODS``: what the harness relies on.

Each method is built on a small training set of the first kind it learns from (a SVK
cantilever's Newton path; the same cantilever loaded at three positions; a linear bar's
HHT trajectory; the operators alone) and must: report its kind, take exactly the options
its constructor declares, step inside the envelope with status "ok", flag a parameter far
outside it, reconstruct a full finite field, give outputs equal to the output functionals
applied to its reconstruction, and refuse to reconstruct a failed step.
"""
from __future__ import annotations

import inspect
import json

import numpy as np
import pytest

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import (Dirichlet, LinearElastic, PointLoad, Problem, SaintVenantKirchhoff,
                                    make_backend)
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.refsolvers.newton import newton_solve
from tissuebench.refsolvers.remesh import gmsh_available
from tissuebench.rom import METHODS, MODEL_KINDS, OnlineModel, StepResult, Training, make_method
from tissuebench.rom.pgd.strip import IncisionStrip
from tissuebench.studies.units import _jsonable

TIP = 4.0


def _cantilever(x_load, material=None):
    mesh = box_mesh((TIP, 1.0, 1.0), (8, 2, 2), "tetra")
    return Problem(mesh, material or SaintVenantKirchhoff(1e3, 0.3), "P1",
                   dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9)],
                   loads=[PointLoad(lambda x, a=x_load: np.isclose(x[:, 0], a), np.array([0.0, 0.0, -20.0]) / 9)])


def _tip_output(be):
    c = np.zeros(be.ndof)
    tip = np.flatnonzero(np.isclose(be.problem.nodes[:, 0], TIP))
    c[3 * tip + 2] = 1.0 / len(tip)  # mean vertical tip displacement
    return {"tip_uz": c}


def _path(x_load=TIP):
    be = make_backend("skfem", _cantilever(x_load))
    ref = newton_solve(be, 1.0, n_increments=6, max_increment=1 / 6)
    assert ref.success
    lams = [inc.load_factor for inc in ref.increments if inc.converged]
    return Training(np.column_stack(ref.states), [{"load_factor": lam} for lam in lams], be,
                    outputs=_tip_output(be))


@pytest.fixture(scope="module")
def trainings():
    path = _path()
    groups = {s: _path(s) for s in (2.0, 3.0, 4.0)}
    cols = np.hstack([g.snapshots for g in groups.values()])
    params = [{"position": s, **p} for s, g in groups.items() for p in g.parameters]
    positions = Training(cols, params, groups[4.0].backend, groups=groups, outputs=path.outputs)
    be = make_backend("skfem", _cantilever(TIP, LinearElastic(1e3, 0.3)))
    be.problem  # noqa: B018
    history = lambda t: min(t / 0.05, 1.0)  # noqa: E731
    system = SecondOrderSystem.from_backend(be, history, linear=True)
    dt = 2.5e-3
    res = integrate(system, None, None, dt, 0.1, method="hht", alpha=-0.05)
    trajectory = Training(res.u.T.copy(), [{"time": float(t), "load_factor": history(t)} for t in res.t], be,
                          velocities=res.v.T.copy(), trajectories=np.zeros(len(res.t), int), system=system,
                          history=history, dt=dt, outputs=_tip_output(be))
    operators = Training(backend=path.backend, outputs=path.outputs)
    return {"path": path, "positions": positions, "trajectory": trajectory, "operators": operators}


def _operator_training(name):
    """An operators training on the first catalogue case the method builds from (PGD: the 1D
    source problem, or the cut cornea), made by the harness."""
    from tissuebench.studies.case_entry import CaseEntry
    from tissuebench.studies.training import build_training

    errors = []
    for case in ("heat1d_source", "cornea_cut"):
        entry = CaseEntry(id=case, name=case, variant=None, resolution="ci", backend="skfem",
                          training={"kind": "operators"})
        training = build_training(entry)
        try:
            return training, make_method(name).build(training)
        except ValueError as exc:
            errors.append(f"{case}: {exc}")
    pytest.fail(f"{name} builds from no operators training: {errors}")


def _envelope_mus(model):
    """(inside mus, one far outside) from a model's envelope (integers stay integers)."""
    inside, outside = {}, {}
    for k, (lo, hi) in model.envelope.items():
        ints = isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer))
        inside[k] = (lo + hi) // 2 if ints else 0.5 * (lo + hi)
        outside[k] = hi + 10 * (hi - lo) + 1
    return [inside], outside


def _mus(kind, training):
    """(inside mus, one far outside) for a map/path training."""
    if kind == "positions":
        return [{"position": 2.5, "load_factor": 0.5}, {"position": 3.5, "load_factor": 1.0}], \
            {"position": 9.0, "load_factor": 10.0}
    lams = training.parameter_values("load_factor")
    return [{"load_factor": float(lams[1])}, {"load_factor": float(lams[-1])}], {"load_factor": 10.0 * lams[-1]}


@pytest.mark.parametrize("name", sorted(METHODS))
def test_options_are_the_constructor_keywords(name):
    cls = METHODS[name]
    assert cls.kind in MODEL_KINDS and cls.training_kinds
    params = inspect.signature(cls.__init__).parameters
    assert cls.option_names() == [p for p in params if p != "self" and params[p].kind in
                                  (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)]
    with pytest.raises(ValueError, match="takes no option 'bogus_option'; valid: "):
        make_method(name, bogus_option=1)


@pytest.mark.parametrize("name", sorted(METHODS))
def test_method_contract(name, trainings):
    cls = METHODS[name]
    if name == "coarse_fe" and not gmsh_available():  # a Problem without a scene is coarsened by gmsh
        pytest.skip("gmsh is not installed (the optional extra tissuebench[mesh])")
    # a dynamic model is stepped along the trajectory fixture even when it can build from operators
    kind = "trajectory" if "trajectory" in cls.training_kinds else cls.training_kinds[0]
    if kind == "operators":
        training, model = _operator_training(name)
    else:
        training = trainings[kind]
        model = make_method(name).build(training)
    # a full-FE baseline (rom.fe_baselines) declares its statics kind and steps in time on a trajectory
    assert isinstance(model, OnlineModel) and model.n_reduced >= 1
    assert model.kind == cls.kind or (kind == "trajectory" and model.kind == "trajectory")
    info = getattr(model, "info", {})  # the build record the sweep stores as model_info
    assert isinstance(info, dict) and json.loads(json.dumps(_jsonable(info))) == _jsonable(info)
    model.attach_outputs(training.outputs)
    if model.kind == "trajectory":
        results = model.solve([{"time": k * training.dt, "load_factor": training.history(k * training.dt)}
                               for k in range(1, 6)], state0={"u": training.snapshots[:, 0],
                                                              "v": training.velocities[:, 0]}, dt=training.dt)
        outside = None
    else:
        inside, outside = _envelope_mus(model) if kind == "operators" else _mus(kind, training)
        model.start(inside[0])
        results = [model.step(mu) for mu in inside]
    for res in results:
        assert isinstance(res, StepResult) and res.status == "ok", res.message
        u = model.reconstruct(res)
        assert u.ndim == 1 and np.all(np.isfinite(u))
        for name_out, c in training.outputs.items():
            if c.shape == u.shape:  # a cut mesh has more dofs than the intact one the outputs were made on
                assert model.outputs(res)[name_out] == pytest.approx(c @ u, rel=1e-9, abs=1e-14)
    if outside is not None:
        try:
            far = model.step(outside)
        except ValueError as exc:  # refused, naming the parameter: as good as a flag
            assert any(k in str(exc) for k in outside)
        else:
            assert far.status in ("extrapolation", "beyond_validity", "failed") and far.message
    with pytest.raises(ValueError):
        model.reconstruct(StepResult(None, "failed", "a failed step"))
    with pytest.raises((ValueError, TypeError)):
        model.step({"nonsense": 1.0})
    _check_harness_hooks(cls, model)


def _check_harness_hooks(cls, model):
    """The optional hooks the harness calls (``OnlineModel.contact_nodes``, ``incision_strip``,
    ``contact_force``, ``variant``) answer with their declared types; an attribute of the same
    name (a hook shadowed by data) fails here."""
    nodes = model.contact_nodes()
    if nodes is not None:
        assert isinstance(nodes, np.ndarray) and nodes.ndim == 1 and len(nodes), nodes
        assert np.issubdtype(nodes.dtype, np.integer) and nodes.min() >= 0
    strip, force = model.incision_strip(), model.contact_force()
    if strip is not None:
        assert isinstance(strip, IncisionStrip) and strip.max_cut_length >= 1
        assert force is not None  # the cut references load the tip with it
    if force is not None:
        assert np.shape(force) == (3,) and np.all(np.isfinite(force))
    smaller = {k: 1 for k in cls.nested}
    sliced = model.variant(**smaller)
    # a declared nested option is one the model slices: otherwise the harness would build a
    # parent for every group only to build each unit afresh (issue 29)
    assert (sliced is not None) == bool(cls.nested), (cls.name, cls.nested, sliced)
    if sliced is not None:  # the same offline data, fewer modes: a model like a fresh build
        assert isinstance(sliced, OnlineModel) and sliced.kind == model.kind
        assert sliced.n_reduced <= min(model.n_reduced, smaller.get("n_modes", model.n_reduced))


def test_pod_interp_takes_a_duplicated_snapshot_set_and_refuses_an_ambiguous_one(trainings):
    path = trainings["path"]
    twice = Training(np.hstack([path.snapshots] * 2), path.parameters * 2, path.backend)
    model = make_method("pod_interp", n_modes=path.snapshots.shape[1], interpolation="rbf").build(twice)
    res = model.step({"load_factor": path.parameters[2]["load_factor"]})
    np.testing.assert_allclose(model.reconstruct(res), path.snapshots[:, 2], rtol=0, atol=1e-9)
    clash = Training(np.hstack([path.snapshots, 1.5 * path.snapshots]), path.parameters * 2, path.backend)
    with pytest.raises(ValueError, match="appear 2 times with different snapshots"):
        make_method("pod_interp").build(clash)


# ---------------------------------------------------------------- floor hook and the fast steps
def _straightforward(name, model, training, mu, res, before):
    """The step's reduced state recomputed the plain way (what each method's step did before its
    overhead was taken out, or the equation it solves); ``before``: the model's state before it."""
    from scipy.interpolate import LinearNDInterpolator, RBFInterpolator

    from tissuebench.rom.anm import reduced_path
    from tissuebench.rom.interpolation import interpolation_weights
    from tissuebench.rom.polynomial import ReducedPolynomial

    q = res.q
    if name == "pod_linear":
        fixed, values = model.prescribed(mu)
        rhs = mu["load_factor"] * model.f_r - (model._K_rc @ values if model._K_rc is not None else 0.0)
        return np.linalg.solve(model.K_r, rhs)
    if name == "anm_pod":
        s = model.path[res.info["segment"]]
        a = s.load_factor_to_a(mu["load_factor"])  # the search from a = 0, no table
        assert res.info["a"] == pytest.approx(a, rel=1e-13)
        return sum(a ** p * z for p, z in enumerate(s._Z))
    if name in ("anm_pod_interp", "podi", "grassmann"):
        idx, w, _, _ = interpolation_weights(model.positions, mu["position"])
        poly = ReducedPolynomial(*(np.tensordot(w, T[idx], axes=1) for T in (model._L, model._Q, model._C, model._f)))
        o = model.options
        return reduced_path(poly, mu["load_factor"], o.order, o.eps, o.max_segments).evaluate(mu["load_factor"])
    if name in ("nearest", "pod_interp"):
        p = np.array([mu[k] for k in model.keys], float)
        x = (p - model._lo) / model._span
        if name == "nearest":
            return np.array([float(np.argmin(np.linalg.norm(model._X - x, axis=1)))])
        opts = make_method(name)
        if type(model._f).__name__ == "RbfAtPoint":
            return RBFInterpolator(model._X, model._A, kernel=opts.kernel)(x[None])[0]
        if model._X.shape[1] == 1:
            order = np.argsort(model._X[:, 0])
            return np.array([np.interp(x[0], model._X[order, 0], model._A[order, i]) for i in range(q.size)])
        return LinearNDInterpolator(model._X, model._A)(x[None])[0]
    if name == "pgd":
        vad, fam = model.vademecum, model.vademecum.family
        rows, vals = fam.load_at(mu["position"])
        f = np.zeros(fam.n_free)
        f[rows] = vals
        X, K = vad.X, fam.K
        if model.projection == "srb":  # Galerkin on span X, compared as fields
            u = X @ np.linalg.solve(X.T @ (K @ X), X.T @ f)
        elif model.projection == "prb":
            S = vad.S_at(mu["position"])
            u = X @ (np.linalg.lstsq(model.proj.K_r, vad.gamma * (X.T @ f), rcond=1e-12)[0] * S)
        else:
            u = vad.field(mu["position"])
        return np.linalg.lstsq(model.basis, u, rcond=None)[0]
    if name == "pgd_svk":  # the reduced SVK equilibrium at the contact
        fam = model.vademecum.family
        rows, vals = fam.load_at(int(fam.nodes[int(mu["position"])]))
        f = mu.get("load_factor", 1.0) * (model.basis[rows].T @ vals)
        assert np.linalg.norm(model.poly.force(q) - f) <= 1e-8 * np.linalg.norm(f)
        return q
    if name == "pgd_cutting":
        fam, c = model.vademecum.family, int(mu["cut_length"])
        n = model.r + 3 * int(model.strip.n_enriched[c])
        node = int(fam.nodes[int(mu["position"])])
        rows = fam.free_index[3 * node + np.arange(3)]
        F = model.force[rows >= 0]
        b = np.zeros(n)
        b[:model.r] = model.basis[rows[rows >= 0]].T @ F
        return np.linalg.solve(model.M[:n, :n], b)
    if name == "pod_newton":  # the reduced residual at the converged state
        r, _, scale = model._residual_and_tangent(q, mu["load_factor"])
        assert np.linalg.norm(r) <= model.rtol * scale + model._atol
        return q
    if name == "pgd_direct":  # the vademecum's weights by np.interp per parameter, mapped by R
        vad = model.vademecum
        p = np.r_[before, mu["load_factor"]]
        w = np.ones(vad.n_modes)
        for d, mesh in enumerate(vad.meshes):
            nodes = np.linspace(mesh.lo, mesh.hi, mesh.n_nodes)
            w *= np.array([np.interp(p[d], nodes, vad.factors[d, :, i]) for i in range(vad.n_modes)])
        np.testing.assert_allclose(res.info["weights"], w, rtol=1e-12, atol=1e-14 * np.abs(w).max())
        return q
    return None  # wsc: another issue's step


@pytest.mark.parametrize("name", sorted(METHODS))
def test_floor_hook_runs_and_the_step_matches_a_straightforward_computation(name, trainings):
    """``floor_ops()`` returns a zero-argument callable that runs (the protocol times it beside
    every step); the optimised step gives the state of the plain computation to round-off."""
    cls = METHODS[name]
    kind = "trajectory" if "trajectory" in cls.training_kinds else cls.training_kinds[0]
    if kind == "operators":
        training, model = _operator_training(name)
    else:
        training = trainings[kind]
        model = make_method(name).build(training)
    model.attach_outputs(training.outputs)
    if model.kind == "trajectory":  # a full-FE baseline steps in time on a trajectory training
        model.start({"load_factor": 0.0}, {"u": training.snapshots[:, 0], "v": training.velocities[:, 0]},
                    training.dt)
        mus = [{"time": k * training.dt, "load_factor": training.history(k * training.dt)} for k in range(1, 4)]
    else:
        mus = _envelope_mus(model)[0] if kind == "operators" else _mus(kind, training)[0]
        model.start(mus[0])
    floor = model.floor_ops()
    assert callable(floor)
    floor()
    floor()
    for mu in mus:
        before = getattr(model, "q", None)
        before = None if before is None else np.array(before, copy=True)
        res = model.step(mu)
        assert res.q is not None and res.status == "ok", res.message
        expected = _straightforward(name, model, training, mu, res, before)
        if expected is not None:
            np.testing.assert_allclose(res.q, expected, rtol=1e-9, atol=1e-12 * max(np.abs(expected).max(), 1e-300))
