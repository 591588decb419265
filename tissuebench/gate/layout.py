"""Where a Python package lives in a git repository, at a commit or in the work tree: for
``tissuebench check --against REF`` (:mod:`.project`), which exports the project's packages at
REF and must find them there, src/ layouts and moved packages included.

A package ``name`` of distribution ``dist`` is looked for in the folders its packaging
declares, read from the ``pyproject.toml`` or ``setup.cfg`` that names ``dist`` (anywhere in
the tree: a repository may hold several projects), else the one at the tree's top:

* ``[tool.setuptools] package-dir = {"" = "src"}``, ``[tool.setuptools.packages.find] where``;
* ``[tool.hatch.build.targets.wheel] packages = ["src/name"]``, ``[tool.poetry] packages``'s ``from``;
* ``setup.cfg``: ``[options] package_dir = =src``, ``[options.packages.find] where``;

then the folder it had on the other side (HEAD's), then the tree's top and ``src``. The first
that holds ``name/`` with a ``.py`` file (or ``name.py``) is the package's folder. These files
are the user's: read like input, anything unexpected in them is skipped, never trusted
(a folder outside the tree, a non-string).
"""
from __future__ import annotations

import configparser
import posixpath
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path

from ..rom.plugins import _SOURCE, GROUP
from ..rom.registry import METHOD_NAME
from .ref import _git

__all__ = ["Tree", "Declared", "normal_name"]

CONFIGS = ("pyproject.toml", "setup.cfg")


def normal_name(name) -> str:
    """A distribution's name as packaging compares it (PEP 503)."""
    return re.sub(r"[-_.]+", "-", str(name)).lower()


def _folder(base: str, rel) -> str | None:
    """``rel`` (a folder named in a config in ``base``) relative to the tree's top, None when it is
    not a string or leaves the tree."""
    if not isinstance(rel, str) or rel.startswith("/") or "\\" in rel:
        return None
    path = posixpath.normpath(posixpath.join(base, rel)) if (base or rel) else ""
    return None if path == ".." or path.startswith("../") else ("" if path == "." else path)


@dataclass(frozen=True)
class Declared:
    """What a ``pyproject.toml`` or ``setup.cfg`` declares statically: the distribution's name,
    the folders its packages are in (relative to the config's folder, as written), its version,
    and its ``tissuebench.methods`` entry points (None when it does not declare them statically)."""

    name: str | None = None
    folders: tuple = ()
    version: str | None = None
    entry_points: dict | None = None


def _table(doc, *keys) -> dict:
    """``doc[k1][k2]...`` when every level is a table, else {}."""
    for k in keys:
        doc = doc.get(k) if isinstance(doc, dict) else None
    return doc if isinstance(doc, dict) else {}


def _methods(points) -> dict:
    """The entry points of group ``tissuebench.methods`` that name a ``module:Class`` ({} of a bad table)."""
    if not isinstance(points, dict):
        return {}
    return {k: v.strip() for k, v in points.items() if isinstance(k, str) and METHOD_NAME.fullmatch(k)
            and isinstance(v, str) and _SOURCE.fullmatch(v.strip())}


def _pyproject(text: str) -> Declared:
    doc = tomllib.loads(text)
    project, poetry, st = _table(doc, "project"), _table(doc, "tool", "poetry"), _table(doc, "tool", "setuptools")
    dynamic = project.get("dynamic") if isinstance(project.get("dynamic"), list) else []
    version = (project.get("version") if "version" not in dynamic else None) or poetry.get("version")
    dirs = [_table(st, "package-dir").get("")]
    where = _table(st, "packages", "find").get("where")
    dirs += where if isinstance(where, list) else [where]
    wheel = _table(doc, "tool", "hatch", "build", "targets", "wheel").get("packages")
    dirs += [posixpath.dirname(p) if isinstance(p, str) else None for p in (wheel if isinstance(wheel, list) else [])]
    packages = poetry.get("packages")
    dirs += [p.get("from", "") if isinstance(p, dict) else None for p in (packages if isinstance(packages, list)
                                                                        else [])]
    points = None if "entry-points" in dynamic else _methods(_table(project, "entry-points").get(GROUP, {}))
    return Declared(project.get("name") or poetry.get("name"), tuple(dirs), version, points)


def _setup_cfg(text: str) -> Declared:
    cfg = configparser.ConfigParser(interpolation=None)
    cfg.read_string(text)
    version = cfg.get("metadata", "version", fallback=None)
    if version and version.strip().startswith(("attr:", "file:")):
        version = None
    dirs = []
    for line in cfg.get("options", "package_dir", fallback="").splitlines():
        key, sep, value = line.partition("=")
        if sep and not key.strip():
            dirs.append(value.strip())
    dirs += [w.strip() for w in cfg.get("options.packages.find", "where", fallback="").splitlines() if w.strip()]
    points = {}
    for line in cfg.get("options.entry_points", GROUP, fallback="").splitlines():
        key, sep, value = line.partition("=")
        if sep:
            points[key.strip()] = value.strip()
    return Declared(cfg.get("metadata", "name", fallback=None), tuple(dirs), version, _methods(points))


class Tree:
    """The files of the git repository ``repo`` at commit ``sha``, or in its work tree (``sha``
    None: tracked and untracked files, the ignored ones left out)."""

    def __init__(self, repo, sha: str | None = None):
        self.repo, self.sha = Path(repo), sha
        args = ("ls-tree", "-r", "--name-only", "-z", sha) if sha else ("ls-files", "-z", "--cached", "--others",
                                                                       "--exclude-standard")
        listed = _git(self.repo, *args)
        if listed.returncode != 0:
            raise ValueError(f"git {args[0]} in {self.repo} failed: {listed.stderr.strip()[:300]}")
        files = [f for f in listed.stdout.split("\0") if f]
        self.files = set(files) if sha else {f for f in files if (self.repo / f).is_file()}
        self._py_folders = {posixpath.dirname(f) for f in self.files if f.endswith(".py")}
        self._configs: dict = {}

    def read(self, path: str) -> str:
        """The text of ``path`` in the tree, ``""`` when it cannot be read."""
        if self.sha:
            shown = _git(self.repo, "show", f"{self.sha}:{path}")
            return shown.stdout if shown.returncode == 0 else ""
        try:
            return (self.repo / path).read_text(errors="replace")
        except OSError:
            return ""

    def config(self, path: str) -> Declared:
        """What the ``pyproject.toml`` or ``setup.cfg`` at ``path`` declares (:class:`Declared`, its
        folders relative to the tree's top); nothing from a file that does not parse."""
        if path not in self._configs:
            self._configs[path] = self._parse(path)
        return self._configs[path]

    def _parse(self, path: str) -> Declared:
        try:
            found = (_pyproject if path.endswith(".toml") else _setup_cfg)(self.read(path))
        except (ValueError, configparser.Error, AttributeError, TypeError):
            return Declared()
        base = posixpath.dirname(path)
        return Declared(found.name if isinstance(found.name, str) else None,
                        tuple(f for f in (_folder(base, d) for d in found.folders) if f is not None),
                        found.version if isinstance(found.version, str) else None, found.entry_points)

    def declaring(self, dist: str | None) -> Declared | None:
        """What the config that declares distribution ``dist`` says; None when none does."""
        configs = sorted(f for f in self.files if posixpath.basename(f) in CONFIGS)
        return next((self.config(c) for c in configs if dist and self.config(c).name
                     and normal_name(self.config(c).name) == normal_name(dist)), None)

    def configs_of(self, dist: str | None) -> list[Declared]:
        """What the config declaring distribution ``dist`` says; else the config(s) at the tree's top."""
        found = self.declaring(dist)
        return [found] if found else [self.config(c) for c in sorted(self.files) if c in CONFIGS]

    def holds(self, folder: str, name: str) -> bool:
        """Whether ``folder`` (relative to the top) holds package ``name`` (or module ``name.py``)."""
        pkg = posixpath.join(folder, name) if folder else name
        return f"{pkg}.py" in self.files or any(d == pkg or d.startswith(pkg + "/") for d in self._py_folders)

    def member(self, folder: str, name: str) -> str:
        """The path ``git archive`` exports for package ``name`` in ``folder``: its folder, or its
        module file when it is one."""
        pkg = posixpath.join(folder, name) if folder else name
        return f"{pkg}.py" if f"{pkg}.py" in self.files and pkg not in self._py_folders else pkg

    def locate(self, name: str, dist: str | None, other: str | None = None) -> str | None:
        """The folder (relative to the top, ``""`` for the top) holding package ``name`` of
        distribution ``dist`` (module docstring); ``other``: its folder on the other side. None
        when the tree does not hold it."""
        candidates = [f for c in self.configs_of(dist) for f in c.folders]
        candidates += ([other] if other is not None else []) + ["", "src"]
        return next((f for f in dict.fromkeys(candidates) if self.holds(f, name)), None)

    def version(self, name: str, dist: str | None, folder: str) -> str | None:
        """The version the tree's packaging declares for ``dist``, else ``__version__`` of package
        ``name`` in ``folder``; None when neither says."""
        found = self.declaring(dist)
        if found is not None and found.version:
            return found.version
        pkg = posixpath.join(folder, name) if folder else name
        found = re.search(r"""^__version__\s*=\s*["']([^"'\n]{1,64})["']""", self.read(f"{pkg}/__init__.py"), re.M)
        return found.group(1) if found else None
