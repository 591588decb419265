"""Evaluation sets: where a unit's reduced model is measured against the full reference.

The case entry's ``evaluation`` table has a ``kind`` (default: the training's):

``path``        the reference load path's load factors (``every`` thins them), driven in
                increasing order; ``beyond = [2, 10, 100]`` adds load factors that many
                times the top of the path, where no reference exists: only the step
                status is measured (extrapolation must be flagged, not hidden).
``positions``   held-out load positions (``held_out = n`` points at the midpoints and
                quarter points of the training lattice, or a list), each with its own
                reference path: every (position, load factor) is a point.
``trajectory``  the scene's reference time integration, the model stepped from rest (or
                the reference's initial state) with the load of each step; errors at the
                stored reference steps; ``t_end`` (e.g. 10x the paper's horizon) runs a
                longer reference.
``map``         the reference at each parameter of ``mus = [{...}, ...]`` (any scene
                parameters: ``position``, ``load_scale`` ...), one point per entry, each
                reference run at the full path's last load factor.

Each point carries the model's ``mu``, the reference full field (None where there is
none), the reference monitors, and the abscissa used for validity radii (``x``: load
factor, distance to the nearest stored position, or time).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .reference import cached_solve
from .training import lattice_positions, positional_scene, reference_states

__all__ = ["EVALUATION_KINDS", "EvaluationPoint", "Evaluation", "build_evaluation"]

EVALUATION_KINDS = ("path", "positions", "trajectory", "map")


@dataclass
class EvaluationPoint:
    mu: dict
    reference: np.ndarray | None
    monitors: dict
    x: float
    group: float | None = None  # held-out position (positions kind)


@dataclass
class Evaluation:
    """The points of one evaluation set (in driving order) and what drives a model through them."""

    kind: str
    x_name: str
    points: list
    dt: float | None = None
    state0: dict | None = None
    reference_steps: dict = field(default_factory=dict)  # reference: for timing a full step in process
    info: dict = field(default_factory=dict)


def _monitors(ref, key, value) -> dict:
    """The reference's monitored scalars in the (converged) table row where ``key == value``."""
    t = ref.table
    if "converged" in t:
        t = t[t["converged"].astype(bool)]
    hit = t[np.isclose(t[key].to_numpy(float), value, rtol=1e-12, atol=1e-12)] if key in t else t.iloc[:0]
    if hit.empty:
        return {}
    row = hit.iloc[0]
    return {n: float(row[n]) for n in t.columns if n not in _TABLE_COLUMNS and _is_number(row[n])}


_TABLE_COLUMNS = {"case", "backend", "step", "load_factor", "time", "newton_iterations", "converged", "wall_s",
                  "assembly_s", "solve_s", "final_residual", "message", "kinetic_energy", "strain_energy",
                  "external_work", "energy_error"}


def _is_number(v) -> bool:
    try:
        return bool(np.isfinite(float(v)))
    except (TypeError, ValueError):
        return False


def _path(scene, case, spec):
    ref, _ = cached_solve(scene, case["backend"])
    U, lams = reference_states(ref)
    every = int(spec.get("every", 1))
    idx = np.arange(len(lams))[::-1][::every][::-1]
    points = [EvaluationPoint({"load_factor": float(lams[k])}, U[:, k], _monitors(ref, "load_factor", lams[k]),
                              float(lams[k])) for k in idx]
    top = float(lams[-1]) if len(lams) else float(scene.analysis.get("max_load_factor", 1.0))
    points += [EvaluationPoint({"load_factor": f * top}, None, {}, f * top) for f in spec.get("beyond", [])]
    return Evaluation("path", "load_factor", points, reference_steps={"ref": ref, "scene": scene},
                      info={"reference_status": ref.status, "reference_top": top})


def _held_out(lattice, spec):
    if isinstance(spec, list):
        return np.asarray(spec, float)
    mids = 0.5 * (lattice[:-1] + lattice[1:])
    quarters = lattice[:-1] + 0.25 * np.diff(lattice)
    held = np.sort(np.concatenate([mids, quarters]))
    return held if spec is None else held[np.linspace(0, len(held) - 1, int(spec)).round().astype(int)]


def _positions(scene, case, spec, training_spec):
    lattice = lattice_positions(scene, training_spec.get("positions", 5))
    points, first = [], None
    for s in _held_out(lattice, spec.get("held_out")):
        ref, _ = cached_solve(positional_scene(scene, s, training_spec), case["backend"])
        U, lams = reference_states(ref)
        d = float(np.min(np.abs(lattice - s)))
        first = first or {"ref": ref, "scene": positional_scene(scene, s, training_spec)}
        points += [EvaluationPoint({"load_factor": float(lam), "position": float(s)}, U[:, k],
                                   _monitors(ref, "load_factor", lam), d, group=float(s)) for k, lam in enumerate(lams)]
    return Evaluation("positions", "distance", points, reference_steps=first,
                      info={"lattice": lattice.tolist(), "spacing": float(np.diff(lattice).min())})


def _trajectory(scene, case, spec):
    run = scene.at({k: v for k, v in spec.items() if k in ("load_scale", "t_end")})
    ref, _ = cached_solve(run, case["backend"])
    n = len(ref.steps)
    U = ref.displacement.reshape(n, -1)
    hist = run.history
    points = [EvaluationPoint({"time": float(t), "load_factor": float(hist(t))}, U[k], _monitors(ref, "time", t),
                              float(t)) for k, t in enumerate(ref.steps)]
    state0 = {"u": U[0], "v": ref.velocity.reshape(n, -1)[0]}
    return Evaluation("trajectory", "time", points, dt=float(run.analysis["dt"]), state0=state0,
                      reference_steps={"ref": ref, "scene": run},
                      info={"reference_status": ref.status, "t_end": float(run.analysis["t_end"])})


def _map(scene, case, spec):
    points, first = [], None
    for mu in spec.get("mus", []):
        s = scene.at(mu)
        ref, _ = cached_solve(s, case["backend"])
        U, lams = reference_states(ref)
        first = first or {"ref": ref, "scene": s}
        points.append(EvaluationPoint({**mu, "load_factor": float(lams[-1])}, U[:, -1],
                                      _monitors(ref, "load_factor", lams[-1]), float(len(points))))
    return Evaluation("map", "index", points, reference_steps=first or {})


def build_evaluation(case: dict, scene) -> Evaluation:
    """The :class:`Evaluation` of a case entry (module docstring)."""
    spec = dict(case.get("evaluation") or {})
    kind = spec.pop("kind", case["training"]["kind"])
    if kind == "path":
        return _path(scene, case, spec)
    if kind == "positions":
        return _positions(scene, case, spec, case["training"])
    if kind == "trajectory":
        return _trajectory(scene, case, spec)
    if kind == "map":
        return _map(scene, case, spec)
    raise ValueError(f"evaluation.kind = {kind!r}; valid: {list(EVALUATION_KINDS)}")
