"""Reference runs of catalogue cases (``tissuebench run``).

:func:`run_case` solves a scene with :func:`tissuebench.refsolvers.solve`, with a progress
bar; the CLI then stores it with :func:`tissuebench.reports.run_files.write_result`,
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


from ..cases.scene import Scene, load
from ..reference import ReferenceResult, solve
from ..reference.runner import progress_bar

__all__ = ["run_case", "scene_hash", "default_out", "safe_name"]


def scene_hash(scene) -> str:
    """SHA-256 of the scene file's bytes, its variant and resolution."""
    h = hashlib.sha256(Path(scene.path).read_bytes())
    h.update(f"\0{scene.variant}\0{scene.resolution}".encode())
    return h.hexdigest()


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
             progress: bool = True, linear_solver: str = "auto") -> ReferenceResult:
    """Solve catalogue ``case`` (name, scene file or loaded :class:`Scene`; ``resolution`` and
    ``variant`` apply to a name or a file). A numerical failure is the result's ``status``.
    Store it with :func:`tissuebench.reports.run_files.write_result` (check the output
    location with :func:`.store.check_output_location` before calling this: no work is
    wasted on a folder that cannot be written)."""
    scene = case if isinstance(case, Scene) else load(case, resolution=resolution, variant=variant)
    bar, update = (progress_bar(f"{scene.name} [{backend}, {resolution}]", scene.analysis["type"],
                                scene.units.get("time", "s")) if progress else (None, None))
    try:
        result = solve(scene, backend=backend, progress=update, linear_solver=linear_solver)
    finally:
        if bar is not None:
            bar.close()
    return result
