"""The method registry: one mapping of names to :class:`~.base.RomMethod` classes.

The shipped methods register themselves when :mod:`tissuebench.rom` imports their modules
(:func:`~.base.register`). Methods of other packages are added to the same mapping when it is
first read (:mod:`.plugins`: the entry points of group ``tissuebench.methods``, once per process)
or when a ``"module:Class"`` name is looked up (:func:`~.base.method_class`). Nothing downstream
tells a plugin from a shipped method: it reads :data:`METHODS`, or calls :func:`~.base.method_class`.

This module is the contract below the method contract (:mod:`.base`, whose :func:`~.base.register`
checks a class before it is added) and the plugins (:mod:`.plugins`): it imports neither. What
it needs of the plugins, :mod:`tissuebench.rom` hands it (:meth:`MethodRegistry.arm`: the
entry points; :meth:`MethodRegistry.arm_sources`: the ``"module:Class"`` loader).
``register``, ``method_class``, ``make_method`` and ``check_method_class`` moved to :mod:`.base`
(issue 55); their old path here works for one release, with a DeprecationWarning.
"""
from __future__ import annotations

import re
import threading

from .._moved import moved

__all__ = ["METHODS", "MethodRegistry", "METHOD_NAME"]

__getattr__ = moved(__name__, {name: "tissuebench.rom.base" for name in
                               ("register", "method_class", "make_method", "check_method_class")})

#: a method's registry name: it names a folder of the results store (``method=<name>``)
METHOD_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_.-]{0,99}")


class MethodRegistry(dict):
    """``name -> RomMethod class``. Every read (lookup, ``in``, iteration, ``len``) first runs the
    loader :mod:`tissuebench.rom` arms once its shipped methods are registered (the installed
    plugins: :func:`.plugins.load_entry_points`), once per process."""

    def __init__(self):
        super().__init__()
        self._loader, self._loading, self._lock = None, False, threading.RLock()
        self._source_loader = None

    def arm(self, loader) -> None:
        """Run ``loader(self)`` at the next read (once)."""
        self._loader = loader

    def arm_sources(self, load) -> None:
        """``load("module:Class") -> class``: how :meth:`load_source` imports a method of another
        package and adds it here (:func:`.plugins.load_source`, armed by :mod:`tissuebench.rom`)."""
        self._source_loader = load

    def load_source(self, source: str) -> type:
        """The method class a ``"module:Class"`` name points to, imported and registered by the
        loader :meth:`arm_sources` armed (its ValueError naming the name and what is wrong)."""
        if self._source_loader is None:  # tissuebench.rom arms it as it is imported: never seen downstream
            raise RuntimeError(f"method {source!r}: no loader of 'module:Class' names is armed (import "
                               "tissuebench.rom)")
        return self._source_loader(source)

    def _load(self) -> None:
        if self._loader is None:  # loaded: the common case, without the lock
            return
        with self._lock:  # another thread reading meanwhile waits for the whole registry
            if self._loader is None or self._loading:  # a plugin's import reading the registry it is loaded into
                return
            self._loading = True
            try:
                self._loader(self)
            finally:
                self._loader, self._loading = None, False

    def __getitem__(self, name):
        self._load()
        return super().__getitem__(name)

    def __contains__(self, name) -> bool:
        self._load()
        return super().__contains__(name)

    def __iter__(self):
        self._load()
        return super().__iter__()

    def __len__(self) -> int:
        self._load()
        return super().__len__()

    def get(self, name, default=None):
        self._load()
        return super().get(name, default)

    def keys(self):
        self._load()
        return super().keys()

    def values(self):
        self._load()
        return super().values()

    def items(self):
        self._load()
        return super().items()


METHODS: MethodRegistry = MethodRegistry()
