"""Mesh files that hung or crashed the reader (issue 37, found by tests/studies/test_fuzz_mesh_files.py):
meshio's TetGen, PLY, MDPA and Tecplot readers loop for ever at the end of a truncated file, and a
damaged file can make a reader return a cell block of the wrong shape (an IndexError, or numpy's
'zero-size array to reduction operation' naming no file)."""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
from types import SimpleNamespace
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
    import multiprocessing.connection

    from tissuebench.cases import meshio_guard

    path = _tetgen(tmp_path)
    poll = multiprocessing.connection.Connection.poll
    with mock.patch.object(multiprocessing.connection.Connection, "poll", autospec=True, side_effect=poll) as waited:
        assert meshio_guard.read_with_deadline(path).cells[0].data.shape == (6, 4)
    size_mb = path.stat().st_size / 1e6
    assert waited.call_args.args[1] == pytest.approx(meshio_guard.READ_SECONDS + meshio_guard.SECONDS_PER_MB * size_mb)


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


# ---------------------------------------------------------------- the reader's process (issue 54)
class _Recording:
    """The guard's multiprocessing context, keeping the processes it starts."""

    def __init__(self, ctx):
        self.ctx, self.made = ctx, []

    def Pipe(self, *args, **kwargs):
        return self.ctx.Pipe(*args, **kwargs)

    def Process(self, *args, **kwargs):
        self.made.append(self.ctx.Process(*args, **kwargs))
        return self.made[-1]


@pytest.fixture
def recording():
    from tissuebench.cases import meshio_guard

    rec = _Recording(meshio_guard._context())
    with mock.patch.object(meshio_guard, "_context", return_value=rec):
        yield rec


def _hang(*_):
    time.sleep(3600)  # C code: a thread cannot be stopped there, a process can


def test_a_hung_read_is_killed_in_its_process_and_the_parent_is_untouched(tmp_path, watchdog, recording):
    """The reader sleeps in C (no async exception reaches it): its process is killed at the deadline;
    the parent's own threads run on, and no thread of the read is left behind (a24e7fa left one, sleeping)."""
    stop, ticks = threading.Event(), []

    def work():
        while not stop.is_set():
            ticks.append(1)
            time.sleep(0.01)
    mine = threading.Thread(target=work, name="the parent's worker", daemon=True)
    mine.start()
    before = set(threading.enumerate())
    path = _tetgen(tmp_path)
    try:
        with mock.patch("tissuebench.cases.meshio_guard.READ_SECONDS", 0.5), mock.patch("meshio.read", _hang):
            with pytest.raises(ValueError, match=rf"^{path}: meshio cannot read it: it did not finish in 0\.5\d* s"):
                read_mesh(path)
        assert set(threading.enumerate()) == before and mine.is_alive()
        n, end = len(ticks), time.monotonic() + 30.0
        while len(ticks) == n and time.monotonic() < end:
            time.sleep(0.01)
        assert len(ticks) > n    # still working
    finally:
        stop.set()
        mine.join(5)
    (child,) = recording.made
    assert not child.is_alive() and child.exitcode == -signal.SIGKILL
    assert child.name == "meshio.read body.node"
    # and the same reader, answering, is read through the same process
    assert read_mesh(_tetgen(tmp_path)).n_cells == 6
    assert len(recording.made) == 2 and not recording.made[1].is_alive()


def test_a_reader_that_kills_its_process_is_said(tmp_path, watchdog, recording):
    path = _tetgen(tmp_path)
    with mock.patch("meshio.read", lambda *_: os._exit(3)):
        with pytest.raises(ValueError, match=rf"^{path}: meshio cannot read it: its reading process died \(exit "
                                             r"code 3\) without an answer$"):
            read_mesh(path)
    with mock.patch("meshio.read", lambda *_: sys.exit("meshio gave up")):
        with pytest.raises(ValueError, match=rf"^{path}: meshio cannot read it: SystemExit: meshio gave up$"):
            read_mesh(path)
    assert len(recording.made) == 2 and recording.made[0].exitcode == 3


def _fake(points, data):
    return SimpleNamespace(points=points, cells=[SimpleNamespace(type="tetra", data=data)])


def test_what_crosses_the_pipe_is_arrays(tmp_path, watchdog):
    """Both sides: Python numbers in lists become arrays; ragged rows or objects that are not numbers
    are said, naming the file and the field, and never pickled."""
    from tissuebench.cases.meshio_guard import read_with_deadline

    path = tmp_path / "block.vtu"
    path.write_text("the reader is mocked")
    m = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "tetra")
    as_lists = _fake(np.array(m.points.tolist(), dtype=object), m.cells.tolist())
    with mock.patch("meshio.read", return_value=as_lists):
        got = read_with_deadline(path)
    assert got.points.dtype == float and got.cells[0].data.dtype.kind == "i"
    np.testing.assert_array_equal(got.points, m.points)
    assert got.cells[0].type == "tetra"
    with mock.patch("meshio.read", return_value=_fake(m.points, [[0, 1, 2, 3], [0, 1, 2]])):
        with pytest.raises(ValueError, match=rf"^{path}: cell block 0 \(tetra\) is not an array of vertex indices "):
            read_with_deadline(path)
    with mock.patch("meshio.read", return_value=_fake([[object(), 0.0, 0.0]], m.cells)):
        with pytest.raises(ValueError, match=rf"^{path}: points are not an array of numbers "):
            read_with_deadline(path)


def test_a_daemonic_process_reads_in_process(tmp_path, watchdog, recording):
    """A daemonic process may not have children: the read runs in it, said the same way."""
    from tissuebench.cases import meshio_guard

    path = _tetgen(tmp_path)
    with mock.patch.object(meshio_guard.multiprocessing, "current_process", return_value=SimpleNamespace(daemon=True)):
        assert read_mesh(path).n_cells == 6
        with mock.patch("meshio.read", lambda *_: sys.exit("meshio gave up")):
            with pytest.raises(ValueError, match=rf"^{path}: meshio cannot read it: SystemExit: meshio gave up$"):
                read_mesh(path)
    assert recording.made == []
