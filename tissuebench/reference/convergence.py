"""The reference's mesh-convergence check: the monitored quantities at h and h/2.

Verification practice asks of any reference that its quantities of interest be shown to
converge. :func:`convergence_check` solves the scene with its reference formulation
(:mod:`.formulation`) on its mesh and on the mesh refined once uniformly (every tetrahedron
split in eight: h/2), with the same formulation on both, and states the observed relative
difference of every monitored quantity at the final load factor (or time). A small difference
says the reference has converged to it; a large one says the mesh is too coarse for the
quantity, whatever the ROMs measured against it.

Where the scene asks for an element that locks (``element = "P1"`` at nu >= 0.45, and the
locking indicator says it does), the h/2 run takes the formulation that does not lock (average
nodal pressure tetrahedra) by default: the difference is then the distance of the user's
reference from one that neither locks nor is as coarse, the number that says whether the
reference is a yardstick. ``same_formulation=True`` keeps the scene's element on both meshes
(the mesh convergence of that element alone).

Before it solves anything the check estimates the h/2 run's memory (:mod:`.memory`: one
assembly and one factorisation at h, scaled) and refuses, with the estimate, a refinement that
would not fit (:class:`RefinementTooLarge`).

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
from ..refsolvers.anp import AnpBackend
from ..refsolvers.backends import make_backend
from .formulation import ANP_MATERIALS, FORMULATION_LABELS, formulation_of
from .locking import decided_elsewhere
from .memory import MEMORY_MARGIN, RefinedMemory, available_bytes, estimate_refined_peak, size_text
from .progress_lines import SolveLines
from .runner import solve

__all__ = ["refined_scene", "refined_formulation", "convergence_check", "RefinementTooLarge", "CONVERGENCE_COLUMNS"]

CONVERGENCE_COLUMNS = ["case", "formulation", "formulation_h_half", "quantity", "h", "h_half", "rel_diff", "dofs_h",
                       "dofs_h_half", "status_h", "status_h_half", "wall_s", "memory_estimate_h_half", "how"]


class RefinementTooLarge(MemoryError):
    """The h/2 run would not fit in the memory the check may use; ``estimate`` (a
    :class:`~.memory.RefinedMemory`) and ``limit`` (bytes) say by how much."""

    def __init__(self, message, estimate, limit):
        super().__init__(message)
        self.estimate, self.limit = estimate, limit


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


def refined_formulation(scene, form, same_formulation: bool = False) -> tuple[str, str]:
    """``(name, why)``: the formulation of the h/2 run. The h mesh's, unless it is P1 asked for where
    the h mesh's locking indicator says P1 locks and the material has a volumetric part: then average
    nodal pressure tetrahedra (module docstring), unless ``same_formulation``."""
    ind = form.indicator or {}
    locks = form.name == "displacement" and form.element == "P1" and ind.get("computed") and ind.get("locks")
    if not locks or same_formulation:
        return form.name, "the h mesh's"
    if scene.material.get("name") not in ANP_MATERIALS:
        return form.name, f"the h mesh's (material {scene.material.get('name')!r}: no formulation that does not lock)"
    return "anp", ("P1 locks on the h mesh (its indicator), so h/2 takes a formulation that does not: the difference "
                   "is the h reference's distance from one that neither locks nor is as coarse (locking and mesh "
                   "together; --same-formulation for P1 on both)")


def _estimate(scene, fine_scene, backend, fine_name):
    """The h/2 run's memory (:func:`~.memory.estimate_refined_peak`), measured at h with its formulation."""
    if fine_name not in ("displacement", "anp"):
        return RefinedMemory(None, None, None, 0, 0, 0.0, why=f"not estimated for the {fine_name} formulation")
    pb = scene.to_problem("P1" if fine_name == "anp" else scene.element)
    be = make_backend(backend, pb)
    if fine_name == "anp":
        be = AnpBackend(pb, be)
    return estimate_refined_peak(be, len(fine_scene.to_problem().free_dofs))


def _fits(scene, fine_scene, backend, fine_name, memory_limit, say):
    """The h/2 run's memory estimate, said; :class:`RefinementTooLarge` when it would not fit."""
    estimate = _estimate(scene, fine_scene, backend, fine_name)
    limit = available_bytes() if memory_limit is None else int(memory_limit)
    what = "the available memory" if memory_limit is None else "memory_limit"
    say(f"convergence {scene.name} h/2: {estimate.text()}; {what} {size_text(limit)}")
    if estimate.peak is not None and MEMORY_MARGIN * estimate.peak > limit:
        raise RefinementTooLarge(
            f"{scene.name}: the h/2 run would not fit: {estimate.text()}, x {MEMORY_MARGIN:g} margin = "
            f"{size_text(MEMORY_MARGIN * estimate.peak)} > {what} {size_text(limit)}; nothing was solved "
            "(a coarser mesh, a machine with more memory, or --memory-limit to try anyway)", estimate, limit)
    return estimate


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


def convergence_check(scene, backend: str = "skfem", progress=None, log=None, same_formulation: bool = False,
                      memory_limit: int | None = None) -> pd.DataFrame:
    """One row per monitored quantity of ``scene``: its final value at h and at h/2, the relative
    difference ``|h - h/2| / |h/2|``, the dofs and statuses of both runs, the formulation of each,
    the wall time and the h/2 run's memory estimate (bytes; these two vary from run to run)
    (:data:`CONVERGENCE_COLUMNS`).

    Parameters
    ----------
    scene : Scene
        A finite-element scene on tetrahedra.
    backend : {"skfem", "ngsolve"}
    progress : callable, optional
        ``progress(done, total)`` of each solve (:func:`~.runner.solve`).
    log : callable, optional
        ``log(text)``: a line per step of the check (module docstring); None: nothing said.
    same_formulation : bool
        Keep the h mesh's formulation at h/2 even where it locks (:func:`refined_formulation`).
    memory_limit : int, optional
        Bytes the h/2 run may take above the process's memory; default the machine's available
        memory now. A run estimated above it (times :data:`~.memory.MEMORY_MARGIN`) is refused.

    Raises
    ------
    RefinementTooLarge
        Before any solve, when the h/2 run's estimated memory exceeds ``memory_limit``.
    """
    if not scene.is_fe:
        raise ValueError(f"{scene.name}: the h/2 check is for finite-element scenes, not a {scene.model} model")
    if memory_limit is not None and not memory_limit > 0:
        raise ValueError(f"convergence_check: memory_limit must be > 0 bytes, got {memory_limit!r}")
    say = log or (lambda _text: None)
    say(f"convergence {scene.name}: choosing the reference formulation")
    form = formulation_of(scene, backend)
    say(f"convergence {scene.name}: formulation {form.label} ({form.reason})")
    fine_name, fine_why = refined_formulation(scene, form, same_formulation)
    fine_label = form.label if fine_name == form.name else FORMULATION_LABELS[fine_name]
    say(f"convergence {scene.name} h/2: {fine_label} ({fine_why}); refining the mesh (each tetrahedron split in eight)")
    fine_scene = refined_scene(scene, fine_name)
    estimate = _fits(scene, fine_scene, backend, fine_name, memory_limit, say)
    t0 = time.perf_counter()
    coarse = _solve_mesh(scene, backend, form, f"convergence {scene.name} h", progress, log)
    fine = _solve_mesh(fine_scene, backend, formulation_of(fine_scene, backend), f"convergence {scene.name} h/2",
                       progress, log)
    wall = time.perf_counter() - t0
    a, b = _final(coarse), _final(fine)
    memory = np.nan if estimate.peak is None else float(estimate.peak)
    how = (f"h: {form.label} ({form.reason}); h/2: {fine_label} ({fine_why}), each tetrahedron split in eight, "
           f"{fine_scene.mesh.n_vertices} vertices")
    rows = []
    for m in scene.monitors:
        q = m["name"]
        h, h2 = a.get(q, np.nan), b.get(q, np.nan)
        rel = abs(h - h2) / abs(h2) if np.isfinite(h) and np.isfinite(h2) and h2 != 0 else np.nan
        rows.append({"case": scene.name, "formulation": form.label, "formulation_h_half": fine_label, "quantity": q,
                     "h": h, "h_half": h2, "rel_diff": rel, "dofs_h": int(coarse.problem.ndof),
                     "dofs_h_half": int(fine.problem.ndof), "status_h": coarse.status, "status_h_half": fine.status,
                     "wall_s": wall, "memory_estimate_h_half": memory, "how": how})
    say(f"convergence {scene.name}: both meshes in {wall:.3g} s")
    return pd.DataFrame(rows, columns=CONVERGENCE_COLUMNS)
