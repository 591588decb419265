"""``tissuebench sweep --scene FILE --all-methods``: the sweep spec of a user's scene, written out.

:func:`scene_spec_text` builds a spec every registered method that applies to the scene can run
in (:mod:`.applicability`), with a held-out evaluation by default, so that no recommendation
rests on data a method has seen:

* **static scene**: a ``path`` case learning from every other state of the reference load path,
  measured on the states it left out (``held_out = true``) and past the path's top
  (``beyond``: the reference continued with the path's increment, so the validity radius is
  measured in the scene's units); the error of the recommendation is the headline
  (``claimed_error``: peak-normalised over the training range, its held-out states, quarter
  points and near rest: issue 52), the validity radius says how far past it each model holds;
  with a ``[parameters.position]``, a ``positions`` case
  (a few stored positions, held-out ones between them); the point-load vademecums (PGD) on an
  ``operators`` case when they apply.
* **dynamic scene**: a ``trajectory`` case measured on a run the model has not seen: another
  load amplitude (``load_scale``) between the two the training runs cover (the scene's, and
  :data:`_TRAINING_SCALES` of it: issue 42, a reduced model is trained over the amplitudes it
  is to be used at), or, where supports prescribe a displacement ``load_scale`` does not scale,
  a window after the training's horizon (one run); and an ``operators`` case (skinning-cubature
  without snapshots). A motion is ranked and reported by ``peak_rel_l2`` (the worst step's error
  over the run's largest displacement: a motion's headline, the same number as ``claimed_error``
  there), not by the relative RMSE over the history.

Each method gets a small grid of its main options (:data:`METHOD_OPTIONS`; a method registered
later runs with its defaults). The spec is a TOML file the user can read, edit and run again
(``tissuebench sweep SPEC.toml``); the methods that apply to no case are listed with why, one
line each.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

from ..cases.monitors import resolve_monitors
from ..cases.scene import load
from ..rom import METHODS
from .atomic_files import write_text
from .applicability import evaluation_why_not, load_scale_why_not, why_not
from .case_entry import CaseEntry
from .ladder import RUNG_METHODS

__all__ = ["METHOD_OPTIONS", "ERROR_METRIC", "scene_cases", "scene_spec_text", "write_scene_spec"]

#: the error a generated spec ranks and reports by, per analysis type (module docstring)
ERROR_METRIC = {"static": "claimed_error", "dynamic": "peak_rel_l2"}

#: the options a generated spec sweeps per method: (fixed options, grid, protocol overrides)
METHOD_OPTIONS = {
    "pod_linear": ({}, {"n_modes": [3, 5]}, {}),
    "pod_newton": ({}, {"n_modes": [3]}, {"latency_steps": 20, "warmup": 2}),
    "anm_pod": ({"eps": 1e-6, "max_segments": 1}, {"n_modes": [3, 5], "order": [3, 6]}, {}),
    "nearest": ({}, {}, {}),
    "pod_interp": ({}, {"n_modes": [3, 5], "interpolation": ["linear", "rbf"]}, {}),
    "anm_pod_interp": ({"order": 6}, {"n_modes": [3]}, {}),
    "podi": ({"order": 6}, {"n_modes": [3]}, {}),
    "grassmann": ({"order": 6}, {"n_modes": [3]}, {}),
    "pgd": ({}, {"n_modes": [6]}, {}),
    "pgd_svk": ({}, {"n_modes": [6]}, {}),
    "pgd_cutting": ({}, {"n_modes": [6]}, {}),
    "wsc": ({"rtol": 1e-3}, {"handles": [0.03, 0.05], "cubature_elements": [0.1]}, {}),
    # POD-Galerkin dynamics: the hyper-reduced model and its full-assembly ceiling, two basis sizes
    "pod_galerkin": ({}, {"n_modes": [20, 30], "hyper": ["ecsw", "none"]}, {}),
    "pgd_direct": ({"n_nodes": 50, "margin": 0.25}, {"pod_modes": [3, 8]}, {}),
    # the practitioner baselines: a Newton solve per step (seconds on an organ) is timed on 20 steps
    "linear_fe": ({}, {}, {}),
    "corotational_fe": ({}, {}, {"latency_steps": 20, "warmup": 2}),
    "coarse_fe": ({}, {"coarsening": [2]}, {"latency_steps": 20, "warmup": 2}),
}
_HELD_OUT_SCALE = 0.75  # a trajectory measured at another load amplitude than it learnt
_TRAINING_SCALES = (0.5,)  # the training's runs besides the scene's own amplitude: 0.75 lies between
_MARKER = "# Written by `tissuebench sweep --scene ... --all-methods`"


def scene_cases(scene, scene_name: str, variant: str | None = None) -> list[dict]:
    """The case entries of a scene (module docstring), held out by default."""
    base = {"name": scene_name, **({"variant": variant} if variant else {})}
    if scene.analysis["type"] == "static":
        cases = [{**base, "id": "path", "training": {"kind": "path", "every": 2},
                  "evaluation": {"kind": "path", "held_out": True, "beyond": [1.25, 1.5, 2.0]}}]
        if "position" in scene.parameters:
            cases.append({**base, "id": "positions",
                          "training": {"kind": "positions", "positions": 3, "load_steps": 4},
                          "evaluation": {"kind": "positions", "held_out": 2}})
        evaluation = {"kind": "cut_lengths"} if scene.cut is not None else {"kind": "contact_nodes", "count": 3}
        cases.append({**base, "id": "operators", "training": {"kind": "operators"}, "evaluation": evaluation})
        return cases
    training = {"kind": "trajectory"}
    if load_scale_why_not(scene):  # supports prescribe a displacement: a later window instead
        t_end, dt = float(scene.analysis["t_end"]), float(scene.analysis["dt"])
        held = {"kind": "trajectory", "t_end": 1.5 * t_end, "from_time": t_end + dt}
    else:
        held = {"kind": "trajectory", "load_scale": _HELD_OUT_SCALE}
        training["runs"] = [{"load_scale": s} for s in _TRAINING_SCALES]
    return [{**base, "id": "trajectory", "training": training, "evaluation": held},
            {**base, "id": "operators", "training": {"kind": "operators"}, "evaluation": held}]


def _method_options(name: str, scene) -> tuple[dict, dict, dict]:
    fixed, grid, protocol = METHOD_OPTIONS.get(name, ({}, {}, {}))
    fixed = dict(fixed)
    if name == "pgd_direct":  # an explicit scheme inside the step where the system is nonlinear
        fixed["integrator"] = "central_difference" if METHODS[name].note(scene) else "hht"
    if name == "wsc":
        fixed["cubature"] = "bgbc"
    if name == "linear_fe" and scene.analysis["type"] == "static":  # and Bro-Nielsen's condensed step
        grid["condensed"] = [False, True]
    return fixed, dict(grid), dict(protocol)


def _baselines_once(methods: list, cases: list[dict]) -> list:
    """A practitioner baseline (:data:`~tissuebench.studies.ladder.RUNG_METHODS`) learns nothing
    from its training: it runs in the first case it fits (the path, the trajectory), not again on
    the operators; at contact nodes only beside a point-load vademecum, whose accessible nodes
    (a layered cornea dome's anterior surface) it is measured on."""
    contact = {c["id"] for c in cases if c["evaluation"]["kind"] == "contact_nodes"}
    vademecum = any(set(fits) & contact for name, fits, *_ in methods
                    if METHODS[name].applies.point_load and name not in RUNG_METHODS)
    kept = []
    for name, fits, *rest in methods:
        if name in RUNG_METHODS:
            fits = [f for f in fits if f not in contact or vademecum]
            fits = [f for f in fits if f not in contact][:1] + [f for f in fits if f in contact]
        if fits:
            kept.append((name, fits, *rest))
    return kept


def _toml(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    return json.dumps(value)


def scene_spec_text(scene, scene_name: str, variant: str | None = None,
                    resolution: str = "ci") -> tuple[str, list[tuple[str, str]]]:
    """``(spec TOML text, [(method, why not)])`` of every registered method on ``scene``
    (referred to as ``scene_name`` in the spec: a path relative to the spec's folder)."""
    cases = scene_cases(scene, scene_name, variant)
    used, methods, left_out = set(), [], []
    for name in sorted(METHODS):
        cls = METHODS[name]
        fixed, grid, protocol = _method_options(name, scene)
        fits, reasons = [], []
        for c in cases:
            if c["training"]["kind"] not in cls.training_kinds:
                continue
            why = why_not(cls, scene, c["training"]["kind"], fixed) or evaluation_why_not(cls, CaseEntry.from_dict(c),
                                                                                        scene)
            if c["evaluation"]["kind"] in ("cut_lengths", "contact_nodes") and not why:
                needs = "cut_lengths" if cls.applies.needs_cut else "contact_nodes"
                why = "" if c["evaluation"]["kind"] == needs else f"measured on {needs}, not here"
            (reasons if why else fits).append(why or c["id"])
        if not fits:
            reasons = reasons or [why_not(cls, scene, k) for k in cls.training_kinds]
            distinct = list(dict.fromkeys(r for r in reasons if r)) or [
                f"learns from {list(cls.training_kinds)} training"]
            left_out.append((name, "; ".join(distinct)))
            continue
        methods.append((name, fits, fixed, grid, protocol))
    methods = _baselines_once(methods, cases)
    for _, fits, *_ in methods:
        used.update(fits)
    lines = [_MARKER + ": every registered method that applies to",
             f"# {scene.name}, with a held-out evaluation (no recommendation rests on data a method has seen).",
             "# Edit it and run it again with `tissuebench sweep THIS_FILE --out FOLDER`.",
             "[sweep]", f"name = {_toml(scene.name)}",
             f"description = {_toml(f'every method that applies to {scene.name}, held-out evaluation')}",
             f"resolution = {_toml(resolution)}",
             # the headline, peak-normalised (issue 52): over the training range in statics (how far
             # past it a model holds is its validity radius, on the continued reference), over the run
             # in motion
             f"error_metric = {_toml(ERROR_METRIC['static' if scene.analysis['type'] == 'static' else 'dynamic'])}",
             ""]
    for c in cases:
        if c["id"] not in used:
            continue
        lines += ["[[case]]"] + [f"{k} = {_toml(v)}" for k, v in c.items()] + [""]
    for name, fits, fixed, grid, protocol in methods:
        lines += ["[[method]]", f"name = {_toml(name)}", f"cases = {_toml(fits)}"]
        lines += [f"options = {_toml(fixed)}"] if fixed else []
        lines += [f"grid = {_toml(grid)}"] if grid else []
        lines += [f"protocol = {_toml(protocol)}"] if protocol else []
        lines.append("")
    if left_out:
        lines += ["# not applicable to this scene (tissuebench methods SCENE):"]
        lines += [f"#   {name}: {why}" for name, why in left_out]
    return "\n".join(lines) + "\n", left_out


def write_scene_spec(scene_path, out: Path, variant: str | None = None,
                     resolution: str = "ci") -> tuple[Path, list[tuple[str, str]]]:
    """Write the spec of the scene file ``scene_path`` beside the results folder ``out``
    (``<out>.spec.toml``; a file there that this function did not write is never replaced);
    returns its path and the methods left out with why."""

    scene = load(scene_path, resolution=resolution, variant=variant)
    if scene.is_fe:  # what run and scene check refuse is refused before any unit: a load on the clamp, a free
        resolve_monitors(scene, scene.to_problem())  # body, a monitor off the body
    spec_path = Path(f"{Path(out)}.spec.toml")
    if spec_path.exists() and (not spec_path.is_file() or not spec_path.read_text(
            encoding="utf-8", errors="replace").startswith(_MARKER)):
        raise FileExistsError(f"--out = {out}: the spec would replace {spec_path}, which tissuebench did not write; "
                              "choose another --out")
    spec_path.parent.mkdir(parents=True, exist_ok=True)
    try:
        rel = os.path.relpath(Path(scene_path).resolve(), spec_path.parent.resolve())
    except ValueError:  # another drive (Windows)
        rel = str(Path(scene_path).resolve())
    text, left_out = scene_spec_text(scene, rel, variant, resolution)
    write_text(spec_path, text, "the spec of --out")
    return spec_path, left_out
