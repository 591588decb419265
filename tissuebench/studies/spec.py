"""Sweep specifications (TOML), validated like the scenes, and their expansion into units.

A spec names the cases (catalogue scenes with variant, resolution, backend, what the
methods learn from and where they are measured), the methods of :data:`rom.METHODS` (a
registry name, or ``"module:Class"`` of a method in another package) with a grid of
options, the protocol and the error metric of the derived tables::

    [sweep]
    name = "anm_pod"
    description = "ANM-POD orders x modes (anm-pod §6)"
    resolution = "ci"                 # default resolution of the cases (--resolution overrides)
    error_metric = "claimed_error"    # the error of the Pareto front, the report and the gate

    [protocol]                        # optional; defaults shown
    latency_steps = 2000              # timed haptic steps: 20 samples beyond the p99
    latency_budget_s = 60             # seconds of timing after which a slow model stops short
    warmup = 20
    blas_threads = 1
    reference_samples = 3
    seed = 0

    [[case]]
    name = "liver_palpation"          # catalogue case or scene file; id defaults to the name
    backend = "skfem"                 # variant, resolution, mu = {nu = 0.499} (Scene.at) optional
    mesh = { paper = { divisions = [40, 7, 7] } }   # optional: builder parameters per resolution
    paper_points = [{ label = "paper 74/1880", step_ms = 10.7, error = 0.218 }]  # optional, on the Pareto plot
    scaling_group = "liver"           # optional: this scene on several meshes (studies.scaling)
    training = { kind = "path" }      # path | positions | trajectory | operators (studies.training)
    evaluation = { kind = "path", beyond = [2.0] }   # default: the training's kind (studies.evaluation)

    [[method]]
    name = "anm_pod"
    cases = ["liver_palpation"]       # default: every case whose training kind the method takes
    protocol = { latency_steps = 20 } # optional: this method's protocol (e.g. a full-assembly ROM)
    options = { eps = 1e-6 }          # fixed options
    grid = { n_modes = [1, 4, 9], order = [1, 6] }   # cartesian product (and/or)
    list = [{ n_modes = 2, order = 3 }]             # explicit option sets
    [method.paper]                    # replaces options/grid/list at --resolution paper
    grid = { n_modes = [1, 2, 3], order = [1, 2, 3] }

Every error names the key and the value and lists the valid choices (exit 2 in the CLI);
values are checked when the spec loads, counts against named maxima (:mod:`.limits`), and the
number of units is counted before the grid expands (``max_units``, default
:data:`~.limits.MAX_UNITS`). The same unit listed twice (a ``[[method]]`` repeated) runs once.
"""
from __future__ import annotations

import hashlib
import itertools
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..cases.scene import RESOLUTIONS, list_cases, resolve_toml
from ..choices import BACKEND_NAMES
from ..cases.schema import c_nonneg, c_pos, c_str, check_table, key_text, value_text
from ..rom import METHODS, method_class
from ..rom.plugins import source_of
from .applicability import evaluation_why_not, why_not
from .case_entry import CaseEntry, fill_evaluation_kind, fill_training_kind
from .evaluation import EVALUATION_KINDS
from .limits import MAX_UNITS, check_load_scale, check_option_values, check_protocol
from .scaling import check_group_name, check_scaling_groups
from .training import TRAINING_KINDS, case_scene
from .units import DEFAULT_PROTOCOL, WorkUnit, options_text, unit_key

__all__ = ["PRESETS_DIR", "ERROR_METRICS", "SweepSpec", "load_spec", "list_presets", "expand_units", "check_pair"]

PRESETS_DIR = Path(__file__).resolve().parent / "presets"
ERROR_METRICS = ("claimed_error", "max_rel_l2", "mean_rel_l2", "rmse_rel", "max_rel_l2_in_envelope",
                 "max_monitor_rel_error", "peak_rel_l2", "max_abs_error")
#: a spec without ``error_metric``: the headline error (issue 52, studies/metrics.py)
DEFAULT_ERROR_METRIC = "claimed_error"
_TOP = {"sweep", "protocol", "case", "method"}
_SWEEP = {"name", "description", "resolution", "error_metric"}
_NAME = re.compile(r"[^/\\\x00-\x1f\x7f]{1,100}")  # a spec name is part of a folder name: no separator
_CASE = {"name", "id", "variant", "backend", "resolution", "training", "evaluation", "mu", "mesh", "paper_points",
         "scaling_group"}
# a published configuration drawn beside ours on the case's Pareto plot (paper resolution)
_PAPER_POINT = {"label": c_str, "step_ms": c_pos, "error": c_nonneg}
_METHOD = {"name", "cases", "options", "grid", "list", "paper", "protocol"}
# what each key means: the spec-format reference of the documentation is generated from the key
# sets above, these words and the limits (a key without its words fails the docs' test)
TOP_DOC = {"sweep": "the sweep's name, description, resolution and error metric",
           "protocol": "how each unit is timed (optional; the defaults below)",
           "case": "array of tables `[[case]]`: the scenes, what the methods learn from and where they are measured",
           "method": "array of tables `[[method]]`: the methods and their option sets"}
SWEEP_DOC = {"name": "names the results folder `out/sweep-NAME-RES` (default: the file's name)",
             "description": "one line (`tissuebench sweep --list` shows it)",
             "resolution": "the cases' default resolution (`--resolution` overrides; default `\"ci\"`)",
             "error_metric": "the error of the Pareto front, the report and the gate (default `\"claimed_error\"`: "
                             "the headline, peak-normalised over the claimed range)"}
CASE_DOC = {"name": "a catalogue case or the path of a scene file (relative to the spec's folder)",
            "id": "the case's id in the results (default: the name); a case listed twice needs ids",
            "variant": "the scene's variant", "backend": "the reference's backend (default `\"skfem\"`)",
            "resolution": "this case's resolution (default: the sweep's)",
            "training": "what the methods learn from: `{ kind = ..., <its keys> }` (default `{ kind = \"path\" }`)",
            "evaluation": "where the methods are measured: `{ kind = ..., <its keys> }` (default: the training's kind)",
            "mu": "the scene at these parameters (`Scene.at`: `position`, `load_scale`, `nu`, `E`, ..., "
                  "`max_load_factor`, `load_steps`, `t_end`, `dt`, `integrator`); training and evaluation both run "
                  "at it",
            "mesh": "another mesh of the scene's builder per resolution: `{ paper = { divisions = [40, 7, 7] } }`",
            "paper_points": "published points drawn on this case's Pareto plot at paper resolution: "
                            "`[{ label, step_ms, error }]`",
            "scaling_group": "this scene on several meshes (the cost-versus-size fits); the cases of a group "
                             "differ only in `mesh`"}
METHOD_DOC = {"name": "a registered method (`tissuebench methods`)",
              "cases": "the case ids it runs on (default: every case whose training kind it learns from and to "
                       "which it applies)",
              "options": "options fixed for every set", "grid": "`{ option = [values] }`: the cartesian product",
              "list": "explicit option sets `[{ ... }, ...]` (with and/or instead of `grid`)",
              "paper": "`{ options, grid, list }` replacing them at `--resolution paper`",
              "protocol": "this method's protocol overrides (e.g. fewer timed steps for a full-assembly ROM)"}
ERROR_METRICS_DOC = {"claimed_error": "the headline: max ||u_rom - u_ref|| over the claimed range (a path's training "
                                      "range: held-out states, quarter points, near rest; every point of a motion) / "
                                      "max ||u_ref|| over it",
                     "max_rel_l2": "the largest relative l2 error of the full field over the evaluation points",
                     "mean_rel_l2": "the mean relative l2 error over the points",
                     "rmse_rel": "sqrt(sum ||u_rom - u_ref||^2 / sum ||u_ref||^2) over the points",
                     "max_rel_l2_in_envelope": "the largest relative l2 error over the points inside the training "
                                               "envelope",
                     "max_monitor_rel_error": "the largest relative error of the monitored outputs",
                     "peak_rel_l2": "max ||u_rom - u_ref|| over the points / max ||u_ref||: the worst step's error "
                                    "against the run's peak displacement (a motion)",
                     "max_abs_error": "the largest nodal displacement error, in the scene's length unit (not relative)"}
BACKENDS = BACKEND_NAMES


def _fail(path, value, what):
    raise ValueError(f"{path} = {value_text(value)}: {what}")


def _table(path, value, keys):
    if not isinstance(value, dict):
        _fail(path, value, "expected a table")
    for k in value:
        if k not in keys:
            raise ValueError(f"{path}.{key_text(k)}: unknown key (valid: {sorted(keys)})")
    return value


@dataclass
class SweepSpec:
    name: str
    description: str
    resolution: str
    error_metric: str
    protocol: dict
    cases: list  # of CaseEntry, in spec order
    methods: list
    text: str
    source: str
    # (case, method, options) pairs left out because the method does not apply, each with why
    skipped: list = field(default_factory=list)

    @property
    def hash(self) -> str:
        return hashlib.sha256(f"{self.text}\0{self.resolution}".encode()).hexdigest()


def list_presets() -> list[tuple[str, str]]:
    """``(name, description)`` of the shipped presets."""
    out = []
    for p in sorted(PRESETS_DIR.glob("*.toml")):
        raw = tomllib.loads(p.read_text())
        out.append((p.stem, raw.get("sweep", {}).get("description", "")))
    return out


def _resolve(spec_or_preset) -> Path:
    return resolve_toml(spec_or_preset, PRESETS_DIR, "preset", lambda: [n for n, _ in list_presets()])


def _check_case(i, c, resolution, default_resolution, folder: Path | None = None):
    path = f"case[{i}]"
    _table(path, c, _CASE)
    if "name" not in c:
        raise ValueError(f"{path}.name: missing required key")
    name = c["name"]
    if isinstance(name, str) and folder is not None and name not in list_cases() and _is_file(str(folder / name)) \
            and not Path(name).is_absolute():
        # a scene file named relative to the spec's folder (a spec written by sweep --scene) is that
        # one, whatever lies at the same relative path from the working folder
        name = str((folder / name).resolve())
    elif isinstance(name, str) and name not in list_cases() and not Path(name).is_absolute() \
            and not _is_file(name) and _is_file(str(PRESETS_DIR / name)):
        # a scene shipped with the presets (presets/scenes/), also from a copy of a preset elsewhere
        name = str((PRESETS_DIR / name).resolve())
    if not isinstance(name, str) or (name not in list_cases() and not _is_file(name)):
        _fail(f"{path}.name", name, f"unknown case; valid: {list_cases()}")
    backend = c.get("backend", "skfem")
    if backend not in BACKENDS:
        _fail(f"{path}.backend", backend, f"valid: {list(BACKENDS)}")
    res = resolution or c.get("resolution", default_resolution)
    if res not in RESOLUTIONS:
        _fail(f"{path}.resolution", res, f"valid: {list(RESOLUTIONS)}")
    training = dict(_table(f"{path}.training", c.get("training", {"kind": "path"}), {"kind"} | set().union(
        *(k.keys for k in TRAINING_KINDS.values()))))
    kind = fill_training_kind(training, f"{path}.training")
    _table(f"{path}.training", training, {"kind"} | TRAINING_KINDS[kind].keys)
    evaluation = dict(_table(f"{path}.evaluation", c.get("evaluation", {}), {"kind"} | set().union(
        *(k.keys for k in EVALUATION_KINDS.values()))))
    ekind = fill_evaluation_kind(evaluation, kind, f"{path}.evaluation")
    _table(f"{path}.evaluation", evaluation, {"kind"} | EVALUATION_KINDS[ekind].keys)
    cid = c.get("id", Path(name).stem)
    if not (isinstance(cid, str) and re.fullmatch(r"[A-Za-z0-9_.-]+", cid) and cid not in (".", "..")):
        _fail(f"{path}.id", cid, "a case id names a results folder: letters, digits, '_', '.', '-' only")
    entry = {"id": cid, "name": name, "variant": c.get("variant"),
             "resolution": res, "backend": backend, "training": training, "evaluation": evaluation}
    if "mu" in c:
        entry["mu"] = _table(f"{path}.mu", c["mu"], set(c["mu"]) if isinstance(c["mu"], dict) else set())
        if "load_scale" in entry["mu"]:  # the case's loads: at rest or overflowing, no error measures them
            check_load_scale(f"{path}.mu.load_scale", entry["mu"]["load_scale"])
    if "mesh" in c:  # builder parameters per resolution: {paper = {divisions = [40, 7, 7]}}
        mesh = _table(f"{path}.mesh", c["mesh"], set(RESOLUTIONS))
        entry["mesh"] = {r: dict(_table(f"{path}.mesh.{r}", t, set(t) if isinstance(t, dict) else set()))
                         for r, t in mesh.items()}
    if "paper_points" in c:
        points = c["paper_points"]
        if not isinstance(points, list) or not points:
            _fail(f"{path}.paper_points", points, "expected a non-empty array of tables {label, step_ms, error}")
        entry["paper_points"] = [check_table(f"{path}.paper_points[{j}]", dict(p) if isinstance(p, dict) else p,
                                             _PAPER_POINT, required=tuple(_PAPER_POINT)) for j, p in enumerate(points)]
    if "scaling_group" in c:  # one scene on several meshes: the cost-versus-size fits (studies/scaling.py)
        entry["scaling_group"] = check_group_name(f"{path}.scaling_group", c["scaling_group"])
    entry = _named(path, CaseEntry, **entry)
    scene = _named(path, case_scene, entry)  # the scene must load and take the mu (their errors name the key)
    TRAINING_KINDS[kind].check(f"{path}.training", training, scene, None)
    EVALUATION_KINDS[ekind].check(f"{path}.evaluation", evaluation, scene, training)
    return entry, scene


def _is_file(name: str) -> bool:
    try:
        return Path(name).is_file()
    except (OSError, ValueError):  # a NUL byte, a name too long for the file system
        return False


def _named(path, fn, *args, **kwargs):
    """Call ``fn(*args, **kwargs)``; a ValueError it raises is re-raised prefixed with the spec ``path``."""
    try:
        return fn(*args, **kwargs)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _option_sets(path, m, cls, max_sets):
    """The option sets of a method entry: ``options`` merged into each grid point and list entry
    (distinct, in order; counted before the grid is expanded: at most ``max_sets``)."""
    grid, fixed, explicit = m.get("grid", {}), m.get("options", {}), m.get("list", [])
    for key, value in (("grid", grid), ("options", fixed)):
        if not isinstance(value, dict):
            _fail(f"{path}.{key}", value, "expected a table")
        _named(f"{path}.{key}", cls.check_options, value)
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            _fail(f"{path}.grid.{key}", values, "expected a non-empty list of values")
    if not isinstance(explicit, list) or not all(isinstance(o, dict) for o in explicit):
        _fail(f"{path}.list", explicit, "expected an array of option tables")
    for j, o in enumerate(explicit):
        _named(f"{path}.list[{j}]", cls.check_options, o)
    n = math.prod(len(v) for v in grid.values()) if grid else 0
    if n + len(explicit) > max_sets:
        _fail(f"{path}.grid", {k: f"{len(v)} values" for k, v in grid.items()},
              f"{n + len(explicit)} option sets; at most {max_sets} units may be planned (--max-units)")
    for key, values in grid.items():  # the type of each value once, before the product
        for v in values:
            check_option_values(f"{path}.grid", cls, {key: v}, construct=False)
    sets = (dict(zip(grid, combo)) for combo in itertools.product(*grid.values())) if grid else iter(())
    if not grid and not explicit and ("grid" in m or "list" in m):
        _fail(f"{path}.grid", grid, "the grid and list give no option set")
    out = {}
    for where, o in itertools.chain(((f"{path}.grid", o) for o in sets),
                                    ((f"{path}.list[{j}]", o) for j, o in enumerate(explicit))):
        opts = {**fixed, **o}
        text = options_text(opts)
        if text not in out:
            check_option_values(where, cls, opts)
            out[text] = opts
    if not out:
        check_option_values(f"{path}.options", cls, dict(fixed))
        out[options_text(fixed)] = dict(fixed)
    return list(out.values())


def _check_method(i, m, cases, resolution, max_sets, scenes, skipped):
    path = f"method[{i}]"
    _table(path, m, _METHOD)
    name = m.get("name")
    if not isinstance(name, str) or (":" not in name and name not in METHODS):
        _fail(f"{path}.name", name, f"unknown method; valid: {sorted(METHODS)} (or 'module:Class' of a method in "
              "another package)")
    try:  # a "module:Class" name: imported and registered under the class's name (rom.plugins)
        cls = method_class(name)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}.name: {exc}") from None
    gone = cls.unavailable()
    if gone:  # a library it wraps is not installed here: its cases are skipped, saying why (RomMethod.unavailable)
        wanted = m.get("cases")
        ids = wanted if isinstance(wanted, list) else [c.id for c in cases if c.training_kind in cls.training_kinds]
        skipped.extend({"case": c, "method": cls.name, "options": "", "why": gone} for c in ids)
        return None
    if resolution == "paper" and "paper" in m:  # the paper grid replaces grid/list; options merge
        paper = _table(f"{path}.paper", m["paper"], {"options", "grid", "list"})
        for where, table in ((f"{path}.options", m), (f"{path}.paper.options", paper)):
            if not isinstance(table.get("options", {}), dict):
                _fail(where, table["options"], "expected a table")
        src, opath = {**paper, "options": {**m.get("options", {}), **paper.get("options", {})}}, f"{path}.paper"
    else:
        src, opath = m, path
    sets = _option_sets(opath, src, cls, max_sets)
    ids = [c.id for c in cases]
    wanted = m.get("cases")
    if wanted is None:
        chosen = [c for c in cases if c.training_kind in cls.training_kinds]
        if not chosen:
            _fail(f"{path}.name", name, f"learns from {list(cls.training_kinds)} training sets; no case of the spec "
                  f"offers one (case trainings: {[c.training_kind for c in cases]})")
    else:
        if not isinstance(wanted, list) or not wanted:
            _fail(f"{path}.cases", wanted, "expected a non-empty list of case ids")
        for w in wanted:
            if w not in ids:
                _fail(f"{path}.cases", w, f"not a case id of this spec; valid: {ids}")
        chosen = [c for c in cases if c.id in wanted]
        for c in chosen:
            if c.training_kind not in cls.training_kinds:
                _fail(f"{path}.cases", c.id, f"its training kind {c.training_kind!r} is not one method "
                      f"{name!r} learns from ({list(cls.training_kinds)})")
    chosen, excluded = _applicable(path, cls, chosen, wanted is not None, sets, scenes, skipped)
    protocol = _table(f"{path}.protocol", m.get("protocol", {}), set(DEFAULT_PROTOCOL))
    return {"name": cls.name, "source": source_of(cls), "cases": [c.id for c in chosen], "option_sets": sets,
            "protocol": protocol, "excluded": excluded}


def _applicable(path, cls, chosen, explicit, sets, scenes, skipped):
    """``(cases, excluded (case id, options text) pairs)`` of a method entry that apply
    (:mod:`.applicability`), before any reference is computed: a pair the entry names
    (``cases = [...]``) is refused, one chosen by default is skipped and recorded in
    ``skipped`` (``{"case", "method", "options", "why"}``, one line each in the CLI)."""
    keep, excluded, reasons = [], [], []
    for c in chosen:
        scene = scenes[c.id]
        why = why_not(cls, scene, c.training_kind) or evaluation_why_not(cls, c, scene)
        bad = {} if why else {options_text(o): r for o in sets if (r := cls.why_not(scene, o))}
        if why or len(bad) == len(sets):
            why = why or next(iter(bad.values()))
            if explicit:
                _fail(f"{path}.cases", c.id, f"method {cls.name!r} does not apply to this case: {why}")
            skipped.append({"case": c.id, "method": cls.name, "options": "", "why": why})
            reasons.append(f"{c.id}: {why}")
            continue
        for text, r in bad.items():
            if explicit:
                _fail(f"{path}.cases", c.id, f"method {cls.name!r} with options {text} does not apply to this "
                      f"case: {r}")
            skipped.append({"case": c.id, "method": cls.name, "options": text, "why": r})
            excluded.append((c.id, text))
        keep.append(c)
    if not keep:
        _fail(f"{path}.name", cls.name, "applies to no case of the spec: " + "; ".join(reasons))
    return keep, excluded


def check_pair(case: dict, method, options: dict | None = None):
    """What a spec of this one ``[[case]]`` table and one ``[[method]]`` naming it (a registry or
    ``"module:Class"`` name, or a class) with ``options`` is checked for when it loads: the
    validated :class:`~.case_entry.CaseEntry`, or the ValueError :func:`load_spec` would raise
    (:mod:`tissuebench.testing` asks it whether an evaluation is refused before any work)."""
    entry, scene = _check_case(0, case, None, case.get("resolution", "ci"))
    cls = method_class(method)
    sets = [dict(options or {})]
    cls.check_options(sets[0])
    check_option_values("method[0].options", cls, sets[0])
    _applicable("method[0]", cls, [entry], True, sets, {entry.id: scene}, [])
    return entry


def _read(path: Path) -> tuple[str, dict]:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        return text, tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None


def _check_sweep_table(sweep: dict, path: Path) -> tuple[str, str]:
    """``(name, description)``; the name becomes part of the default results folder."""
    name = sweep.get("name", path.stem)
    if not isinstance(name, str) or not _NAME.fullmatch(name) or name.strip() in ("", ".", ".."):
        _fail("sweep.name", name, "expected 1 to 100 printable characters without '/' or '\\' (it names the "
              "results folder out/sweep-NAME-RES)")
    description = sweep.get("description", "")
    if not isinstance(description, str) or len(description) > 2000:
        _fail("sweep.description", description, "expected a string of at most 2000 characters")
    return name, description


def load_spec(spec_or_preset, resolution: str | None = None, only: list | None = None,
              max_units: int | None = None) -> SweepSpec:
    """Read and validate a sweep spec (a path or a preset name); ``resolution`` overrides the
    cases'; ``only`` (case ids) keeps those cases and the methods' units on them; more than
    ``max_units`` units (default :data:`~.limits.MAX_UNITS`) is refused before expanding them."""
    max_units = MAX_UNITS if max_units is None else max_units
    if isinstance(max_units, bool) or not isinstance(max_units, int) or max_units < 1:
        _fail("--max-units", max_units, "expected a positive integer")
    path = _resolve(spec_or_preset)
    text, raw = _read(path)
    for key in raw:
        if key not in _TOP:
            raise ValueError(f"{key_text(key)}: unknown top-level key in {path} (valid: {sorted(_TOP)})")
    sweep = _table("sweep", raw.get("sweep", {}), _SWEEP)
    name, description = _check_sweep_table(sweep, path)
    if resolution is not None and resolution not in RESOLUTIONS:
        _fail("resolution", resolution, f"valid: {list(RESOLUTIONS)}")
    res = resolution or sweep.get("resolution", "ci")
    if res not in RESOLUTIONS:
        _fail("sweep.resolution", res, f"valid: {list(RESOLUTIONS)}")
    metric = sweep.get("error_metric", DEFAULT_ERROR_METRIC)
    if metric not in ERROR_METRICS:
        _fail("sweep.error_metric", metric, f"unknown metric; valid: {list(ERROR_METRICS)}")
    protocol = {**DEFAULT_PROTOCOL, **_table("protocol", raw.get("protocol", {}), set(DEFAULT_PROTOCOL))}
    check_protocol("protocol", protocol)
    raw_cases = raw.get("case", [])
    if not isinstance(raw_cases, list) or not raw_cases:
        raise ValueError(f"case: a sweep needs at least one [[case]] ({path})")
    checked = [_check_case(i, c, resolution, res, path.parent) for i, c in enumerate(raw_cases)]
    cases, scenes = [c for c, _ in checked], {c.id: s for c, s in checked}
    ids = [c.id for c in cases]
    if len(set(ids)) != len(ids):
        _fail("case", ids, "case ids must be unique (give `id` to a case listed twice)")
    check_scaling_groups([c.as_dict() for c in cases])
    raw_methods = raw.get("method", [])
    if not isinstance(raw_methods, list) or not raw_methods:
        raise ValueError(f"method: a sweep needs at least one [[method]] ({path})")
    skipped = []
    methods = [m for m in (_check_method(i, m, cases, res, max_units, scenes, skipped)
                           for i, m in enumerate(raw_methods)) if m is not None]
    if not methods:
        _fail("method", [s["method"] for s in skipped], "no method of the spec can run here: "
              + "; ".join(dict.fromkeys(s["why"] for s in skipped)))
    if only is not None:
        unknown = sorted(set(only) - set(ids)) if isinstance(only, (list, tuple, set)) and only else [only]
        if unknown:
            _fail("--cases", unknown[0], f"not a case id of {path.name}; valid: {ids}")
        cases = [c for c in cases if c.id in only]
        skipped = [s for s in skipped if s["case"] in only]
        methods = [{**m, "cases": [c for c in m["cases"] if c in only],
                    "excluded": [e for e in m["excluded"] if e[0] in only]} for m in methods]
        methods = [m for m in methods if m["cases"]]
        if not methods:
            _fail("--cases", ",".join(only), "no method of the spec runs on these cases: the sweep would select no "
                  "unit")
    for i, m in enumerate(methods):
        m["protocol"] = {**protocol, **m["protocol"]}
        check_protocol(f"method[{i}].protocol", m["protocol"])
    planned = sum(len(m["option_sets"]) * len(m["cases"]) - len(m["excluded"]) for m in methods)
    if planned > max_units:
        _fail("method", f"{planned} units", f"at most {max_units} units may be planned (--max-units raises the "
              "limit)")
    return SweepSpec(name, description, res, metric, protocol, cases, methods, text, str(path), skipped)


def expand_units(spec: SweepSpec) -> list[WorkUnit]:
    """One :class:`WorkUnit` per distinct (case, method, option set), keys computed: in spec
    order, except that the option sets of one nested group (one parent, :func:`_nested_parents`)
    run one after another, where the group first appears, so that a process builds each
    parent once (a grid whose nested option varies fastest would otherwise interleave the
    groups and rebuild their parents unit after unit). A unit planned twice (the same
    ``[[method]]`` listed twice) is kept once. Linear in the number of units."""
    scene_hashes = {c.id: case_scene(c).content_hash() for c in spec.cases}
    by_id = {c.id: c for c in spec.cases}
    meta = {"name": spec.name, "hash": spec.hash}
    units, seen = [], set()
    for m in spec.methods:
        parents = _nested_parents(m["name"], m["option_sets"])
        groups = {}
        for i, parent in enumerate(parents):
            groups.setdefault(i if parent is None else options_text(parent), []).append(i)
        order = [i for members in groups.values() for i in members]
        excluded = set(m.get("excluded", ()))
        for cid in m["cases"]:
            for opts, parent in ((m["option_sets"][i], parents[i]) for i in order):
                if (cid, options_text(opts)) in excluded:
                    continue
                case = by_id[cid]
                key = unit_key(case, scene_hashes[cid], m["name"], opts, m["protocol"])
                if key not in seen:
                    seen.add(key)
                    units.append(WorkUnit(case, m["name"], opts, dict(m["protocol"]), meta, key, parent,
                                          m.get("source", "")))
    return units


def _nested_parents(method: str, option_sets: list) -> list:
    """Per option set, the options with the method's nested options at the maximum over the
    sets that agree on every other option (None when nothing is nested or a value is not a
    number). One pass to group the sets, one to read the groups: linear in the sets."""
    nested = method_class(method).nested
    if not nested:
        return [None] * len(option_sets)
    rest_of = [options_text({k: v for k, v in o.items() if k not in nested}) for o in option_sets]
    groups: dict = {}
    for opts, rest in zip(option_sets, rest_of):
        groups.setdefault(rest, []).append(opts)
    tops: dict = {}
    for rest, group in groups.items():
        top = {}
        for k in nested:
            values = [o.get(k) for o in group]
            top[k] = max(values) if all(isinstance(v, int) and not isinstance(v, bool) for v in values) else None
        tops[rest] = top
    out = []
    for opts, rest in zip(option_sets, rest_of):
        top = tops[rest]
        if len(groups[rest]) < 2 or any(k not in opts or top[k] is None for k in nested):
            out.append(None)
        else:
            out.append({**opts, **top})
    return out
