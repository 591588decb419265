"""Reference runs of catalogue cases, stored with provenance (``tissuebench run``).

:func:`run_case` solves a scene with :func:`tissuebench.refsolvers.solve` and writes,
atomically (a failed run leaves nothing behind), into one folder:

- ``results.parquet``: one row per load increment or time step (case, backend, step,
  load_factor or time, newton_iterations, converged, wall_s, one column per monitor);
- ``fields.npz``: points, cells, steps, displacement per stored step;
- ``deformed.vtu`` and ``deformed.png`` (final state; pyvista off-screen, or a line
  plot for the 1D models) and ``monitors.png`` (each monitor against the load path);
- ``manifest.json``: versions, git commit, machine, date, the scene's hash, status.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from ..cases.scene import Scene, load
from .reference import ReferenceResult, solve
from .store import atomic_directory, provenance, write_json_atomic

__all__ = ["run_case", "scene_hash", "write_result"]


def scene_hash(scene) -> str:
    """SHA-256 of the scene file's bytes, its variant and resolution."""
    h = hashlib.sha256(Path(scene.path).read_bytes())
    h.update(f"\0{scene.variant}\0{scene.resolution}".encode())
    return h.hexdigest()


def _progress_bar(label):
    from tqdm import tqdm

    bar = tqdm(total=100, desc=label, unit="%", bar_format="{l_bar}{bar}| {n:.0f}/{total_fmt}% [{elapsed}]")

    def update(done, total):
        bar.n = 100.0 * done / total
        bar.refresh()
    return bar, update


def run_case(case, backend: str = "skfem", resolution: str = "ci", variant: str | None = None,
             out: Path | None = None, overwrite: bool = False, progress: bool = True,
             linear_solver: str = "direct") -> ReferenceResult:
    """Solve catalogue ``case`` (name, scene file or loaded :class:`Scene`) and, with
    ``out``, store it (``resolution`` and ``variant`` apply to a name or a file).

    Raises ``FileExistsError`` before any work when ``out`` exists and ``overwrite`` is
    False; a numerical failure is the result's ``status``, still written.
    """
    scene = case if isinstance(case, Scene) else load(case, resolution=resolution, variant=variant)
    if out is not None and Path(out).exists() and not overwrite:
        raise FileExistsError(f"output folder {out} exists; pass overwrite (--force) to replace it")
    bar, update = _progress_bar(f"{scene.name} [{backend}, {resolution}]") if progress else (None, None)
    try:
        result = solve(scene, backend=backend, progress=update, linear_solver=linear_solver)
    finally:
        if bar is not None:
            bar.close()
    if out is not None:
        write_result(result, scene, Path(out), overwrite)
    return result


def write_line_vtu(result, path: Path) -> Path:
    """The final state of a 1D model on its line cells (VTU), one point array per component."""
    import meshio

    U = result.final_displacement
    meshio.Mesh(result.points, [("line", result.cells)],
                point_data={c: U[:, i] for i, c in enumerate(result.components)}).write(path)
    return Path(path)


def write_result(result: ReferenceResult, scene, out: Path, overwrite: bool = False) -> Path:
    """Write the files of a run into ``out`` atomically (see the module docstring)."""
    from .describe import paper_comparison
    from ..reports.figures import plot_line_state, plot_monitors
    from ..reports.plots import plot_deformed, write_vtu

    with atomic_directory(out, overwrite) as tmp:
        result.table.to_parquet(tmp / "results.parquet", index=False)
        np.savez_compressed(tmp / "fields.npz", points=result.points, cells=result.cells,
                            steps=result.steps, displacement=result.displacement,
                            components=np.array(result.components))
        if result.cell_type == "line":
            write_line_vtu(result, tmp / "deformed.vtu")
            plot_line_state(result, tmp / "deformed.png")
        else:
            mesh, u = result.problem.mesh, result.final_displacement.ravel()
            write_vtu(mesh, u, tmp / "deformed.vtu")
            plot_deformed(mesh, u, tmp / "deformed.png",
                          title=f"{result.case} ({result.backend}, {result.resolution}): {result.status}")
        plot_monitors(result, tmp / "monitors.png")
        write_json_atomic(tmp / "manifest.json", provenance(
            case=result.case, variant=result.variant, resolution=result.resolution, backend=result.backend,
            scene_file=str(scene.path), scene_hash=scene_hash(scene), status=result.status, ok=result.ok,
            message=result.message, wall_s=result.wall_s, plan=result.plan.reasons, info=result.info,
            paper_comparison=paper_comparison(scene, result.table).to_dict("records")))
    return out
