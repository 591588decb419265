"""Backend agreement: every finite-element scene given (a sweep's, read back by
:func:`tissuebench.reports.backends.scenes_of_results`) solved by both backends, compared.

scikit-fem and NGSolve implement the same elements, materials and loads independently
(:mod:`tissuebench.refsolvers.backends`) on the same mesh and the same dof numbering (the
:class:`~tissuebench.refsolvers.problem.Problem`), so their reference runs must agree to
the solvers' tolerance. Per scene (deduplicated by content hash) one row: both statuses, the
relative L2 difference of the final displacement field and the largest relative difference
of the monitored quantities at the last stored step, and a verdict against :data:`RTOL`.
A 1D model (one implementation) is a row that says so; a run that fails on one backend
only is a ``disagree`` row with both messages.
"""
from __future__ import annotations

import time

import numpy as np
import pandas as pd

from ..choices import BACKEND_NAMES
from .cache import cached_solve

__all__ = ["RTOL", "backend_agreement"]

RTOL = 1e-6  # Newton tolerances are 1e-8..1e-10 relative; the difference is the solvers', not the FE's
BACKENDS = BACKEND_NAMES


def _compare(case_id, scene) -> dict:

    row = {"case": case_id, "scene": scene.name, "variant": scene.variant or "", "resolution": scene.resolution}
    if not scene.is_fe:
        return {**row, "verdict": "n/a", "how": f"1D model {scene.model}: one implementation"}
    t0 = time.perf_counter()
    a, b = (cached_solve(scene, name)[0] for name in BACKENDS)
    ua, ub = a.final_displacement.ravel(), b.final_displacement.ravel()
    row.update(skfem_status=a.status, ngsolve_status=b.status, ndof=ua.size, seconds=time.perf_counter() - t0)
    if a.status != b.status or len(a.steps) != len(b.steps):
        return {**row, "verdict": "disagree", "how": f"skfem {a.status} ({len(a.steps)} steps): {a.message[:120]}; "
                f"ngsolve {b.status} ({len(b.steps)} steps): {b.message[:120]}"}
    ma, mb = a.monitors_at(), b.monitors_at()
    scale = max(float(np.linalg.norm(ua)), 1e-300)
    row["field_rel_diff"] = float(np.linalg.norm(ub - ua) / scale)
    diffs = {k: abs(mb[k] - ma[k]) / max(abs(ma[k]), 1e-12 * scale, 1e-300) for k in ma if k in mb}
    worst = max(diffs, key=diffs.get) if diffs else ""
    row.update(monitor_rel_diff=float(diffs[worst]) if worst else np.nan, worst_monitor=worst,
               monitor_skfem=ma.get(worst, np.nan), monitor_ngsolve=mb.get(worst, np.nan))
    ok = row["field_rel_diff"] <= RTOL and (not worst or row["monitor_rel_diff"] <= RTOL)
    return {**row, "verdict": "agree" if ok else "disagree",
            "how": f"final step of {len(a.steps)}, {a.status} on both"}


def backend_agreement(scenes, progress=None) -> pd.DataFrame:
    """One row per distinct scene of ``[(case id, scene)]`` (module docstring); a computation
    that raises is a ``failed`` row with its message."""
    rows, seen = [], {}
    for case_id, scene in scenes:
        h = scene.content_hash()
        if h in seen:
            rows.append({**seen[h], "case": case_id})
            continue
        if progress:
            progress(case_id)
        try:
            row = _compare(case_id, scene)
        except Exception as exc:  # a backend that cannot run the scene is a finding, shown as such
            row = {"case": case_id, "scene": scene.name, "variant": scene.variant or "",
                   "resolution": scene.resolution, "verdict": "failed", "how": f"{type(exc).__name__}: {exc}"[:300]}
        seen[h] = row
        rows.append(row)
    cols = ["case", "scene", "variant", "resolution", "ndof", "skfem_status", "ngsolve_status", "field_rel_diff",
            "worst_monitor", "monitor_skfem", "monitor_ngsolve", "monitor_rel_diff", "verdict", "how", "seconds"]
    return pd.DataFrame(rows).reindex(columns=cols)
