"""Validation of the physical sections of a scene: material, model, dirichlet, load, analysis.

``[material]`` (FE only): name (linear | svk | neo_hookean | neo_hookean_decoupled | mooney_rivlin |
guccione),
its parameters, density (optional, > 0), fibres (Guccione, optional 3-vector).
``[model]`` (1D models only): the discrete model's parameters.
``[[dirichlet]]``: region, components ("xyz" or list), value (number or one per
component) or motion (``{type = "rotation", axis, center, angle_deg}``), scaled (bool).
``[[load]]``: type (point | traction | pressure | follower_pressure | body), region,
value, distribute ("total" | "per_node" | "interpolate", point loads: "interpolate" puts one
point force at the region's ``nearest`` point, spread on the nodes of its cell by the shape
functions, so the load moves continuously with the point), history.
``[analysis]``: type static (load_steps, max_load_factor, stop_at_divergence, max_cuts (halvings of
an increment Newton does not converge before the run stalls; default: down to 1/4096 of the
target), formulation (below), incompressible (mixed only: J = 1 imposed, the material's volumetric
part unused; default false: the perturbed Lagrangian with the material's volumetric modulus)
or dynamic (dt, t_end, integrator, integrator_options, lumped, dt_sweep, formulation).
``formulation``: "displacement" | "anp" (linear tetrahedra with the volumetric energy averaged at
the vertices, which do not lock, see :mod:`tissuebench.refsolvers.anp`) | "mixed" (static only:
u-p Taylor-Hood P2-P1, see :mod:`tissuebench.refsolvers.mixed`); without it the reference chooses
(:mod:`tissuebench.reference.formulation`).
"""
from __future__ import annotations

import numpy as np

from ..refsolvers.dynamics import make_integrator
from .histories import DEFAULT_HISTORY, check_history
from .regions import check_region
from .schema import (COMPONENTS_1D, c_any, c_bool, c_enum, c_int_range, c_name, c_nonneg, c_num, c_numlist,
                     c_nu, c_pos, c_str, c_table, c_vec3, check_components, check_table, fail, is_num, require)

__all__ = ["MATERIAL_SCHEMAS", "MODEL_SCHEMAS", "LOAD_TYPES", "INTEGRATOR_NAMES", "MAX_LOAD_STEPS", "MAX_TIME_STEPS",
           "VOLUMETRIC_MATERIALS", "check_material", "check_model", "check_dirichlet", "check_load", "check_analysis",
           "check_formulation"]

# bounds on the work a scene may ask for: a typo (dt = 1e-300, load_steps = 10**9) is refused
# when the scene loads, naming the key, instead of exhausting the memory hours later
MAX_LOAD_STEPS = 100_000
MAX_TIME_STEPS = 10_000_000

_ENU = {"E": c_pos, "nu": c_nu}
MATERIAL_SCHEMAS = {
    "linear": _ENU, "svk": _ENU, "neo_hookean": _ENU, "neo_hookean_decoupled": _ENU,
    "mooney_rivlin": {"mu1": c_pos, "mu2": c_nonneg, "kappa": c_pos},
    "guccione": {"C": c_pos, "bf": c_pos, "bt": c_pos, "bfs": c_pos, "kappa": c_pos, "fibres": c_vec3},
}
MODEL_SCHEMAS = {  # model: (schema, required keys)
    "poisson1d": ({"q": c_num, "conductivity": c_pos, "source_range": c_numlist}, ("q",)),
    "frame2dof": ({"masses": c_numlist, "storey_stiffness": c_pos}, ("masses", "storey_stiffness")),
    "hermite_beam": ({"E": c_pos, "A": c_pos, "I": c_pos, "rho": c_pos}, ("E", "A", "I", "rho")),
}
LOAD_TYPES = ("point", "traction", "pressure", "follower_pressure", "body")
INTEGRATOR_NAMES = ("hht", "bathe", "newmark", "backward_euler", "central_difference", "forward_euler")

_MOTION_SCHEMA = {"type": c_enum("rotation"), "axis": c_vec3, "center": c_vec3, "angle_deg": c_num}
DIRICHLET_SCHEMA = {"region": check_region, "components": c_any, "value": c_any, "motion": c_any, "scaled": c_bool,
                    "name": c_name}
LOAD_SCHEMA = {"type": c_enum(*LOAD_TYPES), "region": check_region, "value": c_any, "history": check_history,
               "distribute": c_enum("total", "per_node", "interpolate"), "name": c_name}

# what each key means: the scene-format reference of the documentation is generated from these
# tables (a key without its words fails the docs' test)
MATERIAL_DOC = {
    "name": "the constitutive law (strain energies in `tissuebench.refsolvers.materials`)",
    "density": "mass per volume, needed by dynamic scenes",
    "E": "Young's modulus [stress unit]", "nu": "Poisson's ratio",
    "mu1": "first Mooney-Rivlin coefficient [stress unit]", "mu2": "second Mooney-Rivlin coefficient [stress unit]",
    "kappa": "bulk modulus of the volumetric penalty [stress unit]", "C": "Guccione's scale [stress unit]",
    "bf": "Guccione's fibre exponent", "bt": "Guccione's transverse exponent", "bfs": "Guccione's shear exponent",
    "fibres": "the fibre direction (default x)",
}
MODEL_DOC = {
    "q": "the source term", "conductivity": "the conductivity", "source_range": "where the source acts",
    "masses": "the storey masses", "storey_stiffness": "the stiffness of each storey",
    "E": "Young's modulus", "A": "the cross-section area", "I": "the second moment of area", "rho": "the density",
}
MOTION_DOC = {"type": "`\"rotation\"`", "axis": "the rotation axis", "center": "a point of the axis",
              "angle_deg": "the angle at load factor 1 [degrees]"}
DIRICHLET_DOC = {
    "region": "the nodes held (a region table)",
    "components": "the components fixed: `\"xyz\"`, `[\"x\", \"z\"]` or indices (1D models: their dof names); "
                  "default all",
    "value": "the prescribed displacement at load factor 1: one number for all components or one per component "
             "(default 0)",
    "motion": "instead of `value`: a rigid motion (a rotation table, below) applied as the load factor grows",
    "scaled": "the value scales with the load factor (default `true`)",
    "name": "a name shown by `tissuebench scene check`",
}
LOAD_DOC = {
    "type": "`\"point\"`, `\"traction\"` (dead, per area), `\"pressure\"` (dead, normal), "
            "`\"follower_pressure\"` (follows the deformed surface) or `\"body\"` (per volume)",
    "region": "where it acts (a region table; not for a body load)",
    "value": "at load factor 1: a 3-vector (point, traction, body) or a number (pressures; 1D models)",
    "history": "the load factor against (pseudo-)time (a history table; default a ramp to 1 at t = 1)",
    "distribute": "point loads: `\"total\"` spread evenly over the region's nodes (default), `\"per_node\"`, or "
                  "`\"interpolate\"` (one force at the region's `nearest` point, spread by the shape functions)",
    "name": "a name shown by `tissuebench scene check`",
}
STATIC_DOC = {
    "type": "`\"static\"`", "load_steps": "load increments from 0 to `max_load_factor`",
    "max_load_factor": "the last load factor (default 1)",
    "stop_at_divergence": "run until Newton stops converging; the last converged load factor is the measurement",
    "formulation": "`\"displacement\"` (P1 or P2 displacement), `\"anp\"` (average nodal pressure tetrahedra: "
                   "the default where P1 locks) or `\"mixed\"` (u-p Taylor-Hood P2-P1 with the bulk modulus)",
    "incompressible": "with `formulation = \"mixed\"`: J = 1 imposed by the pressure field (the material's "
                      "volumetric part unused); by default the mixed form keeps the material's bulk modulus",
    "max_cuts": "halvings of an increment Newton does not converge before the run stalls",
    "note": "documentation",
}
DYNAMIC_DOC = {
    "type": "`\"dynamic\"`", "dt": "the time step [time unit]", "t_end": "the end time [time unit]",
    "integrator": "the time integrator (see `INTEGRATOR_NAMES`)",
    "integrator_options": "options of the integrator (`alpha` of HHT ...), checked by its constructor",
    "lumped": "a lumped mass matrix", "dt_sweep": "time steps of a study of the step size",
    "store_every": "keep every n-th step in the results", "note": "documentation",
    "formulation": "`\"displacement\"` or `\"anp\"` (average nodal pressure tetrahedra: the default where P1 "
                   "locks); `\"mixed\"` is static only",
}
_STATIC = {"type": c_str, "load_steps": c_int_range(1, MAX_LOAD_STEPS), "max_load_factor": c_pos,
           "stop_at_divergence": c_bool, "formulation": c_enum("displacement", "anp", "mixed"),
           "incompressible": c_bool, "max_cuts": c_int_range(0, 20),
           "note": c_str}
_DYNAMIC = {"type": c_str, "dt": c_pos, "t_end": c_pos, "integrator": c_str, "integrator_options": c_table,
            "lumped": c_bool, "dt_sweep": c_numlist, "store_every": c_int_range(1, MAX_TIME_STEPS), "note": c_str,
            "formulation": c_enum("displacement", "anp", "mixed")}
#: materials with a volumetric part U(J) (the mixed formulation replaces it, ANP averages it)
VOLUMETRIC_MATERIALS = ("neo_hookean", "neo_hookean_decoupled", "mooney_rivlin", "guccione")


def check_material(path, m):
    """Validate ``[material]``: the parameters required depend on its ``name``."""
    c_table(path, m)
    # the name selects the schema, so it is checked before the rest of the table
    require(path, m, ("name",), f"(in {path})")
    name = m["name"]
    if not isinstance(name, str) or name not in MATERIAL_SCHEMAS:
        fail(f"{path}.name", name, f"unknown material; valid: {sorted(MATERIAL_SCHEMAS)}")
    schema = dict(MATERIAL_SCHEMAS[name], name=c_str, density=c_pos)
    req = [k for k in MATERIAL_SCHEMAS[name] if k != "fibres"]  # Guccione fibres default to x
    return check_table(path, m, schema, required=req)


def check_model(path, m, model):
    """Validate ``[model]``, the parameters of the 1D discrete ``model``."""
    schema, req = MODEL_SCHEMAS[model]
    return check_table(path, m, schema, required=req)


def check_dirichlet(path, d, model):
    """Validate a ``[[dirichlet]]`` entry; ``value`` becomes one float per component."""
    d = check_table(path, d, DIRICHLET_SCHEMA, required=("region",))
    default = "xyz" if model == "fe" else list(COMPONENTS_1D[model])
    d["components"] = check_components(f"{path}.components", d.get("components", default), model)
    if "value" in d and "motion" in d:
        fail(f"{path}.motion", d["motion"], "give either value or motion, not both")
    if "motion" in d:
        d["motion"] = _check_motion(path, d)
    d["value"] = _check_dirichlet_value(f"{path}.value", d.get("value", 0.0), len(d["components"]))
    d.setdefault("scaled", True)
    return d


def _check_motion(path, d):
    motion = check_table(f"{path}.motion", d["motion"], _MOTION_SCHEMA, required=tuple(_MOTION_SCHEMA))
    if d["components"] != [0, 1, 2]:
        fail(f"{path}.components", d["components"], "a rotation prescribes all of x, y, z")
    if np.linalg.norm(motion["axis"]) == 0:
        fail(f"{path}.motion.axis", motion["axis"], "zero axis")
    return motion


def _check_dirichlet_value(path, v, n):
    if is_num(v):
        return [float(v)] * n
    if isinstance(v, list) and len(v) == n and all(is_num(x) for x in v):
        return [float(x) for x in v]
    fail(path, v, f"expected a number or {n} numbers (one per component)")


def check_load(path, ld, model):
    """Validate a ``[[load]]`` entry; fills the default history and distribution."""
    ld = check_table(path, ld, LOAD_SCHEMA, required=("type", "value"))
    kind = ld["type"]
    if model != "fe" and kind != "point":
        fail(f"{path}.type", kind, f"a {model} model takes point loads only")
    if kind != "body":
        require(path, ld, ("region",), f"for a {kind!r} load")
    vector = kind in ("point", "traction", "body") and model == "fe"
    ld["value"] = (c_vec3 if vector else c_num)(f"{path}.value", ld["value"])
    ld.setdefault("history", dict(DEFAULT_HISTORY))
    ld.setdefault("distribute", "total")
    return ld


def check_analysis(path, a):
    """Validate ``[analysis]``, static or dynamic."""
    c_table(path, a)
    kind = a.get("type")
    if kind not in ("static", "dynamic"):
        fail(f"{path}.type", kind, "expected 'static' or 'dynamic'")
    if kind == "static":
        return check_table(path, a, _STATIC, required=("load_steps",))
    a = check_table(path, a, _DYNAMIC, required=("dt", "t_end", "integrator"))
    if a["integrator"] not in INTEGRATOR_NAMES:
        fail(f"{path}.integrator", a["integrator"], f"unknown integrator; valid: {list(INTEGRATOR_NAMES)}")
    if a["t_end"] < a["dt"]:
        fail(f"{path}.t_end", a["t_end"], f"must be >= dt = {a['dt']}")
    _check_step_count(f"{path}.dt", a["dt"], a["t_end"])
    for i, dt in enumerate(a.get("dt_sweep", [])):
        if dt <= 0:
            fail(f"{path}.dt_sweep[{i}]", dt, "expected a time step > 0")
        _check_step_count(f"{path}.dt_sweep[{i}]", dt, a["t_end"])
    if "integrator_options" in a:
        _check_integrator_options(f"{path}.integrator_options", a["integrator"], a["integrator_options"])
    return a


def check_formulation(element, analysis, material):
    """Refuse an ``analysis.formulation`` the element or material cannot have, naming both
    (what ``scene check``, ``describe`` and ``run`` then all refuse alike)."""
    form = analysis.get("formulation")
    name = (material or {}).get("name")
    if analysis.get("incompressible") and form != "mixed":
        fail("analysis.incompressible", True, "only the mixed formulation imposes J = 1 (formulation = 'mixed')")
    if form == "mixed":
        if analysis.get("type") == "dynamic":
            fail("analysis.formulation", form, "the mixed formulation is static only (its pressure field has no "
                 "inertia); a dynamic scene without a formulation gets average nodal pressure tetrahedra where P1 "
                 "locks")
        if element not in (None, "P2"):
            fail("analysis.formulation", form, f"the mixed formulation is Taylor-Hood P2-P1: mesh.element must be "
                 f"'P2' (or left out), not {element!r}")
        if name not in VOLUMETRIC_MATERIALS:
            fail("analysis.formulation", form, f"material {name!r} has no volumetric part to replace by a pressure; "
                 f"valid: {list(VOLUMETRIC_MATERIALS)}")
    if form == "anp":
        if element not in (None, "P1"):
            fail("analysis.formulation", form, f"average nodal pressure is for linear tetrahedra: mesh.element must "
                 f"be 'P1' (or left out), not {element!r}")
        if name not in VOLUMETRIC_MATERIALS + ("linear",):
            fail("analysis.formulation", form, f"material {name!r} has no volumetric part U(J) to average at the "
                 f"vertices; valid: {list(VOLUMETRIC_MATERIALS + ('linear',))}")


def _check_step_count(path, dt, t_end):
    n = t_end / dt
    if not n <= MAX_TIME_STEPS:
        fail(path, dt, f"t_end / dt = {n:.3g} time steps; at most {MAX_TIME_STEPS}")


def _check_integrator_options(path, name, options):
    """The options must configure the integrator (names and values checked by its constructor)."""

    try:
        make_integrator(name, **options)
    except (ValueError, TypeError, ArithmeticError) as exc:
        fail(path, options, f"not options of integrator {name!r}: {exc}")
