"""What the tutorials' kernel needs before their first cell (a hidden cell runs :func:`setup`).

myst-nb runs each tutorial in a fresh temporary folder, as a reader would start in an empty one.
``%%bash`` cells run with ``bash -e -o pipefail``: a command that fails stops its cell and fails
the docs build (IPython's own ``%%bash`` looks only at the last command's status). Where a
tutorial starts from a folder of ``examples/``, :func:`setup` copies it into the working folder,
as a reader copies it out of a clone (the tutorial shows every file of it).
"""
from __future__ import annotations

import atexit
import os
import shutil
import signal
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _bash(line, cell):
    done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", cell], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    print(done.stdout, end="")
    if done.returncode:  # the tail of the output in the message: the build log shows only the error
        tail = "\n".join(done.stdout.splitlines()[-15:])
        raise RuntimeError(f"a command of this cell exited with status {done.returncode}; its output ends:\n{tail}")


def _stop(pid_files, folder: Path) -> None:
    """Send SIGTERM to the processes whose ids the files ``pid_files`` of ``folder`` hold."""
    for name in pid_files:
        try:
            os.kill(int((folder / name).read_text().split()[0]), signal.SIGTERM)
        except (OSError, ValueError, IndexError):  # never started, or already stopped by the page
            pass


def setup(example: str | None = None, stop_pids=()) -> None:
    """Register the strict ``%%bash``; copy ``examples/<example>`` into the working folder; at the
    kernel's exit stop the background processes whose ids the page wrote to ``stop_pids`` files
    (a cell that fails must not leave a cluster running)."""
    from IPython import get_ipython

    get_ipython().register_magic_function(_bash, magic_kind="cell", magic_name="bash")
    if example:
        shutil.copytree(REPO / "examples" / example, Path.cwd(), dirs_exist_ok=True)
    if stop_pids:
        atexit.register(_stop, tuple(stop_pids), Path.cwd())
