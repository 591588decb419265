"""``scene.png``: a scene as a user would check it by eye (``tissuebench scene check``).

Drawn into the working folder (``./scene.png``) or ``--out FILE.png``, never beside the scene
file: a catalogue scene lives inside the installed package (:func:`picture_path`).

The mesh (translucent surface), the constrained nodes (red), the loads as arrows at the loaded
nodes (orange, scaled to a tenth of the body), the monitor points (blue spheres). Rendered by
pyvista off screen in a child process like every picture of the package
(:mod:`.plots`: EGL, then OSMesa), matplotlib when no renderer works.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from ..studies.atomic_files import output_file, replacing
from .plots import RENDER_TIMEOUT_S, _windows, write_vtu

__all__ = ["draw_scene", "render_scene_child", "monitor_points", "picture_path", "DEFAULT_PICTURE"]

DEFAULT_PICTURE = Path("scene.png")  # in the working folder


def picture_path(out=None, force: bool = False) -> Path:
    """The file ``scene check`` draws into, checked before any work: ``out``, or
    :data:`DEFAULT_PICTURE` in the working folder when None.

    Returns the file to write (a symbolic link is written through). ValueError naming ``--out``
    and the path for a folder, a name not ending in ``.png``, a device, FIFO, socket or loop of
    links, an unwritable folder; FileExistsError for an existing picture without ``force``.
    """
    option = "--out" if out is not None else "--out (default)"
    path = DEFAULT_PICTURE if out is None else Path(out)
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a folder; give a file name like scene.png")
    target = output_file(path, option)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{option} {path}: the picture is a PNG file; give a name ending in .png")
    if target.exists() and not force:
        raise FileExistsError(f"{option} {path}: exists; pass --force to replace it (or --out FILE.png, "
                              "or --out - for no picture)")
    return target


def monitor_points(scene) -> np.ndarray:
    """(k, 3) coordinates of the scene's point monitors (bbox fractions resolved)."""
    pts = []
    mesh = scene.mesh
    lo, hi = mesh.points.min(axis=0), mesh.points.max(axis=0)
    surface = mesh.points[np.unique(mesh.boundary_facets)]
    for m in scene.monitors:
        if "point" in m:
            p = np.asarray(m["point"], float)
            p = lo + p * (hi - lo) if m.get("frame") == "bbox" else p
            if m.get("boundary"):  # read at the nearest boundary node
                p = surface[np.argmin(np.linalg.norm(surface - p, axis=1))]
            pts.append(p)
    return np.array(pts).reshape(-1, 3)


def draw_scene(scene, summary: dict, path: Path) -> str:
    """Draw ``scene`` with the node sets of its ``summary`` (:func:`~tissuebench.studies.scene_check.scene_summary`)
    to ``path`` (PNG, replaced atomically; check it first with :func:`picture_path`); returns the
    renderer used (``"pyvista"`` or ``"matplotlib"``)."""
    path = Path(path)
    mesh = scene.mesh
    pts = mesh.points
    size = float(np.linalg.norm(np.ptp(pts, axis=0))) or 1.0
    loads = np.asarray(summary["load_vectors"], float).reshape(-1, 3)
    norm = np.linalg.norm(loads, axis=1).max(initial=0.0)
    arrows = loads / norm * 0.1 * size if norm > 0 else loads
    fixed = np.asarray(summary["fixed"], int)
    fixed = fixed[fixed < mesh.n_vertices]
    loaded = np.asarray(summary["load_nodes"], int)
    markers = {"fixed": pts[fixed], "loaded": pts[loaded[loaded < mesh.n_vertices]],
               "arrows": arrows[loaded < mesh.n_vertices], "monitors": monitor_points(scene),
               "title": np.array(f"{scene.name}: {len(fixed)} constrained nodes (red), {len(loaded)} loaded (arrows), "
                                 f"{len(scene.monitors)} monitors (blue)")}
    path.parent.mkdir(parents=True, exist_ok=True)
    with replacing(path, "--out", suffix=".png") as png:  # no half-drawn picture, a link written through
        fd, vtu = tempfile.mkstemp(prefix=".scene.", suffix=".vtu", dir=png.parent)
        os.close(fd)
        npz = Path(vtu).with_suffix(".npz")
        try:
            write_vtu(mesh, np.zeros(3 * mesh.n_vertices), vtu)
            np.savez(npz, **markers)
            for window in _windows():
                if _render_in_child(vtu, npz, png, window):
                    return "pyvista"
        finally:
            Path(vtu).unlink(missing_ok=True)
            npz.unlink(missing_ok=True)
        _plot_matplotlib(mesh, markers, png)
        return "matplotlib"


def _render_in_child(vtu, npz, png, window) -> bool:
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true",
           "PYTHONPATH": os.pathsep.join([root] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    if window:
        env["VTK_DEFAULT_OPENGL_WINDOW"] = window
    cmd = [sys.executable, "-c", "import sys; from tissuebench.reports.scene_figure import render_scene_child; "
           "render_scene_child(sys.argv[1:])", str(vtu), str(npz), str(png)]
    try:
        done = subprocess.run(cmd, env=env, stdin=subprocess.DEVNULL, capture_output=True, timeout=RENDER_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return False
    return done.returncode == 0 and Path(png).is_file() and Path(png).stat().st_size > 0


def render_scene_child(argv) -> None:
    """Entry point of the child renderer: ``vtu npz png``."""
    vtu, npz, png = argv
    import pyvista as pv

    grid = pv.read(vtu)
    m = np.load(npz, allow_pickle=False)
    plotter = pv.Plotter(off_screen=True, window_size=(1200, 900))
    plotter.add_mesh(grid.extract_surface(), color="lightgrey", opacity=0.35, show_edges=True, edge_color="grey")
    if len(m["fixed"]):
        plotter.add_points(m["fixed"], color="red", point_size=6, render_points_as_spheres=True)
    if len(m["loaded"]):
        cloud = pv.PolyData(m["loaded"] - m["arrows"])
        cloud["vectors"] = m["arrows"]
        plotter.add_mesh(cloud.glyph(orient="vectors", scale="vectors", factor=1.0, geom=pv.Arrow()), color="orange")
    if len(m["monitors"]):
        plotter.add_points(m["monitors"], color="blue", point_size=14, render_points_as_spheres=True)
    plotter.add_text(str(m["title"]), font_size=9)
    plotter.add_axes()
    plotter.view_isometric()
    plotter.camera.zoom(1.4)
    plotter.screenshot(png)
    plotter.close()


def _plot_matplotlib(mesh, markers, path):
    from .figures import pyplot

    plt = pyplot()
    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    p = mesh.points[np.unique(mesh.boundary_facets)]
    ax.scatter(*p.T, s=1, c="lightgrey")
    if len(markers["fixed"]):
        ax.scatter(*markers["fixed"].T, s=6, c="red", label="constrained")
    if len(markers["loaded"]):
        ax.quiver(*(markers["loaded"] - markers["arrows"]).T, *markers["arrows"].T, color="orange", label="loads")
    if len(markers["monitors"]):
        ax.scatter(*markers["monitors"].T, s=40, c="blue", label="monitors")
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(str(markers["title"]), fontsize=8)
    fig.savefig(path, dpi=110)
    plt.close(fig)
