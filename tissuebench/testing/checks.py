"""The named checks of the method contract (:mod:`tissuebench.rom.base`), in the order they run.

Each check takes a :class:`Context` (the method class, its options, the training it is
checked on) and returns when the method keeps the rule, raises :class:`~.subject.CheckFailure`
saying what is wrong, or :class:`~.subject.CheckSkipped` saying why the rule has nothing to
check on this method. The model-based checks share one build and one drive per contract case
(:mod:`.subject`); the parameter contract is :mod:`.parameters`.
"""
from __future__ import annotations

import inspect
import json
import math

import numpy as np

from ..cases.builders import BUILDERS
from ..cases.schema import MODELS
from ..refsolvers.materials import MATERIALS
from ..rom import MODEL_KINDS, STEP_STATUSES, Applies, OnlineModel, RomMethod, StepResult, make_method
from ..rom.pgd.strip import IncisionStrip
from ..studies.training import TRAINING_KINDS
from ..studies.units import _jsonable
from .cases import CONTRACT_CASES, applies_to, contract_case, primary_case, scene_of, user_case
from .subject import CheckFailure, CheckSkipped, raised, stops, subject

__all__ = ["Context", "CHECK_FUNCTIONS"]

_FLAGS = ("extrapolation", "beyond_validity", "failed")
#: how far (relative to their size) a reconstruction may be off the prescribed values of its step
_PRESCRIBED_RTOL = 1e-3


class Context:
    """What a check reads: the method class, its options and the training asked for (None: the
    built-in cases; a built-in case's name; a [[case]] table)."""

    def __init__(self, cls, options: dict | None = None, training=None):
        self.cls, self.options, self.training = cls, dict(options or {}), training

    def primary(self):
        """The subject on the case the method is checked on (:func:`~.cases.primary_case`)."""
        gone = self.cls.unavailable()
        if gone:  # a library it wraps is not installed here: nothing to build (RomMethod.unavailable)
            raise CheckSkipped(f"{self.cls.name!r} cannot run here: {gone}")
        if self.training is None:
            name = primary_case(self.cls, self.options)
            if name is None:
                raise CheckFailure(f"{self.cls.name!r} applies to none of the built-in contract cases "
                                   f"{list(CONTRACT_CASES)} (its training_kinds {list(self.cls.training_kinds)} and "
                                   "applies); give check_method training= a [[case]] table it applies to")
            case = contract_case(name)
        elif isinstance(self.training, str):
            case = contract_case(self.training)
        else:
            case = user_case(self.training)
        return subject(self.cls, self.options, case)

    def field_subjects(self) -> list:
        """The primary subject, and the one on ``prescribed`` (nonzero prescribed displacements)
        when the method applies there and no training was asked for."""
        out = [self.primary()]
        if self.training is None and out[0].case.name != "prescribed" and applies_to(
                self.cls, CONTRACT_CASES["prescribed"], self.options):
            out.append(subject(self.cls, self.options, contract_case("prescribed")))
        return out


def options_are_constructor_keywords(ctx: Context) -> None:
    """The options are the constructor's named keywords, each with a default; an unknown one is
    refused by name; ``kind``, ``training_kinds``, ``nested`` and ``refinements`` are known values
    (``refinements_for`` answers with some of ``refinements``)."""
    cls = ctx.cls
    params = [] if cls.__init__ is object.__init__ else [  # no constructor of its own: no options
        p for p in inspect.signature(cls.__init__).parameters.values() if p.name != "self"]
    named = [p.name for p in params if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    if cls.option_names() != named:
        raise CheckFailure(f"option_names() = {cls.option_names()}, the constructor's keywords are {named}")
    star = [p.name for p in params if p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    if star:
        raise CheckFailure(f"the constructor takes *{star[0]}: every option must be a named keyword (a spec's grid is "
                           "checked against them by name)")
    required = [p.name for p in params if p.default is p.empty]
    if required:
        raise CheckFailure(f"options {required} have no default: the harness builds a method with its defaults "
                           "(tissuebench sweep --all-methods, a spec that names no options)")
    if cls.kind not in MODEL_KINDS:
        raise CheckFailure(f"kind = {cls.kind!r}; valid: {list(MODEL_KINDS)}")
    kinds = list(cls.training_kinds)
    if not kinds or any(k not in TRAINING_KINDS for k in kinds):
        raise CheckFailure(f"training_kinds = {kinds}: expected some of {list(TRAINING_KINDS)}")
    if any(k not in named for k in cls.nested):
        raise CheckFailure(f"nested = {list(cls.nested)}: not all are options ({named})")
    if any(k not in named for k in cls.refinements):
        raise CheckFailure(f"refinements = {cls.refinements}: not all are options ({named}); tissuebench fit sets "
                           "them by name")
    applied = cls.refinements_for({})
    if not isinstance(applied, dict) or any(k not in cls.refinements for k in applied):
        raise CheckFailure(f"refinements_for({{}}) = {applied!r}: expected a dict of some of refinements "
                           f"{cls.refinements}")
    try:
        make_method(cls, bogus_option=1)
    except ValueError as exc:
        if "bogus_option" not in str(exc):
            raise CheckFailure(f"an unknown option is refused without its name: {exc}") from None
    else:
        raise CheckFailure("an unknown option (bogus_option = 1) was accepted: check_options must refuse it by name")
    try:
        make_method(cls, **ctx.options)
    except Exception as exc:  # noqa: BLE001
        raise CheckFailure(f"the constructor refused options {ctx.options}: {raised(exc)}") from None


def applies_is_declared_and_consistent(ctx: Context) -> None:
    """``applies = Applies(...)`` is declared on the class, with known models, materials, mesh
    builders and training kinds, and ``why_not`` agrees with it on every built-in scene."""
    cls = ctx.cls
    if not any("applies" in vars(k) for k in cls.__mro__ if k is not RomMethod):
        raise CheckFailure("the class declares no `applies = Applies(...)` (what it needs of a scene, the parameters "
                           "its step reads); `Applies()` says: any finite-element scene, a step reading only "
                           "load_factor and time")
    a = cls.applies
    if not isinstance(a, Applies):
        raise CheckFailure(f"applies = {a!r}: expected a tissuebench.rom.Applies")
    for field, values, known in (("models", a.models, MODELS), ("materials", a.materials, MATERIALS),
                                 ("mesh_builders", a.mesh_builders, BUILDERS)):
        if values is None and field != "models":
            continue
        if isinstance(values, str) or not isinstance(values, (tuple, list)) or any(v not in known for v in values):
            raise CheckFailure(f"applies.{field} = {values!r}: expected a tuple of {sorted(known)}")
    if not isinstance(a.parameters, dict):
        raise CheckFailure(f"applies.parameters = {a.parameters!r}: expected a dict training kind -> parameter names")
    for kind, keys in a.parameters.items():
        if kind not in cls.training_kinds:
            raise CheckFailure(f"applies.parameters names training kind {kind!r}, which training_kinds "
                               f"{list(cls.training_kinds)} does not list")
        if isinstance(keys, str) or any(not isinstance(k, str) or k in ("load_factor", "time") for k in keys):
            raise CheckFailure(f"applies.parameters[{kind!r}] = {keys!r}: expected a tuple of scene parameter names "
                               "(load_factor and time are read by every step)")
    for table in CONTRACT_CASES.values():
        scene = scene_of(table)
        try:
            why = cls.why_not(scene, None)
            reads = {k: cls.reads(scene, k) for k in cls.training_kinds}
        except Exception as exc:  # noqa: BLE001
            raise CheckFailure(f"why_not/reads raised on scene {table['name']!r}: {raised(exc)}") from None
        if not isinstance(why, str) or any(not isinstance(r, tuple) for r in reads.values()):
            raise CheckFailure(f"on scene {table['name']!r}: why_not gave {why!r} (a str), reads gave {reads} "
                               "(tuples)")
        if not why and (scene.model not in a.models or (a.materials is not None and (
                scene.material or {}).get("name") not in a.materials)):
            raise CheckFailure(f"why_not says it applies to scene {table['name']!r} (a {scene.model} model, material "
                               f"{(scene.material or {}).get('name')!r}), which its applies = {a} excludes")


def builds_an_online_model(ctx: Context) -> None:
    """The build returns an :class:`~tissuebench.rom.OnlineModel` of the declared kind with at least one
    reduced coordinate, and a JSON-able ``info`` (the sweep stores it)."""
    s = ctx.primary()
    model = s.model()
    if not isinstance(model, OnlineModel):
        raise CheckFailure(f"build returned {type(model).__name__}, not a tissuebench.rom.OnlineModel")
    n = model.n_reduced
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise CheckFailure(f"n_reduced = {n!r}: expected an integer >= 1")
    trajectory = s.case.entry.training_kind == "trajectory"
    if model.kind != ctx.cls.kind and not (trajectory and model.kind == "trajectory"):
        raise CheckFailure(f"the model's kind {model.kind!r} is not the method's {ctx.cls.kind!r}")
    info = getattr(model, "info", {})
    if not isinstance(info, dict):
        raise CheckFailure(f"model.info is a {type(info).__name__}: expected a dict (the sweep stores it as JSON)")
    try:
        json.loads(json.dumps(_jsonable(info)))
    except (TypeError, ValueError) as exc:
        raise CheckFailure(f"model.info cannot be stored as JSON: {exc}") from None


def build_does_not_mutate_training(ctx: Context) -> None:
    """The build leaves its training as it found it (a case's training is shared by its units)."""
    s = ctx.primary()
    s.model()
    if s.mutated:
        raise CheckFailure(f"the build changed its training: {', '.join(s.mutated)} (the units of a case share one "
                           "training: copy what you change)")


def step_does_not_mutate_mu(ctx: Context) -> None:
    """``start`` and ``step`` leave the mapping of parameters they are given as they found it (the
    harness keeps stepping with the evaluation's points and reports a result's ``mu``: a step
    that writes into it moves every later step and message; the checks after this one judge the
    asked values, put back)."""
    s = ctx.primary()
    s.driven()
    if s.watched.changed:
        call, asked, left = s.watched.changed[0]
        what = "start(mu0)" if call == "start" else "step(mu)"
        keys = sorted({*asked, *left} - {k for k in asked if k in left and repr(asked[k]) == repr(left[k])})
        more = f" (and {len(s.watched.changed) - 1} more call(s))" if len(s.watched.changed) > 1 else ""
        raise CheckFailure(f"{what} changed the parameters it was given at {asked}: left {left} ({', '.join(keys)} "
                           f"changed){more}; the harness steps with and reports the mapping it passed: copy mu "
                           "before changing it")


def steps_return_reduced_states(ctx: Context) -> None:
    """Every step of the drive that does not fail returns its reduced state: a finite floating
    numpy array of shape ``(n_reduced,)``, ``n_reduced`` read right after that step (a cut model's
    grows as it cuts); a step that cannot answer returns status ``"failed"`` (``q`` None) saying
    why."""
    s = ctx.primary()
    s.driven()
    for mu, res, n in s.watched.steps:  # as the model returned them (the harness fails a non-finite one)
        if not isinstance(res, StepResult):
            raise CheckFailure(f"the step at {mu} (case {s.case.name!r}) returned a {type(res).__name__}: expected "
                               "a tissuebench.rom.StepResult")
        q, at = res.q, f"at {mu} (case {s.case.name!r}, status {res.status!r})"
        if q is None:
            if res.status != "failed":
                raise CheckFailure(f"the step {at} returned no state (q None): only a failed step has none")
            continue
        if isinstance(n, BaseException):
            raise CheckFailure(f"n_reduced, read after the step {at}, raised {raised(n)}")
        if not isinstance(q, np.ndarray):
            raise CheckFailure(f"the state returned {at} is a {type(q).__name__}: expected a numpy array of shape "
                               f"(n_reduced,) = ({n},)")
        if not np.issubdtype(q.dtype, np.floating):
            raise CheckFailure(f"the state returned {at} has dtype {q.dtype}: expected a floating array")
        if q.shape != (n,):
            raise CheckFailure(f"the state returned {at} has shape {q.shape}; n_reduced = {n!r} after that step: a "
                               "step returns the (n_reduced,) reduced state")
        bad = np.flatnonzero(~np.isfinite(q))
        if len(bad):
            raise CheckFailure(f"the state returned {at} is not finite: q[{bad[0]}] = {q[bad[0]]} ({len(bad)} of "
                               f"{q.size} entries); a step that cannot answer returns status 'failed' (q None) "
                               "saying why")


def reconstruct_is_the_full_field(ctx: Context) -> None:
    """``reconstruct`` returns a finite ``(n_dof,)`` field, the prescribed (Dirichlet) values of its
    step included (to 1e-3 of their size: :data:`_PRESCRIBED_RTOL`), at every evaluation point of
    every case checked."""
    checked = 0
    for s in ctx.field_subjects():
        evaluation, driven, _ = s.driven()
        backend = getattr(s.training, "backend", None)
        fixed = np.asarray(backend.problem.fixed_dofs) if backend is not None else np.zeros(0, int)
        for p, res, u in zip(evaluation.points, driven.results, driven.fields):
            if res is None or res.q is None or p.reference is None:
                continue
            where = f"case {s.case.name!r} at {dict(res.mu or p.mu)}"
            u = np.asarray(u)
            if u.shape != p.reference.shape:
                raise CheckFailure(f"reconstruct returned shape {u.shape} {where}; the full field has shape "
                                   f"{p.reference.shape} (every dof of the scene, prescribed values included)")
            if not np.all(np.isfinite(u)):
                raise CheckFailure(f"reconstruct returned a non-finite value {where}")
            if len(fixed) and u.shape == (backend.ndof,):
                gap = float(np.abs(u[fixed] - p.reference[fixed]).max())
                prescribed, scale = float(np.abs(p.reference[fixed]).max()), float(np.abs(p.reference).max())
                # placed, if approximately (a POD of whole snapshots gives them to its own accuracy);
                # missing, zeroed or another step's are off by their own size
                if gap > max(_PRESCRIBED_RTOL * prescribed, 1e-9 * scale):
                    raise CheckFailure(f"reconstruct misses the prescribed (Dirichlet) values {where}: at the fixed "
                                       f"dofs it is off by {gap:.3g}, the prescribed values reach {prescribed:.3g}; "
                                       "LinearReconstruction places them from training.backend.problem")
            checked += 1
    if not checked:
        raise CheckFailure("no step returned a state to reconstruct (statuses: "
                           f"{[getattr(r, 'status', None) for r in driven.results][:6]})")


def outputs_agree_with_reconstruct(ctx: Context) -> None:
    """``outputs`` gives each attached output functional applied to the reconstructed field."""
    compared = 0
    for s in ctx.field_subjects():
        evaluation, driven, _ = s.driven()
        for res, y, u in zip(driven.results, driven.outputs, driven.fields):
            if res is None or res.q is None or u is None:
                continue
            for name, c in s.training.outputs.items():
                if c.shape != np.shape(u):  # a cut mesh has more dofs than the intact one the outputs act on
                    continue
                if name not in y:
                    raise CheckFailure(f"outputs() lacks the attached output {name!r} (has {sorted(y)})")
                want, got = float(c @ u), float(y[name])
                if not math.isclose(got, want, rel_tol=1e-9, abs_tol=1e-14 * float(np.abs(c) @ np.abs(u)) + 1e-300):
                    raise CheckFailure(f"outputs()[{name!r}] = {got:.10g} on case {s.case.name!r} at {res.mu}; the "
                                       f"functional applied to reconstruct() gives {want:.10g}")
                compared += 1
    if not compared:
        raise CheckSkipped("the cases checked have no monitored output on the model's field")


def steps_inside_are_ok(ctx: Context) -> None:
    """Every step at parameters inside the training's range (a model without snapshots: its
    ``envelope``) returns status ``"ok"`` with a finite state and finite outputs; a trajectory
    model's every step."""
    s = ctx.primary()
    evaluation, driven, _ = s.driven()
    ranges = _envelope(s.training, s.model())
    for p, res, y in zip(evaluation.points, driven.results, driven.outputs):
        if res is None:
            continue
        inside = evaluation.kind == "trajectory" or all(
            k in ranges and ranges[k][0] <= v <= ranges[k][1] for k, v in p.mu.items())
        where = f"a step inside the training ({dict(p.mu)}, case {s.case.name!r})"
        if inside and res.status != "ok":
            raise CheckFailure(f"{where} returned status {res.status!r}: {res.message}")
        if inside:
            bad = _non_finite(res.q, y)
            if bad:
                raise CheckFailure(f"{where} returned status 'ok' with {bad}: a step that cannot answer returns "
                                   "status 'failed' saying why")


def _non_finite(q, outputs) -> str:
    """What is not finite in a state ``q`` and its ``outputs`` (``"a non-finite state (q[2] = nan)"``),
    or "" (a state that is no array of numbers: :func:`steps_return_reduced_states` names it)."""
    try:
        values = np.asarray(q, dtype=float).ravel() if q is not None else np.zeros(0)
    except (TypeError, ValueError):
        values = np.zeros(0)
    bad = np.flatnonzero(~np.isfinite(values))
    if len(bad):
        return f"a non-finite state (q[{bad[0]}] = {values[bad[0]]})"
    wrong = {}
    for k, v in (outputs or {}).items():
        try:
            if not math.isfinite(float(v)):
                wrong[k] = float(v)
        except (TypeError, ValueError):
            wrong[k] = v
    return f"non-finite outputs {wrong}" if wrong else ""


def _envelope(training, model) -> dict:
    """``{parameter: (lo, hi)}`` of the training's snapshots (time apart), else the model's ``envelope``."""
    out = {}
    for params in training.parameters or []:
        for k, v in params.items():
            if k != "time" and isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool):
                lo, hi = out.get(k, (v, v))
                out[k] = (min(lo, v), max(hi, v))
    return out or {k: tuple(v) for k, v in (getattr(model, "envelope", None) or {}).items()}


def floor_ops_runs(ctx: Context) -> None:
    """``floor_ops()`` returns a zero-argument callable that runs (timed beside every step)."""
    s = ctx.primary()
    s.driven()
    model = s.model()
    try:
        floor = model.floor_ops()
    except BaseException as exc:  # noqa: BLE001 - the method's code (an exit too)
        if stops(exc):
            raise
        raise CheckFailure(f"floor_ops() raised {raised(exc)}") from None
    if not callable(floor):
        raise CheckFailure(f"floor_ops() returned {type(floor).__name__}, not a zero-argument callable")
    try:
        floor()
        floor()
    except BaseException as exc:  # noqa: BLE001
        if stops(exc):
            raise
        raise CheckFailure(f"the callable floor_ops() returned raised {raised(exc)}") from None


def step_is_deterministic(ctx: Context) -> None:
    """Driven twice from the same start, a model returns the same states; a state it returned is
    never changed afterwards (``StepResult.q`` belongs to the result)."""
    s = ctx.primary()
    evaluation, first, copies = s.driven()
    owners = {}
    for res in first.results:  # one array per step: a buffer handed out twice is rewritten under its first holder
        if res is not None and res.q is not None and np.size(res.q):
            # an array by its buffer (views of one buffer too); anything else by identity (np.asarray
            # of a list is a new array whose address a later one may reuse)
            where = res.q.__array_interface__["data"][0] if isinstance(res.q, np.ndarray) else ("object", id(res.q))
            if where in owners:
                raise CheckFailure(f"the state returned at {res.mu} is the array returned at {owners[where]}: the "
                                   "model changed the state it returned after returning it (a StepResult's q belongs "
                                   "to the result: return a new array each step)")
            owners[where] = res.mu
    _, second = s.drive()
    for a, b, kept in zip(first.results, second.results, copies):
        if a is None and b is None:
            continue
        mu = (a or b).mu
        if (a is None) != (b is None) or a.status != b.status:
            raise CheckFailure(f"two drives from the same start differ at {mu}: status "
                               f"{getattr(a, 'status', None)!r}, then {getattr(b, 'status', None)!r}")
        if a.q is None:
            continue
        if not _same(np.asarray(a.q), kept):
            raise CheckFailure(f"the model changed the state it returned at {mu} after returning it (a StepResult's q "
                               "belongs to the result: return a new array each step)")
        if np.shape(b.q) != kept.shape or not _same(np.asarray(b.q), kept, 1e-12):
            raise CheckFailure(f"two drives from the same start gave different states at {mu} (no seeded randomness "
                               "and no state kept from one run to the next: start() must reset it)")


def _same(a: np.ndarray, b: np.ndarray, tol: float = 0.0) -> bool:
    """``a`` equals ``b`` to ``tol`` times the largest finite entry of ``b``, NaN equal to NaN (a
    non-finite state is :func:`steps_return_reduced_states`' to name, not a changed one)."""
    if a.shape != b.shape:
        return False
    if not (np.issubdtype(a.dtype, np.number) and np.issubdtype(b.dtype, np.number)):
        return bool(np.array_equal(a, b))
    finite = np.abs(b[np.isfinite(b)])
    scale = max(float(finite.max()) if finite.size else 0.0, 1e-300)
    return bool(np.allclose(a, b, rtol=0.0, atol=tol * scale, equal_nan=True)) if tol else \
        bool(np.array_equal(a, b, equal_nan=True))


def extrapolation_is_flagged(ctx: Context) -> None:
    """A step far outside the training's parameters is flagged (``extrapolation``,
    ``beyond_validity`` or ``failed``, with a message) or refused naming the parameter."""
    s = ctx.primary()
    model = s.model()
    if model.kind == "trajectory":
        raise CheckSkipped("a trajectory model steps in time from its state: the trajectory checks measure it")
    ranges = _envelope(s.training, model)
    if not ranges:
        raise CheckSkipped("its training has no parameters and the model no `envelope` (name -> (lo, hi))")
    inside, outside = {}, {}
    for k, (lo, hi) in ranges.items():
        ints = isinstance(lo, (int, np.integer)) and isinstance(hi, (int, np.integer))
        inside[k] = (lo + hi) // 2 if ints else 0.5 * (lo + hi)
        outside[k] = hi + 10 * (hi - lo) + 1
    try:  # copies: a model that writes into its mu must not change what the message quotes
        model.start(dict(inside))
        model.step(dict(inside))
        far = model.step(dict(outside))
    except (ValueError, TypeError) as exc:
        if not any(k in str(exc) for k in outside):
            raise CheckFailure(f"a step at {outside} raised without naming the parameter: {exc}") from None
        return
    if far.status not in _FLAGS or not far.message:
        raise CheckFailure(f"a step at {outside}, far outside the training's {ranges}, returned status "
                           f"{far.status!r} with message {far.message!r}: extrapolation must be flagged")


def failure_is_reported(ctx: Context) -> None:
    """A failed step carries no state and a message; ``reconstruct`` refuses it, ``outputs`` gives
    NaN; a step at parameters it cannot read raises naming them, or fails saying why."""
    s = ctx.primary()
    _, driven, _ = s.driven()
    model = s.model()
    for res in driven.results:
        if res is None:
            continue
        if res.status not in STEP_STATUSES or (res.status != "ok" and not res.message):
            raise CheckFailure(f"a step at {res.mu} returned status {res.status!r} with message {res.message!r}: "
                               "a step that is not ok says why")
    failed = StepResult(None, "failed", "a failed step")
    try:
        u = model.reconstruct(failed)
    except ValueError:
        pass
    except Exception as exc:  # noqa: BLE001
        raise CheckFailure(f"reconstruct of a failed step raised {raised(exc)}: expected a ValueError") from None
    else:
        raise CheckFailure(f"reconstruct of a failed step returned a field ({type(u).__name__}) instead of refusing it "
                           "(ValueError): a failure must never become a field")
    y = model.outputs(failed)
    if any(not math.isnan(float(v)) for v in y.values()):
        raise CheckFailure(f"outputs of a failed step = {y}: expected NaN for every output")
    try:
        res = model.step({"nonsense": 1.0})
    except (ValueError, TypeError):
        return
    if res.status != "failed" or not res.message:
        raise CheckFailure(f"a step at {{'nonsense': 1.0}} returned status {res.status!r}: a step without the "
                           "parameters it reads must raise naming them, or fail saying why")


def harness_hooks_answer(ctx: Context) -> None:
    """The optional hooks the harness calls (``contact_nodes``, ``incision_strip``,
    ``contact_force``, ``variant``) answer with their declared types; a declared ``nested`` option
    is one ``variant`` slices."""
    cls, model = ctx.cls, ctx.primary().model()
    nodes = model.contact_nodes()
    if nodes is not None and not (isinstance(nodes, np.ndarray) and nodes.ndim == 1 and len(nodes)
                                  and np.issubdtype(nodes.dtype, np.integer) and nodes.min() >= 0):
        raise CheckFailure(f"contact_nodes() = {nodes!r}: expected None or a non-empty (n,) array of node ids")
    strip, force = model.incision_strip(), model.contact_force()
    if strip is not None and (not isinstance(strip, IncisionStrip) or force is None):
        raise CheckFailure("incision_strip() returned a strip without contact_force(), or not an IncisionStrip")
    if force is not None and not (np.shape(force) == (3,) and np.all(np.isfinite(force))):
        raise CheckFailure(f"contact_force() = {force!r}: expected a finite (3,) vector")
    smaller = {k: 1 for k in cls.nested}
    sliced = model.variant(**smaller)
    if (sliced is not None) != bool(cls.nested):
        raise CheckFailure(f"nested = {list(cls.nested)} but variant({smaller}) returned "
                           f"{'a model' if sliced is not None else 'None'}: declare as nested exactly the options "
                           "the model slices")
    if sliced is not None and not (isinstance(sliced, OnlineModel) and sliced.kind == model.kind and
                                   sliced.n_reduced <= min(model.n_reduced, smaller.get("n_modes", model.n_reduced))):
        raise CheckFailure(f"variant({smaller}) is not a smaller model of the same kind")


def parameters_are_honoured(ctx: Context) -> None:
    """(:mod:`.parameters`) every scene parameter an evaluation may change changes the result, is
    flagged, or is refused when the spec loads (``load_scale`` included); given at a step through
    the Python API, it or a misspelt key is refused naming it, flagged, or changes the answer."""
    from .parameters import check_parameters_honoured

    check_parameters_honoured(ctx)


#: name -> check function, in the order :func:`~tissuebench.testing.check_method` runs them
CHECK_FUNCTIONS = {f.__name__: f for f in (
    options_are_constructor_keywords, applies_is_declared_and_consistent, builds_an_online_model,
    build_does_not_mutate_training, step_does_not_mutate_mu, steps_return_reduced_states,
    reconstruct_is_the_full_field, outputs_agree_with_reconstruct,
    steps_inside_are_ok, floor_ops_runs, step_is_deterministic, extrapolation_is_flagged, failure_is_reported,
    harness_hooks_answer, parameters_are_honoured)}
