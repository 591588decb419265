"""The sweep specs a fit runs: the scene's generated spec, one family per case, grown round by round.

A fit never measures anything itself: every round is a sweep spec (TOML, the format of
:mod:`~tissuebench.studies.spec`) run by :func:`~tissuebench.studies.sweep.run_sweep`, so each
number of a fit is a unit of a results store that ``tissuebench sweep SPEC`` reproduces (the
same case entry, method, options and protocol: the same unit key).

It starts from the spec ``tissuebench sweep --scene SCENE --all-methods`` writes
(:func:`~tissuebench.studies.scene_spec.scene_spec_text`: which methods apply, their option
grids and protocols, the training protocol and its held-out evaluation) and keeps its primary
case, the ``path`` of a static scene or the ``trajectory`` of a dynamic one, without its
``beyond`` (past the training range is not what a fit trains for) and, on a path, with
``extrapolation = true``: the range a fit trains for is the whole path, so the headline error
counts every point of it, those a model flags as outside its own validity included (an ANM series
of one segment that flags 21 of 23 points claims 0.0002 % over the other two, not the path). A
static scene with a ``[parameters.position]`` has a second case, its ``positions`` one, whose
stored and held-out positions are written as lists (a position the fit adds moves neither). Each
method of those cases is a
**family** with a case of its own (id: the method's name; ``<name>.positions`` on the positions
case), whose training grows by the runs the fit adds (:mod:`~tissuebench.studies.path_runs` on a
path; ``runs = [{load_scale = ...}]`` on a trajectory; a stored position more) while its
evaluation stays the scene's held-out one.
"""
from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...cases.scene import list_cases, load
from ..ladder import RUNG_METHODS
from ..scene_spec import ERROR_METRIC, scene_spec_text
from ..training import lattice_positions

__all__ = ["Family", "ScenePlan", "scene_plan", "family_case", "round_spec", "toml_text", "SIZE_KEYS",
           "lattice", "held_out"]

#: the option that sizes a family's model, in order of preference: grown where training no longer helps
SIZE_KEYS = ("n_modes", "pod_modes", "handles")


@dataclass
class Family:
    """One method of the primary case: its fixed options, option grid and protocol overrides as the
    generated spec gives them, and the option that sizes it (``""``: none)."""

    name: str
    options: dict
    grid: dict
    protocol: dict
    size_key: str = ""
    learns: bool = True  # False: a practitioner baseline, which learns nothing from references
    case_kind: str = ""  # the primary case it trains on: "path", "positions" or "trajectory"
    id: str = ""  # its case id and key: the method's name, "<name>.positions" on the positions case

    def __post_init__(self):
        self.id = self.id or self.name
        self.case_kind = self.case_kind or "path"

    def option_sets(self) -> list[dict]:
        """The option sets of the generated grid (the fixed options merged into each)."""
        sets = [dict(self.options)]
        for key, values in self.grid.items():
            sets = [{**s, key: v} for s in sets for v in values]
        return sets


@dataclass
class ScenePlan:
    """What a fit of one scene starts from (module docstring)."""

    scene: object
    name: str  # the case name of the specs: a catalogue name or the scene file's absolute path
    variant: str | None
    resolution: str
    analysis: str  # "static" | "dynamic"
    base_cases: dict  # {case kind: the generated spec's case table}, the first one primary
    error_metric: str
    families: list = field(default_factory=list)
    not_fitted: list = field(default_factory=list)  # (method, why)

    @property
    def base_case(self) -> dict:
        """The primary case: the path of a static scene, the trajectory of a dynamic one."""
        return next(iter(self.base_cases.values()))

    def family(self, family_id: str) -> Family:
        return next(f for f in self.families if f.id == family_id)


def _size_key(grid: dict, options: dict) -> str:
    return next((k for k in SIZE_KEYS if k in grid or k in options), "")


def scene_plan(scene_arg, variant: str | None = None, resolution: str = "ci", methods=None) -> ScenePlan:
    """The plan of a fit of ``scene_arg`` (a catalogue name or a scene file): the generated spec's
    primary case and its families (``methods``: only these; ValueError naming one that does not
    apply, with the valid ones)."""
    scene = load(scene_arg, resolution=resolution, variant=variant)
    name = scene_arg if str(scene_arg) in list_cases() else str(Path(scene_arg).resolve())
    text, left_out = scene_spec_text(scene, name, variant, resolution)
    raw = tomllib.loads(text)
    analysis = scene.analysis["type"]
    primary = "path" if analysis == "static" else "trajectory"
    cases = {c["id"]: c for c in raw.get("case", [])}
    if primary not in cases:
        raise ValueError(f"{scene.name}: no method learns from a {primary} training here, so there is nothing to "
                         f"train to a requirement (tissuebench methods {scene_arg})")
    kinds = [primary] + (["positions"] if analysis == "static" and "positions" in cases else [])
    base_cases = {}
    for kind in kinds:
        base = dict(cases[kind])
        base["evaluation"] = {k: v for k, v in base["evaluation"].items() if k != "beyond"}
        if kind == "path":  # the whole path is the fit's range: a model's flagged points count in its error
            base["evaluation"]["extrapolation"] = True
        if kind == "positions":  # the stored and held-out positions as lists: positions the fit adds move neither
            base["training"] = {**base["training"], "positions": lattice(scene, base["training"]["positions"])}
            base["evaluation"] = {**base["evaluation"],
                                  "held_out": held_out(base["training"]["positions"], base["evaluation"]["held_out"])}
        base_cases[kind] = base
    plan = ScenePlan(scene, name, variant, resolution, analysis, base_cases, ERROR_METRIC[analysis])
    for m in raw.get("method", []):
        fits = [k for k in kinds if k in m["cases"]]
        if not fits:
            plan.not_fitted.append((m["name"], f"learns from {m['cases']} training, not a {' or '.join(kinds)}: no "
                                               "reference to add"))
            continue
        options, grid = dict(m.get("options", {})), dict(m.get("grid", {}))
        for kind in fits:
            plan.families.append(Family(m["name"], options, grid, dict(m.get("protocol", {})),
                                        _size_key(grid, options), learns=m["name"] not in RUNG_METHODS,
                                        case_kind=kind, id=m["name"] if kind == primary else f"{m['name']}.{kind}"))
    plan.not_fitted += [(name, why) for name, why in left_out]
    if methods:
        known = {f.id for f in plan.families} | {f.name for f in plan.families}
        for wanted in methods:
            if wanted not in known:
                why = dict(plan.not_fitted).get(wanted, "not a registered method")
                raise ValueError(f"--methods = {wanted!r}: not a family of this fit ({why}); valid: {sorted(known)}")
        plan.families = [f for f in plan.families if f.name in methods or f.id in methods]
    if not plan.families:
        raise ValueError(f"{scene.name}: no method applies to the {' or '.join(kinds)} case")
    return plan


def lattice(scene, spec) -> list[float]:
    """The stored positions of a ``positions`` training (``spec``: a count over the scene's range,
    or a list), as a list (:func:`~tissuebench.studies.training.lattice_positions`)."""
    return [float(f"{x:.12g}") for x in lattice_positions(scene, spec)]


def held_out(positions: list, spec) -> list[float]:
    """The held-out positions of a ``positions`` evaluation (``spec``: a count or a list) of the
    lattice ``positions``, as a list: the rule of the evaluation (the middles and quarter points of
    the lattice's intervals, ``spec`` of them evenly spread), frozen so that the positions a fit
    adds to the training never move them."""
    if isinstance(spec, list):
        return [float(x) for x in spec]
    lat = np.sort(np.asarray(positions, float))
    held = np.sort(np.concatenate([0.5 * (lat[:-1] + lat[1:]), lat[:-1] + 0.25 * np.diff(lat)]))
    if spec is not None:
        held = held[np.linspace(0, len(held) - 1, int(spec)).round().astype(int)]
    return [float(f"{x:.12g}") for x in held]  # -0.9, not -0.8999999999999999: the same reference to 1e-12


def family_case(plan: ScenePlan, family: str, runs: list, case_id: str | None = None,
                evaluation: dict | None = None) -> dict:
    """The case table of ``family`` (its id) with the fit's added ``runs`` (after the protocol's
    own; on the positions case, ``[{"position": s}]``: the stored positions gain ``s``)."""
    kind = plan.family(family).case_kind
    case = {k: v for k, v in plan.base_cases[kind].items() if k != "id"}
    training = dict(case["training"])
    if kind == "positions":
        training["positions"] = sorted(list(training["positions"]) + [float(r["position"]) for r in runs])
    else:
        base_runs = list(training.get("runs", []))
        if base_runs or runs:
            training["runs"] = base_runs + [dict(r) for r in runs]
    return {"id": case_id or family, **case, "training": training,
            "evaluation": dict(evaluation if evaluation is not None else case["evaluation"])}


def round_spec(plan: ScenePlan, name: str, entries: list) -> dict:
    """A spec of ``entries``: ``[(case table, Family, option sets or None for the generated grid)]``."""
    cases, methods = [], []
    for case, fam, option_sets in entries:
        if case["id"] not in [c["id"] for c in cases]:
            cases.append(case)
        m = {"name": fam.name, "cases": [case["id"]]}
        if option_sets is None:
            m.update({k: v for k, v in (("options", fam.options), ("grid", fam.grid)) if v})
        else:
            m["list"] = [dict(o) for o in option_sets]
        if fam.protocol:
            m["protocol"] = dict(fam.protocol)
        methods.append(m)
    sweep = {"name": name, "description": f"tissuebench fit of {plan.scene.name}", "resolution": plan.resolution,
             "error_metric": plan.error_metric}
    return {"sweep": sweep, "case": cases, "method": methods}


def _value(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v) for v in value) + "]"
    if isinstance(value, bool):
        return "true" if value else "false"
    return json.dumps(value)


def toml_text(spec: dict, header: str = "") -> str:
    """The TOML text of a spec dict (``[sweep]``, ``[[case]]``, ``[[method]]``; tables inline)."""
    lines = [f"# {line}" for line in header.splitlines()] if header else []
    lines += ["[sweep]"] + [f"{k} = {_value(v)}" for k, v in spec["sweep"].items()] + [""]
    for section in ("case", "method"):
        for table in spec[section]:
            lines += [f"[[{section}]]"] + [f"{k} = {_value(v)}" for k, v in table.items()] + [""]
    text = "\n".join(lines)
    assert tomllib.loads(text) == {k: spec[k] for k in ("sweep", "case", "method")}, "spec text round trip"
    return text
