"""``meshio.read`` with a deadline: a malformed file must not hang the tool.

Several of meshio's text readers loop for ever at the end of a truncated file (they call
``readline()`` until a keyword that never comes: a ``.node`` (TetGen) or ``.ply`` cut short, an
``.mdpa`` without its ``End Nodes``, a Tecplot ``.dat`` cut in its header: 2 to 8 of 40 damaged
files each, measured with meshio 5.3). :func:`read_with_deadline` runs the read in a child
process, which sends the mesh's arrays back through a pipe (numbers and type names only, no
pickled reader objects); past the deadline the child is killed, whatever it is doing (a loop of
Python code or of C), and the caller gets a ValueError naming the file. The parent's threads
and state are never touched. The deadline grows with the file's size, so a large mesh is never
cut short: :data:`READ_SECONDS` plus :data:`SECONDS_PER_MB` per megabyte (meshio parses ASCII
meshes at several MB/s).

The child is forked where the platform can (it starts in milliseconds with meshio already
imported, and sees the parent's state, a test's mock of ``meshio.read`` included), spawned
elsewhere. A daemonic process may not have children: there the read runs in-process, without a
deadline.
"""
from __future__ import annotations

import contextlib
import io
import multiprocessing
from pathlib import Path
from typing import NamedTuple

import numpy as np

__all__ = ["READ_SECONDS", "SECONDS_PER_MB", "CellArrays", "MeshArrays", "read_with_deadline"]

#: the least time a read is given [s]
READ_SECONDS = 60.0
#: and this much more per megabyte of the file [s]
SECONDS_PER_MB = 10.0
#: the time a killed child is given to be reaped [s]
_REAP_SECONDS = 5.0
#: numpy kinds that cross the pipe as they are: booleans, integers, floats, complex, text
_PLAIN_KINDS = "biufcUS"


class CellArrays(NamedTuple):
    """One cell block of the file: meshio's type name and its connectivity array."""

    type: str
    data: np.ndarray


class MeshArrays(NamedTuple):
    """What :func:`read_with_deadline` returns: the points and the cell blocks, as arrays."""

    points: np.ndarray
    cells: list


class _Malformed(Exception):
    """The reader returned something that is not an array (said as such, naming the file)."""


def _context():
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else "spawn")


def _plain(what: str, value, not_array: str) -> np.ndarray:
    """``value`` as an array that crosses the pipe as data; _Malformed naming ``what`` otherwise."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind == "O":  # Python numbers or strings in a list: their values, or not an array
            arr = arr.astype(float)
    except (TypeError, ValueError) as exc:  # ragged rows, text that is no number
        raise _Malformed(f"{what} {not_array} ({exc})") from None
    if arr.dtype.kind not in _PLAIN_KINDS:
        raise _Malformed(f"{what} {not_array} ({arr.dtype})")
    return arr


def _read_arrays(path: str) -> MeshArrays:
    import meshio

    mesh = meshio.read(path)
    points = _plain("points", mesh.points, "are not an array of numbers")
    cells = [CellArrays(str(b.type), _plain(f"cell block {i} ({b.type})", b.data, "is not an array of vertex indices"))
             for i, b in enumerate(mesh.cells)]
    return MeshArrays(points, cells)


def _child(path: str, conn) -> None:
    """The read in the child: sends ``("mesh", points, [(type, data)])``, ``("malformed", text)``
    or ``("error", exception type, text, what meshio printed)``."""
    said = io.StringIO()
    try:
        # meshio prints its complaints: they go into the message, not onto the terminal
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            m = _read_arrays(path)
        reply = ("mesh", m.points, [tuple(c) for c in m.cells])
    except _Malformed as exc:
        reply = ("malformed", str(exc))
    except BaseException as exc:  # noqa: BLE001 - ReadError, KeyError, ...; meshio 5 even calls sys.exit
        reply = ("error", type(exc).__name__, str(exc), said.getvalue())
    conn.send(reply)
    conn.close()


def read_with_deadline(path: Path) -> MeshArrays:
    """The arrays of ``meshio.read(path)``; ValueError naming ``path`` when meshio raises (or
    exits, or its process dies), returns something that is not arrays, or does not finish
    before the deadline (module docstring)."""
    import meshio  # noqa: F401 - loaded once in the parent, so a forked child starts with it

    path = Path(path)
    deadline = READ_SECONDS + SECONDS_PER_MB * path.stat().st_size / 1e6
    if multiprocessing.current_process().daemon:
        return _reply_to_arrays(path, _in_process(str(path)))
    ctx = _context()
    receive, send = ctx.Pipe(duplex=False)
    child = ctx.Process(target=_child, args=(str(path), send), name=f"meshio.read {path.name}", daemon=True)
    child.start()
    send.close()  # the child holds the only writing end: its death is an EOF here
    answered = False
    try:
        if not receive.poll(deadline):
            raise ValueError(f"{path}: meshio cannot read it: it did not finish in {deadline:.3g} s (its reader "
                             "loops on this file: a truncated or malformed mesh file?)")
        try:
            reply = receive.recv()
        except EOFError:
            child.join(_REAP_SECONDS)
            raise ValueError(f"{path}: meshio cannot read it: its reading process died (exit code "
                             f"{child.exitcode}) without an answer") from None
        answered = True
    finally:
        receive.close()
        if answered:  # it exits on its own once it has answered
            child.join(_REAP_SECONDS)
        if child.is_alive():  # past the deadline (or the parent interrupted): killed, whatever it runs
            child.kill()
            child.join(_REAP_SECONDS)
    return _reply_to_arrays(path, reply)


class _Reply:
    """A stand-in for the pipe's sending end: keeps the one reply."""

    reply = None

    def send(self, reply):
        self.reply = reply

    def close(self):
        pass


def _in_process(path: str):
    """The child's reply, computed here (a daemonic process may not fork a reader)."""
    box = _Reply()
    _child(path, box)
    return box.reply


def _reply_to_arrays(path: Path, reply) -> MeshArrays:
    kind = reply[0]
    if kind == "malformed":
        raise ValueError(f"{path}: {reply[1]}")
    if kind == "error":
        _, name, text, printed = reply
        detail = " ".join(printed.split())[:300]
        raise ValueError(f"{path}: meshio cannot read it: {name}: {text}" + (f" ({detail})" if detail else ""))
    _, points, cells = reply
    return MeshArrays(points, [CellArrays(t, d) for t, d in cells])
