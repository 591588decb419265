"""``meshio.read`` with a deadline: a malformed file must not hang the tool.

Several of meshio's text readers loop for ever at the end of a truncated file (they call
``readline()`` until a keyword that never comes: a ``.node`` (TetGen) or ``.ply`` cut short, an
``.mdpa`` without its ``End Nodes``, a Tecplot ``.dat`` cut in its header: 2 to 8 of 40 damaged
files each, measured with meshio 5.3). :func:`read_with_deadline` runs the read in a worker
thread; past the deadline, an exception is raised inside that thread (which ends a loop of Python
code) and the caller gets a ValueError naming the file. The deadline grows with the file's size,
so a large mesh is never cut short: :data:`READ_SECONDS` plus :data:`SECONDS_PER_MB` per
megabyte (meshio parses ASCII meshes at several MB/s).
"""
from __future__ import annotations

import contextlib
import ctypes
import io
import threading
from pathlib import Path

__all__ = ["READ_SECONDS", "SECONDS_PER_MB", "read_with_deadline"]

#: the least time a read is given [s]
READ_SECONDS = 60.0
#: and this much more per megabyte of the file [s]
SECONDS_PER_MB = 10.0


class _Stopped(BaseException):
    """Raised inside a reader past its deadline (a BaseException: a reader's ``except Exception``
    must not swallow it and loop on)."""


def _stop(thread: threading.Thread) -> None:
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(thread.ident), ctypes.py_object(_Stopped))


def read_with_deadline(path: Path):
    """``meshio.read(path)``, and what it printed; ValueError naming ``path`` when meshio raises
    (or exits) or does not finish before the deadline (module docstring)."""
    import meshio

    path = Path(path)
    deadline = READ_SECONDS + SECONDS_PER_MB * path.stat().st_size / 1e6
    outcome: dict = {}

    def run():
        try:
            outcome["mesh"] = meshio.read(path)
        except _Stopped:
            pass
        except BaseException as exc:  # noqa: BLE001 - ReadError, KeyError, ...; meshio 5 even calls sys.exit
            outcome["error"] = exc

    said = io.StringIO()
    # meshio prints its complaints: they go into the message, not onto the terminal
    with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
        worker = threading.Thread(target=run, name=f"meshio.read {path.name}", daemon=True)
        worker.start()
        worker.join(deadline)
        if worker.is_alive():
            _stop(worker)
            worker.join(1.0)
            raise ValueError(f"{path}: meshio cannot read it: it did not finish in {deadline:.3g} s (its reader "
                             "loops on this file: a truncated or malformed mesh file?)")
    if "error" in outcome:
        exc = outcome["error"]
        detail = " ".join(said.getvalue().split())[:300]
        raise ValueError(f"{path}: meshio cannot read it: {type(exc).__name__}: {exc}"
                         + (f" ({detail})" if detail else "")) from exc
    return outcome["mesh"]
