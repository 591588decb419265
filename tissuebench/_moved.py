"""The old import paths of names that moved (issue 55), kept for one release with a DeprecationWarning.

A module whose names moved keeps its file, reduced to ``__getattr__ = moved(__name__, NEW)``:
reading one of those names there (``from tissuebench.studies.ab_stats import verdicts``) imports
it from its new module at that moment, warns ``DeprecationWarning`` naming both paths, and
returns the same object. The new module is named by a string, so the old one imports nothing
of the layers above it and no two files import each other; nothing in tissuebench reads an old
path (``tests/test_layers.py`` checks both). The old paths go in the next release.
"""
from __future__ import annotations

import importlib
import warnings

__all__ = ["moved"]


def moved(old: str, new):
    """The module ``__getattr__`` of module ``old`` whose names moved to ``new``: a module name
    (every name moved there) or ``{name: module name}`` (those names only). A name the new module
    lacks, or any other, raises AttributeError as a missing attribute of ``old`` does."""

    def __getattr__(name: str):
        target = new.get(name) if isinstance(new, dict) else new
        if target is None or name.startswith("__"):  # dunders (``__all__``, ``__path__``) are the old module's own
            raise AttributeError(f"module {old!r} has no attribute {name!r}")
        try:
            value = getattr(importlib.import_module(target), name)
        except AttributeError:
            raise AttributeError(f"module {old!r} has no attribute {name!r} (its names moved to {target!r})") from None
        warnings.warn(f"{old}.{name} moved to {target}.{name}: import it from there ({old} keeps it for one "
                      "release)", DeprecationWarning, stacklevel=2)
        return value

    return __getattr__
