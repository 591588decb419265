"""Evaluation sets: where a unit's reduced model is measured against the full reference.

The case entry's ``evaluation`` table has a ``kind`` (default: the training's):

``path``        the reference load path's load factors (``every`` thins them; ``held_out =
                true`` keeps only the states the training left out: every other state with
                ``training.every = 2``), and the range the training claims at load factors the
                path has no state at (:mod:`.path_range`: the quarter points and the middle of
                every training interval, and near rest 1/8, 1/16, 1/64 and 1/1024 of the first
                training state, from the path solved with a finer increment and short runs
                from rest; ``refine = r`` cuts the interval into ``r``, default 4; ``refine =
                1``: the path's states only), driven in increasing order. ``beyond = [1.5, 2]``
                measures past the path, up to those multiples of its top: the reference is
                continued with the path's increment (:func:`~.path_range.beyond_scene`: at most
                ``BEYOND_MAX_INCREMENTS`` times the path's increments past it, halved at most
                ``BEYOND_MAX_CUTS`` times where Newton does not converge, until it stalls;
                its last converged load factor is
                ``info["reference_limit"]``) and every converged state past the top is a point
                with its reference (``beyond``: not in the unit's error columns, which stay the
                path's; in the validity radius only with ``extrapolation = true``: by default
                "valid to" stops at the training range, :func:`~.metrics.summarise_points`);
                a factor past where the reference stopped is a point without one (only its
                step status is measured: extrapolation must be flagged, not hidden).
``positions``   held-out load positions (``held_out = n`` points at the midpoints and
                quarter points of the training lattice, or a list), each with its own
                reference path: every (position, load factor) is a point.
``trajectory``  the scene's reference time integration, the model stepped from rest (or
                the reference's initial state) with the load of each step; errors at the
                stored reference steps; ``t_end`` (e.g. 10x the paper's horizon) runs a
                longer reference; ``from_time`` keeps only the steps from that time on (a
                later window than the training's: the model steps from the start, its error is
                measured where it has not seen the answer); ``load_scale`` scales the loads
                (another amplitude, reaching the model as its load factor). Where the load
                ends constant, the long-run energy drift
                of the reference and of the model (:mod:`.energy`).
``map``         the reference at each parameter of ``mus = [{...}, ...]`` (scene parameters a
                model represents: ``position``, ``load_scale``, ``max_load_factor``; see
                :mod:`.applicability`), one point per entry, each reference run at the full
                path's last load factor. ``load_scale`` and ``max_load_factor`` reach the
                model as its load factor (``load_scale * last load factor``).
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
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ..refsolvers.backends import make_backend
from ..reference.cut import cut_references
from .energy import EnergyDrift, conservative_window, reference_drift
from .kinds import Kind, no_references
from .limits import (MAX_LOAD_SCALE, check_contact_nodes_evaluation, check_cut_lengths_evaluation,
                     check_map_evaluation, check_path_evaluation, check_positions_evaluation,
                     check_trajectory_evaluation)
from ..reference import cached_solve
from .path_range import DEFAULT_REFINE, beyond_scene, interval_every, range_scenes, range_states
from .path_states import reference_states, training_indices
from .training import lattice_positions, positional_reference, positional_scene

if TYPE_CHECKING:  # annotations only: case_entry imports this module's kind registry
    from .case_entry import CaseEntry

__all__ = ["EVALUATION_KINDS", "EvaluationPoint", "Evaluation", "build_evaluation", "evaluation_references"]



@dataclass
class EvaluationPoint:
    mu: dict
    reference: np.ndarray | None
    monitors: dict
    x: float
    group: float | None = None  # held-out position (positions kind)
    beyond: bool = False  # past the training path's top (evaluation.beyond): in the validity radius only


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
    history: object = None  # trajectory: the load factor the model is driven with, history(t) (load_scale folded in)
    reference_step_s: float | None = None  # the full step, when the evaluation timed it itself
    # trajectory: the reference's long-run energy drift over the constant-load window (its
    # window_start and scale are the model's too, :mod:`.energy`); None without such a window
    reference_energy: EnergyDrift | None = None


def _path(scene, case, spec):
    ref, _ = cached_solve(scene, case.backend)
    U, lams = reference_states(ref)
    every = int(spec.get("every", 1))
    idx = np.arange(len(lams))[::-1][::every][::-1]
    if spec.get("held_out"):  # the states the path training did not keep (training._path's choice)
        trained = set(training_indices(len(lams) + 1, case.training.get("every", 1)) - 1)
        idx = np.array([k for k in idx if k not in trained], dtype=int)
    points = [EvaluationPoint({"load_factor": float(lams[k])}, U[:, k], ref.monitors_at("load_factor", lams[k]),
                              float(lams[k])) for k in idx]
    # the range the training claims, between its states and near rest (path_range)
    between, range_info = range_states(scene, case.backend, interval_every(case), spec.get("refine", DEFAULT_REFINE),
                                       lams)
    points += [EvaluationPoint({"load_factor": lam}, u, monitors, lam) for lam, u, monitors in between]
    points.sort(key=lambda p: p.x)  # driven in increasing order
    top = float(lams[-1]) if len(lams) else float(scene.analysis.get("max_load_factor", 1.0))
    info = {"reference_status": ref.status, "reference_top": top, **load_measure(scene, ref, case.backend),
            **range_info, "extrapolation": bool(spec.get("extrapolation", False))}
    factors = sorted(float(f) for f in spec.get("beyond", []))
    reached = top
    if factors and factors[-1] > 1.0 and ref.status == "success":
        ext, _ = cached_solve(beyond_scene(scene, factors[-1] * top), case.backend)
        Ue, lams_e = reference_states(ext) if len(ext.steps) > 1 else (np.zeros((U.shape[0], 0)), np.zeros(0))
        past = [k for k, lam in enumerate(lams_e) if top * (1 + 1e-12) < lam <= factors[-1] * top * (1 + 1e-9)]
        points += [EvaluationPoint({"load_factor": float(lams_e[k])}, Ue[:, k],
                                   ext.monitors_at("load_factor", lams_e[k]), float(lams_e[k]), beyond=True)
                   for k in past]
        reached = float(lams_e[-1]) if len(lams_e) else top
        info.update(reference_limit=reached, reference_beyond_status=ext.status,
                    reference_beyond_message=ext.message[:300])
    points += [EvaluationPoint({"load_factor": f * top}, None, {}, f * top, beyond=True) for f in factors
               if f * top > reached * (1 + 1e-9)]
    return Evaluation("path", "load_factor", points, reference_steps={"ref": ref, "scene": scene}, info=info)


def load_measure(scene, ref, backend: str) -> dict:
    """What load factor 1 is in the scene's units (``x_scale``, ``x_unit``): the magnitude of the
    net force of its point, traction and body loads (force unit), else its pressure (stress
    unit), else the largest prescribed displacement (length unit); ``{}`` for the 1D models."""
    if not scene.is_fe or ref.problem is None:
        return {}
    units = scene.units
    kinds = {ld["type"] for ld in scene.loads}
    if kinds & {"point", "traction", "body"}:
        be = make_backend(backend, ref.problem)
        f = be.external_force(np.zeros(be.ndof), 1.0).reshape(-1, 3).sum(axis=0)
        return {"x_scale": float(np.linalg.norm(f)), "x_unit": units.get("force", "")}
    if kinds & {"pressure", "follower_pressure"}:
        return {"x_scale": max(abs(float(ld["value"])) for ld in scene.loads if "pressure" in ld["type"]),
                "x_unit": units.get("stress", "")}
    u = np.abs(ref.problem.prescribed_values(1.0))
    return {"x_scale": float(u.max()), "x_unit": units.get("length", "")} if u.size and u.max() > 0 else {}


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
        ref, _ = positional_reference(scene, s, training_spec, case.backend)
        U, lams = reference_states(ref)
        d = float(np.min(np.abs(lattice - s)))
        first = first or {"ref": ref, "scene": positional_scene(scene, s, training_spec)}
        points += [EvaluationPoint({"load_factor": float(lam), "position": float(s)}, U[:, k],
                                   ref.monitors_at("load_factor", lam), d, group=float(s))
                   for k, lam in enumerate(lams)]
    pos = scene.parameters["position"]
    unit = pos.get("unit") or (scene.units.get("length", "") if pos.get("frame") != "bbox"
                               else "fraction of the bounding box")
    return Evaluation("positions", "distance", points, reference_steps=first,
                      info={"lattice": lattice.tolist(), "spacing": float(np.diff(lattice).min()), "x_scale": 1.0,
                            "x_unit": unit})


def _scaled(history, scale: float):
    """``history`` times ``scale`` (the load factor of a run whose loads ``load_scale`` scaled)."""
    return history if scale == 1.0 else (lambda t: scale * history(t))


def _trajectory_run(scene, spec: dict):
    """The reference run a trajectory evaluation reads: the scene at its ``load_scale`` and ``t_end``."""
    return scene.at({k: v for k, v in spec.items() if k in ("load_scale", "t_end")})


def _trajectory(scene, case, spec):
    run = _trajectory_run(scene, spec)
    ref, _ = cached_solve(run, case.backend)
    n = len(ref.steps)
    U = ref.displacement.reshape(n, -1)
    # the model is driven by the load factor: the run's loads are load_scale times the training's
    # (exact: load_scale is refused at spec load where supports prescribe a displacement)
    hist = _scaled(scene.history, float(spec.get("load_scale", 1.0)))
    dt = float(run.analysis["dt"])
    start = float(spec.get("from_time", -np.inf)) - 1e-9 * dt
    # the initial state stays the first point (the model starts from it); the window's steps follow
    points = [EvaluationPoint({"time": float(t), "load_factor": float(hist(t))}, U[k], ref.monitors_at("time", t),
                              float(t)) for k, t in enumerate(ref.steps) if k == 0 or t >= start]
    state0 = {"u": U[0], "v": ref.velocity.reshape(n, -1)[0]}
    t_end = float(run.analysis["t_end"])
    t_c = conservative_window(hist, dt, t_end, float(ref.steps[0]))
    return Evaluation("trajectory", "time", points, dt=dt, state0=state0, reference_steps={"ref": ref, "scene": run},
                      info={"reference_status": ref.status, "t_end": t_end, "x_scale": 1.0,
                            "x_unit": scene.units.get("time", "s")}, history=hist,
                      reference_energy=None if t_c is None else reference_drift(ref.table, t_c, t_end))


def model_mu(mu: dict, load_factor: float) -> dict:
    """The parameters a model steps with for scene parameters ``mu`` whose reference ends at
    ``load_factor``: ``load_scale`` folded into the load factor, ``max_load_factor`` already in it
    (:mod:`.applicability` refuses, at spec load, any key a model does not read)."""
    out = {k: v for k, v in mu.items() if k not in ("load_scale", "max_load_factor")}
    out["load_factor"] = float(mu.get("load_scale", 1.0)) * float(load_factor)
    return out


def _map(scene, case, spec):
    points, first = [], None
    for mu in spec.get("mus", []):
        s = scene.at(mu)
        ref, _ = cached_solve(s, case.backend)
        U, lams = reference_states(ref)
        first = first or {"ref": ref, "scene": s}
        points.append(EvaluationPoint(model_mu(mu, lams[-1]), U[:, -1], ref.monitors_at("load_factor", lams[-1]),
                                      float(len(points))))
    return Evaluation("map", "index", points, reference_steps=first or {})


def _cut_lengths(scene, case, spec, model):
    """Per cut length of the model's incision: the linear FE of the same cut mesh (module docstring)."""
    strip, force = model.incision_strip(), model.contact_force()
    if strip is None or force is None:
        raise ValueError(f"evaluation.kind = 'cut_lengths' needs a cutting model (one with an incision strip); "
                         f"{model.name!r} has none")
    solved = cut_references(scene, case.backend, strip, force)  # once per process and strip
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
    nodes = model.contact_nodes()  # a vademecum's parameter nodes, or a baseline's accessible surface
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
        ref, _ = cached_solve(s, case.backend)
        U, lams = reference_states(ref)
        first = first or {"ref": ref, "scene": s}
        points += [EvaluationPoint({"node": node, "load_factor": float(lam)}, U[:, k],
                                   ref.monitors_at("load_factor", lam), float(lam), group=float(node))
                   for k, lam in enumerate(lams)]
    return Evaluation("contact_nodes", "load_factor", points, reference_steps=first, info={"nodes": pick.tolist()})


def _path_references(case: CaseEntry, scene) -> list:
    refine = case.evaluation.get("refine", DEFAULT_REFINE)
    return [scene] + [run for _, run in range_scenes(scene, interval_every(case), refine)]


def _positions_references(case: CaseEntry, scene) -> list:
    lattice = lattice_positions(scene, case.training.get("positions", 5))
    held = case.evaluation.get("held_out")
    return [positional_scene(scene, s, case.training) for s in _held_out(lattice, held)]


def _trajectory_references(case: CaseEntry, scene) -> list:
    return [_trajectory_run(scene, case.evaluation)]


def _map_references(case: CaseEntry, scene) -> list:
    return [scene.at(mu) for mu in case.evaluation.get("mus", [])]


#: the evaluation kinds (:class:`~.kinds.Kind`): options, value checks, builder, references read
EVALUATION_KINDS = {k.name: k for k in (
    Kind("path", frozenset({"every", "beyond", "held_out", "refine", "extrapolation"}),
         lambda sc, c, o, m: _path(sc, c, o), _path_references, check_path_evaluation),
    Kind("positions", frozenset({"held_out"}), lambda sc, c, o, m: _positions(sc, c, o, c.training),
         _positions_references, check_positions_evaluation),
    Kind("trajectory", frozenset({"t_end", "load_scale", "from_time"}), lambda sc, c, o, m: _trajectory(sc, c, o),
         _trajectory_references, check_trajectory_evaluation),
    Kind("map", frozenset({"mus"}), lambda sc, c, o, m: _map(sc, c, o), _map_references, check_map_evaluation),
    # the cut meshes and contact nodes come from the model: their references are solved in the unit
    Kind("cut_lengths", frozenset({"steps_per_length"}), _cut_lengths, no_references,
         check_cut_lengths_evaluation, needs_model=True),
    Kind("contact_nodes", frozenset({"count"}), _contact_nodes, no_references, check_contact_nodes_evaluation,
         needs_model=True),
)}
# what each kind is and what its keys mean (the spec-format reference of the documentation; the
# module docstring says more)
EVALUATION_KIND_DOCS = {
    "path": ("the reference load path's states, in increasing load factor",
             {"every": "keep every k-th state", "held_out": "`true`: only the states a path training with "
              "`every = 2` (or more) left out",
              "beyond": "multiples of the path's top to measure up to, the reference continued past it until it "
                        "stalls: `[2.0]`",
              "refine": "parts each training interval is cut into for the points between training states (default "
                        "4: the quarter points and middle; `1`: the path's states only), and the points near rest",
              "extrapolation": "`true`: the validity radius counts the points past the training range (`beyond`); "
                               "by default it stops at the training range"}),
    "positions": ("held-out load positions, each with its reference path",
                  {"held_out": "how many (midpoints and quarter points of the training lattice), or a list"}),
    "trajectory": ("the scene's reference time integration, the model stepped from the start",
                   {"t_end": "a longer horizon than the scene's (at least its `dt`: one step)",
                    "load_scale": f"another load amplitude: not 0, at most {MAX_LOAD_SCALE:g} in magnitude "
                                  "(`MAX_LOAD_SCALE`)",
                    "from_time": "measure only from this time on (a window after the training's)"}),
    "map": ("the reference at each listed parameter", {"mus": "the parameters: `[{ position = 0.5 }, ...]`"}),
    "cut_lengths": ("a scalpel advancing along the scene's `[cut]` incision, against the linear FE of each cut mesh",
                    {"steps_per_length": "timed haptic steps per cut length"}),
    "contact_nodes": ("contact nodes of a surface vademecum, each against the scene's reference with the point load "
                      "moved there", {"count": "how many contact nodes"}),
}
#: the kinds built after the model (the incision strip, the contact nodes)
NEEDS_MODEL = tuple(name for name, k in EVALUATION_KINDS.items() if k.needs_model)


def evaluation_references(case: CaseEntry, scene) -> list:
    """The scenes whose reference runs :func:`build_evaluation` reads for ``case``, known from the
    case entry alone, nothing solved (see :func:`~.training.training_references`). Not declared:
    the continuation of a path past its top (``beyond``: its length is the reference's last load
    factor, and it is run only when the path succeeded), the kinds that need the model
    (:data:`NEEDS_MODEL`), a held-out position solved again with more load steps."""
    return EVALUATION_KINDS[case.evaluation_kind].references(case, scene)


def build_evaluation(case: CaseEntry, scene, model=None) -> Evaluation:
    """The :class:`Evaluation` of a case entry (module docstring); ``model`` for the kinds
    in :data:`NEEDS_MODEL`."""
    spec, kind = case.evaluation_options(), case.evaluation_kind
    if kind not in EVALUATION_KINDS:
        raise ValueError(f"evaluation.kind = {kind!r}; valid: {list(EVALUATION_KINDS)}")
    ev = EVALUATION_KINDS[kind].build(scene, case, spec, model)
    if kind == "cut_lengths":
        return ev
    ref = ev.reference_steps.get("ref")
    if ref is not None:  # what the full model did there: a failure of the reference is data too
        ev.info.update(reference_status=ref.status, reference_message=ref.message[:300],
                       reference_energy_growth=float(ref.info.get("energy_growth_ratio", np.nan)))
    return ev
