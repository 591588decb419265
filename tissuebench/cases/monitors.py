"""Monitored quantities of the scene files (``[[monitor]]``): validation and evaluation.

Quantities: max_displacement; displacement and deformed_coordinate (at the node
nearest to ``point``, one ``component`` or the norm); reaction_force, nominal_stress
(reaction / ``area``) and moment (about ``axis`` through ``center``) on a ``region``,
which need the internal force vector; volume_ratio (deformed / reference volume);
strain_energy (needs a backend, not evaluated here). Every value is multiplied by
``scale`` (e.g. 1e-3 for kPa).
"""
from __future__ import annotations

import numpy as np

from .regions import check_region
from .schema import AXES, c_bool, c_enum, c_frame, c_num, c_pos, c_str, c_vec3, check_table, require

__all__ = ["MONITOR_QUANTITIES", "check_monitor", "evaluate_monitors", "unit_vector"]

MONITOR_QUANTITIES = ("max_displacement", "displacement", "deformed_coordinate", "reaction_force",
                      "nominal_stress", "moment", "volume_ratio", "strain_energy")
_MONITOR_NEEDS = {"displacement": ("point", "component"), "deformed_coordinate": ("point", "component"),
                  "reaction_force": ("region", "component"), "nominal_stress": ("region", "component", "area"),
                  "moment": ("region", "axis", "center")}
_MONITOR_SCHEMA = {"name": c_str, "quantity": c_enum(*MONITOR_QUANTITIES), "region": check_region,
                   "point": c_vec3, "component": c_enum("x", "y", "z", "u", "w", "theta", "norm"),
                   "axis": c_vec3, "center": c_vec3, "area": c_pos, "scale": c_num, "unit": c_str,
                   "boundary": c_bool, "frame": c_frame}


def check_monitor(path, m, model):
    """Validate a ``[[monitor]]`` entry; returns the checked table."""
    m = check_table(path, m, _MONITOR_SCHEMA, required=("name", "quantity"))
    require(path, m, _MONITOR_NEEDS.get(m["quantity"], ()), f"for quantity {m['quantity']!r}")
    return m


def unit_vector(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def evaluate_monitors(scene, problem, u, f_int=None) -> dict:
    """Values of the ``[[monitor]]`` quantities of ``scene`` for displacement ``u`` (full
    dof vector) of ``problem`` (from ``scene.to_problem()``); reactions need the internal
    force ``f_int``."""
    U = np.asarray(u, float).reshape(-1, 3)
    out = {}
    for m in scene.monitors:
        q = m["quantity"]
        if q == "max_displacement":
            val = float(np.linalg.norm(U, axis=1).max())
        elif q in ("displacement", "deformed_coordinate"):
            val = _point_value(scene, m, problem.nodes, U)
        elif q in ("reaction_force", "nominal_stress", "moment"):
            val = _reaction(scene, m, problem.nodes, U, f_int)
        elif q == "volume_ratio":
            val = _volume_ratio(problem.mesh, U)
        else:
            raise ValueError(f"monitor {m['name']!r}: quantity {q!r} needs a backend (strain energy)")
        out[m["name"]] = val * m.get("scale", 1.0)
    return out


def _point_value(scene, m, nodes, U):
    spec = {"nearest": m["point"], "boundary": m.get("boundary", False), "frame": m.get("frame", "absolute")}
    i = scene.select(m["name"], spec, nodes)[0]
    vec = U[i] + (nodes[i] if m["quantity"] == "deformed_coordinate" else 0.0)
    return float(np.linalg.norm(vec) if m["component"] == "norm" else vec[AXES[m["component"]]])


def _reaction(scene, m, nodes, U, f_int):
    if f_int is None:
        raise ValueError(f"monitor {m['name']!r} needs f_int")
    F = np.asarray(f_int, float).reshape(-1, 3)
    idx = scene.select(m["name"], m["region"], nodes)
    if m["quantity"] == "moment":
        # about the axis through the deformed positions: the arm follows the body
        arm = nodes[idx] + U[idx] - np.asarray(m["center"])
        return float(np.sum(np.cross(arm, F[idx]) @ unit_vector(m["axis"])))
    val = float(F[idx, AXES[m["component"]]].sum())
    return val / m["area"] if m["quantity"] == "nominal_stress" else val


def _volume_ratio(mesh, U):
    from ..refsolvers import Mesh

    # only the vertices carry the geometry (P2 mid-edge nodes follow the straight edges)
    deformed = Mesh(mesh.points + U[: mesh.n_vertices], mesh.cells, mesh.cell_type, reorient=False)
    return float(deformed.cell_volumes().sum() / mesh.cell_volumes().sum())
