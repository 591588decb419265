"""The project under test of ``tissuebench check --against REF``: the git repository REF is
resolved in, its packages the sweep runs, and the code of each side (:class:`~.sides.Code`).

**Which repository** (said in the output, with why):

1. ``--project PATH``: the git repository holding PATH;
2. else, when the sweep's methods from other packages (plugins) all come from packages whose
   source lies in one git repository (an editable install, a folder on ``PYTHONPATH``): that one;
3. else the working directory's repository (a user's CI runs from its checkout, whether its
   package is installed editable or not);
4. else, when the sweep runs tissuebench's own methods only, the repository of the
   tissuebench this process runs (tissuebench's CI: today's behaviour).

**Which packages**: tissuebench and every top-level package of the sweep's plugin methods (all
the top-level packages of their distributions), each either inside the repository (this
process imports it from the work tree) or found in it by its packaging (:mod:`.layout`: a
non-editable install of the repository's package, a src/ layout). Those are the project's: REF's
processes run REF's copy of each, exported from git at REF (:func:`export_project`) and first on
their ``PYTHONPATH``. Every other package is the same on both sides: tissuebench itself when the
project is another (the tissuebench this process runs, after REF's packages on the path).
"""
from __future__ import annotations

import importlib.metadata
import importlib.util
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from ..rom.plugins import GROUP
from .sides import Code
from .layout import Tree, normal_name
from .ref import _git

__all__ = ["Package", "Project", "find_project", "export_project", "head_code", "describe_head", "git_top"]


@dataclass(frozen=True)
class Package:
    """A package of the project under test: import ``name``, its ``distribution``, the ``folder``
    holding it in the work tree (relative to the repository's top, ``""`` for the top) and the
    folder this process imports it from (``imported``: HEAD's side)."""

    name: str
    distribution: str | None
    folder: str
    imported: Path | None


@dataclass(frozen=True)
class Project:
    """The repository REF is resolved in (its top), why it is that one, its packages the sweep
    runs, and the packages the sweep runs that it does not hold (``outside``: name -> where this
    process imports it from; the same on both sides)."""

    repo: Path
    how: str
    packages: tuple
    outside: dict


def git_top(path) -> Path | None:
    """The top of the git work tree holding ``path`` (a file or folder), None outside one."""
    p = Path(path)
    p = p if p.is_dir() else p.parent
    if not p.is_dir():
        return None
    top = _git(p, "rev-parse", "--show-toplevel")
    return Path(top.stdout.strip()).resolve() if top.returncode == 0 and top.stdout.strip() else None


def _imported_from(top: str) -> Path | None:
    """The folder (a ``sys.path`` entry) this process imports top-level package ``top`` from."""
    module = sys.modules.get(top)
    file = getattr(module, "__file__", None)
    if file is None:
        try:
            spec = importlib.util.find_spec(top)
        except (ImportError, ValueError):
            return None
        if spec is None:
            return None
        if spec.submodule_search_locations:
            return Path(list(spec.submodule_search_locations)[0]).parent
        file = spec.origin
    if not file or not Path(file).is_absolute():
        return None
    path = Path(file)
    return path.parent.parent if path.stem == "__init__" else path.parent


def _plugin_tops(methods) -> dict:
    """``{top-level package: distribution}`` of the plugin methods ``methods`` (``(source,
    distribution)`` pairs, source "module:Class"), with every top-level package of their
    distributions (a package imports its siblings)."""
    tops = {}
    by_dist = {}
    for top, dists in importlib.metadata.packages_distributions().items():
        for d in dists:
            by_dist.setdefault(d, set()).add(top)
    for source, dist in methods:
        if not isinstance(source, str) or ":" not in source:
            continue
        tops.setdefault(source.split(":")[0].split(".")[0], dist if isinstance(dist, str) and dist else None)
        if isinstance(dist, str) and dist:
            for sibling in by_dist.get(dist, ()):
                if sibling.isidentifier() and not sibling.startswith("__editable__"):
                    tops.setdefault(sibling, dist)
    tops.pop("tissuebench", None)
    return tops


def _relative(path: Path | None, repo: Path) -> str | None:
    if path is None:
        return None
    try:
        rel = path.resolve().relative_to(repo)
    except ValueError:
        return None
    return "" if str(rel) == "." else rel.as_posix()


def find_project(methods, head_root: Path, project=None, cwd=None) -> Project:
    """The project under test (module docstring) of a sweep whose plugin methods are ``methods``
    (``(source, distribution)`` pairs); ``head_root``: the folder holding the tissuebench this
    process runs. ValueError naming what was searched when there is no repository."""
    tops = _plugin_tops(methods)
    where = {top: _imported_from(top) for top in tops}
    cwd = Path.cwd() if cwd is None else Path(cwd)
    if project is not None:
        repo = git_top(project)
        if repo is None:
            raise ValueError(f"--project = {str(project)!r}: not inside a git checkout (no repository to find REF in)")
        how = "given by --project"
    else:
        homes = {git_top(f / top) if f is not None else None for top, f in where.items()}
        here = git_top(cwd)
        if tops and len(homes) == 1 and None not in homes:
            repo = homes.pop()
            how = f"the repository of the package{'s' if len(tops) > 1 else ''} {', '.join(sorted(tops))} of the " \
                  "sweep's plugin methods"
            if here is not None and here != repo:
                how += f"; the working directory is in another one, {here} (--project to gate that)"
        elif here is not None:
            repo, how = here, "the working directory's repository"
        elif not tops and git_top(head_root / "tissuebench") is not None:
            repo, how = git_top(head_root / "tissuebench"), "the repository of this tissuebench (the sweep runs its " \
                                                           "methods only)"
        else:
            places = "; ".join(f"{top} is imported from {f}" for top, f in sorted(where.items()) if f)
            raise ValueError(f"--against: no git repository to find REF in: the working directory {cwd} is not in a "
                             f"git checkout{(' and neither is a plugin package (' + places + ')') if places else ''}; "
                             "give --project PATH (the repository of the code under test)")
    return Project(repo, how, *_packages(repo, tops, where, head_root))


def _packages(repo: Path, tops: dict, where: dict, head_root: Path) -> tuple[tuple, dict]:
    """The project's packages and the ones outside it (module docstring)."""
    work = None
    inside, outside = [], {}
    for name, dist, imported in [("tissuebench", "tissuebench", Path(head_root))] + [
            (t, tops[t], where[t]) for t in sorted(tops)]:
        folder = _relative(imported, repo)
        if folder is None:
            work = work or Tree(repo)
            folder = work.locate(name, dist)
        if folder is None:
            outside[name] = imported
        else:
            inside.append(Package(name, dist, folder, imported))
    return tuple(inside), outside


def _archive(repo: Path, sha: str, members: list, dest: Path) -> None:
    archive = subprocess.run(["git", "-C", str(repo), "archive", "--format=tar", sha, "--", *members],
                             capture_output=True)
    if archive.returncode != 0:
        raise ValueError(f"--against: git archive {sha[:12]} failed: {archive.stderr.decode(errors='replace')[:300]}")
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)


def export_project(project: Project, sha: str, dest: Path, head_root: Path) -> tuple[Code, str]:
    """The project's packages at commit ``sha`` exported into ``dest`` (``git archive``), each
    where REF's packaging puts it (:mod:`.layout`): ``(REF's code, what it holds)``. A package
    REF lacks is None in the code (REF cannot run its methods); tissuebench outside the project
    is this one (``head_root``), last on the path. ValueError when the project holds tissuebench
    and REF does not."""
    dest.mkdir(parents=True, exist_ok=True)
    tree = Tree(project.repo, sha)
    path, packages, said, dists = [], {}, [], set()
    for p in project.packages:
        folder = tree.locate(p.name, p.distribution, p.folder)
        if folder is None:
            packages[p.name] = None
            said.append(f"no package {p.name}")
            continue
        _archive(project.repo, sha, [tree.member(folder, p.name)], dest)
        root = dest / folder if folder else dest
        packages[p.name] = root
        if root not in path:
            path.append(root)
        version = tree.version(p.name, p.distribution, folder)
        said.append(f"{p.distribution or p.name} {version or '(version not declared)'}"
                    + (f" ({p.name} in {folder or 'the top'}/)" if p.distribution != p.name or folder else "")
                    + (_metadata(tree, project, p, root, version, sha) if p.distribution not in dists else ""))
        dists.add(p.distribution)
    if "tissuebench" not in packages:
        packages["tissuebench"] = Path(head_root)
        path.append(Path(head_root))
        said.append(f"tissuebench {_installed_version('tissuebench')} from {head_root} (the same on both sides)")
    elif packages["tissuebench"] is None:
        raise ValueError(f"--against: commit {sha[:12]} has no tissuebench package")
    return Code(tuple(path), packages), ", ".join(said)


def _metadata(tree: Tree, project: Project, package: Package, root: Path, version: str | None, sha: str) -> str:
    """Write REF's metadata of a plugin distribution (name, version, its ``tissuebench.methods``
    entry points as REF's packaging declares them) beside REF's package: first on the path,
    it hides the installed (HEAD's) metadata from REF's processes (:mod:`importlib.metadata`
    takes the first distribution of a name), so REF's entry points load REF's classes. ``""``,
    or what is left to the installed metadata."""
    if package.distribution is None or package.name == "tissuebench":
        return ""
    declared = tree.declaring(package.distribution)
    if declared is None or declared.entry_points is None:
        return "; entry points: the installed metadata (REF's packaging does not declare them statically)"
    info = root / f"{normal_name(package.distribution).replace('-', '_')}-{version or '0+ref.' + sha[:12]}.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {package.distribution}\n"
                                   f"Version: {version or '0+ref.' + sha[:12]}\n")
    (info / "top_level.txt").write_text("".join(f"{p.name}\n" for p in project.packages
                                                if p.distribution == package.distribution))
    (info / "entry_points.txt").write_text("\n".join([f"[{GROUP}]"] + [f"{k} = {v}" for k, v in
                                                                         sorted(declared.entry_points.items())]) + "\n")
    return ""


def _installed_version(dist: str | None) -> str:
    try:
        return importlib.metadata.version(dist) if dist else "(no installed distribution)"
    except importlib.metadata.PackageNotFoundError:
        return "(no installed distribution)"


def head_code(project: Project, head_root: Path) -> Code:
    """HEAD's side: this tissuebench first on the path, each package of the project from where
    this process imports it."""
    packages = {"tissuebench": Path(head_root)}
    for p in project.packages:
        if p.name != "tissuebench":
            packages[p.name] = p.imported
    return Code((Path(head_root),), packages)


def describe_head(project: Project, head_root: Path) -> str:
    """HEAD's side in words: the work tree's commit (and whether it has uncommitted changes), the
    version and origin of each package of the project, and tissuebench's."""
    sha = _git(project.repo, "rev-parse", "HEAD").stdout.strip()[:12] or "(no commit)"
    dirty = _git(project.repo, "status", "--porcelain", "--untracked-files=no").stdout.strip()
    work = Tree(project.repo)
    said = []
    for p in project.packages:
        version = work.version(p.name, p.distribution, p.folder) or _installed_version(p.distribution)
        said.append(f"{p.distribution or p.name} {version} ({p.name} from {p.imported})")
    if "tissuebench" not in {p.name for p in project.packages}:
        said.append(f"tissuebench {_installed_version('tissuebench')} from {head_root}")
    return (f"the working tree of {project.repo} at {sha}{' with uncommitted changes' if dirty else ''}: "
            + ", ".join(said))
