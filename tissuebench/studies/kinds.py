"""The contract of a training or an evaluation kind (``training = { kind = "path", every = 2 }``).

A kind declares what a case entry's table may hold (``keys``, besides ``kind``), how those
values are checked against the scene (``check``), what it builds (``build``), which reference
runs it reads, known from the case entry alone (``references``: the dask executor computes each
as a task, :mod:`.executors`), and, for a training, the scene analysis it learns from; for an
evaluation, whether it is built after the model (``needs_model``: the incision strip, the
contact nodes). The registries are :data:`.training.TRAINING_KINDS` and
:data:`.evaluation.EVALUATION_KINDS`; the spec (:mod:`.spec`), the applicability rules and the
units read every kind through them, so a new kind is one function set and one registry entry.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

__all__ = ["Kind", "the_scene", "no_references"]


@dataclass(frozen=True)
class Kind:
    """One training or evaluation kind.

    Attributes
    ----------
    name : str
    keys : frozenset of str
        The options of its table (``kind`` aside); any other key is refused, naming it.
    build : callable
        Training: ``(scene, case, options, info) -> Training``; evaluation:
        ``(scene, case, options, model) -> Evaluation`` (``options``: the table without ``kind``).
    references : callable
        ``(case, scene) -> list of Scene``: the reference runs ``build`` reads, nothing solved.
    check : callable
        ``(path, table, scene, training) -> None``: ValueError naming ``path.key`` and the value
        (``training``: the case's training table, for an evaluation that depends on it).
    analysis : str or None
        Training: the scene analysis it learns from (``"static"``, ``"dynamic"``; None: the
        method's model kind decides).
    needs_model : bool
        Evaluation: built after the model.
    """

    name: str
    keys: frozenset
    build: Callable
    references: Callable
    check: Callable
    analysis: str | None = None
    needs_model: bool = False


def the_scene(case: dict, scene) -> list:
    """``Kind.references`` of a kind that reads the scene's own reference run (a path)."""
    return [scene]


def no_references(case: dict, scene) -> list:
    """``Kind.references`` of a kind that reads none, or none known before the model is built."""
    return []
