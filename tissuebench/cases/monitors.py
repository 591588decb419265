"""Monitored quantities of the scene files (``[[monitor]]``): validation and evaluation.

Quantities: max_displacement; displacement and deformed_coordinate (at ``point``, one
``component`` or the norm); reaction_force, nominal_stress
(reaction / ``area``) and moment (about ``axis`` through ``center``) on a ``region``: the
force the supports exert on the body at the region's fixed dofs, ``f_int - f_ext`` there
(:meth:`~tissuebench.refsolvers.problem.Problem.support_reactions`: a load lumped onto a
supported node is the support's to carry), so that in statics the reactions of every support
and the applied load add up to zero whatever the load (point, traction, pressure, gravity);
volume_ratio (deformed / reference volume);
strain_energy (needs a backend, not evaluated here). Every value is multiplied by
``scale`` (e.g. 1e-3 for kPa).

Point monitors (displacement, deformed_coordinate) interpolate the nodal field at the
physical ``point`` (``frame = "bbox"``: fractions of the mesh bounding box) with the
element's shape functions (:mod:`.probes`): the monitor stays at the same material point
whatever the mesh, which a mesh-refinement study needs. A point on a node reads that
node; a point just off a curved, faceted boundary is clipped into the nearest cell. The
deformed coordinate is the interpolated reference position plus the interpolated
displacement, consistent when the point was clipped. A monitor with ``boundary = true``
instead reads the boundary node nearest to ``point``: it marks a loaded surface node
(e.g. the liver tool tip, where a point load acts on that very node). The probes are
built once per problem and monitor and reused at every step.
"""
from __future__ import annotations

import weakref

import numpy as np

from ..refsolvers import Mesh
from .probes import Probe, make_probe
from .regions import check_region
from .schema import AXES, c_bool, c_enum, c_frame, c_name, c_num, c_pos, c_str, c_vec3, check_table, require

__all__ = ["MONITOR_QUANTITIES", "REACTION_QUANTITIES", "check_monitor", "evaluate_monitors", "linear_outputs",
           "resolve_monitors", "unit_vector", "needs_reactions"]

MONITOR_QUANTITIES = ("max_displacement", "displacement", "deformed_coordinate", "reaction_force",
                      "nominal_stress", "moment", "volume_ratio", "strain_energy")
#: the quantities read from the support reactions
REACTION_QUANTITIES = ("reaction_force", "nominal_stress", "moment")
_MONITOR_NEEDS = {"displacement": ("point", "component"), "deformed_coordinate": ("point", "component"),
                  "reaction_force": ("region", "component"), "nominal_stress": ("region", "component", "area"),
                  "moment": ("region", "axis", "center")}
_MONITOR_SCHEMA = {"name": c_name, "quantity": c_enum(*MONITOR_QUANTITIES), "region": check_region,
                   "point": c_vec3, "component": c_enum("x", "y", "z", "u", "w", "theta", "norm"),
                   "axis": c_vec3, "center": c_vec3, "area": c_pos, "scale": c_num, "unit": c_str,
                   "boundary": c_bool, "frame": c_frame}
# what each quantity and key means (the scene-format reference of the documentation)
MONITOR_QUANTITY_DOC = {
    "max_displacement": "the largest nodal displacement magnitude",
    "displacement": "the displacement at `point` (one `component`, or `\"norm\"`)",
    "deformed_coordinate": "the deformed position at `point` (one `component`)",
    "reaction_force": "the reaction on `region` (one `component`)",
    "nominal_stress": "the reaction on `region` divided by the reference `area`",
    "moment": "the moment of the reactions on `region` about `axis` through `center`",
    "volume_ratio": "deformed over reference volume",
    "strain_energy": "the stored energy (evaluated by a backend)",
}
MONITOR_DOC = {
    "name": "the column name in the results", "quantity": "what is measured (see the quantities)",
    "region": "the nodes of a reaction, stress or moment (a region table)",
    "point": "where a point monitor reads (interpolated in its cell)",
    "component": "`\"x\"`, `\"y\"`, `\"z\"` (1D: `\"u\"`, `\"w\"`, `\"theta\"`) or `\"norm\"`",
    "axis": "`moment`: the axis", "center": "`moment`: a point of the axis", "area": "`nominal_stress`: the area",
    "scale": "a factor applied to the value (1e-3 for kPa ...)", "unit": "documentation: the unit after `scale`",
    "boundary": "read at the boundary node nearest to `point` instead of interpolating",
    "frame": "`\"bbox\"`: `point` as fractions of the bounding box",
}


def check_monitor(path, m, model):
    """Validate a ``[[monitor]]`` entry; returns the checked table."""
    m = check_table(path, m, _MONITOR_SCHEMA, required=("name", "quantity"))
    require(path, m, _MONITOR_NEEDS.get(m["quantity"], ()), f"for quantity {m['quantity']!r}")
    return m


def unit_vector(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def needs_reactions(scene) -> bool:
    """Whether a monitor of ``scene`` reads the support reactions."""
    return any(m["quantity"] in REACTION_QUANTITIES for m in scene.monitors)


def evaluate_monitors(scene, problem, u, reactions=None) -> dict:
    """Values of the ``[[monitor]]`` quantities of ``scene`` for displacement ``u`` (full
    dof vector) of ``problem`` (from ``scene.to_problem()``); the reaction monitors need
    ``reactions``, the (n_dof,) forces the supports exert
    (:meth:`~tissuebench.refsolvers.problem.Problem.support_reactions`)."""
    U = np.asarray(u, float).reshape(-1, 3)
    out = {}
    for m in scene.monitors:
        q = m["quantity"]
        if q == "max_displacement":
            val = float(np.linalg.norm(U, axis=1).max())
        elif q in ("displacement", "deformed_coordinate"):
            val = _point_value(m, _probe(scene, m, problem), U)
        elif q in REACTION_QUANTITIES:
            val = _reaction(scene, m, problem.nodes, U, reactions)
        elif q == "volume_ratio":
            val = _volume_ratio(problem.mesh, U)
        else:
            raise ValueError(f"monitor {m['name']!r}: quantity {q!r} needs a backend (strain energy)")
        out[m["name"]] = val * m.get("scale", 1.0)
    return out


def resolve_monitors(scene, problem) -> None:
    """Place every monitor on ``problem`` as a run does (a point's probe, a reaction's region),
    before any solve: a point off the body or a region that selects no node is the run's
    ValueError, said by ``scene check`` and ``sweep --scene`` rather than after a reference."""
    for m in scene.monitors:
        if m["quantity"] in ("displacement", "deformed_coordinate"):
            _probe(scene, m, problem)
        elif m["quantity"] in ("reaction_force", "nominal_stress", "moment"):
            scene.select(m["name"], m["region"], problem.nodes)


def linear_outputs(scene, problem) -> dict:
    """``{monitor name: c (n_dof,)}`` for the monitors that are linear in the displacement
    (``displacement`` at a point, one x/y/z component): ``value = c @ u``. Reduced models
    project these offline, so their haptic step reports them without the full field."""
    out = {}
    for m in scene.monitors:
        if m["quantity"] != "displacement" or m["component"] not in AXES:
            continue
        probe = _probe(scene, m, problem)
        c = np.zeros(problem.ndof)
        np.add.at(c, 3 * np.asarray(probe.nodes) + AXES[m["component"]], probe.weights * m.get("scale", 1.0))
        out[m["name"]] = c
    return out


def _point_value(m, probe, U):
    vec = probe(U)
    if m["quantity"] == "deformed_coordinate":
        # an interpolating probe reports the requested material point moved by u (the faceted
        # mesh misses a curved surface by O(h^2 / R), which must not enter the value); a
        # node probe (boundary monitors) reports its node
        vec = vec + (np.asarray(probe.point, float) if probe.cell >= 0 else probe.location)
    return float(np.linalg.norm(vec) if m["component"] == "norm" else vec[AXES[m["component"]]])


# problem -> {monitor key: Probe}; weak, so that a dropped problem frees its probes
_PROBES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _probe(scene, m, problem) -> Probe:
    """The cached :class:`~.probes.Probe` of point monitor ``m`` on ``problem``."""
    try:
        cache = _PROBES.setdefault(problem, {})
    except TypeError:  # not weak-referenceable: build every time
        cache = {}
    key = (m["name"], tuple(m["point"]), bool(m.get("boundary", False)), m.get("frame", "absolute"))
    if key not in cache:
        cache[key] = _make_monitor_probe(scene, m, problem)
    return cache[key]


def _make_monitor_probe(scene, m, problem) -> Probe:
    nodes = problem.nodes
    if m.get("boundary", False):
        # a loaded surface node (tool tip): the nearest boundary node, not an interpolation
        spec = {"nearest": m["point"], "boundary": True, "frame": m.get("frame", "absolute")}
        i = int(scene.select(m["name"], spec, nodes)[0])
        p = _physical_point(m, problem.mesh)
        return Probe(np.array([i]), np.ones(1), p, nodes[i].copy(), float(np.linalg.norm(nodes[i] - p)), -1)
    try:
        return make_probe(problem.mesh, nodes, problem.element, _physical_point(m, problem.mesh),
                          cell_nodes=problem.layout[1])
    except ValueError as e:
        raise ValueError(f"{scene.name}: monitor {m['name']!r}: {e}") from None


def _physical_point(m, mesh) -> np.ndarray:
    """``m["point"]`` in the length unit: ``frame = "bbox"`` gives fractions of the mesh
    bounding box, as for the region selectors."""
    p = np.asarray(m["point"], float)
    if m.get("frame", "absolute") != "bbox":
        return p
    lo, hi = mesh.points.min(axis=0), mesh.points.max(axis=0)
    return lo + p * (hi - lo)


def _reaction(scene, m, nodes, U, reactions):
    if reactions is None:
        raise ValueError(f"monitor {m['name']!r} needs the support reactions")
    F = np.asarray(reactions, float).reshape(-1, 3)
    idx = scene.select(m["name"], m["region"], nodes)
    if m["quantity"] == "moment":
        # about the axis through the deformed positions: the arm follows the body
        arm = nodes[idx] + U[idx] - np.asarray(m["center"])
        return float(np.sum(np.cross(arm, F[idx]) @ unit_vector(m["axis"])))
    val = float(F[idx, AXES[m["component"]]].sum())
    return val / m["area"] if m["quantity"] == "nominal_stress" else val


def _volume_ratio(mesh, U):

    # only the vertices carry the geometry (P2 mid-edge nodes follow the straight edges)
    deformed = Mesh(mesh.points + U[: mesh.n_vertices], mesh.cells, mesh.cell_type, reorient=False)
    return float(deformed.cell_volumes().sum() / mesh.cell_volumes().sum())
