"""Declarative scene files of the case catalogue (``tissuebench/cases/catalogue/*.toml``).

:func:`load` reads a scene (by case name or path) with :mod:`tomllib`, applies a
variant (``[variants.<name>]``) and a mesh resolution (``ci`` or ``paper``), validates
every key against a small schema table and returns a :class:`Scene`. Errors are
``ValueError`` naming the key path and the offending value (e.g. ``material.nu = 0.7``).

Schema (see the README of the catalogue, and any scene file, for examples)
------------------------------------------------------------------------
``[case]``       name, description, paper (optional: the publication a catalogue case reproduces),
                 model ("fe" default | "poisson1d" | "frame2dof" | "hermite_beam"), default_variant
                 (optional; without it the base scene is the default, whatever variants exist)
``[units]``      length (required), force, stress, mass, time (strings, documentation)
``[mesh]``       builder (see :mod:`.builders`), element ("P1" | "P2" | "Q1"; FE only, optional: without
                 it P1 on tetrahedra, where the reference may choose a formulation that does not
                 lock, Q1 on hexahedra, P2 for the mixed formulation),
                 ``[mesh.params]`` shared builder parameters, ``[mesh.ci]`` and
                 ``[mesh.paper]`` per-resolution parameters (merged over params);
                 or a mesh file: ``file = "kidney.msh"`` (any meshio volume mesh of tetrahedra
                 or hexahedra, the path relative to the scene file), with the length unit of
                 its coordinates ``unit = "mm"`` (m, cm, mm, um; converted to ``[units]
                 length``) or ``scale = <factor>`` (one of the two is required), and
                 ``element`` (P1, or P2 on tetrahedra; Q1 on hexahedra). One file serves both
                 resolutions.
``[material]``   FE only: name (linear | svk | neo_hookean | mooney_rivlin | guccione), its
                 parameters, density (optional, > 0), fibres (Guccione, optional 3-vector)
``[model]``      non-FE only: the discrete model's parameters
``[[dirichlet]]`` region, components ("xyz" or list), value (number or one per component)
                 or motion (``{type = "rotation", axis, center, angle_deg}``), scaled (bool)
``[[load]]``     type (point | traction | pressure | follower_pressure | body), region,
                 value, distribute (point loads: "total" spread evenly over the selected
                 nodes | "per_node" | "interpolate": one force at the region's ``nearest``
                 point, or the closest point of the body, spread by the shape functions of
                 its cell), history
``[analysis]``   type static (load_steps, max_load_factor, stop_at_divergence) or dynamic
                 (dt, t_end, integrator, integrator_options, lumped, dt_sweep)
``[[monitor]]``  name, quantity, and its keys (region, point, component, axis, center, area, scale);
                 a ``point`` is read by interpolation in its cell (``boundary = true``: the
                 nearest boundary node), see :mod:`.probes`
``[paper]``      free table: the numbers the paper reports; ``[paper.compare.<monitor>]``
                 (value, note) puts our final monitored value beside the paper's, with the
                 reason they differ (printed by ``tissuebench run``)
``[cut]``        incisions (angle_deg, radii) and depth_fraction: the mesh is cut along them,
                 nodes duplicated on the cut faces (see :mod:`.cutting`)
``[parameters]`` parameters a study may evaluate the scene at (``position``: a point load
                 moved along a line), see :mod:`.parameters` and :meth:`Scene.at`
``[variants.X]`` overrides: material/model/analysis/mesh replace, dirichlet/load/monitor
                 append, paper/case/parameters merge; ``histories = { <load name> = {history} }``
                 replaces the history of the named loads (a dynamic variant of a static scene)

Regions (node selectors evaluated on coordinates; exactly one primary key):
``plane = "x"`` + value [+ tol]; ``box = [[lo], [hi]]``; ``nearest = [x, y, z]`` [+ count];
``sphere = [x, y, z]`` + radius; ``fraction = "y"`` + side ("min"|"max") + amount;
``ellipsoid = [a, b, c]`` [+ center, tol]; ``all = true``. Modifiers: ``boundary = true``
(boundary nodes only), ``frame = "bbox"`` (points/values as fractions of the mesh bounding box).

Histories (load factor versus time, or pseudo-time = load factor in statics):
constant; ramp (t0, t1); step (t0); sine (amplitude, frequency, phase);
ramp_hold_release (t_ramp, t_hold, t_release); tabulated (t, values). Every load of a scene
follows the same one (one load factor drives them all): loads with different histories are
refused when the scene loads.

The validation of each part lives in :mod:`.schema` (primitives), :mod:`.regions`,
:mod:`.histories`, :mod:`.monitors` and :mod:`.sections`; :mod:`.assembly` turns a
scene into a solvable problem. Their public names are re-exported here.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import tomllib
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Callable

import numpy as np

from ..choices import RESOLUTIONS
from ..refsolvers import make_material
from . import assembly
from .assembly import LineModel
from .builder_params import check_builder_params, require_regular_file
from .cutting import check_cut
from .histories import History, check_history_resolution, check_history_values, shared_history
from .monitors import check_monitor, evaluate_monitors
from .parameters import apply_mu, check_parameters_table
from .regions import MeshGeometry, compile_region
# the checkers were defined here before the split: re-exported for existing imports
from .schema import (MODELS, c_name, key_text, c_any, c_bool, c_enum, c_int1, c_nonneg, c_num, c_numlist, c_nu,  # noqa: F401
                     c_pos, c_str, c_table, c_vec3, check_table, fail)
from .sections import (INTEGRATOR_NAMES, LOAD_TYPES, MATERIAL_SCHEMAS, MODEL_SCHEMAS,  # noqa: F401
                       check_analysis, check_dirichlet, check_formulation, check_load, check_material, check_model)
from .variants import apply_variant

__all__ = ["CATALOGUE_DIR", "Scene", "History", "load", "list_cases", "compile_region", "MODELS",
           "RESOLUTIONS"]

CATALOGUE_DIR = Path(__file__).resolve().parent / "catalogue"


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
    cut: dict | None = None  # validated [cut] table (see .cutting); the mesh is then cut
    parameters: dict = dataclasses.field(default_factory=dict)  # validated [parameters] (see .parameters)
    mu: dict = dataclasses.field(default_factory=dict)  # the parameters this scene was evaluated at (at())

    # ------------------------------------------------------------------ parameters, identity
    def at(self, mu: dict) -> "Scene":
        """This scene evaluated at parameters ``mu`` (``{"position": s}``, analysis overrides
        ``max_load_factor`` / ``load_steps``); ValueError naming an unknown key or a bad value.
        The mesh is shared (not rebuilt) when only loads or analysis change."""
        if not mu:
            return self
        fields = apply_mu({"loads": self.loads, "analysis": self.analysis, "material": self.material},
                          self.parameters, dict(mu), self.name)
        a = fields["analysis"]
        if a.get("type") == "dynamic" and ("t_end" in mu or "dt" in mu) and not a["t_end"] >= a["dt"]:
            # t_end < dt: no step at all (the run's arrays were empty, 'zero-size array' far downstream)
            key = "t_end" if "t_end" in mu else "dt"
            fail(f"{self.name}: mu.{key}", mu[key], f"t_end = {a['t_end']:g} is below dt = {a['dt']:g}: a dynamic "
                 "run needs at least one time step (t_end >= dt)")
        return self.with_loads(fields.pop("loads"), mu, **fields)

    def with_loads(self, loads: list, mu: dict, **fields) -> "Scene":
        """This scene with ``loads`` (validated as in a scene file) and other non-mesh ``fields``
        replaced, ``mu`` recorded (it enters :meth:`content_hash`). The mesh is shared, not rebuilt."""
        loads = [check_load(f"load[{i}]", ld, self.model) for i, ld in enumerate(loads)]
        shared_history(loads)
        _check_histories(loads, fields.get("analysis", self.analysis), "mu.dt" if "dt" in mu else "analysis.dt",
                         self.units.get("time", ""))
        new = dataclasses.replace(self, mu={**self.mu, **dict(mu)}, loads=loads, **fields)
        if "built" in self.__dict__:  # cached_property: reuse the mesh already built
            new.__dict__["built"] = self.__dict__["built"]
        return new

    def with_mesh(self, params: dict) -> "Scene":
        """This scene on another mesh of its builder: ``params`` override the builder's
        parameters at this resolution (checked as ``mesh.<resolution>`` of a scene file, e.g.
        ``{"divisions": [40, 7, 7]}``). The mesh is rebuilt; :meth:`content_hash` changes."""
        if not isinstance(params, dict):
            raise TypeError(f"mesh parameters must be a table, got {type(params).__name__}")
        if not params:
            return self
        merged = check_builder_params(self.mesh_spec["builder"], {"params": self.mesh_spec["params"],
                                                                  self.resolution: dict(params)},
                                      (self.resolution,), self.resolution)[self.resolution]
        return dataclasses.replace(self, mesh_spec={**self.mesh_spec, "params": merged})

    def content(self) -> dict:
        """Everything that determines a reference run of this scene (JSON-able): the validated
        tables, resolution, variant, ``mu`` and the SHA-256 of the mesh files the builder reads."""
        from .builders import mesh_sources

        sources = {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in mesh_sources(
            self.mesh_spec["builder"], self.mesh_spec["params"])}
        mesh = {k: v for k, v in self.mesh_spec.items() if k != "resolutions"}
        if mesh["builder"] == "file":  # the file's content (mesh_sources) is its identity, not where it lies
            mesh["params"] = {**mesh["params"], "path": Path(mesh["params"]["path"]).name}
        return {"name": self.name, "resolution": self.resolution, "variant": self.variant, "model": self.model,
                "mesh": mesh,
                "mesh_sources": sorted(sources.values()), "material": self.material, "model_params": self.model_params,
                "dirichlet": self.dirichlet, "loads": self.loads, "analysis": self.analysis,
                "monitors": self.monitors, "cut": self.cut, "mu": self.mu}

    def content_hash(self) -> str:
        """SHA-256 of :meth:`content`: two scenes with the same hash give the same reference."""
        return hashlib.sha256(json.dumps(self.content(), sort_keys=True, default=_jsonable).encode()).hexdigest()

    # ------------------------------------------------------------------ basics
    @property
    def model(self) -> str:
        return self.case.get("model", "fe")

    @property
    def is_fe(self) -> bool:
        return self.model == "fe"

    @property
    def mesh_label(self) -> str:
        """What the mesh is, for a reader: ``the mesh file kidney.msh (mm)`` or ``the cornea_dome mesh``."""
        spec = self.mesh_spec
        if spec["builder"] == "file":
            how = f"{spec['unit']}" if spec.get("unit") else f"scaled by {spec['params']['scale']:g}"
            return f"the mesh file {Path(spec['params']['path']).name} ({how})"
        if spec["builder"] == "liver" and spec["params"].get("path"):
            return f"the mesh file {Path(spec['params']['path']).name} (liver builder)"
        return f"the {spec['builder']} mesh"

    @property
    def element(self) -> str | None:
        """The element: the scene's ``[mesh] element``, else P2 for the mixed formulation, Q1 on
        hexahedra, P1 on tetrahedra (reading the cell type builds the mesh)."""
        given = self.mesh_spec.get("element")
        if given or not self.is_fe:
            return given
        if self.analysis.get("formulation") == "mixed":
            return "P2"
        return "Q1" if self.mesh.cell_type == "hexahedron" else "P1"

    @property
    def element_given(self) -> bool:
        """True when the scene names its element (``[mesh] element``): then it gets that one,
        even where it locks; otherwise the reference may choose a formulation that does not."""
        return bool(self.mesh_spec.get("element"))

    @property
    def density(self) -> float | None:
        return None if self.material is None else self.material.get("density")

    @cached_property
    def built(self):
        # built on first use: validating a scene must not mesh it (netgen is slow)
        from .builders import build_mesh

        built = build_mesh(self.mesh_spec["builder"], **self.mesh_spec["params"])
        if self.cut is None:
            return built
        from .cutting import apply_cut

        return apply_cut(built, self.cut)

    @property
    def mesh(self):
        return self.built.mesh

    @property
    def mesh_info(self) -> dict:
        return self.built.info

    @cached_property
    def geometry(self) -> MeshGeometry:
        return MeshGeometry.of(self.mesh)

    def region(self, spec) -> Callable:
        return compile_region(spec, self.mesh, self.geometry)

    def select(self, path, spec, coords) -> np.ndarray:
        """Indices of the ``coords`` in region ``spec``; an empty selection is an error
        naming the scene entry ``path``."""
        idx = np.flatnonzero(self.region(spec)(coords))
        if idx.size == 0:
            raise ValueError(f"{self.name}: {path}.region {spec} selects no node")
        return idx

    @property
    def history(self) -> History:
        """The load history shared by all loads (and the scaled Dirichlet values): one per scene,
        checked when it loads (:func:`~.histories.shared_history`)."""
        return History(shared_history(self.loads))

    # ------------------------------------------------------------------ models
    def make_material(self):

        params = {k: v for k, v in self.material.items() if k not in ("name", "density")}
        if "fibres" in params:
            params["fibres"] = np.asarray(params["fibres"], float)
        return make_material(self.material["name"], **params)

    def to_problem(self, element: str | None = None):
        """The :class:`~tissuebench.refsolvers.Problem` of this scene.

        Region selectors are resolved to node indices and facets on the mesh. Loads and
        prescribed values are those of load factor 1 (the Problem scales them linearly);
        prescribed *motions* (rotations) are not linear in the factor and are passed as
        ``Dirichlet.motion``, evaluated at each load factor (angle times the factor).
        """
        if not self.is_fe:
            raise ValueError(f"{self.name}: model {self.model!r} is not a finite-element scene; use line_model()")
        return assembly.fe_problem(self, element)

    def line_model(self) -> LineModel:
        """The 1D discrete model (poisson1d, frame2dof, hermite_beam) with resolved node sets."""
        if self.is_fe:
            raise ValueError(f"{self.name}: a finite-element scene; use to_problem()")
        return assembly.line_model(self)

    def evaluate_monitors(self, problem, u, reactions=None) -> dict:
        """Values of the ``[[monitor]]`` quantities for displacement ``u`` (full dof vector)
        of ``problem`` (from :meth:`to_problem`); the reaction monitors need ``reactions``, the
        (n_dof,) forces of the supports (``problem.support_reactions(f_int, f_ext)``)."""
        return evaluate_monitors(self, problem, u, reactions)


# =============================================================================== loading
_TOP = {"case", "units", "mesh", "material", "model", "dirichlet", "load", "analysis", "monitor", "paper",
        "variants", "cut", "parameters"}
_CASE_SCHEMA = {"name": c_name, "paper": c_str, "description": c_str, "model": c_enum(*MODELS),
                "default_variant": c_str}
_UNITS_SCHEMA = {k: c_str for k in ("length", "force", "stress", "mass", "time", "note")}
_MESH_SCHEMA = {"builder": c_str, "element": c_enum("P1", "P2", "Q1"), "params": c_table, "ci": c_table,
                "paper": c_table, "note": c_str}
_MESH_FILE_SCHEMA = {"file": c_str, "unit": c_str, "scale": c_pos, "element": c_enum("P1", "P2", "Q1"),
                     "note": c_str}
# what each key means: the scene-format reference of the documentation is generated from the
# schema tables above and these words (a key without its words fails the docs' test)
TOP_DOC = {
    "case": "what the scene is: its name, description, source paper, model",
    "units": "the units the numbers of the scene are in (a mesh file's coordinates are converted to the length)",
    "mesh": "the mesh: a builder with its parameters per resolution, or a mesh file",
    "material": "finite-element scenes: the constitutive law and its parameters",
    "model": "1D models (`case.model` other than `\"fe\"`): the discrete model's parameters",
    "dirichlet": "array of tables `[[dirichlet]]`: supports (at least one)",
    "load": "array of tables `[[load]]`: the loads, scaled by the load factor",
    "analysis": "static (a load path in load steps) or dynamic (time stepping)",
    "monitor": "array of tables `[[monitor]]`: the scalar quantities recorded at every step",
    "paper": "free table of the numbers the source paper reports; `[paper.compare.<monitor>]` puts our value "
             "beside the paper's",
    "variants": "`[variants.<name>]`: tables merged over the base scene (see Variants)",
    "cut": "incisions cut into the mesh (the layered cornea)",
    "parameters": "parameters a study may evaluate the scene at (`[parameters.position]`)",
}
CASE_DOC = {
    "name": "the case's name (tables, titles, the default results folder)",
    "paper": "the publication and section a catalogue case reproduces (optional: an organ of your own has none)",
    "description": "one sentence: what is modelled",
    "model": "`\"fe\"` (finite elements, default) or a 1D model",
    "default_variant": "the variant loaded when none is asked for (without it: the base scene)",
}
UNITS_DOC = {
    "length": "the length unit of every coordinate and length of the scene (`\"m\"`, `\"mm\"` ...)",
    "force": "documentation", "stress": "documentation", "mass": "documentation", "time": "documentation",
    "note": "documentation",
}
MESH_DOC = {
    "builder": "a mesh builder of the package (see Mesh builders)",
    "element": "`\"P1\"`, `\"P2\"` (tetrahedra) or `\"Q1\"` (hexahedra); FE scenes only",
    "params": "the builder's parameters shared by both resolutions",
    "ci": "the builder's parameters at ci resolution (merged over `params`; may be empty)",
    "paper": "the builder's parameters at paper resolution (merged over `params`; may be empty)",
    "note": "documentation",
}
MESH_FILE_DOC = {
    "file": "any volume mesh meshio reads (tetrahedra or hexahedra), relative to the scene file; its content is part "
            "of the scene's hash",
    "unit": "the length unit of the file's coordinates (see `LENGTH_UNITS`), converted to `[units] length`",
    "scale": "instead of `unit`: the factor from the file's coordinates to `[units] length`",
    "element": "`\"P1\"` or `\"P2\"` on tetrahedra, `\"Q1\"` on hexahedra",
    "note": "documentation",
}
PAPER_COMPARE_SCHEMA = {"value": c_num, "note": c_str}
PAPER_COMPARE_DOC = {"value": "the paper's value of the monitor (in the monitor's unit, after its `scale`)",
                     "note": "why ours differs, printed beside it by `tissuebench run`"}
#: length units a mesh file's coordinates may be stated in, in metres
LENGTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "um": 1e-6, "µm": 1e-6}


def list_cases() -> list[str]:
    """Names of the scene files in the catalogue."""
    return sorted(p.stem for p in CATALOGUE_DIR.glob("*.toml"))


def resolve_toml(name_or_path, folder: Path, what: str, names) -> Path:
    """The TOML file a name or path means: anything that looks like a path is one
    (FileNotFoundError naming it when absent); a bare word is ``folder/<word>.toml``
    (ValueError listing ``names()`` when there is none)."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.parent != Path("."):
        if not p.is_file():
            raise FileNotFoundError(f"{what} file {p} does not exist")
        return p
    cand = folder / f"{name_or_path}.toml"
    if not cand.is_file():
        raise ValueError(f"unknown {what} {str(name_or_path)!r}; valid: {names()}")
    return cand


def _resolve_path(name_or_path) -> Path:
    return resolve_toml(name_or_path, CATALOGUE_DIR, "case", list_cases)


def _check_mesh_file(raw, model, path: Path, units: dict):
    """``[mesh] file = ...``: the file (relative to the scene file), its length unit or scale
    (stated, and converted to ``[units] length``), the element."""
    mesh = check_table("mesh", raw, _MESH_FILE_SCHEMA, required=("file",))
    if model != "fe":
        fail("mesh.file", mesh["file"], f"a {model} model builds its own 1D mesh (mesh.builder)")
    try:
        p = Path(mesh["file"]).expanduser()
        p = p if p.is_absolute() else path.parent / p
    except (OSError, ValueError, RuntimeError) as exc:  # unknown ~user
        fail("mesh.file", mesh["file"], f"not a usable file path ({exc})")
    # a folder, a FIFO, /dev/zero, a loop of links: said as what they are, never opened
    require_regular_file(p, f"mesh.file = {mesh['file']!r}: mesh file {p}", hint=" (a relative path is taken from "
                         f"the scene file's folder {path.parent})")
    if "unit" in mesh and "scale" in mesh:
        fail("mesh.scale", mesh["scale"], "give the file's unit or a scale, not both")
    if "unit" in mesh:
        unit, length = mesh["unit"], units.get("length")
        if unit not in LENGTH_UNITS:
            fail("mesh.unit", unit, f"unknown length unit; valid: {list(LENGTH_UNITS)} (or give mesh.scale)")
        if length not in LENGTH_UNITS:
            fail("mesh.unit", unit, f"cannot convert to the scene's [units] length = {length!r} (not one of "
                 f"{list(LENGTH_UNITS)}); give mesh.scale instead")
        scale = LENGTH_UNITS[unit] / LENGTH_UNITS[length]
    elif "scale" in mesh:
        scale = mesh["scale"]
    else:
        fail("mesh.file", mesh["file"], "state the length unit of the file's coordinates: mesh.unit = \"mm\" (or "
             f"{', '.join(repr(u) for u in LENGTH_UNITS if u != 'mm')}), or mesh.scale = <factor to the scene's "
             f"[units] length = {units.get('length')!r}>")
    params = {"path": str(p.resolve()), "scale": float(scale)}
    return {"builder": "file", "element": mesh.get("element"), "params": params,
            "resolutions": {r: dict(params) for r in RESOLUTIONS}, "file": mesh["file"],
            "unit": mesh.get("unit")}


def _check_mesh(raw, resolution, model, path: Path | None = None, units: dict | None = None):
    if isinstance(raw, dict) and "file" in raw:
        if "builder" in raw:
            fail("mesh.builder", raw["builder"], "give either a builder or a file, not both")
        return _check_mesh_file(raw, model, path or Path("."), units or {})
    mesh = check_table("mesh", raw, _MESH_SCHEMA, required=("builder",) + RESOLUTIONS)
    from .builders import BUILDERS

    if mesh["builder"] not in BUILDERS:
        fail("mesh.builder", mesh["builder"], f"unknown builder; valid: {sorted(BUILDERS)}")
    tables = {k: mesh[k] for k in ("params",) + RESOLUTIONS if k in mesh}
    resolutions = check_builder_params(mesh["builder"], tables, RESOLUTIONS, resolution)
    return {"builder": mesh["builder"], "element": mesh.get("element"), "params": resolutions[resolution],
            "resolutions": resolutions}


def _read_raw(path: Path) -> dict:
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text: {exc}") from None
    except ValueError as exc:  # TOMLDecodeError, or an integer literal beyond Python's digit limit
        raise ValueError(f"{path}: not valid TOML: {exc}") from None
    for key in raw:
        if key not in _TOP:
            raise ValueError(f"{key_text(key)}: unknown top-level key in {path} (valid: {sorted(_TOP)})")
    return raw


def _require_table(raw, key, path):
    if key not in raw:
        raise ValueError(f"{key}: missing required table in {path}")
    return raw[key]


def _check_entries(raw, model, path):
    """The ``[[dirichlet]]``, ``[[load]]`` and ``[[monitor]]`` arrays, checked."""
    for key in ("dirichlet", "load", "monitor"):
        if not isinstance(raw.get(key, []), list):
            fail(key, raw[key], f"expected an array of tables ([[{key}]])")
    if not raw.get("dirichlet"):
        raise ValueError(f"dirichlet: a scene needs at least one [[dirichlet]] entry ({path})")
    monitors = [check_monitor(f"monitor[{i}]", d, model) for i, d in enumerate(raw.get("monitor", []))]
    _check_monitor_names(monitors)
    return ([check_dirichlet(f"dirichlet[{i}]", d, model) for i, d in enumerate(raw["dirichlet"])],
            [check_load(f"load[{i}]", d, model) for i, d in enumerate(raw.get("load", []))], monitors)


# columns of a run's result table: a monitor of one of these names would overwrite it
RESERVED_COLUMNS = ("case", "backend", "step", "load_factor", "time", "newton_iterations", "converged", "wall_s",
                    "assembly_s", "solve_s", "final_residual", "message", "kinetic_energy", "strain_energy",
                    "external_work", "energy_error")


def _check_monitor_names(monitors):
    seen = {}
    for i, m in enumerate(monitors):
        name = m["name"]
        if name in RESERVED_COLUMNS:
            fail(f"monitor[{i}].name", name, f"a column of the result table; reserved: {list(RESERVED_COLUMNS)}")
        if name in seen:
            fail(f"monitor[{i}].name", name, f"already the name of monitor[{seen[name]}]")
        seen[name] = i


def _check_paper(paper, monitors):
    """``[paper]`` is free, except ``[paper.compare.<monitor>]``: ``value`` (number) and ``note``."""
    paper = c_table("paper", paper)
    names = {m["name"] for m in monitors}
    for name, ref in c_table("paper.compare", paper.get("compare", {})).items():
        if name not in names:
            fail(f"paper.compare.{name}", ref, f"not a monitor of the scene; monitors: {sorted(names)}")
        check_table(f"paper.compare.{name}", ref, PAPER_COMPARE_SCHEMA, required=("value",))
    return paper


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
    raw = _read_raw(path)
    all_variants = tuple(c_table("variants", raw.get("variants", {})))
    raw, variant = apply_variant(raw, variant, path)
    case = check_table("case", raw.get("case", {}), _CASE_SCHEMA, required=("name", "description"))
    model = case.get("model", "fe")
    units = check_table("units", raw.get("units", {}), _UNITS_SCHEMA, required=("length",))
    for key in ("mesh", "analysis"):
        _require_table(raw, key, path)
    mesh = _check_mesh(raw["mesh"], resolution, model, path, units)
    material = model_params = None
    if model == "fe":
        material = check_material("material", _require_table(raw, "material", path))
    else:
        model_params = check_model("model", _require_table(raw, "model", path), model)
    dirichlet, loads, monitors = _check_entries(raw, model, path)
    shared_history(loads)  # refused here, so that every command refuses it alike
    analysis = check_analysis("analysis", raw["analysis"])
    _check_histories(loads, analysis, time_unit=units.get("time", ""))
    if model == "fe":
        check_formulation(mesh.get("element"), analysis, material)
    return Scene(name=case["name"], path=path, resolution=resolution, variant=variant, variants=all_variants,
                 case=case, units=units, mesh_spec=mesh, material=material, model_params=model_params,
                 dirichlet=dirichlet, loads=loads, analysis=analysis, monitors=monitors,
                 paper=_check_paper(raw.get("paper", {}), monitors),
                 cut=check_cut("cut", raw["cut"]) if "cut" in raw else None,
                 parameters=check_parameters_table("parameters", raw.get("parameters", {}), loads))


def _check_histories(loads, analysis, dt_path: str = "analysis.dt", time_unit: str = "") -> None:
    """Every load's history a finite number over the analysis: the time of a dynamic one (at its
    half steps), the load factor of a static one (its pseudo-time); and a dynamic one's resolved
    by its time step ``dt`` (named ``dt_path``) and by each of its ``dt_sweep``
    (:func:`~.histories.check_history_resolution`)."""
    steps = []  # (name, dt) of every time step the history is sampled at
    if analysis["type"] == "dynamic":
        horizon, dt = float(analysis["t_end"]), float(analysis["dt"])
        steps = [(dt_path, dt)] + [(f"analysis.dt_sweep[{j}]", float(d))
                                   for j, d in enumerate(analysis.get("dt_sweep", ()))]
    else:
        horizon, dt = float(analysis.get("max_load_factor", 1.0)), None
    for i, ld in enumerate(loads):
        check_history_values(f"load[{i}].history", ld["history"], horizon, dt)
        for name, step in steps:
            check_history_resolution(f"load[{i}].history", ld["history"], step, name, time_unit)


def _jsonable(obj):
    """JSON form of the numpy values a validated scene may hold (hashing only)."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer)):
        return obj.item()
    raise TypeError(f"scene content: {type(obj).__name__} is not JSON-able")
