"""The code one side of ``tissuebench check --against REF`` runs, and the check that the side's
processes import that code and no other.

A side (:class:`Code`) is a list of folders put first on ``PYTHONPATH`` of its processes
(:func:`code_env`) and, for each package of the project under test, the folder its modules must
come from: REF's export of it, or the copy this process imports on HEAD's side. Import hooks
can hand out another copy: an editable install's finder (setuptools' ``__editable__`` finders sit
on ``sys.meta_path``) serves a module that REF's package lacks from HEAD's work tree, and an
entry point names ``module:Class`` of whichever copy of ``module`` is found first. So every
process of a side reports where it imported each module of those packages from, and
:func:`foreign` names the packages served from elsewhere: not that side's code.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["Code", "as_code", "code_env", "foreign", "MODULE_FILES"]


@dataclass(frozen=True)
class Code:
    """What one side runs.

    Attributes
    ----------
    path : tuple of Path
        Folders first on ``PYTHONPATH`` of the side's processes, in this order.
    packages : dict
        Import name -> the folder holding that package (a ``sys.path`` entry), or None when the
        side has no such package (REF's commit lacks it): any of its modules imported there is
        another side's code. ``tissuebench`` is always one of them.
    """

    path: tuple
    packages: dict = field(default_factory=dict)

    def folder(self, package: str) -> Path | None:
        return self.packages.get(package)


def as_code(code) -> Code:
    """``code`` as a :class:`Code`: a folder holding a ``tissuebench`` package is that package alone."""
    if isinstance(code, Code):
        return code
    root = Path(code)
    return Code((root,), {"tissuebench": root})


def code_env(code) -> dict:
    """This process's environment with the side's folders (:class:`Code`, or a folder holding a
    tissuebench package) first on ``PYTHONPATH``: a child process then runs that code.
    ``PYTHONSAFEPATH=1`` (Python 3.11): ``python -m`` and ``-c`` would put the working folder
    before ``PYTHONPATH``, and from a checkout's root that is HEAD's package (REF's sweep ran
    HEAD's code there, CI's case)."""
    first = [str(p) for p in as_code(code).path]
    rest = [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p and p not in first]
    return {**os.environ, "PYTHONSAFEPATH": "1", "PYTHONPATH": os.pathsep.join(first + rest)}


# run in a side's process (python -c, or pasted into a probe): prints {module: file} of every loaded
# module of the packages named in TOPS
MODULE_FILES = ("{n: getattr(m, '__file__', None) for n, m in list(sys.modules.items()) "
                "if n.split('.')[0] in TOPS}")


def _inside(file: str, folder: Path, top: str) -> bool:
    """Whether module file ``file`` is package (or module) ``top`` of the folder ``folder``."""
    for f, d in ((Path(os.path.abspath(file)), Path(os.path.abspath(folder))), (Path(file).resolve(),
                                                                              Path(folder).resolve())):
        try:
            rel = f.relative_to(d)
        except ValueError:
            continue
        if rel.parts and (rel.parts[0] == top if len(rel.parts) > 1 else rel.parts[0].split(".")[0] == top):
            return True
    return False


def foreign(files: dict, code) -> dict:
    """``{package: why}`` for every package of ``code`` whose modules in ``files`` (module name ->
    file, as a side's process reported them) do not come from the side's folder of it; a module
    without a file (a namespace package) is not judged."""
    code = as_code(code)
    out = {}
    for name in sorted(files):
        top, file = name.split(".")[0], files[name]
        if top in out or top not in code.packages or not file:
            continue
        folder = code.packages[top]
        if folder is None:
            out[top] = f"{name} comes from {file}, and this side has no package {top}"
        elif not _inside(file, folder, top):
            out[top] = f"{name} comes from {file}, not from {Path(folder) / top}"
    return out
