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
                longer reference. Where the load ends constant, the long-run energy drift
                of the reference and of the model (:mod:`.energy`).
``map``         the reference at each parameter of ``mus = [{...}, ...]`` (any scene
                parameters: ``position``, ``load_scale`` ...), one point per entry, each
                reference run at the full path's last load factor.
``contact_nodes`` (the surface vademecums, ``pgd`` and ``pgd_svk``, whose model knows its
                contact nodes, and the practitioner baselines, whose ``contact_nodes`` are the
                same anterior-surface list) ``count`` contact nodes of the model, evenly spaced through
                its list; per node the intact scene (no ``[cut]``) with its point load moved
                onto that node, the full reference path (SVK Newton where the scene is SVK):
                one point per (node, load factor), ``mu = {node, load_factor}``.
``cut_lengths`` a scalpel advancing node by node along an incision of the scene's ``[cut]``
                (the cutting methods, whose model knows the incision strip): per cut length
                ``c``, the model at ``{node: the scalpel tip, cut_length: c}`` against the
                linear FE of the same cut mesh under the same contact force; the haptic
                sequence timed is the scalpel's (``steps_per_length`` steps per length, the
                online enrichment included), and the reference step is the full FE step of a
                cut (assembly, factorisation, solve) timed here, in the same process.

Each point carries the model's ``mu``, the reference full field (None where there is
none), the reference monitors, and the abscissa used for validity radii (``x``: load
factor, distance to the nearest stored position, or time).
"""
from __future__ import annotations

import copy
import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np

from .energy import EnergyDrift, conservative_window, reference_drift
from .reference import cached_solve
from .training import lattice_positions, positional_scene, reference_states

__all__ = ["EVALUATION_KINDS", "EvaluationPoint", "Evaluation", "build_evaluation"]

EVALUATION_KINDS = ("path", "positions", "trajectory", "map", "cut_lengths", "contact_nodes")
NEEDS_MODEL = ("cut_lengths", "contact_nodes")  # built after the model: the incision strip, the contact nodes


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
    timing_mus: list | None = None  # the haptic sequence to time, when the evaluation defines one
    reference_step_s: float | None = None  # the full step, when the evaluation timed it itself
    # trajectory: the reference's long-run energy drift over the constant-load window (its
    # window_start and scale are the model's too, :mod:`.energy`); None without such a window
    reference_energy: EnergyDrift | None = None


def _path(scene, case, spec):
    ref, _ = cached_solve(scene, case["backend"])
    U, lams = reference_states(ref)
    every = int(spec.get("every", 1))
    idx = np.arange(len(lams))[::-1][::every][::-1]
    points = [EvaluationPoint({"load_factor": float(lams[k])}, U[:, k], ref.monitors_at("load_factor", lams[k]),
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
                                   ref.monitors_at("load_factor", lam), d, group=float(s))
                   for k, lam in enumerate(lams)]
    return Evaluation("positions", "distance", points, reference_steps=first,
                      info={"lattice": lattice.tolist(), "spacing": float(np.diff(lattice).min())})


def _trajectory(scene, case, spec):
    run = scene.at({k: v for k, v in spec.items() if k in ("load_scale", "t_end")})
    ref, _ = cached_solve(run, case["backend"])
    n = len(ref.steps)
    U = ref.displacement.reshape(n, -1)
    hist = run.history
    points = [EvaluationPoint({"time": float(t), "load_factor": float(hist(t))}, U[k], ref.monitors_at("time", t),
                              float(t)) for k, t in enumerate(ref.steps)]
    state0 = {"u": U[0], "v": ref.velocity.reshape(n, -1)[0]}
    dt, t_end = float(run.analysis["dt"]), float(run.analysis["t_end"])
    t_c = conservative_window(hist, dt, t_end, float(ref.steps[0]))
    return Evaluation("trajectory", "time", points, dt=dt, state0=state0, reference_steps={"ref": ref, "scene": run},
                      info={"reference_status": ref.status, "t_end": t_end},
                      reference_energy=None if t_c is None else reference_drift(ref.table, t_c, t_end))


def _map(scene, case, spec):
    points, first = [], None
    for mu in spec.get("mus", []):
        s = scene.at(mu)
        ref, _ = cached_solve(s, case["backend"])
        U, lams = reference_states(ref)
        first = first or {"ref": ref, "scene": s}
        points.append(EvaluationPoint({**mu, "load_factor": float(lams[-1])}, U[:, -1],
                                      ref.monitors_at("load_factor", lams[-1]), float(len(points))))
    return Evaluation("map", "index", points, reference_steps=first or {})


# the linear FE of each cut length of one strip, solved (and its full step timed) once per
# process: every unit of a sweep on that strip compares with the same fields (a unit took 25 s
# of its 50 s re-solving them at paper resolution)
_CUT_REFERENCES: dict = {}


def _cut_lengths(scene, case, spec, model):
    """Per cut length of the model's incision: the linear FE of the same cut mesh (module docstring)."""
    from ..refsolvers.backends import make_backend
    from ..rom.pgd.reference import cut_problem, linear_reference

    strip = getattr(model, "strip", None)
    if strip is None:
        raise ValueError(f"evaluation.kind = 'cut_lengths' needs a cutting model (one with an incision strip); "
                         f"{model.name!r} has none")
    lengths = range(strip.max_cut_length + 1)
    key = (scene.content_hash(), case["backend"], strip.depth_fraction, np.asarray(model.force, float).tobytes(),
           repr(strip.incision(strip.max_cut_length)), tuple(int(strip.tip(c)) for c in lengths))
    if key not in _CUT_REFERENCES:
        solved = []
        for c in lengths:
            t0 = time.perf_counter()
            be = make_backend(case["backend"], cut_problem(scene, strip, c, model.force))
            u, _ = linear_reference(be)
            solved.append((u, time.perf_counter() - t0))
        _CUT_REFERENCES.clear()  # one scene's strip at a time: the units of a sweep come case by case
        _CUT_REFERENCES[key] = solved
    solved = _CUT_REFERENCES[key]
    points = [EvaluationPoint({"node": int(strip.tip(c)), "cut_length": c}, u, {}, float(c))
              for c, (u, _) in enumerate(solved)]
    full_steps = [t for _, t in solved]
    per_length = int(spec.get("steps_per_length", 20))
    return Evaluation("cut_lengths", "cut_length", points, info={"max_cut_length": strip.max_cut_length},
                      timing_mus=[p.mu for p in points for _ in range(per_length)],
                      reference_step_s=float(np.median(full_steps)))


def contact_scene(scene, node: int):
    """The intact ``scene`` (``[cut]`` dropped) with its one point load moved onto mesh ``node``
    (``mu["contact_node"]`` records it, so the reference is cached per node)."""
    intact = scene if scene.cut is None else dataclasses.replace(scene, cut=None)
    n = intact.mesh.n_vertices
    if isinstance(node, bool) or not isinstance(node, (int, np.integer)) or not 0 <= node < n:
        raise ValueError(f"contact node = {node!r}: not a node of the intact mesh (0 .. {n - 1})")
    which = [i for i, ld in enumerate(intact.loads) if ld["type"] == "point"]
    if len(which) != 1:
        raise ValueError(f"a contact needs exactly one point load in {scene.name!r}, found {len(which)}")
    loads = copy.deepcopy(intact.loads)
    loads[which[0]]["region"] = {"nearest": [float(x) for x in intact.mesh.points[node]], "count": 1}
    return intact.with_loads(loads, {"contact_node": int(node)})


def _contact_nodes(scene, case, spec, model):
    """Per contact node of the model: the reference path of the intact scene loaded there."""
    family = getattr(getattr(model, "vademecum", None), "family", None)
    nodes = getattr(model, "contact_nodes", None) if family is None else family.nodes  # or a baseline's
    if nodes is None:
        raise ValueError(f"evaluation.kind = 'contact_nodes' needs a surface vademecum (pgd, pgd_svk on a 3D "
                         f"scene); {model.name!r} has no contact nodes")
    count = spec.get("count", 5)
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise ValueError(f"evaluation.count = {count!r}: expected a positive integer (contact nodes)")
    pick = np.asarray(nodes)[np.unique(np.linspace(0, len(nodes) - 1, min(count, len(nodes))).round().astype(int))]
    intact = dataclasses.replace(scene, cut=None)  # meshed once, shared by every node's scene
    points, first = [], None
    for node in pick.tolist():
        s = contact_scene(intact, node)
        ref, _ = cached_solve(s, case["backend"])
        U, lams = reference_states(ref)
        first = first or {"ref": ref, "scene": s}
        points += [EvaluationPoint({"node": node, "load_factor": float(lam)}, U[:, k],
                                   ref.monitors_at("load_factor", lam), float(lam), group=float(node))
                   for k, lam in enumerate(lams)]
    return Evaluation("contact_nodes", "load_factor", points, reference_steps=first, info={"nodes": pick.tolist()})


def build_evaluation(case: dict, scene, model=None) -> Evaluation:
    """The :class:`Evaluation` of a case entry (module docstring); ``model`` for the kinds
    in :data:`NEEDS_MODEL`."""
    spec = dict(case.get("evaluation") or {})
    kind = spec.pop("kind", case["training"]["kind"])
    if kind == "cut_lengths":
        return _cut_lengths(scene, case, spec, model)
    if kind == "contact_nodes":
        ev = _contact_nodes(scene, case, spec, model)
    elif kind == "path":
        ev = _path(scene, case, spec)
    elif kind == "positions":
        ev = _positions(scene, case, spec, case["training"])
    elif kind == "trajectory":
        ev = _trajectory(scene, case, spec)
    elif kind == "map":
        ev = _map(scene, case, spec)
    else:
        raise ValueError(f"evaluation.kind = {kind!r}; valid: {list(EVALUATION_KINDS)}")
    ref = ev.reference_steps.get("ref")
    if ref is not None:  # what the full model did there: a failure of the reference is data too
        ev.info.update(reference_status=ref.status, reference_message=ref.message[:300],
                       reference_energy_growth=float(ref.info.get("energy_growth_ratio", np.nan)))
    return ev
