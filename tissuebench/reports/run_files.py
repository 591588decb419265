"""The folder of a reference run (``tissuebench run``), written atomically: results table,
fields, VTU/PNG pictures, the ParaView time series of a dynamic run and the manifest
(:mod:`tissuebench.studies.run` solves; this writes)."""
from __future__ import annotations

from pathlib import Path

import meshio
import numpy as np

from ..studies.describe import paper_comparison
from ..reference import ReferenceResult
from ..studies.run import scene_hash
from ..studies.atomic_folders import atomic_directory, provenance, write_json_atomic
from . import plots
from .figures import plot_line_state, plot_monitors

__all__ = ["write_result", "write_line_vtu"]


def write_line_vtu(result, path: Path) -> Path:
    """The final state of a 1D model on its line cells (VTU), one point array per component."""
    U = result.final_displacement
    meshio.Mesh(result.points, [("line", result.cells)],
                point_data={c: U[:, i] for i, c in enumerate(result.components)}).write(path)
    return Path(path)


def write_result(result: ReferenceResult, scene, out: Path, overwrite: bool = False) -> Path:
    """Write the files of a run into ``out`` atomically (see :mod:`tissuebench.studies.run`);
    ``overwrite`` replaces an existing folder."""
    with atomic_directory(out, overwrite) as tmp:
        result.table.to_parquet(tmp / "results.parquet", index=False)
        np.savez_compressed(tmp / "fields.npz", points=result.points, cells=result.cells,
                            steps=result.steps, displacement=result.displacement,
                            components=np.array(result.components))
        files = {}
        if result.plan.analysis == "dynamic":
            plots.write_time_series(result.points, result.cells, result.cell_type, result.components, result.steps,
                              result.displacement, tmp)
            files["motion.pvd"] = f"ParaView time series, {len(result.steps)} stored states"
        if result.cell_type == "line":
            write_line_vtu(result, tmp / "deformed.vtu")
            plot_line_state(result, tmp / "deformed.png")
        else:
            mesh, u = result.problem.mesh, result.final_displacement.ravel()
            plots.write_vtu(mesh, u, tmp / "deformed.vtu")
            files["deformed.png"] = "rendered by " + plots.plot_deformed(
                mesh, u, tmp / "deformed.png",
                title=f"{result.case} ({result.backend}, {result.resolution}): {result.status}")
        plot_monitors(result, tmp / "monitors.png")
        write_json_atomic(tmp / "manifest.json", provenance(
            case=result.case, variant=result.variant, resolution=result.resolution, backend=result.backend,
            scene_file=str(scene.path), scene_hash=scene_hash(scene), status=result.status, ok=result.ok,
            message=result.message, wall_s=result.wall_s, plan=result.plan.reasons, info=result.info,
            files=files, paper_comparison=paper_comparison(scene, result.table).to_dict("records")))
    return out
