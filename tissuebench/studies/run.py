"""Reference runs of built-in cases: solve, tabulate, plot and store with provenance."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd

from ..cases.bar import bar_tension
from ..refsolvers import make_backend
from ..refsolvers.newton import NewtonOptions, newton_solve
from .store import atomic_directory, hash_json, provenance, write_json_atomic

CASES = {"bar_tension": bar_tension}


def _progress_bar(total_label):
    from tqdm import tqdm

    bar = tqdm(total=100, desc=total_label, unit="%", bar_format="{l_bar}{bar}| {n:.0f}/{total_fmt}% [{elapsed}]")

    def update(lam, target):
        bar.n = 100.0 * lam / target
        bar.refresh()

    return bar, update


def run_case(case: str, backend: str = "skfem", resolution: str = "ci", out: Path | None = None,
             overwrite: bool = False, n_increments: int = 3, progress: bool = True):
    """Run a built-in static case; write results.parquet, fields.npz, deformed.vtu/.png, manifest.json.

    Returns the results table (one row per converged load increment).
    """
    if case not in CASES:
        raise ValueError(f"unknown case {case!r}; valid: {sorted(CASES)}")
    t0 = time.perf_counter()
    spec = CASES[case](resolution=resolution)
    pb = spec.problem
    be = make_backend(backend, pb)
    bar, update = _progress_bar(f"{case} [{backend}]") if progress else (None, None)
    try:
        result = newton_solve(be, 1.0, NewtonOptions(n_increments=n_increments), progress=update)
    finally:
        if bar is not None:
            bar.close()
    rows = []
    converged = [inc for inc in result.increments if inc.converged]
    for step, (inc, u) in enumerate(zip(converged, result.states), start=1):
        rows.append({"case": case, "backend": backend, "step": step, "load_factor": inc.load_factor,
                     "newton_iterations": inc.iterations, "converged": True, "wall_s": inc.wall_s,
                     "assembly_s": inc.assembly_s, "solve_s": inc.solve_s,
                     "final_residual": inc.residual_norms[-1], **spec.monitors(u, be.internal_force(u))})
    table = pd.DataFrame(rows)
    if out is not None:
        _write(Path(out), overwrite, case, backend, resolution, spec, result, table, time.perf_counter() - t0)
    return table, result


def _write(out, overwrite, case, backend, resolution, spec, result, table, wall):
    from ..reports.plots import plot_deformed, write_vtu

    pb = spec.problem
    scene = {"case": case, "resolution": resolution, "element": pb.element,
             "material": type(pb.material).__name__, "material_params": pb.material.__dict__,
             "n_nodes": len(pb.nodes), "n_cells": pb.mesh.n_cells}
    with atomic_directory(out, overwrite) as tmp:
        table.to_parquet(tmp / "results.parquet", index=False)
        np.savez_compressed(tmp / "fields.npz", points=pb.nodes, cells=pb.layout[1],
                            load_factor=table["load_factor"].to_numpy() if len(table) else np.zeros(0),
                            displacement=np.array(result.states).reshape(len(result.states), -1, 3))
        write_vtu(pb.mesh, result.u, tmp / "deformed.vtu")
        plot_deformed(pb.mesh, result.u, tmp / "deformed.png",
                      title=f"{case} ({backend}, {resolution}), load factor {result.load_factor:.3g}")
        write_json_atomic(tmp / "manifest.json", provenance(
            scene=scene, scene_hash=hash_json(scene), backend=backend, status=result.status,
            message=result.message, wall_s=wall))
