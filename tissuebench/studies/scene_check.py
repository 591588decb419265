"""``tissuebench scene check FILE``: what a scene models, counted, before any solve.

A user who wrote a scene for their own organ wants to see that the clamp, the load and the
monitors landed where they meant, in the units they meant, before waiting for a reference:
:func:`scene_summary` validates the scene (the loader's checks, then the problem's: node
sets, rigid-body modes) and counts what it models; :func:`~tissuebench.reports.scene_figure.draw_scene`
draws it. Nothing is solved: the critical time step is one eigenvalue of the lumped system.
"""
from __future__ import annotations

import numpy as np

from ..cases.monitors import resolve_monitors
from ..cases.scene import LENGTH_UNITS
from ..reference.formulation import formulation_of
from ..refsolvers.backends import make_backend
from ..refsolvers.dynamics import SecondOrderSystem, critical_time_step

__all__ = ["scene_summary", "summary_lines", "small_strain"]

_SIZE_M = (1e-4, 10.0)  # an organ between 0.1 mm and 10 m across: outside, the unit is likely wrong


def small_strain(material: dict) -> dict:
    """The material's small-strain constants: Young's modulus E, Poisson's ratio nu, shear modulus
    mu and bulk modulus K (in the scene's stress unit), where the law has them."""
    m = dict(material or {})
    name = m.get("name")
    if "E" in m and "nu" in m:
        E, nu = m["E"], m["nu"]
        return {"E": E, "nu": nu, "mu": E / (2 * (1 + nu)), "K": E / (3 * (1 - 2 * nu))}
    if name == "mooney_rivlin":
        mu, K = 2.0 * (m["mu1"] + m["mu2"]), m["kappa"]
        return {"E": 9 * K * mu / (3 * K + mu), "nu": (3 * K - 2 * mu) / (2 * (3 * K + mu)), "mu": mu, "K": K}
    return {}


def _bbox(scene) -> dict:
    lo, hi = scene.mesh.points.min(axis=0), scene.mesh.points.max(axis=0)
    out = {"size": (hi - lo).tolist(), "unit": scene.units.get("length", "?")}
    metre = LENGTH_UNITS.get(out["unit"])
    if metre is not None:
        diag = float(np.linalg.norm(hi - lo)) * metre
        out["diagonal_m"] = diag
        if not _SIZE_M[0] <= diag <= _SIZE_M[1]:
            out["warning"] = (f"the body is {diag:.3g} m across: is mesh.unit (or the scale) right? "
                              f"([units] length = {out['unit']!r})")
    return out


def _critical_time_step(scene, backend) -> float | None:
    """dt_cr of central difference on the lumped system at rest (None without a density)."""
    if not scene.density:
        return None

    system = SecondOrderSystem.from_backend(backend, lambda t: 1.0, lumped=True, linear=False)
    return critical_time_step(system)


def scene_summary(scene, backend: str = "skfem") -> dict:
    """Counts of what ``scene`` (a validated :class:`~tissuebench.cases.scene.Scene`, FE) models:
    mesh, bounding box, clamped and loaded nodes, the total load, monitors, rigid-body modes
    removed, the material at small strain, the critical time step. Raises ValueError (naming the
    entry) where the problem cannot be built (a region that selects no node, free rigid modes)."""
    if not scene.is_fe:
        scene.line_model()  # its checks: node sets, a load on the supports
        return {"name": scene.name, "model": scene.model, "nodes": int(len(scene.mesh.points))}

    pb = scene.to_problem()  # the problem's checks: node sets, shared dofs, rigid-body modes
    resolve_monitors(scene, pb)  # a monitor point off the body: the run's refusal, before it
    be = make_backend(backend, pb)
    form = formulation_of(scene, backend)
    nodes = pb.nodes
    clamps = []
    for d, entry in zip(pb.dirichlet, scene.dirichlet):
        dofs = d.resolve(nodes)[0]
        clamps.append({"name": entry.get("name", ""), "nodes": int(len(np.unique(dofs // 3))),
                       "components": "".join("xyz"[c] for c in entry["components"]),
                       "prescribed": "motion" in entry or any(v != 0.0 for v in entry["value"])})
    f = be.external_force(np.zeros(be.ndof), 1.0).reshape(-1, 3)
    loaded = np.flatnonzero(np.linalg.norm(f, axis=1) > 0)
    monitors = [{"name": m["name"], "quantity": m["quantity"]} for m in scene.monitors]
    return {"name": scene.name, "model": "fe", "element": scene.element, "mesh": scene.mesh_label,
            "vertices": int(scene.mesh.n_vertices), "cells": int(scene.mesh.n_cells), "nodes": int(len(nodes)),
            "dofs": int(pb.ndof), "free_dofs": int(len(pb.free_dofs)), "bbox": _bbox(scene), "clamps": clamps,
            "fixed_nodes": int(len(np.unique(pb.fixed_dofs // 3))), "rigid_modes_removed": 6,
            "bodies": int(scene.mesh.components.max()) + 1,
            "loaded_nodes": int(len(loaded)), "total_load": f.sum(axis=0).tolist(), "monitors": monitors,
            "material": {"name": scene.material["name"], **small_strain(scene.material)},
            "density": scene.density, "analysis": scene.analysis["type"],
            "dt_critical": _critical_time_step(scene, be), "load_nodes": loaded, "load_vectors": f[loaded],
            "formulation": form.label, "formulation_reason": form.reason, "locking_warning": form.warning,
            "locking_indicator": form.indicator or {},
            "fixed": np.unique(pb.fixed_dofs // 3)}


def summary_lines(s: dict, units: dict) -> list[str]:
    """The summary as the CLI prints it."""
    if s.get("model") != "fe":
        return [f"{s['name']}: a {s['model']} model with {s['nodes']} nodes"]
    L, F, P = units.get("length", ""), units.get("force", ""), units.get("stress", "")
    b = s["bbox"]
    lines = [f"{s['name']}: {s['element']} on {s['mesh']}: {s['vertices']} vertices, {s['cells']} cells, "
             f"{s['dofs']} dofs ({s['free_dofs']} free)",
             f"  size {' x '.join(f'{x:.4g}' for x in b['size'])} {L}"
             + (f" ({b['diagonal_m']:.3g} m across)" if "diagonal_m" in b else "")]
    if "warning" in b:
        lines.append(f"  WARNING: {b['warning']}")
    for c in s["clamps"]:
        what = "prescribed displacement" if c["prescribed"] else "fixed"
        lines.append(f"  dirichlet {c['name'] or ''}: {c['nodes']} nodes, components {c['components']} {what}")
    bodies = f" of each of the {s['bodies']} bodies (connected parts) of the mesh" if s.get("bodies", 1) > 1 else ""
    lines.append(f"  {s['fixed_nodes']} constrained nodes remove all 6 rigid-body modes{bodies}")
    total = np.asarray(s["total_load"])
    lines.append(f"  loads: {s['loaded_nodes']} loaded nodes, total force at load factor 1 "
                 f"[{', '.join(f'{x:.4g}' for x in total)}] {F} (|F| = {np.linalg.norm(total):.4g} {F})")
    lines.append(f"  monitors: {', '.join(m['name'] + ' (' + m['quantity'] + ')' for m in s['monitors']) or 'none'}")
    m = s["material"]
    if "E" in m:
        lines.append(f"  material {m['name']} at small strain: E = {m['E']:.4g} {P}, nu = {m['nu']:.4g}, "
                     f"shear modulus {m['mu']:.4g} {P}, bulk modulus {m['K']:.4g} {P}")
    else:
        lines.append(f"  material {m['name']}")
    if s["dt_critical"] is not None:
        lines.append(f"  critical time step of central difference (lumped mass, at rest): {s['dt_critical']:.3g} "
                     f"{units.get('time', 's')}")
    else:
        lines.append("  no density: no critical time step (a static scene needs none)")
    lines.append(f"  analysis: {s['analysis']}")
    if s.get("formulation"):
        lines.append(f"  formulation: {s['formulation']}: {s['formulation_reason']}")
    if s.get("locking_warning"):
        lines.append(f"  {s['locking_warning']}")
    return lines
