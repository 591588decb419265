"""Contract tests, parametrised over every entry of ``rom.METHODS``, through the shipped battery
:mod:`tissuebench.testing` (the one source of truth a plugin's own tests run too): one test per
(method, named check), each method on the first built-in catalogue case it applies to.

Besides the battery: white-box tests of some methods' fast steps against a plain computation.
"""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.rom import METHODS, Training, make_method
from tissuebench.testing import parametrize_with_checks
from tissuebench.testing.cases import contract_case, primary_case

# options that keep each build small (a method registered later runs with its defaults)
OPTIONS = {"pod_linear": {"n_modes": 3}, "pod_newton": {"n_modes": 3}, "anm_pod": {"n_modes": 3, "order": 3},
           "pod_interp": {"n_modes": 3}, "anm_pod_interp": {"n_modes": 3, "order": 3},
           "podi": {"n_modes": 3, "order": 3}, "grassmann": {"n_modes": 3, "order": 3}, "pgd": {"n_modes": 5},
           "pgd_svk": {"n_modes": 3}, "pgd_cutting": {"n_modes": 3},
           "wsc": {"handles": 2, "cubature": "full"},
           "pgd_direct": {"pod_modes": 2, "pgd_modes": 8, "integrator": "central_difference", "n_nodes": 20}}
# the parameter contract of these takes seconds to tens of seconds each: the slow run has it
_SLOW = ("wsc", "pgd_cutting", "pgd_svk", "anm_pod_interp", "podi", "grassmann")


@parametrize_with_checks(sorted(METHODS), options=OPTIONS,
                         marks={(m, "parameters_are_honoured"): pytest.mark.slow for m in _SLOW})
def test_method_contract(method, check):
    check(method)


def _contract_case(name):
    """The built-in case a method is checked on, and the model built there (small options)."""
    options = OPTIONS.get(name, {})
    case = contract_case(primary_case(METHODS[name], options))
    return case.training, make_method(name, **options).build(case.training)


def _envelope_mus(model):
    """Parameters inside the envelope of a model built from operators (integers stay integers)."""
    inside = {}
    for k, (lo, hi) in model.envelope.items():
        ints = isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer))
        inside[k] = (lo + hi) // 2 if ints else 0.5 * (lo + hi)
    return [inside]


def _mus(training):
    """Two parameter sets of the training's snapshots (the middle one and the last)."""
    return [dict(training.parameters[len(training.parameters) // 2]), dict(training.parameters[-1])]


def test_pod_interp_takes_a_duplicated_snapshot_set_and_refuses_an_ambiguous_one():
    path = contract_case("path").training
    twice = Training(np.hstack([path.snapshots] * 2), path.parameters * 2, path.backend)
    model = make_method("pod_interp", n_modes=path.snapshots.shape[1], interpolation="rbf").build(twice)
    res = model.step({"load_factor": path.parameters[2]["load_factor"]})
    np.testing.assert_allclose(model.reconstruct(res), path.snapshots[:, 2], rtol=0,
                               atol=1e-9 * np.abs(path.snapshots).max())
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
        # the weights' scale: the product of the factors' (a weight exactly zero at rest is round-off in the step)
        scale = np.prod([np.abs(vad.factors[d]).max() for d in range(len(vad.meshes))])
        np.testing.assert_allclose(res.info["weights"], w, rtol=1e-12, atol=1e-14 * scale)
        return q
    return None  # wsc: another issue's step


@pytest.mark.parametrize("name", sorted(n for n in METHODS if METHODS[n].__module__.startswith("tissuebench.")))
def test_the_step_matches_a_straightforward_computation(name):
    """The optimised step gives the state of the plain computation to round-off (the floor hook
    runs first, as the protocol times it beside every step)."""
    training, model = _contract_case(name)
    model.attach_outputs(training.outputs)
    if model.kind == "trajectory":  # a full-FE baseline steps in time on a trajectory training
        model.start({"load_factor": 0.0}, {"u": training.snapshots[:, 0], "v": training.velocities[:, 0]},
                    training.dt)
        mus = [{"time": k * training.dt, "load_factor": training.history(k * training.dt)} for k in range(1, 4)]
    else:
        mus = _envelope_mus(model) if not training.parameters else _mus(training)
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
