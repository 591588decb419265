"""The parameter a fit adds references along: the contract (:class:`Axis`) and its two kinds.

An axis knows, for the primary case of a scene (:mod:`.specs`):

* which values a training learnt (``trained``) and the held-out evaluation measures
  (``measured``), and so the candidates between them (:mod:`.candidates`);
* the training run that adds a reference at a value (``run``), in the spec's own terms;
* the cheap indicator of a built model at candidate values (``indicators``), and at the
  evaluation's own points, beside the true errors a unit measured there (``point_check``: the
  indicator's ranking checked against the truth, :func:`~.indicator.rank_correlation`);
* the evaluations of the dense check (``dense_evaluations``), at values neither the training
  nor the greedy ever uses.

:class:`PathAxis`: the load factor of a static path (a run ``{max_load_factor, load_steps}``).
:class:`AmplitudeAxis`: the amplitude ``load_scale`` of a motion (a run ``{load_scale}``), over
``[lowest training amplitude, 1]``. :class:`PositionAxis`: the position of a scene's moving load
(``[parameters.position]``: a stored position more, with its reference path). A scene whose
supports prescribe a displacement has no amplitude axis (``load_scale`` does not scale it): its
fit can only grow the model.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np

from ...reference import cached_solve
from ...reference.formulation import scene_backend
from ..applicability import load_scale_why_not
from ..evaluation import Evaluation, EvaluationPoint
from ..path_states import reference_states
from ..protocol import drive
from ..training import positional_scene
from .candidates import amplitude_candidates, gap_middles, path_candidates, run_steps
from .indicator import (path_fields, path_residuals, rank_correlation, trajectory_fields, trajectory_residuals)

__all__ = ["Axis", "PathAxis", "AmplitudeAxis", "PositionAxis", "axis_of", "DENSE_FRACTIONS"]

#: the dense check's amplitudes of a motion, as fractions of the claimed range (thirds: never a dyadic candidate)
DENSE_FRACTIONS = (1.0 / 3.0, 2.0 / 3.0)


class Axis(ABC):
    """The parameter of a family's training that a fit adds references along (module docstring)."""

    #: the parameter's name (``load_factor``, ``load_scale``)
    name: str = ""

    @abstractmethod
    def trained(self, case: dict, training) -> list[float]:
        """The values the training of ``case`` (its table; ``training``: built) learnt."""

    @abstractmethod
    def measured(self, case: dict, points) -> list[float]:
        """The values the held-out evaluation measures (``points``: a unit's point rows)."""

    @abstractmethod
    def candidates(self, trained, measured) -> np.ndarray:
        """Where a reference may be added."""

    @abstractmethod
    def run(self, value: float) -> dict:
        """The training run that adds a reference at ``value``."""

    @abstractmethod
    def indicators(self, model, training, values) -> np.ndarray:
        """The indicator of ``model`` at each of ``values`` (``inf`` where it fails)."""

    @abstractmethod
    def point_check(self, model, training, case: dict, points) -> tuple[float, int]:
        """``(Spearman's rho, pairs)`` of the indicator against the true error at the evaluation's points."""

    @abstractmethod
    def dense_evaluations(self, case: dict) -> list[tuple[str, dict]]:
        """``[(suffix, evaluation table)]`` of the dense check."""


def _measured_points(points):
    """The rows of a unit's points that the headline reads: with a reference, not the initial
    state, not past the path (``beyond``)."""
    keep = points["has_reference"].astype(bool) & (points["status"] != "initial")
    if "beyond" in points:
        keep &= ~points["beyond"].astype(bool)
    return points[keep]


class PathAxis(Axis):
    """The load factor of a static path (module docstring)."""

    name = "load_factor"

    def __init__(self, scene, backend: str):
        ref, _ = cached_solve(scene, backend)
        U, lams = reference_states(ref)
        self.top = float(lams[-1])  # the range the path claims: rest to its last converged state
        self.top_state = U[:, -1]
        a = scene.analysis
        self.increment = float(a.get("max_load_factor", 1.0)) / int(a.get("load_steps", 1))
        self._scale = {}

    def trained(self, case, training):
        return sorted(set(float(x) for x in training.parameter_values("load_factor")))

    def measured(self, case, points):
        return sorted(set(float(x) for x in _measured_points(points)["x"]))

    def candidates(self, trained, measured):
        return path_candidates(trained, measured, self.top)

    def run(self, value):
        return {"max_load_factor": float(value), "load_steps": run_steps(value, self.increment)}

    def force_scale(self, training) -> float:
        """The indicator's denominator: the largest force of the range, the internal force of the
        path's top reference state over every dof (the loads and the supports' reactions: a
        scene pulled by a prescribed displacement has no external force on its free dofs)."""
        be = training.backend
        key = id(be)
        if key not in self._scale:
            self._scale[key] = float(np.linalg.norm(np.asarray(be.internal_force(self.top_state), float)))
        return self._scale[key]

    def _indicator(self, model, training, values):
        values = np.asarray(values, float)
        fields = path_fields(model, values)
        res, ext = path_residuals(training.backend, fields, values, training.free_dofs)
        scale = max(self.force_scale(training), float(np.max(ext, initial=0.0)))
        return res / scale if scale > 0 else np.full(len(values), np.inf)

    def indicators(self, model, training, values):
        return self._indicator(model, training, values)

    def point_check(self, model, training, case, points):
        pts = _measured_points(points)
        if pts.empty:
            return float("nan"), 0
        ind = self._indicator(model, training, pts["x"].to_numpy(float))
        return rank_correlation(ind, pts["peak_rel"].to_numpy(float))

    def dense_evaluations(self, case):
        # thirds of the training intervals (refine = 3: a finer path of 3x the increments) beside the
        # held-out states and near rest: never the dyadic middles the greedy adds
        return [("dense", {**case["evaluation"], "refine": 3})]


class AmplitudeAxis(Axis):
    """The amplitude ``load_scale`` of a motion over ``[lowest training amplitude, 1]``."""

    name = "load_scale"

    def __init__(self, scene, base_case: dict):
        self.scene = scene
        runs = base_case["training"].get("runs", [])
        self.lo = min([1.0] + [float(r.get("load_scale", 1.0)) for r in runs])
        self.hi = 1.0
        a = scene.analysis
        self.dt, self.t_end = float(a["dt"]), float(a["t_end"])
        self.integrator, self.options = a.get("integrator", "hht"), dict(a.get("integrator_options", {}))

    def trained(self, case, training):
        return sorted({1.0} | {float(r.get("load_scale", 1.0)) for r in case["training"].get("runs", [])})

    def measured(self, case, points):
        return [float(case["evaluation"].get("load_scale", 1.0))]

    def candidates(self, trained, measured):
        if self.hi <= self.lo:
            return np.zeros(0)
        return amplitude_candidates(trained, measured, self.lo, self.hi)

    def run(self, value):
        return {"load_scale": float(value)}

    def _state0(self, training, scale):
        n = training.snapshots.shape[0]
        u = training.snapshots[:, 0] if training.snapshots is not None else np.zeros(n)
        v = training.velocities[:, 0] if training.velocities is not None else np.zeros(n)
        return {"u": scale * np.asarray(u, float), "v": scale * np.asarray(v, float)}

    def residuals(self, model, training, scale):
        """``(times, ||r||, ||f_ext||, exact)`` of ``model`` driven at amplitude ``scale``."""
        state0 = self._state0(training, scale)
        times, fields = trajectory_fields(model, training.history, self.dt, self.t_end, state0, scale)
        return trajectory_residuals(training.system, times, fields, state0["v"], self.integrator, self.options,
                                    scale)

    def indicators(self, model, training, values):
        out = []
        for s in values:
            _, res, ext, _ = self.residuals(model, training, float(s))
            peak = float(np.max(ext, initial=0.0))
            out.append(float(np.max(res, initial=0.0)) / peak if peak > 0 else np.inf)
        return np.asarray(out)

    def point_check(self, model, training, case, points):
        """Per stored step of the held-out run: the residual of that step against its error."""
        pts = _measured_points(points)
        if pts.empty:
            return float("nan"), 0
        scale = float(case["evaluation"].get("load_scale", 1.0))
        times, res, ext, _ = self.residuals(model, training, scale)
        peak = float(np.max(ext, initial=0.0))
        by_step = {int(round(t / self.dt)): r / peak if peak > 0 else np.inf for t, r in zip(times, res)}
        steps = np.rint(pts["x"].to_numpy(float) / self.dt).astype(int)
        ind = np.array([by_step.get(int(k), np.nan) for k in steps])
        return rank_correlation(ind, pts["peak_rel"].to_numpy(float))

    def dense_evaluations(self, case):
        return [(f"dense{i + 1}", {**case["evaluation"], "load_scale": float(self.lo + f * (self.hi - self.lo))})
                for i, f in enumerate(DENSE_FRACTIONS)] if self.hi > self.lo else []


def _mu_of(text: str) -> dict:
    """The parameters of a stored point row's ``mu`` text (``"load_factor=1.5, position=0.41"``)."""
    out = {}
    for part in str(text).split(","):
        key, _, value = part.strip().partition("=")
        if key:
            out[key] = float(value)
    return out


class PositionAxis(Axis):
    """The position of the load along the scene's ``[parameters.position]`` (a ``positions``
    training: one reference path per stored position). A run adds a stored position
    (``{"position": s}``: the training's list gains ``s``); the held-out positions are the
    evaluation's own list, frozen when the fit starts (:func:`.specs.held_out`)."""

    name = "position"

    def __init__(self, scene, base_case: dict, backend: str):
        self.scene, self.backend_name = scene, backend
        self.lo, self.hi = (float(x) for x in scene.parameters["position"]["range"])
        self.spec = {k: v for k, v in base_case["training"].items() if k in ("max_load_factor", "load_steps")}
        self._backends = {}

    def trained(self, case, training):
        return sorted(float(x) for x in case["training"]["positions"])

    def measured(self, case, points):
        return sorted(float(x) for x in case["evaluation"]["held_out"])

    def candidates(self, trained, measured):
        return gap_middles(list(trained) + list(measured), self.lo, self.hi)

    def run(self, value):
        return {"position": float(value)}

    def backend_at(self, s: float):
        """The full model with its load at position ``s`` (the internal force is the scene's; the
        external force moves), built once per position."""
        key = round(float(s), 12)
        if key not in self._backends:
            self._backends[key] = scene_backend(positional_scene(self.scene, s, self.spec), self.backend_name)
        return self._backends[key]

    def _load_factors(self, training) -> list[float]:
        return sorted({float(p["load_factor"]) for p in training.parameters or [] if "load_factor" in p})

    def force_scale(self, training) -> float:
        """The largest force of the range: the internal force of the top state of the first
        stored position's reference, over every dof."""
        group = next(iter((training.groups or {}).values()), None)
        top = (group.snapshots if group is not None else training.snapshots)[:, -1]
        return float(np.linalg.norm(np.asarray(training.backend.internal_force(top), float)))

    def _indicator(self, model, training, mus) -> np.ndarray:
        out = []
        scale = self.force_scale(training)
        for mu in mus:
            fields = path_fields_at(model, [mu])
            be = self.backend_at(mu["position"])
            res, _ = path_residuals(be, fields, [mu["load_factor"]], training.free_dofs)
            out.append(float(res[0]) / scale if scale > 0 else np.inf)
        return np.asarray(out)

    def indicators(self, model, training, values):
        lams = self._load_factors(training)
        out = []
        for s in values:  # a position's indicator: its worst load factor of the training's paths
            ind = self._indicator(model, training, [{"position": float(s), "load_factor": lam} for lam in lams])
            out.append(float(np.max(ind, initial=0.0)))
        return np.asarray(out)

    def point_check(self, model, training, case, points):
        pts = _measured_points(points)
        if pts.empty:
            return float("nan"), 0
        mus = [_mu_of(t) for t in pts["mu"]]
        mus = [{"position": mu["position"], "load_factor": mu["load_factor"]} for mu in mus]
        return rank_correlation(self._indicator(model, training, mus), pts["peak_rel"].to_numpy(float))

    def dense_evaluations(self, case):
        # the thirds of every interval between the fit's first stored positions: never a dyadic middle
        lat = np.sort(np.asarray(case["training"]["positions"], float))
        thirds = sorted(float(a + f * (b - a)) for a, b in zip(lat[:-1], lat[1:]) for f in DENSE_FRACTIONS)
        return [("dense", {**case["evaluation"], "held_out": thirds})]


def path_fields_at(model, mus) -> list:
    """The full fields of a map model stepped at the parameter sets ``mus`` (in their order)."""
    points = [EvaluationPoint(dict(mu), None, {}, float(k)) for k, mu in enumerate(mus)]
    return drive(model, Evaluation("map", "index", points)).fields


def axis_of(plan, backend: str, kind: str | None = None) -> Axis | None:
    """The axis of a fit's case ``kind`` (default: the primary); None for a motion without one (a
    prescribed displacement)."""
    kind = kind or next(iter(plan.base_cases))
    if kind == "path":
        return PathAxis(plan.scene, backend)
    if kind == "positions":
        return PositionAxis(plan.scene, plan.base_cases["positions"], backend)
    if load_scale_why_not(plan.scene):
        return None
    return AmplitudeAxis(plan.scene, plan.base_case)
