"""What the tutorials' kernel needs before their first cell (a hidden cell runs :func:`setup`).

myst-nb runs each tutorial in a fresh temporary folder, as a reader would start in an empty one.
``%%bash`` cells run with ``bash -e -o pipefail``: a command that fails stops its cell and fails
the docs build (IPython's own ``%%bash`` looks only at the last command's status). Where a
tutorial starts from a folder of ``examples/``, :func:`setup` copies it into the working folder,
as a reader copies it out of a clone (the tutorial shows every file of it).
"""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _bash(line, cell):
    done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", cell], stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    print(done.stdout, end="")
    if done.returncode:
        raise RuntimeError(f"a command of this cell exited with status {done.returncode}")


def setup(example: str | None = None) -> None:
    """Register the strict ``%%bash``; copy ``examples/<example>`` into the working folder."""
    from IPython import get_ipython

    get_ipython().register_magic_function(_bash, magic_kind="cell", magic_name="bash")
    if example:
        shutil.copytree(REPO / "examples" / example, Path.cwd(), dirs_exist_ok=True)
