"""How a family's model grows in ``tissuebench fit`` once more training no longer helps (:mod:`.loop`).

Two axes, both tried in the same round: the **size** (``n_modes``, ``pod_modes``, ``handles``:
:data:`.specs.SIZE_KEYS`), along the generated grid and then by :data:`GROWTH` up to
:data:`MAX_GROWTH` times the grid's largest (:func:`next_size`); and a **refinement** at that size,
which a method declares in its contract (:attr:`~tissuebench.rom.base.RomMethod.refinements`, e.g.
ECSW's tolerance halved: more elements in the cubature), up to :data:`MAX_REFINEMENTS` times
(:func:`next_refinement`). A plugin's method declares its own the same way; the fit reads nothing
else of it.
"""
from __future__ import annotations

import math

from ...rom.base import method_class

__all__ = ["next_size", "next_refinement", "refinements_kept", "GROWTH", "MAX_GROWTH", "MAX_REFINEMENTS"]

#: past its grid, a size grows by this factor (rounded up for an integer option)
GROWTH = 1.5
#: the largest size a fit tries, as a multiple of the grid's largest
MAX_GROWTH = 4.0
#: refinements of a family's model a fit tries at most (ECSW: the tolerance down to 1/8 of the lead's)
MAX_REFINEMENTS = 3


def next_size(family, current):
    """The family's next model size after ``current``: the next larger value of its grid, then
    ``GROWTH`` times the current one (an integer rounded up), up to ``MAX_GROWTH`` times the
    grid's largest; None past it or without a size option."""
    if not family.size_key or current is None:
        return None
    values = sorted(family.grid.get(family.size_key, [family.options.get(family.size_key, current)]))
    larger = [v for v in values if v > current]
    if larger:
        return larger[0]
    grown = math.ceil(current * GROWTH) if isinstance(current, int) else float(current) * GROWTH
    return grown if grown <= MAX_GROWTH * max(values) else None


def next_refinement(method, options: dict, done: int = 0):
    """``(option, value)``: the next refinement of the model ``method`` builds with ``options``, the
    first option of its :meth:`~tissuebench.rom.base.RomMethod.refinements_for` ``options`` with a
    positive number for value (``options``' own, else the constructor's default) times its factor;
    None when the method declares none for these options or ``done`` refinements reached
    :data:`MAX_REFINEMENTS`."""
    if done >= MAX_REFINEMENTS:
        return None
    cls = method_class(method)
    for key, factor in cls.refinements_for(dict(options)).items():
        value = options.get(key, cls.option_defaults().get(key))
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            continue
        if isinstance(value, int):
            refined = math.ceil(value * factor) if factor > 1 else math.floor(value * factor)
            if refined != value and refined > 0:
                return key, int(refined)
            continue
        return key, float(f"{value * factor:.12g}")
    return None


def refinements_kept(curve: list, refine_key) -> int:
    """How many growths of a family's learning ``curve`` were refinements of ``refine_key`` that
    became the lead (a refinement measured and not kept does not count)."""
    return sum(bool(refine_key) and p.get("grew") == refine_key and not p.get("dropped") for p in curve)
