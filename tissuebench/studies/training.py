"""Training sets of a sweep's case entry, built from cached reference runs.

A case entry of a sweep spec names what its methods learn from (``training``) with a
``kind`` (the ``training_kinds`` a method declares must include it):

``path``        the scene's reference load path (statics): the initial state and every
                converged state, the load factor as the parameter (``every = k`` keeps every
                k-th state counted back from the last; ``repeat = k`` duplicates the set,
                a rank-deficient training set for the extremes; ``runs = [{max_load_factor =
                3.1, load_steps = 7}]`` adds the last state of each run: :mod:`.path_runs`).
``positions``   one reference path per stored load position (``positions = n`` points of
                the scene's ``[parameters.position]`` range, or a list), each shortened by
                ``max_load_factor`` / ``load_steps``: ``Training.groups = {s: Training}``
                for PODI / Grassmann, and all states with ``{position, load_factor}`` as
                ``snapshots`` for the non-intrusive baselines.
``trajectory``  the scene's reference time integration (dynamics): stored states and
                velocities, ``{time, load_factor}`` per state, the dynamics system, the
                load history and dt; ``runs = [{load_scale = 0.5}, ...]`` adds runs of
                the scene at other parameters (one trajectory id per run).
``operators``   no snapshots: the backend (FE), or the assembled 1D model (its dynamics
                system for a dynamic scene), and the scene (``Training.scene``, on every training), for methods
                that build from operators (PGD).

Every training carries the scene's linear output functionals (``Training.outputs``).
Reference runs go through the content-hashed cache (:mod:`.reference.cache`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..cases import load
from ..cases.monitors import linear_outputs
from ..reference.formulation import scene_backend
from ..refsolvers.line_models import assemble_line_model
from ..rom import Training
from .kinds import Kind, no_references
from .limits import check_nothing, check_path_training, check_positions_training, check_trajectory_training
from .path_runs import merge_states, path_run_scenes, path_run_states
from .path_states import reference_states, require_converged, training_indices
from ..reference import cached_solve, dynamics_system

if TYPE_CHECKING:  # annotations only: case_entry imports this module (through evaluation)
    from .case_entry import CaseEntry

__all__ = ["TRAINING_KINDS", "case_scene", "build_training", "training_references", "lattice_positions",
           "reference_states", "training_indices"]


def case_scene(case: CaseEntry):
    """The scene of a case entry (``name``, ``variant``, ``resolution``, on the mesh of its
    ``mesh.<resolution>`` builder parameters if any, evaluated at its ``mu``: e.g.
    ``{nu = 0.499}`` trains and measures every method of that case at that parameter)."""
    scene = load(case.name, resolution=case.resolution, variant=case.variant)
    mesh = case.mesh_at_resolution()
    if mesh:
        scene = scene.with_mesh(mesh)
    return scene.at(case.mu) if case.mu else scene


def lattice_positions(scene, spec) -> np.ndarray:
    """The stored positions: ``spec`` points evenly over the scene's position range, or a list."""
    if "position" not in scene.parameters:
        raise ValueError(f"{scene.name}: training.kind = 'positions' needs a [parameters.position] table")
    lo, hi = scene.parameters["position"]["range"]
    if isinstance(spec, list):
        return np.asarray(spec, float)
    return np.linspace(lo, hi, int(spec))


def _outputs(scene, problem) -> dict:
    return linear_outputs(scene, problem) if scene.is_fe else {}


def _path(scene, case, spec, info):
    ref, _ = cached_solve(scene, case.backend)
    require_converged(ref)
    # the initial state (load factor 0, at rest) belongs to the path: known exactly for free,
    # it anchors interpolation between the origin and the first converged state
    U = ref.displacement.reshape(len(ref.displacement), -1).T
    lams = np.asarray(ref.steps, float)
    keep = training_indices(len(lams), spec.get("every", 1))
    # runs: one more state each, at its own load factor (path_runs), merged in load-factor order
    U, lams = merge_states(U[:, keep], lams[keep], *path_run_states(scene, spec.get("runs"), case.backend))
    keep = np.tile(np.arange(len(lams)), int(spec.get("repeat", 1)))  # a duplicated snapshot set (extremes)
    be = scene_backend(scene, case.backend, ref.problem)
    return Training(U[:, keep], [{"load_factor": float(lams[k])} for k in keep], be,
                    outputs=_outputs(scene, ref.problem), info={**info, "reference_status": ref.status})


def positional_scene(scene, s, spec):
    """The scene with its load at position ``s`` and the path shortened as ``spec`` says."""
    mu = {"position": float(s)}
    mu.update({k: spec[k] for k in ("max_load_factor", "load_steps") if k in spec})
    return scene.at(mu)


#: a stored position whose reference stalls is solved again with 2x, then 4x the load steps
POSITION_RETRIES = (2, 4)


def positional_reference(scene, s, spec, backend):
    """``(reference, retried load steps or None)`` at stored position ``s``: where Newton stalls
    (a point load on one element can need a finer path: issue 27, 0.952 of the load with 25
    iterations), the path is solved again with :data:`POSITION_RETRIES` times its increments."""
    ref, _ = cached_solve(positional_scene(scene, s, spec), backend)
    steps = int(spec.get("load_steps", scene.analysis.get("load_steps", 1)))
    for factor in POSITION_RETRIES:
        if ref.status == "success":
            break
        finer = {**spec, "load_steps": steps * factor}
        ref, _ = cached_solve(positional_scene(scene, s, finer), backend)
        if ref.status == "success":
            return ref, steps * factor
    return ref, None


def _positions(scene, case, spec, info):
    groups, cols, params, failed, retried = {}, [], [], [], {}
    for s in lattice_positions(scene, spec.get("positions", 5)):
        ref, finer = positional_reference(scene, s, spec, case.backend)
        if finer is not None:
            retried[float(s)] = finer
        if ref.status != "success":  # the other positions still run (and are cached): all failures named
            failed.append(f"position {s:g}: {ref.message}")
            continue
        U, lams = reference_states(ref)
        be = scene_backend(scene, case.backend, ref.problem)
        groups[float(s)] = Training(U, [{"load_factor": float(x)} for x in lams], be)
        cols.append(U)
        params += [{"position": float(s), "load_factor": float(x)} for x in lams]
    if failed:
        tried = f"with {int(spec.get('load_steps', scene.analysis.get('load_steps', 1)))} load steps and " \
                f"{' and '.join(str(f) + 'x' for f in POSITION_RETRIES)} as many"
        raise RuntimeError(f"{scene.name}: the reference did not converge at {len(failed)} stored position(s) "
                           f"({tried}): " + "; ".join(failed))
    first = next(iter(groups.values()))
    return Training(np.hstack(cols), params, first.backend, groups=groups,
                    outputs=_outputs(scene, first.backend.problem),
                    info={**info, "retried_positions": retried} if retried else info)


def _trajectory(scene, case, spec, info):
    runs = [{}] + list(spec.get("runs", []))
    cols, vels, params, ids = [], [], [], []
    for k, mu in enumerate(runs):
        ref, _ = cached_solve(scene.at(mu), case.backend)
        if ref.status != "success":
            raise RuntimeError(f"{scene.name}: training run {mu or 'base'} failed: {ref.message}")
        n = len(ref.steps)
        cols.append(ref.displacement.reshape(n, -1).T)
        vels.append(ref.velocity.reshape(n, -1).T)
        hist = scene.at(mu).history
        params += [{"time": float(t), "load_factor": float(hist(t))} for t in ref.steps]
        ids += [k] * n
    system = dynamics_system(scene, case.backend)
    backend = scene_backend(scene, case.backend) if scene.is_fe else None
    return Training(np.hstack(cols), params, backend, free_dofs=np.asarray(system.free),
                    velocities=np.hstack(vels), trajectories=np.array(ids), system=system,
                    history=scene.history, dt=float(scene.analysis["dt"]),
                    outputs=_outputs(scene, backend.problem) if backend else {}, info=info)


def _operators(scene, case, spec, info):
    if scene.is_fe:
        pb = scene.to_problem()
        return Training(backend=scene_backend(scene, case.backend, pb), outputs=_outputs(scene, pb), info=info)
    if scene.analysis["type"] == "dynamic":
        return Training(system=dynamics_system(scene), info=info)
    return Training(system=assemble_line_model(scene.line_model()), info=info)


def _positions_references(case: CaseEntry, scene) -> list:
    spec = case.training
    return [positional_scene(scene, s, spec) for s in lattice_positions(scene, spec.get("positions", 5))]


def _trajectory_references(case: CaseEntry, scene) -> list:
    return [scene.at(mu) for mu in [{}] + list(case.training.get("runs", []))]


def _path_references(case: CaseEntry, scene) -> list:
    return [scene] + path_run_scenes(scene, case.training.get("runs"))


#: the training kinds (:class:`~.kinds.Kind`): options, value checks, builder, references read
TRAINING_KINDS = {k.name: k for k in (
    Kind("path", frozenset({"every", "repeat", "runs"}), _path, _path_references, check_path_training,
         analysis="static"),
    Kind("positions", frozenset({"positions", "max_load_factor", "load_steps"}), _positions, _positions_references,
         check_positions_training, analysis="static"),
    Kind("trajectory", frozenset({"runs"}), _trajectory, _trajectory_references, check_trajectory_training,
         analysis="dynamic"),
    Kind("operators", frozenset(), _operators, no_references, check_nothing),
)}
# what each kind is and what its keys mean (the spec-format reference of the documentation; the
# module docstring says more)
TRAINING_KIND_DOCS = {
    "path": ("the scene's reference load path (statics): every converged state, the load factor as the parameter",
             {"every": "keep every k-th state, counted back from the last (default 1)",
              "repeat": "duplicate the set k times (a rank-deficient training set, for the extremes)",
              "runs": "one more state per run, the last of the scene solved to another load factor: "
                      "`[{ max_load_factor = 3.1, load_steps = 7 }]` (what `tissuebench fit` adds)"}),
    "positions": ("one reference path per stored load position of the scene's `[parameters.position]`",
                  {"positions": "how many positions over the range (default 5), or a list of them",
                   "max_load_factor": "each path's last load factor", "load_steps": "each path's increments"}),
    "trajectory": ("the scene's reference time integration (dynamics): states, velocities, times",
                   {"runs": "more runs of the scene at other parameters: `[{ load_scale = 0.5 }]`"}),
    "operators": ("no snapshots: the full model's operators (PGD vademecums, the practitioner baselines)", {}),
}


def training_references(case: CaseEntry, scene=None) -> list:
    """The scenes whose reference runs :func:`build_training` reads for ``case`` (on its
    ``case.backend``), known from the case entry alone, nothing solved: the dask executor
    computes each as a task the unit waits for. Not declared: a stored position solved again
    with more load steps (:func:`positional_reference`: only when the first run stalled)."""
    scene = scene or case_scene(case)
    return TRAINING_KINDS[case.training_kind].references(case, scene)


def build_training(case: CaseEntry, scene=None) -> Training:
    """The :class:`~tissuebench.rom.Training` of a case entry (module docstring)."""
    scene = scene or case_scene(case)
    spec, kind = case.training_options(), case.training_kind
    info = {"case": scene.name, "variant": scene.variant, "resolution": scene.resolution,
            "backend": case.backend, "training_kind": kind, "scene_hash": scene.content_hash()}
    training = TRAINING_KINDS[kind].build(scene, case, spec, info)
    # the scene travels with every training (Training.scene): PGD builds from its geometry, the
    # practitioner baselines (rom.fe_baselines) rebuild it on a coarser mesh and read its integrator
    training.scene = scene
    return training
