"""The reference layer's in-process memo: one object, bounded tables per purpose.

Reference work that a sweep's units of one scene share is done once per process and kept
here, never in module dictionaries scattered through the harness (issue 29): the timed
reference step (:mod:`.step_timing`), the semi-discrete systems it and the energy drift
integrate, the linear FE of every cut length of a strip (:mod:`.cut`) and the solves of the
external anchors (:mod:`.anchors`). Each purpose has a bound on how many entries it keeps,
the oldest inserted going first (a sweep runs its units case by case, so the last scene's
entries are the ones still asked for); ``None`` keeps every entry (small values: a float of
seconds, a row of monitors). The on-disk, content-hashed cache of whole reference runs is
another thing (:mod:`.cache`).
"""
from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable

__all__ = ["Memo", "MEMO"]


class Memo:
    """Bounded per-purpose tables of computed values.

    Parameters
    ----------
    bounds : dict
        ``{purpose: how many entries it keeps (None: all)}``; the purposes are fixed here.
    """

    def __init__(self, bounds: dict):
        for purpose, bound in bounds.items():
            if bound is not None and (isinstance(bound, bool) or not isinstance(bound, int) or bound < 1):
                raise ValueError(f"Memo: bound of {purpose!r} = {bound!r}: expected a positive integer or None")
        self._bounds = dict(bounds)
        self._tables = {purpose: OrderedDict() for purpose in bounds}

    def _table(self, purpose: str) -> OrderedDict:
        if purpose not in self._tables:
            raise ValueError(f"Memo: purpose = {purpose!r}: not one of {sorted(self._tables)}")
        return self._tables[purpose]

    def get(self, purpose: str, key: Hashable, compute: Callable):
        """The value of ``key`` for ``purpose``: kept from an earlier call, else ``compute()``
        (then kept, the oldest entries of ``purpose`` dropped past its bound). A ``compute``
        that raises keeps nothing."""
        table = self._table(purpose)
        if key in table:
            return table[key]
        value = compute()
        table[key] = value
        bound = self._bounds[purpose]
        while bound is not None and len(table) > bound:
            table.popitem(last=False)
        return value

    def __contains__(self, item) -> bool:
        purpose, key = item
        return key in self._table(purpose)

    def sizes(self) -> dict:
        """``{purpose: number of entries kept}``."""
        return {purpose: len(table) for purpose, table in self._tables.items()}

    def clear(self, purpose: str | None = None) -> None:
        """Forget every entry of ``purpose`` (of every purpose without one)."""
        for table in ([self._table(purpose)] if purpose is not None else self._tables.values()):
            table.clear()


#: the one memo of the reference layer: reference-step seconds per (scene, backend, samples),
#: the last two dynamics systems, the cut references of the last strip, the anchors' solves, the
#: locking indicators of the last scenes (two linear solves each, asked by the plan and the check)
MEMO = Memo({"reference_step": None, "dynamics_system": 2, "cut_references": 1, "anchors": None, "locking": 64})
