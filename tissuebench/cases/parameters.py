"""Parameterised scenes: the ``[parameters]`` table and :meth:`Scene.at` (``scene.at(mu)``).

A scene may declare the parameters a reduced model can be evaluated at, beyond the load
factor of its load path. Each becomes a key of ``mu`` in :meth:`Scene.at`, which returns a
new scene (its :meth:`~tissuebench.cases.scene.Scene.content_hash` includes ``mu``).

``[parameters.position]`` moves the point of one load along a line::

    [parameters.position]
    load = 0                  # index of the [[load]] entry whose point moves
    axis = "x"                # the coordinate the position sets
    point = [0.5, 1.0, 0.5]   # the other coordinates (the ``axis`` entry is replaced)
    frame = "bbox"            # point and range as fractions of the bounding box ("absolute" default)
    range = [0.35, 0.65]      # the positions a study may sample (training lattice, held out)

The moved load becomes one point force at that point, spread by the shape functions of
its cell (``distribute = "interpolate"``), so the load and the response move continuously
with the position (a nearest-node load would jump from node to node).

Analysis overrides (``mu`` keys ``max_load_factor``, ``load_steps``, ``t_end``, ``dt``,
``integrator``) let a study shorten a training path, lengthen a time horizon, change the time
step or the reference's integrator (the scene's ``integrator_options`` belong to its own
integrator and are dropped with another one);
``load_scale`` multiplies every load's value (training runs at other amplitudes, loads past
the training envelope); a key of the scene's material (``nu``, ``E``, ``mu1`` ...) replaces
that parameter (validated as in the scene file: nu -> 0.5 studies). All are part of the hash.
"""
from __future__ import annotations

import copy

from .schema import AXES, accepts, c_enum, c_int_range, c_num, c_pos, c_str, c_vec3, check_table, fail, key_text
from .sections import INTEGRATOR_NAMES, MAX_LOAD_STEPS, MAX_TIME_STEPS, check_material

__all__ = ["PARAMETER_KINDS", "ANALYSIS_OVERRIDES", "check_parameters_table", "apply_mu"]

_POSITION = {"load": accepts("an integer >= 0")(lambda p, v: _c_index(p, v)), "axis": c_enum(*AXES), "point": c_vec3,
             "frame": c_enum("absolute", "bbox"),
             "range": accepts("`[low, high]`, low < high")(lambda p, v: _c_range(p, v)), "description": c_str,
             "unit": c_str}
PARAMETER_KINDS = {"position": _POSITION}
# what each key means (the scene-format reference of the documentation)
POSITION_DOC = {
    "load": "the index of the `[[load]]` entry (a point load) whose point moves",
    "axis": "the coordinate the position sets", "point": "the other coordinates (the `axis` entry is replaced)",
    "frame": "`\"bbox\"`: `point` and `range` as fractions of the bounding box (default `\"absolute\"`)",
    "range": "`[low, high]`: the positions a study may sample", "description": "documentation",
    "unit": "documentation: the unit of the position",
}
ANALYSIS_OVERRIDES_DOC = {
    "max_load_factor": "a static path's last load factor", "load_steps": "a static path's increments",
    "t_end": "a dynamic run's end time", "dt": "a dynamic run's time step",
    "integrator": "the reference's time integrator (the scene's `integrator_options` are dropped with another one)",
}
_STATIC_KEYS, _DYNAMIC_KEYS = ("max_load_factor", "load_steps"), ("t_end", "dt")  # integrator: below
ANALYSIS_OVERRIDES = {"max_load_factor": c_pos, "load_steps": c_int_range(1, MAX_LOAD_STEPS), "t_end": c_pos,
                      "dt": c_pos, "integrator": c_enum(*INTEGRATOR_NAMES)}


def _c_index(path, v):
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        fail(path, v, "expected a non-negative integer (index of a [[load]] entry)")
    return v


def _c_range(path, v):
    if not (isinstance(v, list) and len(v) == 2):
        fail(path, v, "expected [low, high]")
    lo, hi = (c_num(f"{path}[{i}]", x) for i, x in enumerate(v))
    if not lo < hi:
        fail(path, v, "expected low < high")
    return [lo, hi]


def check_parameters_table(path, raw, loads) -> dict:
    """The validated ``[parameters]`` table (``{name: spec}``) of a scene with ``loads``."""
    if not isinstance(raw, dict):
        fail(path, raw, "expected a table of parameter tables")
    out = {}
    for name, spec in raw.items():
        if name not in PARAMETER_KINDS:
            fail(f"{path}.{key_text(name)}", spec, f"unknown parameter; valid: {sorted(PARAMETER_KINDS)}")
        spec = check_table(f"{path}.{name}", spec, PARAMETER_KINDS[name],
                           required=("load", "axis", "point", "range"))
        if spec["load"] >= len(loads):
            fail(f"{path}.{name}.load", spec["load"], f"the scene has {len(loads)} [[load]] entries")
        if loads[spec["load"]]["type"] != "point":
            fail(f"{path}.{name}.load", spec["load"], "the position parameter moves a point load")
        spec.setdefault("frame", "absolute")
        out[name] = spec
    return out


def apply_mu(scene_fields: dict, parameters: dict, mu: dict, who: str) -> dict:
    """New ``loads`` / ``analysis`` / ``material`` of a scene evaluated at ``mu`` (ValueError
    naming a bad key or value)."""
    if not isinstance(mu, dict):
        raise TypeError(f"{who}.at: mu must be a mapping of parameters, got {type(mu).__name__}")
    loads, analysis = copy.deepcopy(scene_fields["loads"]), dict(scene_fields["analysis"])
    material = dict(scene_fields["material"]) if scene_fields.get("material") else None
    material_keys = sorted(k for k in (material or {}) if k not in ("name", "fibres"))
    valid = sorted(parameters) + sorted(ANALYSIS_OVERRIDES) + ["load_scale"] + material_keys
    for key, value in mu.items():
        if key in material_keys:
            material[key] = value  # validated with the whole material below
            continue
        if key in ANALYSIS_OVERRIDES:
            kind = analysis.get("type")
            if key in _STATIC_KEYS and kind != "static" or key in _DYNAMIC_KEYS and kind != "dynamic":
                # accepted, it would change nothing: a parameter study that varies nothing
                fail(f"{who}: mu.{key}", value, f"the scene's analysis is {kind!r}; {key} is a parameter of a "
                     f"{'static' if key in _STATIC_KEYS else 'dynamic'} analysis")
            if key == "integrator":
                if analysis.get("type") != "dynamic":
                    fail(f"{who}: mu.integrator", value, "the scene is not dynamic (no time integrator to change)")
                if value != analysis.get("integrator"):  # the options configure the scene's own integrator
                    analysis.pop("integrator_options", None)
            analysis[key] = ANALYSIS_OVERRIDES[key](f"mu.{key}", value)
            if key in ("t_end", "dt") and "dt" in analysis and "t_end" in analysis \
                    and not analysis["t_end"] / analysis["dt"] <= MAX_TIME_STEPS:
                n = analysis["t_end"] / analysis["dt"]
                fail(f"mu.{key}", value, f"t_end / dt = {n:.3g} time steps; at most {MAX_TIME_STEPS}")
            if key in ("max_load_factor", "load_steps"):
                analysis["stop_at_divergence"] = False  # a shortened path runs to its end
        elif key == "load_scale":
            scale = c_num("mu.load_scale", value)
            for ld in loads:
                v = ld["value"]
                ld["value"] = [scale * x for x in v] if isinstance(v, list) else scale * v
        elif key == "position":
            spec = parameters["position"] if "position" in parameters else fail(
                f"{who}: mu.position", value, f"the scene declares no [parameters.position]; valid keys: {valid}")
            s = c_num("mu.position", value)
            point = list(spec["point"])
            point[AXES[spec["axis"]]] = s
            load = loads[spec["load"]]
            region = {"nearest": point}
            if spec["frame"] == "bbox":
                region["frame"] = "bbox"
            load.update(region=region, distribute="interpolate")
        else:
            fail(f"{who}: mu.{key_text(key)}", value, f"not a parameter of this scene; valid keys: {valid}")
    out = {"loads": loads, "analysis": analysis}
    if material is not None and any(k in material_keys for k in mu):
        out["material"] = check_material("mu (material)", material)
    return out
