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

import numpy as np
import pytest

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import (Dirichlet, LinearElastic, PointLoad, Problem, SaintVenantKirchhoff,
                                    make_backend)
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate
from tissuebench.refsolvers.newton import newton_solve
from tissuebench.rom import METHODS, MODEL_KINDS, OnlineModel, StepResult, Training, make_method

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
    kind = cls.training_kinds[0]
    training = trainings[kind]
    model = make_method(name, **getattr(cls, "contract_options", {})).build(training)
    assert isinstance(model, OnlineModel) and model.kind == cls.kind and model.n_reduced >= 1
    model.attach_outputs(training.outputs)
    if cls.kind == "trajectory":
        results = model.solve([{"time": k * training.dt, "load_factor": training.history(k * training.dt)}
                               for k in range(1, 6)], state0={"u": training.snapshots[:, 0],
                                                              "v": training.velocities[:, 0]}, dt=training.dt)
        outside = None
    else:
        inside, outside = _mus(kind, training)
        model.start(inside[0])
        results = [model.step(mu) for mu in inside]
    for res in results:
        assert isinstance(res, StepResult) and res.status == "ok", res.message
        u = model.reconstruct(res)
        assert u.shape == (training.backend.ndof,) and np.all(np.isfinite(u))
        y = model.outputs(res)["tip_uz"]
        assert y == pytest.approx(training.outputs["tip_uz"] @ u, rel=1e-9, abs=1e-14)
    if outside is not None:
        far = model.step(outside)
        assert far.status in ("extrapolation", "beyond_validity", "failed") and far.message
    with pytest.raises(ValueError):
        model.reconstruct(StepResult(None, "failed", "a failed step"))
    with pytest.raises((ValueError, TypeError)):
        model.step({"nonsense": 1.0})
