"""Pictures of deformed meshes (pyvista, off-screen)."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

_VTK_TYPES = {"tetra": 10, "hexahedron": 12}


def to_pyvista(mesh, u=None):
    """An ``UnstructuredGrid`` of ``mesh`` displaced by the vertex part of ``u`` (ndof,)."""
    import pyvista as pv

    pts = mesh.points.copy()
    grid_cells = np.hstack([np.full((mesh.n_cells, 1), mesh.cells.shape[1]), mesh.cells]).ravel()
    types = np.full(mesh.n_cells, _VTK_TYPES[mesh.cell_type], dtype=np.uint8)
    grid = pv.UnstructuredGrid(grid_cells, types, pts)
    if u is not None:
        disp = np.asarray(u).reshape(-1, 3)[: mesh.n_vertices]
        grid.point_data["displacement"] = disp
        grid.point_data["|u|"] = np.linalg.norm(disp, axis=1)
    return grid


def plot_deformed(mesh, u, path: Path, title: str = "", scale: float = 1.0) -> Path:
    """Render the deformed mesh coloured by |u| over the undeformed outline to ``path`` (PNG)."""
    os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
    import pyvista as pv

    grid = to_pyvista(mesh, u)
    warped = grid.warp_by_vector("displacement", factor=scale)
    plotter = pv.Plotter(off_screen=True, window_size=(1200, 800))
    plotter.add_mesh(grid.extract_feature_edges(), color="grey", opacity=0.4)
    plotter.add_mesh(warped, scalars="|u|", show_edges=True, cmap="viridis",
                     scalar_bar_args={"title": "|u|"})
    if title:
        plotter.add_text(title, font_size=10)
    plotter.view_isometric()
    plotter.screenshot(str(path))
    plotter.close()
    return Path(path)


def write_vtu(mesh, u, path: Path) -> Path:
    """Write the mesh with its displacement field to a VTU file."""
    to_pyvista(mesh, u).save(str(path))
    return Path(path)
