"""Which of a sweep's methods are code of the project under test, for ``tissuebench check
--against REF`` (:mod:`.project`).

REF's processes run REF's export of the project's packages; a package the project does not hold
(tissuebench itself when the project is a plugin's repository, a plugin installed from
elsewhere) is the same on both sides. A method of such a package, run by a tissuebench the
project does not hold either, is compared with itself: its error equals REF's and its A/B ratio
is 1 whatever the commit changed. When *no* method of the sweep is the project's code and the
project is not tissuebench's repository (whose code every method runs through: training,
reconstruction, the timing), e.g. a ``--project`` naming the wrong repository, the gate would
pass vacuously ("1 units hold"): :func:`check_scope` refuses it before any work, saying where
each method's code is imported from. When some are, the others are said in a note.
"""
from __future__ import annotations

import math
from pathlib import Path

from .project import Project, _installed_version

__all__ = ["method_packages", "check_scope"]


def _text(value) -> str:
    """A stored string column's value ("" for None or NaN: an older store lacks the column)."""
    return value if isinstance(value, str) else "" if value is None or (isinstance(value, float) and
                                                                         math.isnan(value)) else str(value)


def method_packages(methods) -> dict:
    """``{top-level package: (sorted method names, distribution, version)}`` of a sweep's methods,
    ``methods`` being ``(name, source, distribution, version)`` rows of its units (source
    ``"module:Class"``, ``""`` for a shipped method: package ``tissuebench``)."""
    found: dict = {}
    for name, source, dist, version in methods:
        source = _text(source)
        top = source.split(":")[0].split(".")[0] if ":" in source else "tissuebench"
        names, d, v = found.get(top, (set(), _text(dist) or None, _text(version) or None))
        names.add(str(name))
        found[top] = (names, d, v)
    return {top: (sorted(names), d, v) for top, (names, d, v) in found.items()}


def _origin(top: str, names: list, dist, version, where) -> str:
    """Where the methods ``names`` of package ``top`` come from, in words."""
    said = (f"method {names[0]!r} is" if len(names) == 1 else
            "methods " + ", ".join(repr(n) for n in names[:6]) + (" ..." if len(names) > 6 else "") + " are")
    if top == "tissuebench":
        said += " tissuebench's own,"
        dist, version = "tissuebench", _installed_version("tissuebench")
    if where is None:
        return f"{said} of package {top} (this process cannot import it)"
    folder = Path(where)
    place = folder / top if (folder / top).exists() else folder / f"{top}.py" if (folder / f"{top}.py").exists() \
        else folder
    if top == "tissuebench":
        return f"{said} imported from {place} ({dist} {version})"
    return f"{said} imported from {place} " + (f"(distribution {dist} {version or '(no version)'})" if dist else
                                                  "(no installed distribution)")


def check_scope(methods, project: Project, against: str) -> list:
    """The notes on the methods that are not code of ``project`` (:func:`method_packages` of
    ``methods``), or ValueError naming the option, the repository and where every method's code
    comes from when none is: REF's export of the project would run the same code on both sides."""
    packages = method_packages(methods)
    held = {p.name for p in project.packages}
    outside = {top: v for top, v in packages.items() if top not in held}
    said = [_origin(top, names, dist, version, project.outside.get(top))
            for top, (names, dist, version) in sorted(outside.items())]
    if not outside:
        return []
    given = project.how == "given by --project"
    where = f"--project {project.repo}" if given else f"the project under test {project.repo} ({project.how})"
    if "tissuebench" in held:  # tissuebench's repository: its changes reach every method, a plugin's too
        return [f"not code of the project under test, the same package on both sides (the project's tissuebench "
                f"differs): {s}" for s in said]
    if len(outside) == len(packages):
        raise ValueError(f"--against {against}: {'; '.join(said)}, which {'is' if len(said) == 1 else 'are'} not "
                         f"inside {where}: REF's export of {project.repo} at {against} would run the same code on "
                         "both sides (every unit would hold whatever changed); give --project a path in the git "
                         "repository holding the source of the code under test")
    return [f"not code of the project under test, the same on both sides (their errors and steps are compared with "
            f"themselves): {s}" for s in said]
