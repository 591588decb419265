"""Reference runs of catalogue cases, stored with provenance (``tissuebench run``).

:func:`run_case` solves a scene with :func:`tissuebench.refsolvers.solve` and writes,
atomically (a failed run leaves nothing behind), into one folder:

- ``results.parquet``: one row per load increment or time step (case, backend, step,
  load_factor or time, newton_iterations, converged, wall_s, one column per monitor);
- ``fields.npz``: points, cells, steps, displacement per stored step;
- dynamics: ``motion.pvd`` + ``motion/step_NNNNN.vtu``, a ParaView time series of every
  stored state (open ``motion.pvd`` in ParaView and play it);
- ``deformed.vtu`` and ``deformed.png`` (final state; pyvista in a child process, or
  matplotlib, or a line plot for the 1D models) and ``monitors.png`` (each monitor against
  the load path);
- ``manifest.json``: versions, git commit, machine, date, the scene's hash, status.
"""
from __future__ import annotations

import hashlib
import re
from pathlib import Path

import numpy as np

from ..cases.scene import Scene, load
from .reference import ReferenceResult, solve
from .store import atomic_directory, check_output_location, clean_leftovers, provenance, write_json_atomic

__all__ = ["run_case", "scene_hash", "write_result", "progress_bar", "default_out", "safe_name"]


def scene_hash(scene) -> str:
    """SHA-256 of the scene file's bytes, its variant and resolution."""
    h = hashlib.sha256(Path(scene.path).read_bytes())
    h.update(f"\0{scene.variant}\0{scene.resolution}".encode())
    return h.hexdigest()


def progress_bar(label: str, analysis: str, time_unit: str = "s", file=None):
    """A tqdm bar of a reference run and its ``update(done, total)`` callback.

    The bar counts what the solver reports, in its unit: the load factor reached (statics,
    ``load factor 0.45/1``) or the time (dynamics, ``t 0.25/5 s``), with the percentage beside."""
    from tqdm import tqdm

    what = "t {n:.4g}/{total:.4g} " + time_unit if analysis == "dynamic" else "load factor {n:.4g}/{total:.4g}"
    bar = tqdm(total=1.0, desc=label, file=file, bar_format="{desc}: {percentage:3.0f}%|{bar}| " + what
               + " [{elapsed}<{remaining}]")

    def update(done, total):
        bar.total = float(total)
        bar.n = float(done)
        bar.refresh()
    return bar, update


def default_out(scene, backend: str, resolution: str) -> Path:
    """``out/<case>[-<variant>]-<backend>-<resolution>``, the scene's names made safe for a
    folder name (only letters, digits, ``_``, ``.``, ``-``: a name like ``../../x`` or
    ``<script>`` cannot leave ``out/`` or make folders)."""
    tag = safe_name(scene.name) + (f"-{safe_name(scene.variant)}" if scene.variant else "")
    return Path("out") / f"{tag}-{backend}-{resolution}"


def safe_name(text: str) -> str:
    """``text`` with every run of other characters than letters, digits, ``_``, ``.``, ``-``
    replaced by ``_``, no leading or trailing ``._-`` (so no hidden or ``..`` name), never
    empty (``case``), at most 80 characters."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", str(text)).strip("._-")[:80]
    return safe or "case"


def run_case(case, backend: str = "skfem", resolution: str = "ci", variant: str | None = None,
             out: Path | None = None, overwrite: bool = False, progress: bool = True,
             linear_solver: str = "auto") -> ReferenceResult:
    """Solve catalogue ``case`` (name, scene file or loaded :class:`Scene`) and, with
    ``out``, store it (``resolution`` and ``variant`` apply to a name or a file).

    The output location is checked before any work: FileExistsError when ``out`` exists and
    ``overwrite`` is False, ValueError when it cannot be written (a file, an unwritable
    parent); what killed runs left beside it is cleaned. A numerical failure is the result's
    ``status``, still written.
    """
    scene = case if isinstance(case, Scene) else load(case, resolution=resolution, variant=variant)
    if out is not None:
        clean_leftovers(out)
        check_output_location(out, overwrite)
    bar, update = (progress_bar(f"{scene.name} [{backend}, {resolution}]", scene.analysis["type"],
                                scene.units.get("time", "s")) if progress else (None, None))
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
    from ..reports.plots import plot_deformed, write_time_series, write_vtu

    with atomic_directory(out, overwrite) as tmp:
        result.table.to_parquet(tmp / "results.parquet", index=False)
        np.savez_compressed(tmp / "fields.npz", points=result.points, cells=result.cells,
                            steps=result.steps, displacement=result.displacement,
                            components=np.array(result.components))
        files = {}
        if result.plan.analysis == "dynamic":
            write_time_series(result.points, result.cells, result.cell_type, result.components, result.steps,
                              result.displacement, tmp)
            files["motion.pvd"] = f"ParaView time series, {len(result.steps)} stored states"
        if result.cell_type == "line":
            write_line_vtu(result, tmp / "deformed.vtu")
            plot_line_state(result, tmp / "deformed.png")
        else:
            mesh, u = result.problem.mesh, result.final_displacement.ravel()
            write_vtu(mesh, u, tmp / "deformed.vtu")
            files["deformed.png"] = "rendered by " + plot_deformed(
                mesh, u, tmp / "deformed.png",
                title=f"{result.case} ({result.backend}, {result.resolution}): {result.status}")
        plot_monitors(result, tmp / "monitors.png")
        write_json_atomic(tmp / "manifest.json", provenance(
            case=result.case, variant=result.variant, resolution=result.resolution, backend=result.backend,
            scene_file=str(scene.path), scene_hash=scene_hash(scene), status=result.status, ok=result.ok,
            message=result.message, wall_s=result.wall_s, plan=result.plan.reasons, info=result.info,
            files=files, paper_comparison=paper_comparison(scene, result.table).to_dict("records")))
    return out
