"""Declarative scene files of the case catalogue (``tissuebench/cases/catalogue/*.toml``).

:func:`load` reads a scene (by case name or path) with :mod:`tomllib`, applies a
variant (``[variants.<name>]``) and a mesh resolution (``ci`` or ``paper``), validates
every key against a small schema table and returns a :class:`Scene`. Errors are
``ValueError`` naming the key path and the offending value (e.g. ``material.nu = 0.7``).

Schema (see the README of the catalogue, and any scene file, for examples)
------------------------------------------------------------------------
``[case]``       name, paper, description, model ("fe" default | "poisson1d" | "frame2dof" |
                 "hermite_beam"), default_variant (optional)
``[units]``      length (required), force, stress, mass, time (strings, documentation)
``[mesh]``       builder (see :mod:`.builders`), element ("P1" | "P2" | "Q1"; FE only),
                 ``[mesh.params]`` shared builder parameters, ``[mesh.ci]`` and
                 ``[mesh.paper]`` per-resolution parameters (merged over params)
``[material]``   FE only: name (linear | svk | neo_hookean | mooney_rivlin | guccione), its
                 parameters, density (optional, > 0), fibres (Guccione, optional 3-vector)
``[model]``      non-FE only: the discrete model's parameters
``[[dirichlet]]`` region, components ("xyz" or list), value (number or one per component)
                 or motion (``{type = "rotation", axis, center, angle_deg}``), scaled (bool)
``[[load]]``     type (point | traction | pressure | follower_pressure | body), region,
                 value, distribute ("total" | "per_node", point loads), history
``[analysis]``   type static (load_steps, max_load_factor, stop_at_divergence) or dynamic
                 (dt, t_end, integrator, integrator_options, lumped, dt_sweep)
``[[monitor]]``  name, quantity, and its keys (region, point, component, axis, center, area, scale)
``[paper]``      free table: the numbers the paper reports
``[methods]``    free table: ROM settings of the paper (modes, orders, handles ...)
``[variants.X]`` overrides: material/model/analysis/mesh replace, dirichlet/load/monitor
                 append, paper/methods/case merge

Regions (node selectors evaluated on coordinates; exactly one primary key):
``plane = "x"`` + value [+ tol]; ``box = [[lo], [hi]]``; ``nearest = [x, y, z]`` [+ count];
``sphere = [x, y, z]`` + radius; ``fraction = "y"`` + side ("min"|"max") + amount;
``ellipsoid = [a, b, c]`` [+ center, tol]; ``all = true``. Modifiers: ``boundary = true``
(boundary nodes only), ``frame = "bbox"`` (points/values as fractions of the mesh bounding box).

Histories (load factor versus time, or pseudo-time = load factor in statics):
constant; ramp (t0, t1); step (t0); sine (amplitude, frequency, phase);
ramp_hold_release (t_ramp, t_hold, t_release); tabulated (t, values).
"""
from __future__ import annotations

import copy
import math
import tomllib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any, Callable

import numpy as np

__all__ = ["CATALOGUE_DIR", "Scene", "History", "load", "list_cases", "compile_region", "MODELS",
           "RESOLUTIONS"]

CATALOGUE_DIR = Path(__file__).resolve().parent / "catalogue"
RESOLUTIONS = ("ci", "paper")
MODELS = ("fe", "poisson1d", "frame2dof", "hermite_beam")
_AXES = {"x": 0, "y": 1, "z": 2}
_COMPONENTS_1D = {"poisson1d": {"u": 0}, "frame2dof": {"u": 0}, "hermite_beam": {"w": 0, "theta": 1}}


# =============================================================================== checks
def _fail(path, value, what):
    raise ValueError(f"{path} = {value!r}: {what}")


def _is_num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def c_str(path, v):
    if not isinstance(v, str) or not v.strip():
        _fail(path, v, "expected a non-empty string")
    return v


def c_bool(path, v):
    if not isinstance(v, bool):
        _fail(path, v, "expected true or false")
    return v


def c_num(path, v):
    if not _is_num(v):
        _fail(path, v, "expected a finite number")
    return float(v)


def c_pos(path, v):
    if not (_is_num(v) and v > 0):
        _fail(path, v, "expected a finite number > 0")
    return float(v)


def c_nonneg(path, v):
    if not (_is_num(v) and v >= 0):
        _fail(path, v, "expected a finite number >= 0")
    return float(v)


def c_int1(path, v):
    if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
        _fail(path, v, "expected an integer >= 1")
    return v


def c_nu(path, v):
    if not (_is_num(v) and -1 < v < 0.5):
        _fail(path, v, "expected a Poisson ratio in (-1, 0.5)")
    return float(v)


def c_vec3(path, v):
    if not (isinstance(v, list) and len(v) == 3 and all(_is_num(x) for x in v)):
        _fail(path, v, "expected a list of 3 finite numbers")
    return [float(x) for x in v]


def c_numlist(path, v):
    if not (isinstance(v, list) and v and all(_is_num(x) for x in v)):
        _fail(path, v, "expected a non-empty list of finite numbers")
    return [float(x) for x in v]


def c_table(path, v):
    if not isinstance(v, dict):
        _fail(path, v, "expected a table")
    return v


def c_any(path, v):
    return v


def c_enum(*choices):
    def check(path, v):
        if v not in choices:
            _fail(path, v, f"expected one of {list(choices)}")
        return v
    return check


def _check_table(path, table, schema, required=(), free=False):
    """Check ``table`` against ``schema`` {key: checker}; unknown keys are errors unless ``free``."""
    c_table(path, table)
    for key in required:
        if key not in table:
            raise ValueError(f"{path}.{key}: missing required key (in {path})")
    out = {}
    for key, value in table.items():
        if key not in schema:
            if free:
                out[key] = value
                continue
            raise ValueError(f"{path}.{key}: unknown key (valid: {sorted(schema)})")
        out[key] = schema[key](f"{path}.{key}", value)
    return out


# =============================================================================== materials / models
_ENU = {"E": c_pos, "nu": c_nu}
MATERIAL_SCHEMAS = {
    "linear": _ENU, "svk": _ENU, "neo_hookean": _ENU,
    "mooney_rivlin": {"mu1": c_pos, "mu2": c_nonneg, "kappa": c_pos},
    "guccione": {"C": c_pos, "bf": c_pos, "bt": c_pos, "bfs": c_pos, "kappa": c_pos, "fibres": c_vec3},
}
MODEL_SCHEMAS = {
    "poisson1d": ({"q": c_num, "conductivity": c_pos, "source_range": c_numlist}, ("q",)),
    "frame2dof": ({"masses": c_numlist, "storey_stiffness": c_pos}, ("masses", "storey_stiffness")),
    "hermite_beam": ({"E": c_pos, "A": c_pos, "I": c_pos, "rho": c_pos}, ("E", "A", "I", "rho")),
}


def _check_material(path, m):
    c_table(path, m)
    name = m.get("name")
    if name is None:
        raise ValueError(f"{path}.name: missing required key (in {path})")
    if name not in MATERIAL_SCHEMAS:
        _fail(f"{path}.name", name, f"unknown material; valid: {sorted(MATERIAL_SCHEMAS)}")
    schema = dict(MATERIAL_SCHEMAS[name], name=c_str, density=c_pos)
    req = [k for k in MATERIAL_SCHEMAS[name] if k != "fibres"]
    return _check_table(path, m, schema, required=req)


# =============================================================================== regions
_REGION_PRIMARY = ("plane", "box", "nearest", "sphere", "fraction", "ellipsoid", "all")
_REGION_SCHEMA = {
    "plane": c_enum("x", "y", "z"), "value": c_num, "tol": c_pos,
    "box": c_any, "nearest": c_vec3, "count": c_int1, "sphere": c_vec3, "radius": c_pos,
    "fraction": c_enum("x", "y", "z"), "side": c_enum("min", "max"), "amount": c_pos,
    "ellipsoid": c_vec3, "center": c_vec3, "all": c_bool, "boundary": c_bool,
    "frame": c_enum("absolute", "bbox"),
}
_REGION_NEEDS = {"plane": ("value",), "sphere": ("radius",), "fraction": ("side", "amount")}


def _check_region(path, r):
    r = _check_table(path, r, _REGION_SCHEMA)
    prim = [k for k in _REGION_PRIMARY if k in r]
    if len(prim) != 1:
        _fail(path, r, f"a region needs exactly one of {list(_REGION_PRIMARY)}")
    for k in _REGION_NEEDS.get(prim[0], ()):
        if k not in r:
            raise ValueError(f"{path}.{k}: missing required key for a {prim[0]!r} region")
    if "box" in r:
        b = r["box"]
        if not (isinstance(b, list) and len(b) == 2):
            _fail(f"{path}.box", b, "expected [[x0, y0, z0], [x1, y1, z1]]")
        lo, hi = c_vec3(f"{path}.box[0]", b[0]), c_vec3(f"{path}.box[1]", b[1])
        if any(a > c for a, c in zip(lo, hi)):
            _fail(f"{path}.box", b, "lower corner above upper corner")
    if r.get("ellipsoid") is not None and min(r["ellipsoid"]) <= 0:
        _fail(f"{path}.ellipsoid", r["ellipsoid"], "semi-axes must be > 0")
    if r.get("all") is False:
        _fail(f"{path}.all", False, "only `all = true` is meaningful")
    return r


@dataclass(frozen=True)
class _MeshGeometry:
    """What region predicates need from a mesh: bounding box and boundary points."""

    lo: np.ndarray
    hi: np.ndarray
    boundary_points: np.ndarray

    @property
    def diag(self):
        return float(np.linalg.norm(self.hi - self.lo)) or 1.0

    @classmethod
    def of(cls, mesh):
        pts = mesh.points
        if getattr(mesh, "cell_type", "") == "line":
            bnd = pts[[0, -1]]
        else:
            f = mesh.boundary_facets
            nf = f.shape[1]
            mids = [(pts[f[:, i]] + pts[f[:, (i + 1) % nf]]) / 2 for i in range(nf)]
            bnd = np.vstack([pts[np.unique(f)]] + mids)
        return cls(pts.min(axis=0), pts.max(axis=0), bnd)


def compile_region(spec: dict, mesh, geometry: _MeshGeometry | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """A predicate ``where(coords (n, 3)) -> bool mask`` for a validated region ``spec``."""
    g = geometry or _MeshGeometry.of(mesh)
    bbox = spec.get("frame", "absolute") == "bbox"
    ext = g.hi - g.lo

    def point(p):
        p = np.asarray(p, float)
        return g.lo + p * ext if bbox else p

    def on_boundary(x):
        from scipy.spatial import cKDTree

        d, _ = cKDTree(g.boundary_points).query(x)
        return d <= 1e-9 * g.diag

    def base(x):
        if spec.get("all"):
            return np.ones(len(x), bool)
        if "plane" in spec:
            a = _AXES[spec["plane"]]
            v = g.lo[a] + spec["value"] * ext[a] if bbox else spec["value"]
            return np.abs(x[:, a] - v) <= spec.get("tol", 1e-6 * g.diag)
        if "box" in spec:
            lo, hi = point(spec["box"][0]), point(spec["box"][1])
            tol = 1e-9 * g.diag
            return np.all((x >= lo - tol) & (x <= hi + tol), axis=1)
        if "sphere" in spec:
            return np.linalg.norm(x - point(spec["sphere"]), axis=1) <= spec["radius"]
        if "fraction" in spec:
            a = _AXES[spec["fraction"]]
            if spec["side"] == "min":
                return x[:, a] <= g.lo[a] + spec["amount"] * ext[a]
            return x[:, a] >= g.hi[a] - spec["amount"] * ext[a]
        if "ellipsoid" in spec:
            c = np.asarray(spec.get("center", [0.0, 0.0, 0.0]))
            q = np.sqrt(np.sum(((x - c) / np.asarray(spec["ellipsoid"])) ** 2, axis=1))
            return np.abs(q - 1.0) <= spec.get("tol", 1e-3)
        raise AssertionError(spec)  # nearest is handled below

    def where(x):
        x = np.asarray(x, float)
        allowed = on_boundary(x) if spec.get("boundary") else np.ones(len(x), bool)
        if "nearest" in spec:
            idx = np.flatnonzero(allowed)
            d = np.linalg.norm(x[idx] - point(spec["nearest"]), axis=1)
            mask = np.zeros(len(x), bool)
            mask[idx[np.argsort(d, kind="stable")[: spec.get("count", 1)]]] = True
            return mask
        return base(x) & allowed

    return where


# =============================================================================== histories
_HISTORY_SCHEMAS = {
    "constant": ({}, ()),
    "ramp": ({"t0": c_num, "t1": c_num}, ("t1",)),
    "step": ({"t0": c_num}, ()),
    "sine": ({"amplitude": c_num, "frequency": c_pos, "phase": c_num}, ("frequency",)),
    "ramp_hold_release": ({"t_ramp": c_pos, "t_hold": c_nonneg, "t_release": c_pos}, ("t_ramp", "t_release")),
    "tabulated": ({"t": c_numlist, "values": c_numlist}, ("t", "values")),
}


def _check_history(path, h):
    c_table(path, h)
    kind = h.get("type")
    if kind not in _HISTORY_SCHEMAS:
        _fail(f"{path}.type", kind, f"unknown history; valid: {sorted(_HISTORY_SCHEMAS)}")
    schema, req = _HISTORY_SCHEMAS[kind]
    out = _check_table(path, h, dict(schema, type=c_str), required=req)
    if kind == "ramp" and not out["t1"] > out.get("t0", 0.0):
        _fail(f"{path}.t1", out["t1"], "must be > t0")
    if kind == "tabulated":
        t, v = out["t"], out["values"]
        if len(t) != len(v) or len(t) < 2 or np.any(np.diff(t) <= 0):
            _fail(f"{path}.t", t, "needs >= 2 strictly increasing times, as many as values")
    return out


@dataclass(frozen=True)
class History:
    """A scalar load factor as a function of (pseudo-)time: ``h(t)``."""

    spec: dict = field(default_factory=lambda: {"type": "ramp", "t1": 1.0})

    def __call__(self, t):
        s, t = self.spec, np.asarray(t, float)
        kind = s["type"]
        if kind == "constant":
            out = np.ones_like(t)
        elif kind == "ramp":
            t0 = s.get("t0", 0.0)
            out = np.clip((t - t0) / (s["t1"] - t0), 0.0, 1.0)
        elif kind == "step":
            out = (t >= s.get("t0", 0.0)).astype(float)
        elif kind == "sine":
            out = s.get("amplitude", 1.0) * np.sin(2 * np.pi * s["frequency"] * t + s.get("phase", 0.0))
        elif kind == "ramp_hold_release":
            a, b = s["t_ramp"], s["t_ramp"] + s.get("t_hold", 0.0)
            c = b + s["t_release"]
            out = np.interp(t, [0.0, a, b, c], [0.0, 1.0, 1.0, 0.0], left=0.0, right=0.0)
        else:  # tabulated
            out = np.interp(t, s["t"], s["values"])
        return float(out) if out.ndim == 0 else out


# =============================================================================== entries
def _check_components(path, v, model):
    names = _AXES if model == "fe" else _COMPONENTS_1D[model]
    items = list(v) if isinstance(v, str) and model == "fe" else v
    if isinstance(items, str):
        items = [items]
    if not isinstance(items, list) or not items:
        _fail(path, v, f"expected a list of components from {sorted(names)}")
    out = []
    for c in items:
        if isinstance(c, int) and not isinstance(c, bool) and c in names.values():
            out.append(c)
        elif c in names:
            out.append(names[c])
        else:
            _fail(path, v, f"unknown component {c!r}; valid: {sorted(names)}")
    if len(set(out)) != len(out):
        _fail(path, v, "repeated component")
    return out


_MOTION_SCHEMA = {"type": c_enum("rotation"), "axis": c_vec3, "center": c_vec3, "angle_deg": c_num}


def _check_dirichlet(path, d, model):
    schema = {"region": _check_region, "components": c_any, "value": c_any, "motion": c_any,
              "scaled": c_bool, "name": c_str}
    d = _check_table(path, d, schema, required=("region",))
    d["components"] = _check_components(f"{path}.components", d.get("components", "xyz" if model == "fe" else
                                                                        list(_COMPONENTS_1D[model])), model)
    if "value" in d and "motion" in d:
        _fail(f"{path}.motion", d["motion"], "give either value or motion, not both")
    if "motion" in d:
        d["motion"] = _check_table(f"{path}.motion", d["motion"], _MOTION_SCHEMA, required=tuple(_MOTION_SCHEMA))
        if d["components"] != [0, 1, 2]:
            _fail(f"{path}.components", d["components"], "a rotation prescribes all of x, y, z")
        if np.linalg.norm(d["motion"]["axis"]) == 0:
            _fail(f"{path}.motion.axis", d["motion"]["axis"], "zero axis")
    v = d.get("value", 0.0)
    if _is_num(v):
        d["value"] = [float(v)] * len(d["components"])
    elif isinstance(v, list) and len(v) == len(d["components"]) and all(_is_num(x) for x in v):
        d["value"] = [float(x) for x in v]
    else:
        _fail(f"{path}.value", v, f"expected a number or {len(d['components'])} numbers (one per component)")
    d.setdefault("scaled", True)
    return d


LOAD_TYPES = ("point", "traction", "pressure", "follower_pressure", "body")


def _check_load(path, ld, model):
    schema = {"type": c_enum(*LOAD_TYPES), "region": _check_region, "value": c_any, "history": _check_history,
              "distribute": c_enum("total", "per_node"), "name": c_str}
    ld = _check_table(path, ld, schema, required=("type", "value"))
    kind = ld["type"]
    if model != "fe" and kind != "point":
        _fail(f"{path}.type", kind, f"a {model} model takes point loads only")
    if kind != "body" and "region" not in ld:
        raise ValueError(f"{path}.region: missing required key for a {kind!r} load")
    vector = kind in ("point", "traction", "body") and model == "fe"
    ld["value"] = (c_vec3 if vector else c_num)(f"{path}.value", ld["value"])
    ld.setdefault("history", {"type": "ramp", "t1": 1.0})
    ld.setdefault("distribute", "total")
    return ld


_MONITOR_QUANTITIES = ("max_displacement", "displacement", "deformed_coordinate", "reaction_force",
                       "nominal_stress", "moment", "volume_ratio", "strain_energy")
_MONITOR_NEEDS = {"displacement": ("point", "component"), "deformed_coordinate": ("point", "component"),
                  "reaction_force": ("region", "component"), "nominal_stress": ("region", "component", "area"),
                  "moment": ("region", "axis", "center")}


def _check_monitor(path, m, model):
    schema = {"name": c_str, "quantity": c_enum(*_MONITOR_QUANTITIES), "region": _check_region,
              "point": c_vec3, "component": c_enum("x", "y", "z", "u", "w", "theta", "norm"), "axis": c_vec3,
              "center": c_vec3, "area": c_pos, "scale": c_num, "unit": c_str, "boundary": c_bool,
              "frame": c_enum("absolute", "bbox")}
    m = _check_table(path, m, schema, required=("name", "quantity"))
    for k in _MONITOR_NEEDS.get(m["quantity"], ()):
        if k not in m:
            raise ValueError(f"{path}.{k}: missing required key for quantity {m['quantity']!r}")
    return m


_STATIC = {"type": c_str, "load_steps": c_int1, "max_load_factor": c_pos, "stop_at_divergence": c_bool,
           "solver": c_str, "note": c_str}
_DYNAMIC = {"type": c_str, "dt": c_pos, "t_end": c_pos, "integrator": c_str, "integrator_options": c_table,
            "lumped": c_bool, "dt_sweep": c_numlist, "store_every": c_int1, "note": c_str}
INTEGRATOR_NAMES = ("hht", "bathe", "newmark", "central_difference", "forward_euler")


def _check_analysis(path, a):
    c_table(path, a)
    kind = a.get("type")
    if kind not in ("static", "dynamic"):
        _fail(f"{path}.type", kind, "expected 'static' or 'dynamic'")
    if kind == "static":
        return _check_table(path, a, _STATIC, required=("load_steps",))
    a = _check_table(path, a, _DYNAMIC, required=("dt", "t_end", "integrator"))
    if a["integrator"] not in INTEGRATOR_NAMES:
        _fail(f"{path}.integrator", a["integrator"], f"unknown integrator; valid: {list(INTEGRATOR_NAMES)}")
    if a["t_end"] < a["dt"]:
        _fail(f"{path}.t_end", a["t_end"], f"must be >= dt = {a['dt']}")
    for i, dt in enumerate(a.get("dt_sweep", [])):
        if dt <= 0:
            _fail(f"{path}.dt_sweep[{i}]", dt, "expected a time step > 0")
    return a


# =============================================================================== the scene
@dataclass(frozen=True)
class LineModel:
    """A 1D discrete model: its mesh, parameters, fixed (node, component) pairs, loads."""

    model: str
    mesh: Any
    params: dict
    fixed: list          # [(node indices, component index)]
    loads: list          # [(node indices, value per node, History)]


@dataclass(frozen=True, eq=False)
class Scene:
    """A validated scene at one resolution and variant (see the module docstring)."""

    name: str
    path: Path
    resolution: str
    variant: str | None
    variants: tuple
    case: dict
    units: dict
    mesh_spec: dict
    material: dict | None
    model_params: dict | None
    dirichlet: list
    loads: list
    analysis: dict
    monitors: list
    paper: dict
    methods: dict

    # ------------------------------------------------------------------ basics
    @property
    def model(self) -> str:
        return self.case.get("model", "fe")

    @property
    def is_fe(self) -> bool:
        return self.model == "fe"

    @property
    def element(self) -> str | None:
        return self.mesh_spec.get("element")

    @property
    def density(self) -> float | None:
        return None if self.material is None else self.material.get("density")

    @cached_property
    def built(self):
        from .builders import build_mesh

        return build_mesh(self.mesh_spec["builder"], **self.mesh_spec["params"])

    @property
    def mesh(self):
        return self.built.mesh

    @property
    def mesh_info(self) -> dict:
        return self.built.info

    @cached_property
    def geometry(self) -> _MeshGeometry:
        return _MeshGeometry.of(self.mesh)

    def region(self, spec) -> Callable:
        return compile_region(spec, self.mesh, self.geometry)

    @property
    def history(self) -> History:
        """The load history shared by all loads (and the scaled Dirichlet values)."""
        specs = [ld["history"] for ld in self.loads]
        if not specs:
            return History({"type": "ramp", "t1": 1.0})
        if any(s != specs[0] for s in specs):
            raise ValueError(f"{self.name}: loads have different histories; use load_histories()")
        return History(specs[0])

    def load_histories(self) -> list[History]:
        return [History(ld["history"]) for ld in self.loads]

    # ------------------------------------------------------------------ FE problem
    def make_material(self):
        from ..refsolvers import make_material

        params = {k: v for k, v in self.material.items() if k not in ("name", "density")}
        if "fibres" in params:
            params["fibres"] = np.asarray(params["fibres"], float)
        return make_material(self.material["name"], **params)

    def _nodes(self, element):
        from ..refsolvers.mesh import node_layout

        return node_layout(self.mesh, element)[0]

    def _select(self, path, spec, coords):
        idx = np.flatnonzero(self.region(spec)(coords))
        if idx.size == 0:
            raise ValueError(f"{self.name}: {path}.region {spec} selects no node")
        return idx

    def _dirichlet_value(self, d, factor):
        m = d.get("motion")
        if m is None:
            return np.asarray(d["value"], float)
        axis = np.asarray(m["axis"], float) / np.linalg.norm(m["axis"])
        angle = math.radians(m["angle_deg"]) * factor
        c = np.asarray(m["center"], float)
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        R = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K

        def value(x):
            return (x - c) @ R.T + c - x
        return value

    def to_problem(self, load_factor: float = 1.0, element: str | None = None):
        """The :class:`~tissuebench.refsolvers.Problem` of this scene.

        Region selectors are resolved to node indices and facets on the mesh. Loads and
        prescribed values are those of load factor 1 (the Problem scales them linearly).
        Prescribed *motions* (rotations) are not linear in the factor: they are evaluated
        at the scene's ``load_factor`` (rotation angle times it), so a twist history is
        followed exactly by building one problem per factor (the intermediate states of a
        single problem follow the chord).
        """
        if not self.is_fe:
            raise ValueError(f"{self.name}: model {self.model!r} is not a finite-element scene; use line_model()")
        from ..refsolvers import BodyForce, Dirichlet, FollowerPressure, PointLoad, Problem, SurfaceTraction

        element = element or self.element
        nodes = self._nodes(element)
        dirichlet = []
        for i, d in enumerate(self.dirichlet):
            idx = self._select(f"dirichlet[{i}]", d["region"], nodes)
            dirichlet.append(Dirichlet(idx, tuple(d["components"]), self._dirichlet_value(d, load_factor),
                                       d["scaled"]))
        loads = []
        for i, ld in enumerate(self.loads):
            kind, path = ld["type"], f"load[{i}]"
            if kind == "body":
                loads.append(BodyForce(np.asarray(ld["value"], float)))
                continue
            if kind == "point":
                idx = self._select(path, ld["region"], nodes)
                f = np.asarray(ld["value"], float)
                loads.append(PointLoad(idx, f / len(idx) if ld["distribute"] == "total" else f))
                continue
            facets = self.mesh.select_facets(self.region(ld["region"]))
            if len(facets) == 0:
                raise ValueError(f"{self.name}: {path}.region {ld['region']} selects no boundary facet")
            if kind == "follower_pressure":
                loads.append(FollowerPressure(facets, float(ld["value"])))
            elif kind == "traction":
                loads.append(SurfaceTraction(facets, np.asarray(ld["value"], float)))
            else:  # dead pressure on a plane region: a traction -p N
                loads.append(SurfaceTraction(facets, -float(ld["value"]) * self._plane_normal(path, facets)))
        return Problem(self.mesh, self.make_material(), element, dirichlet=dirichlet, loads=loads,
                       density=self.density or 1.0)

    def _plane_normal(self, path, facets):
        p = self.mesh.points
        n = np.cross(p[facets[:, 1]] - p[facets[:, 0]], p[facets[:, 2]] - p[facets[:, 0]])
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        if np.max(np.linalg.norm(n - n[0], axis=1)) > 1e-6:
            raise ValueError(f"{self.name}: {path}: a dead 'pressure' needs a plane region; "
                             f"use follower_pressure or traction")
        return n[0]

    # ------------------------------------------------------------------ 1D models
    def line_model(self) -> LineModel:
        """The 1D discrete model (poisson1d, frame2dof, hermite_beam) with resolved node sets."""
        if self.is_fe:
            raise ValueError(f"{self.name}: a finite-element scene; use to_problem()")
        x = self.mesh.points
        fixed = [(self._select(f"dirichlet[{i}]", d["region"], x), c)
                 for i, d in enumerate(self.dirichlet) for c in d["components"]]
        loads = []
        for i, ld in enumerate(self.loads):
            idx = self._select(f"load[{i}]", ld["region"], x)
            v = ld["value"] / len(idx) if ld["distribute"] == "total" else ld["value"]
            loads.append((idx, v, History(ld["history"])))
        return LineModel(self.model, self.mesh, dict(self.model_params), fixed, loads)

    # ------------------------------------------------------------------ monitors
    def evaluate_monitors(self, problem, u, f_int=None) -> dict:
        """Values of the ``[[monitor]]`` quantities for displacement ``u`` (full dof vector)
        of ``problem`` (from :meth:`to_problem`); reactions need the internal force ``f_int``."""
        from ..refsolvers import Mesh

        nodes = problem.nodes
        U = np.asarray(u, float).reshape(-1, 3)
        out = {}
        for m in self.monitors:
            q, scale = m["quantity"], m.get("scale", 1.0)
            if q == "max_displacement":
                val = float(np.linalg.norm(U, axis=1).max())
            elif q in ("displacement", "deformed_coordinate"):
                spec = {"nearest": m["point"], "boundary": m.get("boundary", False), "frame": m.get("frame", "absolute")}
                i = self._select(m["name"], spec, nodes)[0]
                vec = U[i] + (nodes[i] if q == "deformed_coordinate" else 0.0)
                val = float(np.linalg.norm(vec) if m["component"] == "norm" else vec[_AXES[m["component"]]])
            elif q in ("reaction_force", "nominal_stress", "moment"):
                if f_int is None:
                    raise ValueError(f"monitor {m['name']!r} needs f_int")
                F = np.asarray(f_int, float).reshape(-1, 3)
                idx = self._select(m["name"], m["region"], nodes)
                if q == "moment":
                    axis = np.asarray(m["axis"], float) / np.linalg.norm(m["axis"])
                    arm = nodes[idx] + U[idx] - np.asarray(m["center"])
                    val = float(np.sum(np.cross(arm, F[idx]) @ axis))
                else:
                    val = float(F[idx, _AXES[m["component"]]].sum())
                    if q == "nominal_stress":
                        val /= m["area"]
            elif q == "volume_ratio":
                mesh = problem.mesh
                deformed = Mesh(mesh.points + U[: mesh.n_vertices], mesh.cells, mesh.cell_type, reorient=False)
                val = float(deformed.cell_volumes().sum() / mesh.cell_volumes().sum())
            else:
                raise ValueError(f"monitor {m['name']!r}: quantity {q!r} needs a backend (strain energy)")
            out[m["name"]] = val * scale
        return out


# =============================================================================== loading
_TOP = {"case", "units", "mesh", "material", "model", "dirichlet", "load", "analysis", "monitor", "paper",
        "methods", "variants"}
_VARIANT_KEYS = {"description", "material", "model", "mesh", "analysis", "dirichlet", "load", "monitor", "paper",
                 "methods", "case"}


def list_cases() -> list[str]:
    """Names of the scene files in the catalogue."""
    return sorted(p.stem for p in CATALOGUE_DIR.glob("*.toml"))


def _resolve_path(name_or_path) -> Path:
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.parent != Path("."):
        if not p.is_file():
            raise FileNotFoundError(f"scene file {p} does not exist")
        return p
    cand = CATALOGUE_DIR / f"{name_or_path}.toml"
    if not cand.is_file():
        raise ValueError(f"unknown case {str(name_or_path)!r}; valid: {list_cases()}")
    return cand


def _apply_variant(raw, variant, path):
    variants = raw.get("variants", {})
    c_table("variants", variants)
    if variant is None:
        variant = raw.get("case", {}).get("default_variant") or (next(iter(variants)) if variants else None)
    if variant is None:
        return raw, None
    if variant not in variants:
        raise ValueError(f"variant {variant!r} of {path}: valid: {sorted(variants)}")
    over = c_table(f"variants.{variant}", variants[variant])
    out = copy.deepcopy({k: v for k, v in raw.items() if k != "variants"})
    for key, val in over.items():
        if key not in _VARIANT_KEYS:
            raise ValueError(f"variants.{variant}.{key}: unknown key (valid: {sorted(_VARIANT_KEYS)})")
        if key == "description":
            continue
        if key in ("dirichlet", "load", "monitor"):
            out[key] = list(out.get(key, [])) + list(val)
        elif key in ("paper", "methods", "case"):
            out[key] = {**out.get(key, {}), **val}
        else:
            out[key] = copy.deepcopy(val)
    return out, variant


def _check_mesh(raw, resolution, model):
    mesh = _check_table("mesh", raw, {"builder": c_str, "element": c_enum("P1", "P2", "Q1"), "params": c_table,
                                      "ci": c_table, "paper": c_table, "note": c_str},
                        required=("builder", "ci", "paper") + (("element",) if model == "fe" else ()))
    from .builders import BUILDERS

    if mesh["builder"] not in BUILDERS:
        _fail("mesh.builder", mesh["builder"], f"unknown builder; valid: {sorted(BUILDERS)}")
    params = {**mesh.get("params", {}), **mesh[resolution]}
    if "path" in params:
        p = Path(params["path"]).expanduser()
        if not p.is_file():
            raise FileNotFoundError(f"mesh.{resolution}.path: mesh file {p} does not exist")
    return {"builder": mesh["builder"], "element": mesh.get("element"), "params": params,
            "resolutions": {r: {**mesh.get("params", {}), **mesh[r]} for r in RESOLUTIONS}}


def load(name_or_path, resolution: str = "ci", variant: str | None = None) -> Scene:
    """Read, merge (variant, resolution) and validate a scene.

    Parameters
    ----------
    name_or_path : str or Path
        A catalogue case name (see :func:`list_cases`) or the path of a scene file.
    resolution : {"ci", "paper"}
    variant : str, optional
        A key of ``[variants]``; default ``case.default_variant`` or the first one.
    """
    if resolution not in RESOLUTIONS:
        raise ValueError(f"resolution = {resolution!r}: expected one of {list(RESOLUTIONS)}")
    path = _resolve_path(name_or_path)
    try:
        raw = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    for key in raw:
        if key not in _TOP:
            raise ValueError(f"{key}: unknown top-level key in {path} (valid: {sorted(_TOP)})")
    all_variants = tuple(raw.get("variants", {}))
    raw, variant = _apply_variant(raw, variant, path)
    case = _check_table("case", raw.get("case", {}), {"name": c_str, "paper": c_str, "description": c_str,
                                                      "model": c_enum(*MODELS), "default_variant": c_str},
                        required=("name", "paper", "description"))
    model = case.get("model", "fe")
    units = _check_table("units", raw.get("units", {}), {k: c_str for k in ("length", "force", "stress", "mass",
                                                                           "time", "note")}, required=("length",))
    for key in ("mesh", "analysis"):
        if key not in raw:
            raise ValueError(f"{key}: missing required table in {path}")
    mesh = _check_mesh(raw["mesh"], resolution, model)
    material = model_params = None
    if model == "fe":
        if "material" not in raw:
            raise ValueError(f"material: missing required table in {path}")
        material = _check_material("material", raw["material"])
    else:
        if "model" not in raw:
            raise ValueError(f"model: missing required table in {path}")
        schema, req = MODEL_SCHEMAS[model]
        model_params = _check_table("model", raw["model"], schema, required=req)
    for key in ("dirichlet", "load", "monitor"):
        if not isinstance(raw.get(key, []), list):
            _fail(key, raw[key], f"expected an array of tables ([[{key}]])")
    if not raw.get("dirichlet"):
        raise ValueError(f"dirichlet: a scene needs at least one [[dirichlet]] entry ({path})")
    dirichlet = [_check_dirichlet(f"dirichlet[{i}]", d, model) for i, d in enumerate(raw["dirichlet"])]
    loads = [_check_load(f"load[{i}]", d, model) for i, d in enumerate(raw.get("load", []))]
    monitors = [_check_monitor(f"monitor[{i}]", d, model) for i, d in enumerate(raw.get("monitor", []))]
    analysis = _check_analysis("analysis", raw["analysis"])
    return Scene(name=case["name"], path=path, resolution=resolution, variant=variant, variants=all_variants,
                 case=case, units=units, mesh_spec=mesh, material=material, model_params=model_params,
                 dirichlet=dirichlet, loads=loads, analysis=analysis, monitors=monitors,
                 paper=c_table("paper", raw.get("paper", {})), methods=c_table("methods", raw.get("methods", {})))
