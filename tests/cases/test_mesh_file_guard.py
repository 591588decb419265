"""Mesh files that hung or crashed the reader (issue 37, found by tests/studies/test_fuzz_mesh_files.py):
meshio's TetGen, PLY, MDPA and Tecplot readers loop for ever at the end of a truncated file, and a
damaged file can make a reader return a cell block of the wrong shape (an IndexError, or numpy's
'zero-size array to reduction operation' naming no file)."""
from __future__ import annotations

import signal
from unittest import mock

import meshio
import numpy as np
import pytest

from tissuebench.cases.io import read_mesh
from tissuebench.cases.meshes import box_mesh


@pytest.fixture
def watchdog():
    """A read that hangs fails the test instead of hanging the run."""
    def hang(*_):
        raise TimeoutError("the read hung")
    previous = signal.signal(signal.SIGALRM, hang)
    signal.alarm(60)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, previous)


def _tetgen(folder, node_text=None):
    m = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "tetra")
    path = folder / "body.node"
    meshio.write(path, meshio.Mesh(m.points, [("tetra", m.cells)]))
    if node_text is not None:
        path.write_text(node_text)
    return path


@pytest.mark.parametrize("text", ["# a comment, then nothing\n", "", "\n\n# header only\n"])
def test_a_reader_that_loops_at_the_end_of_the_file_is_stopped_and_said(tmp_path, watchdog, text):
    path = _tetgen(tmp_path, text)
    with mock.patch("tissuebench.cases.meshio_guard.READ_SECONDS", 0.5):
        with pytest.raises(ValueError, match=rf"{path}: meshio cannot read it: it did not finish in 0.5 s \(its "
                                             "reader loops on this file"):
            read_mesh(path)


def test_a_good_file_of_the_same_format_reads(tmp_path, watchdog):
    assert read_mesh(_tetgen(tmp_path)).n_cells == 6


def test_the_deadline_grows_with_the_file(tmp_path):
    from tissuebench.cases import meshio_guard

    path = _tetgen(tmp_path)
    with mock.patch.object(meshio_guard.threading.Thread, "join") as join, \
            mock.patch.object(meshio_guard.threading.Thread, "is_alive", return_value=False), \
            mock.patch("meshio.read", return_value="mesh"):
        assert meshio_guard.read_with_deadline(path) == "mesh"
    size_mb = path.stat().st_size / 1e6
    assert join.call_args.args[0] == pytest.approx(meshio_guard.READ_SECONDS + meshio_guard.SECONDS_PER_MB * size_mb)


@pytest.mark.parametrize("data, what", [
    (np.zeros((2, 1), dtype=int), r"cell block 0 \(hexahedron\) has shape \(2, 1\), expected \(n, 8\)"),
    (np.arange(8), r"cell block 0 \(hexahedron\) has shape \(8,\), expected \(n, 8\)"),
    (np.full((1, 8), 0.5), r"cell block 0 \(hexahedron\) holds values that are not vertex indices"),
])
def test_a_cell_block_of_the_wrong_shape_is_named(tmp_path, data, what):
    path = tmp_path / "block.vtu"
    path.write_text("the reader is mocked")
    pts = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "hexahedron").points
    broken = meshio.Mesh(pts, [meshio.CellBlock("hexahedron", data)])
    with mock.patch("meshio.read", return_value=broken):
        with pytest.raises(ValueError, match=rf"{path}: {what}"):
            read_mesh(path)


def test_integral_float_indices_are_indices(tmp_path):
    """The other side: a reader that returns its indices as floats (whole numbers) is read."""
    path = tmp_path / "block.vtu"
    path.write_text("the reader is mocked")
    m = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "hexahedron")
    floats = meshio.Mesh(m.points, [meshio.CellBlock("hexahedron", m.cells.astype(float))])
    with mock.patch("meshio.read", return_value=floats):
        assert read_mesh(path).n_cells == 1
