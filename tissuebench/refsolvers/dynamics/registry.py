"""Registry of the time integrators, by name."""
from __future__ import annotations

import inspect

from .base import Integrator
from .explicit import CentralDifference, ForwardEuler
from .implicit import HHT, BackwardEuler, Bathe, Newmark

INTEGRATORS: dict[str, type[Integrator]] = {
    "hht": HHT,
    "bathe": Bathe,
    "newmark": Newmark,
    "backward_euler": BackwardEuler,
    "central_difference": CentralDifference,
    "forward_euler": ForwardEuler,
}


def make_integrator(name_or_class, **opts) -> Integrator:
    """A configured (not yet started) integrator.

    Parameters
    ----------
    name_or_class : str, Integrator subclass or Integrator instance
        A key of :data:`INTEGRATORS`, a class, or an instance (returned as is; then
        ``opts`` must be empty).
    **opts
        Options of the integrator's constructor (e.g. ``alpha`` for HHT,
        ``force`` for central difference, ``newton_rtol``/``newton_max_iter``).
    """
    if isinstance(name_or_class, Integrator):
        if opts:
            raise ValueError(f"options {sorted(opts)} given with an already configured integrator")
        return name_or_class
    if isinstance(name_or_class, type) and issubclass(name_or_class, Integrator):
        if inspect.isabstract(name_or_class):
            raise ValueError(f"{name_or_class.__name__} is abstract (it does not implement _advance); "
                             f"valid: {sorted(INTEGRATORS)} or a subclass that implements it")
        cls = name_or_class
    elif isinstance(name_or_class, str) and name_or_class in INTEGRATORS:
        cls = INTEGRATORS[name_or_class]
    else:
        raise ValueError(f"unknown integrator {name_or_class!r}; valid: {sorted(INTEGRATORS)}")
    try:  # a misspelt option is bad input, reported like the others
        inspect.signature(cls).bind(**opts)
    except TypeError as exc:
        raise ValueError(f"{cls.__name__}: {exc}") from None
    return cls(**opts)
