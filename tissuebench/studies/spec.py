"""Sweep specifications (TOML), validated like the scenes, and their expansion into units.

A spec names the cases (catalogue scenes with variant, resolution, backend, what the
methods learn from and where they are measured), the methods of :data:`rom.METHODS` with
a grid of options, the protocol and the error metric of the derived tables::

    [sweep]
    name = "anm_pod"
    description = "ANM-POD orders x modes (anm-pod §6)"
    resolution = "ci"                 # default resolution of the cases (--resolution overrides)
    error_metric = "max_rel_l2"       # the error of the Pareto front and the gate

    [protocol]                        # optional; defaults shown
    latency_steps = 200               # timed haptic steps (>= 200 for a p99)
    warmup = 20
    blas_threads = 1
    reference_samples = 3
    seed = 0

    [[case]]
    name = "liver_palpation"          # catalogue case or scene file; id defaults to the name
    backend = "skfem"                 # variant, resolution, mu = {nu = 0.499} (Scene.at) optional
    mesh = { paper = { divisions = [40, 7, 7] } }   # optional: builder parameters per resolution
    paper_points = [{ label = "paper 74/1880", step_ms = 10.7, error = 0.218 }]  # optional, on the Pareto plot
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

Every error names the key and the value and lists the valid choices (exit 2 in the CLI).
"""
from __future__ import annotations

import hashlib
import itertools
import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..cases.scene import RESOLUTIONS, list_cases, resolve_toml
from ..cases.schema import c_nonneg, c_pos, c_str, check_table, key_text, value_text
from ..rom import METHODS, method_class
from .evaluation import EVALUATION_KINDS
from .training import TRAINING_KINDS, case_scene
from .units import DEFAULT_PROTOCOL, WorkUnit, unit_key

__all__ = ["PRESETS_DIR", "ERROR_METRICS", "SweepSpec", "load_spec", "list_presets", "expand_units"]

PRESETS_DIR = Path(__file__).resolve().parent / "presets"
ERROR_METRICS = ("max_rel_l2", "mean_rel_l2", "rmse_rel", "max_rel_l2_in_envelope", "max_monitor_rel_error")
_TOP = {"sweep", "protocol", "case", "method"}
_SWEEP = {"name", "description", "resolution", "error_metric"}
_CASE = {"name", "id", "variant", "backend", "resolution", "training", "evaluation", "mu", "mesh", "paper_points"}
# a published configuration drawn beside ours on the case's Pareto plot (paper resolution)
_PAPER_POINT = {"label": c_str, "step_ms": c_pos, "error": c_nonneg}
_METHOD = {"name", "cases", "options", "grid", "list", "paper", "protocol"}
_TRAINING_KEYS = {"path": {"every", "repeat"}, "positions": {"positions", "max_load_factor", "load_steps"},
                  "trajectory": {"runs"}, "operators": set()}
_EVALUATION_KEYS = {"path": {"every", "beyond"}, "positions": {"held_out"}, "trajectory": {"t_end", "load_scale"},
                    "map": {"mus"}, "cut_lengths": {"steps_per_length"}, "contact_nodes": {"count"}}
BACKENDS = ("skfem", "ngsolve")


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
    cases: list
    methods: list
    text: str
    source: str

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


def _check_case(i, c, resolution):
    path = f"case[{i}]"
    _table(path, c, _CASE)
    if "name" not in c:
        raise ValueError(f"{path}.name: missing required key")
    name = c["name"]
    if not isinstance(name, str) or (name not in list_cases() and not _is_file(name)):
        _fail(f"{path}.name", name, f"unknown case; valid: {list_cases()}")
    backend = c.get("backend", "skfem")
    if backend not in BACKENDS:
        _fail(f"{path}.backend", backend, f"valid: {list(BACKENDS)}")
    res = resolution or c.get("resolution", "ci")
    if res not in RESOLUTIONS:
        _fail(f"{path}.resolution", res, f"valid: {list(RESOLUTIONS)}")
    training = dict(_table(f"{path}.training", c.get("training", {"kind": "path"}), {"kind"} | set().union(
        *_TRAINING_KEYS.values())))
    kind = training.setdefault("kind", "path")
    if not isinstance(kind, str) or kind not in TRAINING_KINDS:
        _fail(f"{path}.training.kind", kind, f"valid: {list(TRAINING_KINDS)}")
    _table(f"{path}.training", training, {"kind"} | _TRAINING_KEYS[kind])
    evaluation = dict(_table(f"{path}.evaluation", c.get("evaluation", {}), {"kind"} | set().union(
        *_EVALUATION_KEYS.values())))
    ekind = evaluation.setdefault("kind", kind if kind in EVALUATION_KINDS else "map")
    if not isinstance(ekind, str) or ekind not in EVALUATION_KINDS:
        _fail(f"{path}.evaluation.kind", ekind, f"valid: {list(EVALUATION_KINDS)}")
    _table(f"{path}.evaluation", evaluation, {"kind"} | _EVALUATION_KEYS[ekind])
    cid = c.get("id", Path(name).stem)
    if not (isinstance(cid, str) and re.fullmatch(r"[A-Za-z0-9_.-]+", cid) and cid not in (".", "..")):
        _fail(f"{path}.id", cid, "a case id names a results folder: letters, digits, '_', '.', '-' only")
    entry = {"id": cid, "name": name, "variant": c.get("variant"),
             "resolution": res, "backend": backend, "training": training, "evaluation": evaluation}
    if "mu" in c:
        entry["mu"] = _table(f"{path}.mu", c["mu"], set(c["mu"]) if isinstance(c["mu"], dict) else set())
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
    _named(path, case_scene, entry)  # the scene must load and take the mu (their errors name the key)
    return entry


def _is_file(name: str) -> bool:
    try:
        return Path(name).is_file()
    except (OSError, ValueError):  # a NUL byte, a name too long for the file system
        return False


def _named(path, fn, *args):
    """Call ``fn(*args)``; a ValueError it raises is re-raised prefixed with the spec ``path``."""
    try:
        return fn(*args)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None


def _option_sets(path, m, cls):
    """The option sets of a method entry: ``options`` merged into each grid point and list entry."""
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
    sets = [dict(zip(grid, combo)) for combo in itertools.product(*grid.values())] if grid else []
    sets += [dict(o) for o in explicit]
    if not sets and ("grid" in m or "list" in m):
        _fail(f"{path}.grid", grid, "the grid and list give no option set")
    out = []
    for o in sets or [{}]:
        opts = {**fixed, **o}
        if opts not in out:
            out.append(opts)
    return out


def _check_method(i, m, cases, resolution):
    path = f"method[{i}]"
    _table(path, m, _METHOD)
    name = m.get("name")
    if not isinstance(name, str) or name not in METHODS:
        _fail(f"{path}.name", name, f"unknown method; valid: {sorted(METHODS)}")
    cls = method_class(name)
    if resolution == "paper" and "paper" in m:  # the paper grid replaces grid/list; options merge
        paper = _table(f"{path}.paper", m["paper"], {"options", "grid", "list"})
        for where, table in ((f"{path}.options", m), (f"{path}.paper.options", paper)):
            if not isinstance(table.get("options", {}), dict):
                _fail(where, table["options"], "expected a table")
        src, opath = {**paper, "options": {**m.get("options", {}), **paper.get("options", {})}}, f"{path}.paper"
    else:
        src, opath = m, path
    sets = _option_sets(opath, src, cls)
    ids = [c["id"] for c in cases]
    wanted = m.get("cases")
    if wanted is None:
        chosen = [c for c in cases if c["training"]["kind"] in cls.training_kinds]
        if not chosen:
            _fail(f"{path}.name", name, f"learns from {list(cls.training_kinds)} training sets; no case of the spec "
                  f"offers one (case trainings: {[c['training']['kind'] for c in cases]})")
    else:
        if not isinstance(wanted, list) or not wanted:
            _fail(f"{path}.cases", wanted, "expected a non-empty list of case ids")
        for w in wanted:
            if w not in ids:
                _fail(f"{path}.cases", w, f"not a case id of this spec; valid: {ids}")
        chosen = [c for c in cases if c["id"] in wanted]
        for c in chosen:
            if c["training"]["kind"] not in cls.training_kinds:
                _fail(f"{path}.cases", c["id"], f"its training kind {c['training']['kind']!r} is not one method "
                      f"{name!r} learns from ({list(cls.training_kinds)})")
    protocol = _table(f"{path}.protocol", m.get("protocol", {}), set(DEFAULT_PROTOCOL))
    return {"name": name, "cases": [c["id"] for c in chosen], "option_sets": sets, "protocol": protocol}


def _check_protocol(path, protocol):
    for k, v in protocol.items():
        if isinstance(v, bool) or not isinstance(v, int) or v < (1 if k in ("latency_steps", "reference_samples")
                                                                   else 0):
            _fail(f"{path}.{k}", v, "expected a non-negative integer (latency_steps, reference_samples >= 1)")


def load_spec(spec_or_preset, resolution: str | None = None, only: list | None = None) -> SweepSpec:
    """Read and validate a sweep spec (a path or a preset name); ``resolution`` overrides the
    cases'; ``only`` (case ids) keeps those cases and the methods' units on them."""
    path = _resolve(spec_or_preset)
    text = path.read_text()
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    for key in raw:
        if key not in _TOP:
            raise ValueError(f"{key_text(key)}: unknown top-level key in {path} (valid: {sorted(_TOP)})")
    sweep = _table("sweep", raw.get("sweep", {}), _SWEEP)
    if resolution is not None and resolution not in RESOLUTIONS:
        _fail("resolution", resolution, f"valid: {list(RESOLUTIONS)}")
    res = resolution or sweep.get("resolution", "ci")
    metric = sweep.get("error_metric", "max_rel_l2")
    if metric not in ERROR_METRICS:
        _fail("sweep.error_metric", metric, f"unknown metric; valid: {list(ERROR_METRICS)}")
    protocol = {**DEFAULT_PROTOCOL, **_table("protocol", raw.get("protocol", {}), set(DEFAULT_PROTOCOL))}
    _check_protocol("protocol", protocol)
    raw_cases = raw.get("case", [])
    if not isinstance(raw_cases, list) or not raw_cases:
        raise ValueError(f"case: a sweep needs at least one [[case]] ({path})")
    cases = [_check_case(i, c, resolution) for i, c in enumerate(raw_cases)]
    if resolution is None:
        for c, rc in zip(cases, raw_cases):
            c["resolution"] = rc.get("resolution", res)
    ids = [c["id"] for c in cases]
    if len(set(ids)) != len(ids):
        _fail("case", ids, "case ids must be unique (give `id` to a case listed twice)")
    raw_methods = raw.get("method", [])
    if not isinstance(raw_methods, list) or not raw_methods:
        raise ValueError(f"method: a sweep needs at least one [[method]] ({path})")
    methods = [_check_method(i, m, cases, res) for i, m in enumerate(raw_methods)]
    if only is not None:
        unknown = sorted(set(only) - set(ids))
        if unknown:
            _fail("--cases", unknown[0], f"not a case id of {path.name}; valid: {ids}")
        cases = [c for c in cases if c["id"] in only]
        methods = [{**m, "cases": [c for c in m["cases"] if c in only]} for m in methods]
        methods = [m for m in methods if m["cases"]]
    for i, m in enumerate(methods):
        m["protocol"] = {**protocol, **m["protocol"]}
        _check_protocol(f"method[{i}].protocol", m["protocol"])
    return SweepSpec(str(sweep.get("name", path.stem)), str(sweep.get("description", "")), res, metric, protocol,
                     cases, methods, text, str(path))


def expand_units(spec: SweepSpec) -> list[WorkUnit]:
    """One :class:`WorkUnit` per (case, method, option set), keys computed: in spec order,
    except that the option sets of one nested group (one parent, :func:`_nested_parents`)
    run one after another, where the group first appears, so that a process builds each
    parent once (a grid whose nested option varies fastest would otherwise interleave the
    groups and rebuild their parents unit after unit)."""
    scene_hashes = {c["id"]: case_scene(c).content_hash() for c in spec.cases}
    by_id = {c["id"]: c for c in spec.cases}
    meta = {"name": spec.name, "hash": spec.hash}
    units = []
    for m in spec.methods:
        parents = _nested_parents(m["name"], m["option_sets"])
        groups = {}
        for i, parent in enumerate(parents):
            groups.setdefault(i if parent is None else json.dumps(parent, sort_keys=True), []).append(i)
        order = [i for members in groups.values() for i in members]
        for cid in m["cases"]:
            for opts, parent in ((m["option_sets"][i], parents[i]) for i in order):
                case = by_id[cid]
                key = unit_key(case, scene_hashes[cid], m["name"], opts, m["protocol"])
                units.append(WorkUnit(case, m["name"], opts, dict(m["protocol"]), meta, key, parent))
    return units


def _nested_parents(method: str, option_sets: list) -> list:
    """Per option set, the options with the method's nested options at the maximum over the
    sets that agree on every other option (None when nothing is nested or a value is not a number)."""
    nested = method_class(method).nested
    out = []
    for opts in option_sets:
        rest = {k: v for k, v in opts.items() if k not in nested}
        group = [o for o in option_sets if {k: v for k, v in o.items() if k not in nested} == rest]
        parent = dict(opts)
        for k in nested:
            values = [o.get(k) for o in group]
            if k not in opts or not all(isinstance(v, int) and not isinstance(v, bool) for v in values):
                parent = None
                break
            parent[k] = max(values)
        out.append(parent if parent and len(group) > 1 else None)
    return out
