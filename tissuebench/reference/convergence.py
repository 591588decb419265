"""The reference's mesh-convergence check: the monitored quantities at h and h/2.

Verification practice asks of any reference that its quantities of interest be shown to
converge. :func:`convergence_check` solves the scene with its reference formulation
(:mod:`.formulation`) on its mesh and on the mesh refined once uniformly (every tetrahedron
split in eight: h/2), with the same formulation on both, and states the observed relative
difference of every monitored quantity at the final load factor (or time). A small difference
says the reference has converged to it; a large one says the mesh is too coarse for the
quantity, whatever the ROMs measured against it.
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import pandas as pd

from ..cases.builtmesh import BuiltMesh
from ..refsolvers.mesh import Mesh
from .formulation import formulation_of
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
    return new


def _final(ref) -> dict:
    return ref.monitors_at() if ref.ok else {}


def convergence_check(scene, backend: str = "skfem", progress=None) -> pd.DataFrame:
    """One row per monitored quantity of ``scene``: its final value at h and at h/2, the relative
    difference ``|h - h/2| / |h/2|``, the dofs and statuses of both runs (:data:`CONVERGENCE_COLUMNS`)."""
    if not scene.is_fe:
        raise ValueError(f"{scene.name}: the h/2 check is for finite-element scenes, not a {scene.model} model")
    form = formulation_of(scene, backend)
    t0 = time.perf_counter()
    coarse = solve(scene, backend, progress=progress)
    fine_scene = refined_scene(scene, form.name)
    fine = solve(fine_scene, backend, progress=progress)
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
    return pd.DataFrame(rows, columns=CONVERGENCE_COLUMNS)
