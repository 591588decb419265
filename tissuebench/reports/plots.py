"""Files of deformed meshes: VTU (meshio), a ParaView time series (PVD) and PNG pictures.

Pictures are rendered by pyvista in a child process: VTK's OpenGL windows may print
warnings ("bad X server connection") or crash (no OpenGL library, Ctrl-C during the VTK
import) and none of that may reach the user's terminal or take the run down. Without a
display the child asks VTK for an EGL window (off-screen, no X server), then OSMesa; its
output is captured and dropped. When no renderer works, matplotlib draws the deformed
boundary faces instead (Agg, no display). The parent process never imports VTK.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["write_vtu", "write_time_series", "plot_deformed", "render_child", "RENDER_TIMEOUT_S"]

#: Seconds a child renderer may take before matplotlib is used instead.
RENDER_TIMEOUT_S = 300
_NODE_COUNTS = {("tetra", 4): "tetra", ("tetra", 10): "tetra10", ("hexahedron", 8): "hexahedron",
                ("line", 2): "line"}


def _meshio_mesh(points, cells, cell_type, point_data):
    import meshio

    kind = _NODE_COUNTS.get((cell_type, np.shape(cells)[1]))
    if kind is None:
        raise ValueError(f"cell_type={cell_type!r} with {np.shape(cells)[1]} nodes per cell has no VTK cell type")
    return meshio.Mesh(np.asarray(points, float), [(kind, np.asarray(cells))], point_data=point_data)


def _displacement_data(u, components):
    """Point arrays of a displacement (n_nodes, n_components): a vector and its norm (3D),
    one array per named component (1D models)."""
    u = np.asarray(u, float)
    if tuple(components) == ("x", "y", "z"):
        return {"displacement": u, "|u|": np.linalg.norm(u, axis=1)}
    return {c: u[:, i] for i, c in enumerate(components)}


def write_vtu(mesh, u, path: Path) -> Path:
    """Write ``mesh`` (vertices) with the vertex part of displacement ``u`` (ndof,) to a VTU file."""
    disp = np.asarray(u, float).reshape(-1, 3)[: mesh.n_vertices]
    _meshio_mesh(mesh.points, mesh.cells, mesh.cell_type, _displacement_data(disp, "xyz")).write(path)
    return Path(path)


def write_time_series(points, cells, cell_type, components, times, displacement, folder: Path,
                      name: str = "motion") -> Path:
    """A ParaView time series: ``folder/<name>.pvd`` listing ``folder/<name>/step_NNNNN.vtu``,
    one per stored state, with its time (s) as the ``timestep`` attribute.

    ``displacement``: (n_states, n_nodes, n_components), ``times``: (n_states,). All nodes are
    written (P2: ``tetra10`` cells), so the motion is the one the reference computed."""
    folder = Path(folder)
    (folder / name).mkdir(parents=True, exist_ok=True)
    entries = []
    for k, (t, u) in enumerate(zip(np.asarray(times, float).tolist(), displacement)):
        rel = f"{name}/step_{k:05d}.vtu"
        _meshio_mesh(points, cells, cell_type, _displacement_data(u, components)).write(folder / rel)
        entries.append(f'    <DataSet timestep="{t!r}" group="" part="0" file="{rel}"/>')
    pvd = folder / f"{name}.pvd"
    pvd.write_text('<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1" byte_order="LittleEndian">\n'
                   "  <Collection>\n" + "\n".join(entries) + "\n  </Collection>\n</VTKFile>\n")
    return pvd


# ------------------------------------------------------------------------------ pictures
def plot_deformed(mesh, u, path: Path, title: str = "", scale: float = 1.0) -> str:
    """Render the deformed mesh coloured by |u| over the undeformed outline to ``path`` (PNG);
    returns the renderer used: ``"pyvista"`` (child process) or ``"matplotlib"``."""
    path = Path(path)
    fd, vtu = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".vtu", dir=path.parent)
    os.close(fd)
    try:
        write_vtu(mesh, u, vtu)
        for window in _windows():
            if _render_in_child(vtu, path, title, scale, window):
                return "pyvista"
    finally:
        Path(vtu).unlink(missing_ok=True)
    _plot_matplotlib(mesh, u, path, title, scale)
    return "matplotlib"


def _windows():
    """VTK window classes to try: the default with a display; else EGL, then OSMesa."""
    if os.environ.get("VTK_DEFAULT_OPENGL_WINDOW") or os.environ.get("DISPLAY") or os.environ.get(
            "WAYLAND_DISPLAY") or sys.platform != "linux":
        return [None]
    return ["vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow"]


def _render_in_child(vtu, png, title, scale, window) -> bool:
    root = str(Path(__file__).resolve().parents[2])
    env = {**os.environ, "PYVISTA_OFF_SCREEN": "true",
           "PYTHONPATH": os.pathsep.join([root] + [p for p in [os.environ.get("PYTHONPATH")] if p])}
    if window:
        env["VTK_DEFAULT_OPENGL_WINDOW"] = window
    cmd = [sys.executable, "-c", "import sys; from tissuebench.reports.plots import render_child; "
           "render_child(sys.argv[1:])", str(vtu), str(png), title, repr(float(scale))]
    try:
        done = subprocess.run(cmd, env=env, stdin=subprocess.DEVNULL, capture_output=True,
                              timeout=RENDER_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return False
    return done.returncode == 0 and Path(png).is_file() and Path(png).stat().st_size > 0


def render_child(argv) -> None:
    """Entry point of the child renderer: ``vtu png title scale``."""
    vtu, png, title, scale = argv
    import pyvista as pv

    grid = pv.read(vtu)
    warped = grid.warp_by_vector("displacement", factor=float(scale))
    plotter = pv.Plotter(off_screen=True, window_size=(1200, 800))
    plotter.add_mesh(grid.extract_feature_edges(), color="grey", opacity=0.4)
    plotter.add_mesh(warped, scalars="|u|", show_edges=True, cmap="viridis", scalar_bar_args={"title": "|u|"})
    if title:
        plotter.add_text(title, font_size=10)
    plotter.view_isometric()
    plotter.screenshot(png)
    plotter.close()


def _plot_matplotlib(mesh, u, path, title, scale):
    """The deformed boundary faces, coloured by their mean |u| (no OpenGL needed)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from .figures import pyplot

    plt = pyplot()
    disp = np.asarray(u, float).reshape(-1, 3)[: mesh.n_vertices]
    faces = mesh.boundary_facets
    x = mesh.points + scale * disp
    colour = np.linalg.norm(disp, axis=1)[faces].mean(axis=1)
    fig = plt.figure(figsize=(8, 6))
    ax = fig.add_subplot(projection="3d")
    norm = plt.Normalize(colour.min(), colour.max() if colour.max() > colour.min() else colour.min() + 1)
    ax.add_collection3d(Poly3DCollection(x[faces], facecolors=plt.cm.viridis(norm(colour)), edgecolor="k",
                                         linewidths=0.1))
    lo, hi = x.min(axis=0), x.max(axis=0)
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]), xlabel="x", ylabel="y", zlabel="z")
    ax.set_box_aspect(np.maximum(hi - lo, 1e-12 * max(np.ptp(x), 1.0)))
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap="viridis"), ax=ax, label="|u|", shrink=0.7)
    if title:
        ax.set_title(title, fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)
