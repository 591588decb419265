"""The method registry: one mapping of names to :class:`~.base.RomMethod` classes.

The shipped methods register themselves when :mod:`tissuebench.rom` imports their modules
(:func:`register`). Methods of other packages are added to the same mapping when it is first
read (:mod:`.plugins`: the entry points of group ``tissuebench.methods``, once per process)
or when a ``"module:Class"`` name is looked up (:func:`method_class`). Nothing downstream
tells a plugin from a shipped method: it reads :data:`METHODS`, or calls :func:`method_class`.
"""
from __future__ import annotations

import re
import threading

__all__ = ["METHODS", "MethodRegistry", "register", "method_class", "make_method", "METHOD_NAME", "check_method_class"]

#: a method's registry name: it names a folder of the results store (``method=<name>``)
METHOD_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_.-]{0,99}")


class MethodRegistry(dict):
    """``name -> RomMethod class``. Every read (lookup, ``in``, iteration, ``len``) first runs the
    loader :mod:`tissuebench.rom` arms once its shipped methods are registered (the installed
    plugins: :func:`.plugins.load_entry_points`), once per process."""

    def __init__(self):
        super().__init__()
        self._loader, self._loading, self._lock = None, False, threading.RLock()

    def arm(self, loader) -> None:
        """Run ``loader(self)`` at the next read (once)."""
        self._loader = loader

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


def _where(cls) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def check_method_class(cls, what: str = "register") -> None:
    """TypeError, naming ``what``, for a class that is not a registrable method: not a named
    :class:`~.base.RomMethod` subclass (the name must suit a folder name: letters, digits,
    ``_ . -``, starting with a letter), an unknown ``kind``, or abstract methods left."""
    import inspect

    from .base import MODEL_KINDS, RomMethod

    if not (isinstance(cls, type) and issubclass(cls, RomMethod) and cls.name):
        raise TypeError(f"{what}: {cls!r} is not a named RomMethod subclass (tissuebench.rom.RomMethod with a "
                        "class attribute name)")
    if not isinstance(cls.name, str) or not METHOD_NAME.fullmatch(cls.name):
        raise TypeError(f"{what}: {cls.__qualname__}.name = {cls.name!r}: expected a letter then letters, digits, "
                        "'_', '.' or '-' (it names a results folder)")
    if cls.kind not in MODEL_KINDS:
        raise TypeError(f"{what}: {cls.__name__}.kind = {cls.kind!r}; valid: {MODEL_KINDS}")
    if inspect.isabstract(cls):
        raise TypeError(f"{what}: {cls.__qualname__} does not implement {sorted(cls.__abstractmethods__)}")


def register(cls):
    """Class decorator: add a :class:`~.base.RomMethod` to :data:`METHODS` under ``cls.name``.

    TypeError for a class :func:`check_method_class` refuses; ValueError when another class is
    registered under that name (both named)."""
    check_method_class(cls)
    existing = dict.get(METHODS, cls.name)
    # the same class imported again (importlib.reload, a test module re-run) is the same method
    if existing is not None and existing is not cls and _where(existing) != _where(cls):
        shipped = "the shipped method" if existing.__module__.split(".")[0] == "tissuebench" else "the method"
        raise ValueError(f"method name {cls.name!r} of {_where(cls)} is taken by {shipped} {cls.name!r} "
                         f"({_where(existing)}); rename one of them")
    METHODS[cls.name] = cls
    return cls


def method_class(method) -> type:
    """The :class:`~.base.RomMethod` class of a registry name, a ``"module:Class"`` name (imported
    and registered: :func:`.plugins.load_source`) or a class."""
    from .base import RomMethod

    if isinstance(method, type) and issubclass(method, RomMethod):
        return method
    if isinstance(method, str) and ":" in method:
        from .plugins import load_source

        return load_source(method)
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"unknown ROM method {method!r}; valid: {sorted(METHODS)} (or 'module:Class' of a method "
                         "in another package)")
    return METHODS[method]


def make_method(method, **options):
    """A :class:`~.base.RomMethod` from its registry name, ``"module:Class"`` name or class, with ``options``."""
    from .base import RomMethod

    if isinstance(method, RomMethod):
        if options:
            raise TypeError("make_method: options given with an instance")
        return method
    cls = method_class(method)
    cls.check_options(options)
    return cls(**options)
