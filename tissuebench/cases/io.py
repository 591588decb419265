"""Reading volume meshes from files, and locating the data folder.

:func:`read_mesh` reads any volume mesh meshio understands (VTU, VTK, Gmsh, Medit,
XDMF, ...) into a :class:`~tissuebench.refsolvers.mesh.Mesh`. Only linear tetrahedra
and trilinear hexahedra are volume cells here; other cell blocks (triangles, lines,
vertices of boundary tags) are ignored. Cells with negative signed volume are
reoriented by :class:`Mesh` (the shipped liver mesh has all of them negative; the count is
``Mesh.n_reoriented`` and the builders report it as ``reoriented_cells``); degenerate,
duplicate and overlapping cells and folded meshes (an inverted cell overlapping its
neighbour) are refused, with the path and the cells in the message; coincident nodes (the
mesh is not connected there) are said in a warning naming them.

Coordinates are returned as stored in the file, with no unit conversion: the shipped
liver mesh ``liver/liver_tet.vtu`` is in millimetres.

:func:`data_dir` finds the data folder: ``$TISSUEBENCH_DATA`` when set, else the
folder shipped inside the package (``tissuebench/data``: the liver mesh, with its source and
licence in ``data/liver/README.md``).
"""
from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from ..refsolvers.mesh import CELL_TYPES, HEX_FACES, TET_FACES, Mesh
from .builder_params import require_regular_file
from .meshio_guard import read_with_deadline

__all__ = ["read_mesh", "data_dir", "liver_mesh_path", "DATA_ENV", "PACKAGE_DATA_DIR"]

#: Environment variable that overrides the data folder.
DATA_ENV = "TISSUEBENCH_DATA"

#: The data shipped with the package (the liver mesh).
PACKAGE_DATA_DIR = Path(__file__).resolve().parents[1] / "data"

#: Unit of length of the shipped liver mesh.
LIVER_MESH_UNIT = "mm"


def data_dir(must_exist: bool = False) -> Path:
    """The data folder (``liver/liver_tet.vtu`` ...).

    ``$TISSUEBENCH_DATA`` when set and non-empty, else :data:`PACKAGE_DATA_DIR` (shipped with
    the package, so a clone or an installed wheel needs nothing beside it).

    Parameters
    ----------
    must_exist : bool
        Raise FileNotFoundError (naming the path and how it was chosen) when the folder
        does not exist; by default the path is returned unchecked, so callers can fall
        back to a built-in shape.
    """
    env = os.environ.get(DATA_ENV, "").strip()
    if env:
        path, how = Path(env).expanduser(), f"from ${DATA_ENV}"
    else:
        path, how = PACKAGE_DATA_DIR, f"shipped with the package; set ${DATA_ENV} to override"
    if must_exist and not path.is_dir():
        raise FileNotFoundError(f"data folder {path} ({how}) does not exist")
    return path


def liver_mesh_path(must_exist: bool = False) -> Path:
    """Path of the liver tetrahedral mesh (``<data folder>/liver/liver_tet.vtu``, mm)."""
    path = data_dir() / "liver" / "liver_tet.vtu"
    if must_exist and not path.is_file():
        raise FileNotFoundError(f"liver mesh {path} does not exist (data folder: set ${DATA_ENV})")
    return path


def read_mesh(path, cell_type: str | None = None, reorient: bool = True) -> Mesh:
    """Read a volume mesh file into a :class:`Mesh`.

    Parameters
    ----------
    path : str or Path
        Any volume mesh meshio reads.
    cell_type : {"tetra", "hexahedron"}, optional
        Which volume cells to take when the file holds both (default: the only kind
        present; a file with both kinds needs an explicit choice).
    reorient : bool
        Passed to :class:`Mesh`: reorient negatively oriented cells (default).

    Returns
    -------
    Mesh
        All blocks of the chosen cell type concatenated. Vertices not used by any volume
        cell are dropped and the rest renumbered in their file order (so surface-only
        points of a mixed file do not become free, massless nodes).

    Raises
    ------
    FileNotFoundError
        The file does not exist.
    ValueError
        It is not a regular file (a folder, a FIFO, a device, a loop of links: never opened),
        meshio cannot read it (or does not finish: :mod:`.meshio_guard`), it has no
        tetrahedra/hexahedra, both kinds without ``cell_type``, or a degenerate (zero-volume,
        tangled) cell; the message names ``path``.
    """
    path = Path(path)
    require_regular_file(path, f"mesh file {path}")  # a FIFO or a device is never handed to meshio
    m = read_with_deadline(path)  # a reader looping on a truncated file is stopped, said
    blocks: dict[str, list[np.ndarray]] = {}
    for i, block in enumerate(m.cells):
        if block.type in CELL_TYPES and np.size(block.data):
            blocks.setdefault(block.type, []).append(_vertex_indices(path, i, block))
    if not blocks:
        found = sorted({b.type for b in m.cells}) or ["none"]
        raise ValueError(f"{path}: no volume cells (tetra or hexahedron); cell blocks found: {found}")
    if cell_type is None:
        if len(blocks) > 1:
            raise ValueError(f"{path}: holds both tetra and hexahedron cells; pass cell_type=")
        cell_type = next(iter(blocks))
    elif cell_type not in CELL_TYPES:
        raise ValueError(f"cell_type={cell_type!r} is not one of {sorted(CELL_TYPES)}")
    elif cell_type not in blocks:
        raise ValueError(f"{path}: no {cell_type!r} cells (found {sorted(blocks)})")
    cells = np.vstack(blocks[cell_type])
    try:
        points = np.asarray(m.points, dtype=float)
    except (TypeError, ValueError) as exc:  # a reader's ragged or textual rows
        raise ValueError(f"{path}: points are not an array of numbers ({exc})") from None
    if points.ndim != 2 or points.shape[1] not in (2, 3):
        raise ValueError(f"{path}: points have shape {points.shape}, expected (n, 3)")
    if points.shape[1] == 2:
        raise ValueError(f"{path}: 2D points; a volume mesh needs 3D coordinates")
    if cells.min() < 0 or cells.max() >= len(points):
        raise ValueError(f"{path}: cells reference vertex indices outside 0..{len(points) - 1}")
    used = np.unique(cells)
    if len(used) != len(points):
        renumber = np.full(len(points), -1, dtype=np.int64)
        renumber[used] = np.arange(len(used))
        points, cells = points[used], renumber[cells]
    _check_cell_set(path, cells, cell_type)
    _warn_coincident_nodes(path, points)
    try:
        return Mesh(points, cells, cell_type, reorient=reorient)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from exc


def _vertex_indices(path, i, block) -> np.ndarray:
    """The cells of meshio's block ``i``, shape (n, 4 or 8) int64: a damaged file can make a
    reader return rows of another length, or numbers that are not indices."""
    n = CELL_TYPES[block.type]
    try:
        data = np.asarray(block.data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: cell block {i} ({block.type}) is not an array of vertex indices ({exc})") from None
    if data.ndim != 2 or data.shape[1] != n:
        raise ValueError(f"{path}: cell block {i} ({block.type}) has shape {data.shape}, expected (n, {n}) "
                         "vertex indices")
    if np.issubdtype(data.dtype, np.integer):
        return data.astype(np.int64)
    with np.errstate(invalid="ignore"):
        integral = np.issubdtype(data.dtype, np.floating) and np.all(np.isfinite(data)) and \
            np.all(data == np.round(data)) and np.abs(data).max() < 2.0 ** 62
    if not integral:
        raise ValueError(f"{path}: cell block {i} ({block.type}) holds values that are not vertex indices "
                         f"({data.dtype})")
    return data.astype(np.int64)


def coincident_nodes(points: np.ndarray, rtol: float = 1e-10) -> np.ndarray:
    """Pairs ``(i, j)``, i < j, of nodes closer than ``rtol`` times the mesh's size (sorted)."""
    pts = np.asarray(points, float)
    if len(pts) < 2 or not np.all(np.isfinite(pts)):
        return np.zeros((0, 2), dtype=np.int64)
    from scipy.spatial import cKDTree

    with np.errstate(over="ignore", invalid="ignore"):
        low = pts.min(axis=0)
        size = float(np.max(pts.max(axis=0) - low))
        unit = (pts - low) / size if np.isfinite(size) and size > 0 else None
    if unit is None or not np.all(np.isfinite(unit)):
        return np.zeros((0, 2), dtype=np.int64)
    pairs = cKDTree(unit).query_pairs(rtol, output_type="ndarray")  # scaled: 1e200 m squares without overflow
    return pairs[np.lexsort(pairs.T[::-1])] if len(pairs) else pairs.reshape(0, 2)


def _warn_coincident_nodes(path, points):
    """A node repeated at the same place splits the mesh there (each copy belongs to its own cells:
    a crack the file may not mean); said, naming the nodes, not refused (a cut is made that way)."""
    pairs = coincident_nodes(points)
    if len(pairs):
        i, j = (int(v) for v in pairs[0])
        shown = ", ".join(f"{int(a)}={int(b)}" for a, b in pairs[:6]) + (" ..." if len(pairs) > 6 else "")
        warnings.warn(f"{path}: {len(pairs)} pairs of coincident nodes ({shown}; e.g. nodes {i} and {j} at "
                      f"{np.round(points[i], 12).tolist()}): the cells on either side are not connected there; "
                      "merge them if the body is one piece", stacklevel=3)


def _check_cell_set(path, cells, cell_type):
    """Refuse a file whose cells repeat (the same vertices twice: stiffness and mass counted
    twice) or overlap (a face shared by more than two cells)."""
    _, first, inverse, counts = np.unique(np.sort(cells, axis=1), axis=0, return_index=True,
                                          return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    if (counts > 1).any():
        dup = np.flatnonzero(counts[inverse] > 1)
        raise ValueError(f"{path}: duplicate cells: cells {dup[:12].tolist()} ({len(dup)} cells) repeat the "
                         f"vertices of another cell (e.g. cells[{dup[0]}] = {cells[dup[0]].tolist()})")
    local = TET_FACES if cell_type == "tetra" else HEX_FACES
    faces = np.sort(cells[:, local].reshape(-1, local.shape[1]), axis=1)
    _, inverse, counts = np.unique(faces, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    over = np.flatnonzero(counts[inverse] > 2)
    if len(over):
        shared = np.unique(over // len(local))
        raise ValueError(f"{path}: overlapping cells: cells {shared[:12].tolist()} share a face with more than "
                         f"one other cell (e.g. face {faces[over[0]].tolist()})")
