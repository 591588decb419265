"""The parameter contract (issue 27): for every ``Scene.at`` parameter, an evaluation at a changed
value either changes the model's result, flags it (a step not ok, or a unit that fails), or is
refused when the spec loads. A model must never return its training answer at another
parameter with status ok (a ROM that ignored ``load_scale`` returned 22-36 % error, unflagged).

The method runs on the first base case it applies to (:data:`~.cases.PARAMETER_BASES`, or the
[[case]] asked for); a method that learns trajectories also at another ``load_scale`` on a
trajectory (the practitioner baselines returned the training's load history at load_scale
0.75 with status ok until the ci gate saw it).

The same holds through the Python API (issue 44: ``model.step({"load_factor": 0.3, "E": 6000})``
returned the state at 0.3, status ok): the model built on the base case is started and stepped
with the base step's parameters plus one more, a misspelt key or a scene parameter
(:func:`api_parameters_problems`); it must refuse it naming it (at ``start`` or at the step),
flag it, or answer differently.

A non-finite answer with status ok is none of these (NaN is no "same result" and no changed
one): the check names it, at the base case or at the changed parameter.
"""
from __future__ import annotations

import numpy as np

from ..cases.parameters import ANALYSIS_OVERRIDES
from ..rom import make_method
from ..rom.reads import reads_of
from ..studies.applicability import evaluation_why_not, why_not
from ..studies.case_entry import CaseEntry
from ..studies.evaluation import NEEDS_MODEL, build_evaluation
from ..studies.protocol import drive
from ..studies.spec import check_pair
from ..studies.training import build_training, case_scene
from .cases import applies_to, entry_dict, parameter_base
from .subject import CheckFailure, CheckSkipped, raised, stops

__all__ = ["check_parameters_honoured", "run_entry", "api_parameters_problems"]

_TRAJECTORY_BASES = [{"name": "frame_2dof", "training": {"kind": "trajectory"}},
                     {"name": "wave_block", "variant": "linear", "training": {"kind": "trajectory"}}]


def _built(cls, case: CaseEntry, scene, options: dict):
    """``(model, evaluation, history)`` of ``cls`` built on ``case`` as a unit builds it."""
    training = build_training(case, scene)
    model = make_method(cls, **options).build(training)
    if training.outputs:
        model.attach_outputs(training.outputs)
    ev = build_evaluation(case, scene, model if case.evaluation_kind in NEEDS_MODEL else None)
    history = ev.history or training.history or (scene.history if ev.kind == "trajectory" else None)
    return model, ev, history


def run_entry(cls, entry: dict, options: dict):
    """``(fields, statuses)`` of ``cls`` built and driven through the case-entry dict ``entry`` as a
    unit would be (a refusal or an exception: no fields, and a status saying so)."""
    case = CaseEntry.from_dict(entry)
    scene = case_scene(case)
    why = why_not(cls, scene, case.training_kind, options) or evaluation_why_not(cls, case, scene)
    if why:
        return None, ["refused: " + why]
    try:
        model, ev, history = _built(cls, case, scene, options)
        driven = drive(model, ev, history)
    except BaseException as exc:  # noqa: BLE001 - a unit that raises (an exit too) is stored as failed: flagged
        if stops(exc):
            raise
        return None, [f"failed: {raised(exc)}"]
    # a failed step with its message: "does not run" says why
    statuses = ["initial" if r is None and k == 0 else "not_reached" if r is None else
                f"failed: {r.message}" if r.status == "failed" else r.status for k, r in enumerate(driven.results)]
    return driven.fields, statuses


def _scene_parameters(scene) -> list:
    material = [k for k in (scene.material or {}) if k not in ("name", "fibres")]
    return sorted(scene.parameters) + sorted(ANALYSIS_OVERRIDES) + ["load_scale"] + sorted(material)


def _changed(scene, key):
    """A value of ``key`` other than the scene's."""
    if key == "position":
        lo, hi = scene.parameters["position"]["range"]
        return lo + 0.3 * (hi - lo)
    a, m = scene.analysis, scene.material or {}
    values = {"load_scale": 0.5, "max_load_factor": 0.5 * a.get("max_load_factor", 1.0),
              "load_steps": a.get("load_steps", 1) + 1, "t_end": 1.5 * a.get("t_end", 1.0),
              "dt": 0.5 * a.get("dt", 1.0), "integrator": "newmark" if a.get("integrator") != "newmark" else "hht",
              "nu": 0.3 if m.get("nu") != 0.3 else 0.4}
    return values.get(key, 1.5 * float(m.get(key, 1.0)))


def _differs(a, b) -> bool:
    if a is None or b is None or len(a) != len(b):
        return True
    for u, v in zip(a, b):
        if (u is None) != (v is None):
            return True
        if u is not None and (np.shape(u) != np.shape(v) or
                              np.linalg.norm(u - v) > 1e-9 * max(np.linalg.norm(v), 1e-300)):
            return True
    return False


def _non_finite(fields) -> str:
    """Where the first non-finite value of ``fields`` (a drive's fields, None where no step) is
    (``"field 2 (u[14] = nan)"``), or ""."""
    for n, u in enumerate(fields or []):
        if u is None:
            continue
        values = np.asarray(u, dtype=float).ravel()
        bad = np.flatnonzero(~np.isfinite(values))
        if len(bad):
            return f"field {n} (u[{bad[0]}] = {values[bad[0]]})"
    return ""


def _refused(entry: dict, cls, options) -> bool:
    table = {k: v for k, v in entry.items() if v is not None and k not in ("backend", "id")}
    try:
        check_pair(table, cls, options)
    except ValueError:
        return True
    return False


def _base(ctx):
    """``(entry dict, base evaluation)`` the contract runs on, or None."""
    if ctx.training is None or isinstance(ctx.training, str):
        return parameter_base(ctx.cls, ctx.options)
    table = {k: v for k, v in ctx.training.items() if k != "evaluation"}
    scene = case_scene(CaseEntry.from_dict(entry_dict(table)))
    if scene.analysis["type"] == "dynamic":
        evaluation = {"kind": "trajectory"}
    else:
        mid = {"position": float(np.mean(scene.parameters["position"]["range"]))} if \
            "position" in scene.parameters and ctx.cls.reads(scene, table.get("training", {}).get("kind", "path")) \
            else {}
        evaluation = {"kind": "map", "mus": [mid]}
    return entry_dict(table), evaluation


def check_parameters_honoured(ctx) -> None:
    """The check :func:`~.checks.parameters_are_honoured` (module docstring)."""
    cls, options = ctx.cls, ctx.options
    base = _base(ctx)
    if base is None:
        raise CheckSkipped("applies to none of the parameter contract's base cases")
    entry, evaluation = base
    scene = case_scene(CaseEntry.from_dict(entry))
    comparable = evaluation["kind"] in ("map", "trajectory")
    base_fields, statuses = run_entry(cls, {**entry, "evaluation": evaluation}, options)
    if not all(s in ("ok", "initial") for s in statuses):
        raise CheckFailure(f"the base case {entry['name']!r} ({evaluation['kind']} evaluation) does not run: "
                           f"{statuses[:3]}")
    if _non_finite(base_fields):
        raise CheckFailure(f"the base case {entry['name']!r} ({evaluation['kind']} evaluation) returned a non-finite "
                           f"{_non_finite(base_fields)}, every step ok: no changed parameter can be compared with it "
                           "(a step that cannot answer returns status 'failed' saying why)")
    problems = []
    for key in _scene_parameters(scene):
        value = _changed(scene, key)
        if evaluation["kind"] == "trajectory" and key in ("load_scale", "t_end"):
            changed = {"kind": "trajectory", key: value}
        else:
            changed = {"kind": "map", "mus": [{**evaluation.get("mus", [{}])[0], key: value}]}
        trial = {**entry, "evaluation": changed}
        if _refused(trial, cls, options):
            continue
        fields, statuses = run_entry(cls, trial, options)
        flagged = any(s not in ("ok", "initial") for s in statuses)
        if not flagged and _non_finite(fields):
            problems.append(f"{key} = {value!r}: a non-finite {_non_finite(fields)}, every step ok")
        elif not flagged and not (comparable and _differs(fields, base_fields)):
            problems.append(f"{key} = {value!r}: the same result, every step ok")
    problems += _trajectory_load_scale(ctx, evaluation["kind"])
    problems += api_parameters_problems(cls, {**entry, "evaluation": evaluation}, options)
    if problems:
        raise CheckFailure(f"on case {entry['name']!r}: " + "; ".join(problems) + " (a parameter the model does not "
                           "represent must change its result, be flagged, or be refused: Applies.parameters)")


def _trajectory_load_scale(ctx, base_kind: str) -> list:
    """A method that learns trajectories, checked on a static base, at load_scale 0.5 on a trajectory."""
    cls, options = ctx.cls, ctx.options
    if "trajectory" not in cls.training_kinds or base_kind == "trajectory" or ctx.training is not None:
        return []
    for table in _TRAJECTORY_BASES:
        if applies_to(cls, {**table, "evaluation": {"kind": "trajectory"}}, options):
            break
    else:
        return []
    base = entry_dict({**table, "evaluation": {"kind": "trajectory"}})
    base_fields, statuses = run_entry(cls, base, options)
    if not all(s in ("ok", "initial") for s in statuses):
        return [f"the trajectory base {table['name']!r} does not run: {statuses[:3]}"]
    if _non_finite(base_fields):
        return [f"the trajectory base {table['name']!r} returned a non-finite {_non_finite(base_fields)}, every step "
                "ok"]
    fields, statuses = run_entry(cls, {**base, "evaluation": {"kind": "trajectory", "load_scale": 0.5}}, options)
    if any(s not in ("ok", "initial") for s in statuses):
        return []
    if _non_finite(fields):
        return [f"on trajectory case {table['name']!r}: load_scale 0.5 returned a non-finite {_non_finite(fields)}, "
                "every step ok"]
    if _differs(fields, base_fields):
        return []
    return [f"on trajectory case {table['name']!r}: load_scale 0.5 returned the training's answer, every step ok"]


def _first_step(model, ev, history):
    """``(start, mu)``: ``start(extra)`` starts a run of ``model`` through evaluation ``ev`` as the
    harness does (its first parameters with the ``extra`` ones), and the parameters of its first
    step."""
    if ev.kind == "trajectory":
        p0 = ev.points[0]
        t = p0.mu["time"] + ev.dt
        return (lambda extra: model.start({**p0.mu, **extra}, ev.state0, ev.dt)), \
            {"time": t, "load_factor": float(history(t))}
    mu = dict(ev.points[0].mu)
    return (lambda extra: model.start({**mu, **extra})), mu


def _answer(model, start, mu, extra):
    """The first step's result at ``mu`` and ``extra`` and its field, or the exception raised."""
    try:
        start(extra)
        res = model.step({**mu, **extra})
    except (ValueError, TypeError) as exc:
        return exc, None
    return res, None if res.q is None else model.reconstruct(res)


def api_parameters_problems(cls, entry: dict, options: dict) -> list:
    """Through the Python API (module docstring): the model built on ``entry``, started, and given at
    its first step the base step's parameters plus a misspelt key or a scene parameter (one at a
    time); a key it neither refuses naming it, nor flags, nor answers differently is a problem."""
    case = CaseEntry.from_dict(entry)
    scene = case_scene(case)
    model, ev, history = _built(cls, case, scene, options)
    start, mu0 = _first_step(model, ev, history)
    base, base_field = _answer(model, start, mu0, {})
    if isinstance(base, Exception):
        return [f"the first step of the base case at {mu0} raised {type(base).__name__}: {base}"]
    if base.status == "ok" and _non_finite([base_field]):
        return [f"the first step of the base case at {mu0} (Python API): a non-finite answer, status ok"]
    harness = {"load_factor", "time", "node", "cut_length"} | set(mu0)
    keys = ["bogus_parameter"] + [k for k in _scene_parameters(scene) if k not in harness]
    problems = []
    for key in keys:
        value = _changed(scene, key)
        res, field = _answer(model, start, mu0, {key: value})
        if isinstance(res, Exception):
            if key not in str(res):
                problems.append(f"{key} = {value!r} at a step: refused without naming it ({res})")
            continue
        if res.status == "ok" and _non_finite([field]):
            problems.append(f"{key} = {value!r} at a step (Python API): accepted, a non-finite answer, status ok")
            continue
        same = res.status == base.status and not _differs([field], [base_field])
        if res.status == "ok" and same:
            declared = reads_of(model)
            how = "accepted" if declared is None or key not in declared else "declared as read (step_parameters)"
            problems.append(f"{key} = {value!r} at a step (Python API): {how}, the same answer, status ok")
    return problems
