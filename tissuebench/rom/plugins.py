"""Methods from other packages, added to the one registry (:data:`~.registry.METHODS`).

Two ways in, as pytest (``pytest11``), Dask and fsspec find their third-party backends:

* an **entry point** of group ``tissuebench.methods`` in the installed distribution's
  metadata, ``name = "module:Class"`` (``[project.entry-points."tissuebench.methods"]`` in its
  ``pyproject.toml``): found when the registry is first read, once per process, in every
  process tissuebench starts (executors' workers, REF's sweep, the A/B workers), which read
  the same installed metadata;
* a **``"module:Class"`` name** wherever a method name is accepted (a spec's ``[[method]]
  name``, :func:`~.base.method_class`, ``tissuebench methods --method``): imported and
  registered under the class's ``name``. A sweep's units carry the class path as plain data
  (:attr:`~tissuebench.studies.units.WorkUnit.source`), so a worker process imports it too.

A plugin's ``name`` must be new: one that a shipped method (or another plugin) holds is
refused, naming both. A plugin that fails to load is named with its error
(:data:`FAILURES`, a :class:`PluginWarning`, a line of ``tissuebench methods``); the other
methods work; a ``SystemExit`` or ``KeyboardInterrupt`` its import raises fails it the same way
(:mod:`tissuebench.exits`: a real Ctrl-C still stops the command). :func:`third_party` is what
the unit key and the results store record of a method's code outside tissuebench: its
distribution, version and a hash of its package's ``.py`` files, so a resumed sweep recomputes
a plugin's units after its code changed.
"""
from __future__ import annotations

import functools
import hashlib
import importlib
import importlib.metadata
import importlib.util
import inspect
import re
import warnings
from dataclasses import dataclass
from pathlib import Path

from ..exits import EXIT_TYPES, exit_text, raised_by_code
from .base import check_method_class, method_class
from .registry import METHODS

__all__ = ["GROUP", "Plugin", "PLUGINS", "FAILURES", "PluginWarning", "load_entry_points", "load_source",
           "third_party", "source_of", "is_shipped", "origin"]

GROUP = "tissuebench.methods"
_SOURCE = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


class PluginWarning(UserWarning):
    """A plugin method could not be loaded (the message names it and its error)."""


@dataclass(frozen=True)
class Plugin:
    """Where a plugin method comes from."""

    name: str  # the registry name (the class's ``name``)
    source: str  # "module:Class"
    distribution: str | None  # the installed distribution that ships it (None: a module on sys.path)
    version: str | None
    how: str  # "entry point" or "module:Class"

    def describe(self) -> str:
        dist = f"distribution {self.distribution} {self.version}" if self.distribution else "no installed distribution"
        return f"{self.source} ({dist})"


#: name -> :class:`Plugin`, for every plugin method loaded in this process
PLUGINS: dict[str, Plugin] = {}
#: entry point name -> (what it is, its error), for every plugin that failed to load
FAILURES: dict[str, tuple[str, str]] = {}


def is_shipped(cls) -> bool:
    """True for a class of tissuebench itself."""
    return cls.__module__.split(".")[0] == "tissuebench"


def _where(cls) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def _add(cls, plugin: Plugin) -> None:
    """Register ``cls`` as ``plugin``; ValueError naming both when another class has its name."""
    existing = dict.get(METHODS, cls.name)
    if existing is cls and cls.name in PLUGINS:  # met again (a worker importing a unit's source): as first loaded
        return
    if existing is not None and existing is not cls and _where(existing) != _where(cls):
        other = PLUGINS.get(cls.name)
        holder = (f"the plugin method {cls.name!r} of {other.describe()}" if other is not None else
                  f"the {'shipped ' if is_shipped(existing) else ''}method {cls.name!r} ({_where(existing)})")
        raise ValueError(f"plugin method {cls.name!r} of {plugin.describe()} clashes with {holder}; give the plugin's "
                         "method another name (its class's name and its entry point)")
    dict.__setitem__(METHODS, cls.name, cls)
    PLUGINS[cls.name] = plugin


def _distribution_of(module: str) -> tuple[str | None, str | None]:
    """``(distribution, version)`` installed for the top-level package of ``module``, or (None, None)."""
    return _distribution_of_top(module.split(".")[0])


@functools.lru_cache(maxsize=None)
def _distribution_of_top(top: str) -> tuple[str | None, str | None]:
    # once per process and package: packages_distributions() reads every installed distribution
    names = importlib.metadata.packages_distributions().get(top) or []
    for name in names:
        try:
            return name, importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            continue
    return None, None


def load_entry_points(registry=METHODS) -> None:
    """Add every method of group :data:`GROUP` to the registry (:mod:`.registry` runs it at its
    first read); a plugin that fails is recorded in :data:`FAILURES` and warned about."""
    seen = set()
    for ep in importlib.metadata.entry_points(group=GROUP):
        if (ep.name, ep.value) in seen:  # one distribution found twice on the path
            continue
        seen.add((ep.name, ep.value))
        dist = getattr(ep, "dist", None)
        plugin = Plugin(ep.name, ep.value, dist.name if dist else None, dist.version if dist else None,
                        "entry point")
        try:
            cls = ep.load()
            check_method_class(cls, f"entry point {ep.name} = {ep.value!r}")
            if cls.name != ep.name:
                raise ValueError(f"the entry point is named {ep.name!r} but {cls.__qualname__}.name = {cls.name!r}; "
                                 "give both the same name")
            _add(cls, plugin)
        except (Exception, *EXIT_TYPES) as exc:  # noqa: BLE001 - a broken plugin is named; the other methods work
            if not isinstance(exc, Exception) and not raised_by_code(exc):
                raise  # the user's Ctrl-C while the plugin loaded (tissuebench.exits)
            error = f"{type(exc).__name__}: {exc}" if isinstance(exc, Exception) else exit_text(exc, "its code")
            FAILURES[ep.name] = (plugin.describe(), error)
            warnings.warn(f"plugin method {ep.name!r} of {plugin.describe()} could not be loaded: {error}; the other "
                          "methods are unaffected", PluginWarning, stacklevel=3)


def load_source(source: str) -> type:
    """The class a ``"module:Class"`` name points to, imported and registered (ValueError naming
    the name and what is wrong: not importable, no such attribute, not a method, a clash)."""
    if not isinstance(source, str) or not _SOURCE.fullmatch(source):
        raise ValueError(f"method {source!r}: expected 'module:Class' (a dotted module path, ':', a class name)")
    module, qualname = source.split(":")
    len(METHODS)  # the installed plugins first: a name clash with one of them is found either way
    try:
        obj = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        raise ValueError(f"method {source!r}: cannot import {module!r} ({exc}); install its package (pip install -e "
                         "FOLDER) or put its folder on PYTHONPATH") from None
    except (Exception, *EXIT_TYPES) as exc:  # noqa: BLE001 - the plugin's own import error, named
        if not isinstance(exc, Exception) and not raised_by_code(exc):
            raise  # the user's Ctrl-C while it was imported (tissuebench.exits)
        error = f"{type(exc).__name__}: {exc}" if isinstance(exc, Exception) else exit_text(exc, "its code")
        raise ValueError(f"method {source!r}: importing {module!r} failed: {error}") from None
    for part in qualname.split("."):
        if not hasattr(obj, part):
            raise ValueError(f"method {source!r}: {obj.__name__ if hasattr(obj, '__name__') else module!r} has no "
                             f"attribute {part!r}")
        obj = getattr(obj, part)
    check_method_class(obj, f"method {source!r}")
    if is_shipped(obj) and dict.get(METHODS, obj.name) is obj:
        return obj  # a shipped method by its class path
    _add(obj, Plugin(obj.name, source, *_distribution_of(module), "module:Class"))
    return obj


def source_of(cls) -> str:
    """``"module:Class"`` of a method class that a fresh process can import ("" for a shipped
    method, found by name everywhere, and for a class of ``__main__``, which another process
    cannot import)."""
    if is_shipped(cls) or cls.__module__ in ("__main__", "__mp_main__") or "<locals>" in cls.__qualname__:
        return ""
    return f"{cls.__module__}:{cls.__qualname__}"


@functools.lru_cache(maxsize=None)
def _files_hash(top: str) -> str | None:
    """SHA-256 over the ``.py`` files of top-level package (or module) ``top``, None when it has none
    on disk. Once per process: the code a process runs is the code it imported."""
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):  # __main__ of an interactive session, a module without a spec
        return None
    if spec is None:
        return None
    roots = [Path(p) for p in (spec.submodule_search_locations or [])]
    files = sorted(f for r in roots for f in r.rglob("*.py") if "__pycache__" not in f.parts)
    if not roots and spec.origin and spec.origin.endswith(".py"):
        roots, files = [Path(spec.origin).parent], [Path(spec.origin)]
    if not files:
        return None
    h = hashlib.sha256()
    for f in files:
        rel = next(str(f.relative_to(r)) for r in roots if f.is_relative_to(r))
        h.update(rel.encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def third_party(method) -> dict:
    """What the unit key and the store record of a method's code outside tissuebench: ``{}`` for
    a shipped method, else ``source`` ("module:Class"), ``distribution``, ``version`` (None when
    its package is not an installed distribution) and ``code_hash`` (its package's ``.py`` files)."""
    cls = method_class(method)
    if is_shipped(cls):
        return {}
    plugin = PLUGINS.get(cls.name)
    dist, version = (plugin.distribution, plugin.version) if plugin else _distribution_of(cls.__module__)
    top = cls.__module__.split(".")[0]
    module = inspect.getmodule(cls)
    code = _files_hash(top) if getattr(module, "__file__", None) else None
    return {"source": plugin.source if plugin else f"{cls.__module__}:{cls.__qualname__}", "distribution": dist,
            "version": version, "code_hash": code}


def origin(name: str) -> str:
    """Where method ``name`` comes from, for listings: ``""`` (shipped), or ``"plugin DIST VERSION
    (module:Class)"``."""
    plugin = PLUGINS.get(name)
    if plugin is not None:
        dist = f"{plugin.distribution} {plugin.version}" if plugin.distribution else "no installed distribution"
        return f"plugin {dist} ({plugin.source})"
    cls = dict.get(METHODS, name)
    return "" if cls is None or is_shipped(cls) else f"registered in this process ({_where(cls)})"
