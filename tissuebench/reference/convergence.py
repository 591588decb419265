"""The reference's mesh-convergence check: the monitored quantities at h and h/2.

Verification practice asks of any reference that its quantities of interest be shown to
converge. :func:`convergence_check` solves the scene with its reference formulation
(:mod:`.formulation`) on its mesh and on the mesh refined once uniformly (every tetrahedron
split in eight: h/2), with the same formulation on both, and states the observed relative
difference of every monitored quantity at the final load factor (or time). A small difference
says the reference has converged to it; a large one says the mesh is too coarse for the
quantity, whatever the ROMs measured against it.

The two solves take minutes to hours on an organ's mesh; with ``log`` the check says what it
does as it goes (:class:`~.progress_lines.SolveLines`): each mesh's size and formulation, each
load increment (load factor, Newton iterations, residual), each mesh's end (status, time, the
monitored values).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import pandas as pd

from ..cases.builtmesh import BuiltMesh
from ..refsolvers.mesh import Mesh, node_layout
from .formulation import formulation_of
from .locking import decided_elsewhere
from .progress_lines import SolveLines
from .runner import solve

__all__ = ["refined_scene", "convergence_check", "CONVERGENCE_COLUMNS"]

CONVERGENCE_COLUMNS = ["case", "formulation", "quantity", "h", "h_half", "rel_diff", "dofs_h", "dofs_h_half",
                       "status_h", "status_h_half", "wall_s", "how"]


def refined_scene(scene, formulation: str):
    """``scene`` on its mesh refined once (tetrahedra split in eight, h/2), solved with ``formulation``
    (the coarse one's: the refined mesh must not pick another by its own locking indicator)."""
    import skfem

    mesh = scene.mesh
    if mesh.cell_type != "tetra":
        raise ValueError(f"{scene.name}: the h/2 check refines tetrahedra; this mesh has {mesh.cell_type} cells")
    fine = skfem.MeshTet(mesh.points.T.copy(), mesh.cells.T.copy()).refined(1)
    refined = Mesh(fine.p.T.copy(), fine.t.T.copy(), "tetra")
    new = dataclasses.replace(scene, analysis={**scene.analysis, "formulation": formulation},
                              mesh_spec={**scene.mesh_spec, "element": scene.element, "refined": 1})
    new.__dict__["built"] = BuiltMesh(refined, {**scene.mesh_info, "refined": "uniform, h/2"})
    decided_elsewhere(new, f"h/2 of the convergence check: the formulation ({formulation}) is the h mesh's")
    return new


def _final(ref) -> dict:
    return ref.monitors_at() if ref.ok else {}


def _size(scene, form) -> str:
    """What a mesh's solve is made of: vertices, cells, unknowns and the formulation."""
    mesh = scene.mesh
    dofs = f"{3 * len(node_layout(mesh, scene.element)[0])} displacement dofs"  # the table's dofs_h
    if form.name == "mixed":  # Taylor-Hood: a pressure per vertex besides
        dofs += f" + {mesh.n_vertices} pressure dofs"
    a = scene.analysis
    what = (f"static, {a.get('load_steps', 1)} load steps to load factor {a.get('max_load_factor', 1.0):g}"
            if a["type"] == "static" else f"dynamic, dt {a['dt']:g} to t_end {a['t_end']:g}")
    return f"{mesh.n_vertices} vertices, {mesh.n_cells} {mesh.cell_type} cells, {dofs}; {form.label}; {what}"


def _solve_mesh(scene, backend, form, label, progress, log):
    """``scene`` solved, said through ``log`` (when given) from its size to its end."""
    if log is None:
        return solve(scene, backend, progress=progress)
    log(f"{label}: {_size(scene, form)}")
    lines = SolveLines(log, label, scene.analysis["type"], scene.units.get("time", "s"), forward=progress)
    ref = solve(scene, backend, progress=lines)
    values = ", ".join(f"{q} = {v:.6g}" for q, v in _final(ref).items())
    log(f"{label}: done: {ref.status} in {ref.wall_s:.3g} s"
        + ("" if ref.ok else f" ({ref.message})") + (f"; {values}" if values else ""))
    return ref


def convergence_check(scene, backend: str = "skfem", progress=None, log=None) -> pd.DataFrame:
    """One row per monitored quantity of ``scene``: its final value at h and at h/2, the relative
    difference ``|h - h/2| / |h/2|``, the dofs and statuses of both runs (:data:`CONVERGENCE_COLUMNS`).

    Parameters
    ----------
    scene : Scene
        A finite-element scene on tetrahedra.
    backend : {"skfem", "ngsolve"}
    progress : callable, optional
        ``progress(done, total)`` of each solve (:func:`~.runner.solve`).
    log : callable, optional
        ``log(text)``: a line per step of the check (module docstring); None: nothing said.
    """
    if not scene.is_fe:
        raise ValueError(f"{scene.name}: the h/2 check is for finite-element scenes, not a {scene.model} model")
    say = log or (lambda _text: None)
    say(f"convergence {scene.name}: choosing the reference formulation")
    form = formulation_of(scene, backend)
    say(f"convergence {scene.name}: formulation {form.label} ({form.reason})")
    t0 = time.perf_counter()
    coarse = _solve_mesh(scene, backend, form, f"convergence {scene.name} h", progress, log)
    say(f"convergence {scene.name} h/2: refining the mesh (each tetrahedron split in eight)")
    fine_scene = refined_scene(scene, form.name)
    fine = _solve_mesh(fine_scene, backend, form, f"convergence {scene.name} h/2", progress, log)
    wall = time.perf_counter() - t0
    a, b = _final(coarse), _final(fine)
    how = (f"{form.label} ({form.reason}); h/2: each tetrahedron split in eight, "
           f"{fine_scene.mesh.n_vertices} vertices")
    rows = []
    for m in scene.monitors:
        q = m["name"]
        h, h2 = a.get(q, np.nan), b.get(q, np.nan)
        rel = abs(h - h2) / abs(h2) if np.isfinite(h) and np.isfinite(h2) and h2 != 0 else np.nan
        rows.append({"case": scene.name, "formulation": form.label, "quantity": q, "h": h, "h_half": h2,
                     "rel_diff": rel, "dofs_h": int(coarse.problem.ndof), "dofs_h_half": int(fine.problem.ndof),
                     "status_h": coarse.status, "status_h_half": fine.status, "wall_s": wall, "how": how})
    say(f"convergence {scene.name}: both meshes in {wall:.3g} s")
    return pd.DataFrame(rows, columns=CONVERGENCE_COLUMNS)
