"""Which methods apply to a scene, and which evaluation parameters a method represents.

Checked before any reference is computed: by ``tissuebench methods SCENE`` (every registered
method with applies / why not) and when a sweep spec loads (:mod:`.spec`: an inapplicable
(case, method) pair is refused when the method names the case, skipped with one line when
the case was chosen by default).

Two questions, both answered from declarations (:class:`~tissuebench.rom.base.Applies` on
the method classes, :meth:`~tissuebench.rom.base.RomMethod.why_not`), never by trying:

1. **Does the method apply to the scene?** Its training kinds against the scene's analysis
   (``path`` and ``positions`` learn from a static load path, ``positions`` needs a
   ``[parameters.position]``, ``trajectory`` a dynamic scene, ``operators`` the analysis of
   the model kind), then the class's needs (material, loads, supports, mesh, ``[cut]``,
   integrator).
2. **Does it represent every parameter its evaluation changes?** An evaluation that moves
   a scene parameter (``Scene.at``) away from the training's must reach the model's step:
   ``load_scale`` and ``max_load_factor`` reach it as the load factor (exact when every
   load scales with the load factor and no support prescribes a nonzero displacement, which
   ``load_scale`` does not scale), ``position`` when the method reads it for its training
   kind (``Applies.parameters``). Any other key (the material's ``E``, ``nu``, ..., the
   analysis' ``dt``, ``load_steps``, ``integrator``, ``t_end`` of a static scene) no reduced
   model here represents: refused, with the advice to give it as the case's ``mu`` (training
   and evaluation then both run at it). Without this a model would return its training
   answer at another parameter with status ok (issue 27: 22-36 % error, unflagged).
"""
from __future__ import annotations

from ..rom import METHODS, method_class
from ..rom.plugins import origin
from .case_entry import CaseEntry
from .training import TRAINING_KINDS

__all__ = ["training_why_not", "why_not", "evaluation_keys", "evaluation_why_not",
           "load_scale_why_not", "method_rows", "registry_rows", "LOAD_FACTOR_KEYS"]

#: evaluation parameters that reach every model as its load factor
LOAD_FACTOR_KEYS = ("load_scale", "max_load_factor")


def training_why_not(scene, kind: str, cls=None) -> str:
    """Why training kind ``kind`` cannot be built on ``scene`` (``""`` when it can)."""
    analysis = scene.analysis.get("type")
    want = TRAINING_KINDS[kind].analysis if kind in TRAINING_KINDS else None  # operators: the method's
    if kind == "operators" and cls is not None:
        want = "dynamic" if cls.kind == "trajectory" else "static"
    if want is not None and analysis != want:
        return f"needs a {want} scene; this one is {analysis}"
    if kind == "positions" and "position" not in scene.parameters:
        return ("'positions' training needs a [parameters.position] table (a load moved along a line); the scene has "
                "none")
    return ""


def why_not(method, scene, training_kind: str, options=None) -> str:
    """Why ``method`` (a name or class) cannot learn from ``training_kind`` on ``scene`` with
    ``options`` (None: any option set), or ``""`` when it can."""
    cls = method_class(method)
    if training_kind not in cls.training_kinds:
        return f"learns from {list(cls.training_kinds)} training, not {training_kind!r}"
    return training_why_not(scene, training_kind, cls) or cls.why_not(scene, options)


def load_scale_why_not(scene) -> str:
    """Why ``load_scale`` cannot reach a model as its load factor on ``scene`` (``""`` when it can):
    ``Scene.at`` scales the loads' values but not the prescribed displacements."""
    for i, d in enumerate(scene.dirichlet):
        if "motion" in d or (d.get("scaled", True) and any(v != 0.0 for v in d.get("value", []))):
            name = d.get("name", f"dirichlet[{i}]")
            return (f"load_scale scales the loads but not the displacement that {name!r} prescribes, so no model "
                    "driven by the load factor represents it; give load_scale as the case's mu (training and "
                    "evaluation then run at it)")
    return ""


def evaluation_keys(case: CaseEntry) -> list:
    """The scene parameters (``Scene.at`` keys) an evaluation changes from the training's."""
    ev, kind = case.evaluation, case.evaluation_kind
    keys = set()
    if kind == "positions":
        keys.add("position")
    if kind == "trajectory":
        keys |= {k for k in ("load_scale",) if k in ev}
    if kind == "map":
        for mu in ev.get("mus", []):
            keys |= set(mu)
    return sorted(keys)


def evaluation_why_not(method, case: CaseEntry, scene) -> str:
    """Why ``method`` trained as ``case`` says cannot represent a parameter its evaluation
    changes (module docstring, 2), or ``""``."""
    cls = method_class(method)
    training_kind = case.training_kind
    reads = set(cls.reads(scene, training_kind))
    for key in evaluation_keys(case):
        if key == "load_scale":
            why = load_scale_why_not(scene)
            if why:
                return f"evaluation changes load_scale: {why}"
            continue
        if key in LOAD_FACTOR_KEYS or key in reads:
            continue
        if key == "position":
            return (f"evaluation moves the load (position) but {cls.name!r} trained on {training_kind!r} does not "
                    f"read a position (its step reads {sorted(reads | {'load_factor'})}); train it on 'positions'")
        return (f"evaluation changes {key!r}, which no model trained at the case's scene represents (its step reads "
                f"{sorted(reads | {'load_factor'})}); give {key} as the case's mu (training and evaluation then run "
                "at it)")
    return ""


def method_rows(scene, names=None) -> list[dict]:
    """One row per registered method (or per method of ``names``: registry or ``"module:Class"``
    names): ``method``, ``applies`` (bool), ``learns_from`` (the training kinds that apply), ``why``
    (why not, or what to know when it applies), ``origin`` (``""`` shipped, else the plugin's
    distribution and version: :func:`~tissuebench.rom.plugins.origin`)."""
    rows = []
    for cls in _classes(names):
        name = cls.name
        reasons = {k: why_not(cls, scene, k) for k in cls.training_kinds}
        ok = [k for k, r in reasons.items() if not r]
        if ok:
            why = cls.note(scene)
        else:
            distinct = list(dict.fromkeys(reasons.values()))
            why = distinct[0] if len(distinct) == 1 else "; ".join(f"{k}: {r}" for k, r in reasons.items())
        rows.append({"method": name, "applies": bool(ok), "learns_from": ok, "kind": cls.kind, "why": why,
                     "origin": origin(name)})
    return rows


def _classes(names=None) -> list:
    """The method classes of ``names`` (every registered one when None), in name order."""
    classes = [METHODS[n] for n in sorted(METHODS)] if names is None else [method_class(n) for n in names]
    return sorted(set(classes), key=lambda c: c.name)


def registry_rows(names=None) -> list[dict]:
    """One row per registered method (or per method of ``names``), no scene: ``method``, ``kind``,
    ``training_kinds``, ``origin``."""
    return [{"method": c.name, "kind": c.kind, "training_kinds": list(c.training_kinds), "origin": origin(c.name)}
            for c in _classes(names)]
