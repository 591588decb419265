"""The values a sweep spec may hold, checked when the spec loads (before any work).

Every count of a spec has a named maximum (:data:`LIMITS`), so a typo cannot ask for 10**9
latency steps or reference samples and run for ever; every other value is checked as the
code that uses it will read it (``training.every = 0`` would be a slice step of zero,
``evaluation.mus = []`` an evaluation without a point, ``training.positions = 1`` a lattice
without a spacing, ``load_scale = 0`` a reference at rest, which no relative error measures,
``evaluation.t_end`` below the scene's ``dt`` a trajectory without a step). The options of a
method are checked against its constructor: the type its signature declares (an integer option
is an integer: not ``1.5``, ``"3"`` or ``true``), finite numbers, integers at most
:data:`MAX_OPTION_INT`, then the constructor itself runs (its own range checks:
``n_modes >= 1`` ...). :data:`MAX_UNITS` bounds the units one spec
expands to (``--max-units`` overrides it); it is counted before the grid is expanded.

Every error is a ValueError ``"<key path> = <value>: <what is expected>"``.
"""
from __future__ import annotations

import functools
import inspect
import math

from ..cases.schema import is_num, value_text
from .path_range import DEFAULT_REFINE, range_scenes
from .path_runs import PATH_RUN_KEYS

__all__ = ["LIMITS", "MAX_UNITS", "MAX_BEYOND_FACTOR", "MAX_LOAD_SCALE", "MAX_OPTION_INT", "check_count",
           "check_load_scale", "check_protocol", "check_option_values", "check_path_runs"]

LIMITS = {
    # protocol
    "latency_steps": 100_000, "warmup": 100_000, "blas_threads": 256, "reference_samples": 1_000,
    "seed": 2 ** 32 - 1, "latency_budget_s": 86_400,
    # training
    "every": 10_000, "repeat": 100, "positions": 1_000, "load_steps": 10_000, "runs": 100,
    # evaluation
    "held_out": 1_000, "beyond": 100, "refine": 64, "mus": 1_000, "steps_per_length": 10_000, "count": 10_000,
    "trajectory_steps": 1_000_000,  # t_end / dt of a trajectory evaluation
}
MAX_UNITS = 10_000
#: the largest ``evaluation.beyond`` factor (times the path's top load). The continued reference
#: stops at 1 + BEYOND_MAX_INCREMENTS (5) times the top, so points past it only check that a model
#: flags itself (the shipped presets ask up to 100x); below 1e6 every load factor the code derives
#: from it stays finite: factor x load_steps (the continuation's increments, at most 1e6 x 1e5),
#: factor x top, and a model's powers of it (an ANM series: 1e300 x the top overflowed there)
MAX_BEYOND_FACTOR = 1e6
#: the largest ``load_scale`` in magnitude (times the scene's loads: an evaluation's, a training run's,
#: a case's ``mu``), for the reason of MAX_BEYOND_FACTOR: every number derived from the loads (the
#: load factor, its square in an energy, a model's powers of it) stays far inside the float range
#: for a scene whose own loads do. Far past it they overflow: at 1e306 the clamped beam's reference
#: solved (linear), then the model's state was NaN at its second step; at 1e308 the 20 N load is inf. At 1e6 a
#: model that cannot follow says so (pgd_direct: "outside the vademecum; linearly extrapolated").
MAX_LOAD_SCALE = 1e6
MAX_OPTION_INT = 1_000_000  # an integer option (modes, segments, iterations) beyond it is a typo
_PROTOCOL_MIN = {"latency_steps": 1, "warmup": 0, "blas_threads": 0, "reference_samples": 1, "seed": 0}


def _fail(path, value, what):
    raise ValueError(f"{path} = {value_text(value)}: {what}")


def check_count(path, value, name, lo=1):
    """``value`` an integer in ``[lo, LIMITS[name]]`` (not a bool, not a float)."""
    hi = LIMITS[name]
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        _fail(path, value, f"expected an integer from {lo} to {hi} (the maximum LIMITS[{name!r}] of "
              "tissuebench.studies.limits)")
    return value


def check_load_scale(path, value) -> float:
    """``value`` a ``load_scale``: a finite number, not 0 (a zero load leaves the reference at rest:
    every relative error is inf), at most :data:`MAX_LOAD_SCALE` in magnitude. A negative scale
    reverses the loads (a push for a pull): a load like another."""
    if not is_num(value):
        _fail(path, value, "expected a finite number (the factor on every load of the scene)")
    if value == 0:
        _fail(path, value, "must not be 0 (a zero load has no relative error: the reference stays at rest; a "
              "negative scale reverses the loads)")
    if abs(value) > MAX_LOAD_SCALE:
        _fail(path, value, f"expected at most {MAX_LOAD_SCALE:g} in magnitude (MAX_LOAD_SCALE of "
              "tissuebench.studies.limits): far past it the loads, and the products the models form of them, "
              "overflow the float range (a NaN deep inside a run, after its references)")
    return value


def check_protocol(path, protocol: dict) -> None:
    for k, v in protocol.items():
        if k == "latency_budget_s":  # seconds: any positive number
            if not is_num(v) or not 0 < v <= LIMITS[k]:
                _fail(f"{path}.{k}", v, f"expected a number of seconds > 0 and at most {LIMITS[k]} "
                      f"(LIMITS[{k!r}])")
            continue
        check_count(f"{path}.{k}", v, k, _PROTOCOL_MIN[k])


def _numbers(path, value, name, lo=1, positive=False, hi=None):
    """A list of ``lo`` .. ``LIMITS[name]`` finite numbers (> 0 with ``positive``, <= ``hi``)."""
    if not isinstance(value, list) or not lo <= len(value) <= LIMITS[name]:
        _fail(path, value, f"expected a list of {lo} to {LIMITS[name]} numbers (LIMITS[{name!r}])")
    for i, x in enumerate(value):
        if not is_num(x) or (positive and x <= 0):
            _fail(f"{path}[{i}]", x, "expected a finite number" + (" > 0" if positive else ""))
        if hi is not None and x > hi[0]:
            _fail(f"{path}[{i}]", x, f"expected at most {hi[0]:g} ({hi[1]})")
    return value


def _mu_tables(path, value, name, scene, lo=1):
    """A list of ``lo`` .. ``LIMITS[name]`` parameter tables, each one the scene accepts."""
    if not isinstance(value, list) or not lo <= len(value) <= LIMITS[name]:
        _fail(path, value, f"expected a list of {lo} to {LIMITS[name]} parameter tables (LIMITS[{name!r}])")
    for i, mu in enumerate(value):
        if not isinstance(mu, dict):
            _fail(f"{path}[{i}]", mu, "expected a table of scene parameters")
        if "load_scale" in mu:
            check_load_scale(f"{path}[{i}].load_scale", mu["load_scale"])
        _at(f"{path}[{i}]", scene, mu)
    return value


def _at(path, scene, mu):
    try:
        return scene.at(mu)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from None


def _needs_position(path, kind, scene):
    if "position" not in scene.parameters:
        _fail(f"{path}.kind", kind, f"needs a scene with a [parameters.position] table; {scene.name!r} has none")


def _needs_dynamics(path, kind, scene):
    if scene.analysis.get("type") != "dynamic":
        _fail(f"{path}.kind", kind, f"needs a dynamic scene; {scene.name!r} is {scene.analysis.get('type')!r}")


# ------------------------------------------------------------------------------ kinds' values
# One function per training / evaluation kind (``Kind.check``: ``(path, table, scene, training)``);
# a table's keys are already known to its kind (:mod:`.kinds`).
def check_path_training(path, training: dict, scene, _training=None) -> None:
    for key in ("every", "repeat"):
        if key in training:
            check_count(f"{path}.{key}", training[key], key)
    if "runs" in training:
        check_path_runs(f"{path}.runs", training["runs"], scene)


def check_path_runs(path, runs, scene) -> None:
    """A path training's ``runs`` (:mod:`.path_runs`): a list of at most ``LIMITS["runs"]`` tables
    setting only :data:`~.path_runs.PATH_RUN_KEYS`, each a positive ``max_load_factor`` and a
    ``load_steps`` count, that the scene accepts."""
    if not isinstance(runs, list) or len(runs) > LIMITS["runs"]:
        _fail(path, runs, f"expected a list of at most {LIMITS['runs']} tables (LIMITS['runs'])")
    for i, run in enumerate(runs):
        if not isinstance(run, dict):
            _fail(f"{path}[{i}]", run, "expected a table { max_load_factor = ..., load_steps = ... }")
        for key, value in run.items():
            if key not in PATH_RUN_KEYS:
                _fail(f"{path}[{i}].{key}", value, f"a run of a path training sets only {list(PATH_RUN_KEYS)} (the "
                      "load factor is the model's parameter: give any other as the case's mu)")
        if "max_load_factor" in run and (not is_num(run["max_load_factor"]) or run["max_load_factor"] <= 0):
            _fail(f"{path}[{i}].max_load_factor", run["max_load_factor"], "expected a finite number > 0")
        if "load_steps" in run:
            check_count(f"{path}[{i}].load_steps", run["load_steps"], "load_steps")
        _at(f"{path}[{i}]", scene, run)


def check_positions_training(path, training: dict, scene, _training=None) -> None:
    _needs_position(path, "positions", scene)
    positions = training.get("positions", 5)
    if isinstance(positions, list):
        _numbers(f"{path}.positions", positions, "positions", lo=2)
        if len(set(positions)) != len(positions):
            _fail(f"{path}.positions", positions, "positions must be distinct")
    else:
        check_count(f"{path}.positions", positions, "positions", lo=2)  # one point has no spacing
    if "load_steps" in training:
        check_count(f"{path}.load_steps", training["load_steps"], "load_steps")
    mu = {k: training[k] for k in ("max_load_factor", "load_steps") if k in training}
    lo, _ = scene.parameters["position"]["range"]
    _at(path, scene, {**mu, "position": lo})


def check_trajectory_training(path, training: dict, scene, _training=None) -> None:
    _needs_dynamics(path, "trajectory", scene)
    if "runs" in training:
        _mu_tables(f"{path}.runs", training["runs"], "runs", scene, lo=0)


def check_nothing(path, table: dict, scene, training=None) -> None:
    """A kind without options (``operators``)."""


def check_path_evaluation(path, evaluation: dict, scene, training: dict | None = None) -> None:
    if "every" in evaluation:
        check_count(f"{path}.every", evaluation["every"], "every")
    if "held_out" in evaluation:
        if not isinstance(evaluation["held_out"], bool):
            _fail(f"{path}.held_out", evaluation["held_out"], "expected true or false")
        t = training or {}
        if evaluation["held_out"] and (t.get("kind") != "path" or t.get("every", 1) < 2):
            _fail(f"{path}.held_out", evaluation["held_out"], "the states a path training left out: needs "
                  "training = { kind = \"path\", every = 2 } (or more)")
    if "beyond" in evaluation:
        _numbers(f"{path}.beyond", evaluation["beyond"], "beyond", lo=0, positive=True,
                 hi=(MAX_BEYOND_FACTOR, "times the path's top load: MAX_BEYOND_FACTOR of tissuebench.studies.limits"))
    if "refine" in evaluation:  # parts of a training interval: 1 keeps the path's states only
        check_count(f"{path}.refine", evaluation["refine"], "refine")
    t = training or {}
    refine = evaluation.get("refine", DEFAULT_REFINE)
    try:  # the finer paths are scenes at other load steps: within the scene's limits
        range_scenes(scene, t.get("every", 1) if t.get("kind") == "path" else 1, refine)
    except ValueError as exc:
        _fail(f"{path}.refine", refine, f"the finer reference path between the training states: {exc}")
    if "extrapolation" in evaluation and not isinstance(evaluation["extrapolation"], bool):
        _fail(f"{path}.extrapolation", evaluation["extrapolation"], "expected true or false (true: the validity "
              "radius counts the points past the training range)")


def check_positions_evaluation(path, evaluation: dict, scene, training: dict | None = None) -> None:
    _needs_position(path, "positions", scene)
    held = evaluation.get("held_out")
    if isinstance(held, list):
        _numbers(f"{path}.held_out", held, "held_out")
        for i, s in enumerate(held):
            _at(f"{path}.held_out[{i}]", scene, {"position": s})
    elif held is not None:
        check_count(f"{path}.held_out", held, "held_out")


def check_trajectory_evaluation(path, evaluation: dict, scene, training: dict | None = None) -> None:
    _needs_dynamics(path, "trajectory", scene)
    if "load_scale" in evaluation:
        check_load_scale(f"{path}.load_scale", evaluation["load_scale"])
    t_end, dt = evaluation.get("t_end"), scene.analysis["dt"]
    if is_num(t_end) and 0 < t_end < dt:  # no step to measure (the run's arrays were empty downstream)
        unit = scene.units.get("time", "s")
        _fail(f"{path}.t_end", t_end, f"below the scene's time step dt = {dt:g} {unit}: a trajectory needs at "
              "least one step (t_end >= dt)")
    mu = {k: evaluation[k] for k in ("t_end", "load_scale") if k in evaluation}
    run = _at(path, scene, mu)
    steps = run.analysis["t_end"] / run.analysis["dt"]
    if not steps <= LIMITS["trajectory_steps"]:
        _fail(f"{path}.t_end", run.analysis["t_end"], f"{steps:.3g} time steps of dt = {run.analysis['dt']:g}; "
              f"at most {LIMITS['trajectory_steps']} (LIMITS['trajectory_steps'])")
    if "from_time" in evaluation:
        start = evaluation["from_time"]
        if not is_num(start) or not 0 <= start < run.analysis["t_end"]:
            _fail(f"{path}.from_time", start, f"expected a time in [0, t_end = {run.analysis['t_end']:g}) (the "
                  "window of the evaluation)")


def check_map_evaluation(path, evaluation: dict, scene, training: dict | None = None) -> None:
    _mu_tables(f"{path}.mus", evaluation.get("mus"), "mus", scene)


def check_cut_lengths_evaluation(path, evaluation: dict, scene, training: dict | None = None) -> None:
    if "steps_per_length" in evaluation:
        check_count(f"{path}.steps_per_length", evaluation["steps_per_length"], "steps_per_length")


def check_contact_nodes_evaluation(path, evaluation: dict, scene, training: dict | None = None) -> None:
    if "count" in evaluation:
        check_count(f"{path}.count", evaluation["count"], "count")


# ------------------------------------------------------------------------------ method options
def _declared(param) -> str:
    """The kind of value an option takes: 'bool', 'int', 'float', 'str' or '' (anything),
    from its annotation (``int | None`` ...) or, without one, its default."""
    note, default = param.annotation, param.default
    text = note if isinstance(note, str) else getattr(note, "__name__", "") if note is not inspect.Parameter.empty \
        else ""
    for kind in ("bool", "int", "float", "str"):
        if kind in text.replace(" ", "").split("|"):
            return kind
    if isinstance(default, bool):
        return "bool"
    for kind, typ in (("int", int), ("float", float), ("str", str)):
        if isinstance(default, typ):
            return kind
    return ""


def _nullable(param) -> bool:
    note = param.annotation if isinstance(param.annotation, str) else ""
    return param.default is None or "None" in note


def _finite(path, value):
    if isinstance(value, float) and not math.isfinite(value):
        _fail(path, value, "expected a finite number")
    if isinstance(value, list):
        for i, x in enumerate(value):
            _finite(f"{path}[{i}]", x)
    if isinstance(value, dict):
        for k, x in value.items():
            _finite(f"{path}.{k}", x)


def _check_value(path, name, value, param):
    kind = _declared(param)
    _finite(f"{path}.{name}", value)
    if value is None and _nullable(param):
        return
    if kind == "bool" and not isinstance(value, bool):
        _fail(f"{path}.{name}", value, "expected true or false")
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            _fail(f"{path}.{name}", value, "expected an integer")
        limit = 2 ** 63 - 1 if "seed" in name else MAX_OPTION_INT
        if abs(value) > limit:
            _fail(f"{path}.{name}", value, f"expected an integer of at most {limit} in magnitude")
    if kind == "float" and (isinstance(value, bool) or not is_num(value)):
        _fail(f"{path}.{name}", value, "expected a finite number")
    if kind == "str" and not isinstance(value, str):
        _fail(f"{path}.{name}", value, "expected a string")


@functools.lru_cache(maxsize=None)
def _parameters(cls) -> dict:
    return dict(inspect.signature(cls.__init__).parameters)


def check_option_values(path, cls, options: dict, construct: bool = True) -> None:
    """The values of one option set of method ``cls`` (module docstring); ``path`` names the
    spec entry (``method[0].grid``). ``construct=False``: the declared types only."""
    params = _parameters(cls)
    for name, value in options.items():
        if name in params:
            _check_value(path, name, value, params[name])
    if not construct:
        return
    try:
        cls(**options)
    except Exception as exc:  # noqa: BLE001 - a constructor refusing a value (whatever it raises) is bad input
        shown = ", ".join(f"{k} = {value_text(v)}" for k, v in sorted(options.items()))
        raise ValueError(f"{path}: method {cls.name!r} refuses the options {{{shown}}}: {exc}") from None
