"""The case entry of a sweep: one ``[[case]]`` of a spec, validated, as typed data.

:func:`~.spec.load_spec` checks every ``[[case]]`` table against the catalogue, the scene and
the training and evaluation kinds (:mod:`.kinds`) and builds one :class:`CaseEntry` of it;
everything downstream (units, training and evaluation builders, executors) reads its fields.
Its dict form (:meth:`CaseEntry.as_dict`) is what a unit's key hashes (:func:`~.units.unit_key`),
what ``_sweep.json`` records under ``cases`` and what the A/B probe hands to the code under
test: exactly the dict the spec produced before the entry was typed, so keys and stored
results do not move.
"""
from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import dataclass, fields

from ..cases.schema import value_text
from .evaluation import EVALUATION_KINDS
from .training import TRAINING_KINDS

__all__ = ["CaseEntry", "fill_training_kind", "fill_evaluation_kind"]

# the keys present in the dict form only when the spec gave them (absent, not None)
_OPTIONAL = ("mu", "mesh", "paper_points", "scaling_group")


def fill_training_kind(training: dict, where: str = "training") -> str:
    """``training["kind"]``, set to ``"path"`` (in place) when absent; ValueError naming
    ``<where>.kind`` and the value when it is not a training kind. The one place the default and
    the check live: the spec's loader and the entry's constructor both call it."""
    kind = training.setdefault("kind", "path")
    if not isinstance(kind, str) or kind not in TRAINING_KINDS:
        raise ValueError(f"{where}.kind = {value_text(kind)}: valid: {list(TRAINING_KINDS)}")
    return kind


def fill_evaluation_kind(evaluation: dict, training_kind: str, where: str = "evaluation") -> str:
    """``evaluation["kind"]``, set (in place) when absent to the training's kind where that is an
    evaluation kind, else ``"map"``; ValueError naming ``<where>.kind`` and the value when it is
    not an evaluation kind."""
    kind = evaluation.setdefault("kind", training_kind if training_kind in EVALUATION_KINDS else "map")
    if not isinstance(kind, str) or kind not in EVALUATION_KINDS:
        raise ValueError(f"{where}.kind = {value_text(kind)}: valid: {list(EVALUATION_KINDS)}")
    return kind


def _need(name, value, types, what):
    if not isinstance(value, types) or isinstance(value, bool):
        raise ValueError(f"{name} = {value_text(value)}: expected {what}")


@dataclass(frozen=True)
class CaseEntry:
    """One validated case of a sweep spec (the spec's ``[[case]]`` table, defaults filled in).

    Built by :func:`~.spec.load_spec`, which checks every value against the catalogue, the scene
    and the kinds and names the key and the value it refuses; the constructor checks only the
    types of the fields (a :class:`ValueError` naming the field and the value), so that an entry made in code
    (a test, :meth:`from_dict`) is well formed. Frozen; ``training``, ``evaluation``, ``mu`` and
    ``mesh`` are plain dicts (picklable for the dask executor): read them, never change them.

    Attributes
    ----------
    id : str
        The case's id in the spec: names its results folder (``case=<id>``) and its rows
        (column ``case``); letters, digits, ``_``, ``.``, ``-``.
    name : str
        Catalogue case name, or the path of a scene file (absolute where the spec named it
        relative to its own folder).
    variant : str or None
        The scene's variant (catalogue variants, e.g. ``"tension"``), None for the default.
    resolution : str
        Mesh resolution, ``"ci"`` or ``"paper"`` (:data:`~tissuebench.cases.scene.RESOLUTIONS`).
    backend : str
        FE backend of the references and of the methods' operators: ``"skfem"`` or ``"ngsolve"``.
    training : dict
        What the methods learn from: ``{"kind": <training kind>, <its options>}``; the kinds and
        their options are those of :data:`~.training.TRAINING_KINDS` (e.g. ``every``: states,
        ``positions``: a count or positions in the scene's position unit).
    evaluation : dict
        Where they are measured: ``{"kind": <evaluation kind>, <its options>}``
        (:data:`~.evaluation.EVALUATION_KINDS`; default kind: :func:`default_evaluation_kind`).
    mu : dict or None
        Scene parameters (``Scene.at``, in the scene's units, e.g. ``{"nu": 0.499}``) the case is
        trained and measured at; None: the scene's own.
    mesh : dict or None
        Mesh builder parameters per resolution (``{"paper": {"divisions": [40, 7, 7]}}``); None:
        the catalogue's mesh.
    paper_points : list of dict or None
        Published configurations ``{label, step_ms [ms], error [-]}`` drawn beside the case's
        Pareto front at paper resolution.
    scaling_group : str or None
        This scene on several meshes: the cost-versus-size fits of :mod:`.scaling`.
    """

    id: str
    name: str
    variant: str | None = None
    resolution: str = "ci"
    backend: str = "skfem"
    training: dict | None = None
    evaluation: dict | None = None
    mu: dict | None = None
    mesh: dict | None = None
    paper_points: list | None = None
    scaling_group: str | None = None

    def __post_init__(self):
        for name in ("id", "name", "resolution", "backend"):
            _need(name, getattr(self, name), str, "a string")
        for name in ("variant", "scaling_group"):
            if getattr(self, name) is not None:
                _need(name, getattr(self, name), str, "a string or None")
        for name in ("mu", "mesh"):
            if getattr(self, name) is not None:
                _need(name, getattr(self, name), dict, "a table or None")
        if self.paper_points is not None:
            _need("paper_points", self.paper_points, list, "a list of tables or None")
        training = {"kind": "path"} if self.training is None else self.training
        _need("training", training, Mapping, "a table with a kind")
        training = dict(training)
        kind = fill_training_kind(training)
        evaluation = {} if self.evaluation is None else self.evaluation
        _need("evaluation", evaluation, Mapping, "a table")
        evaluation = dict(evaluation)
        fill_evaluation_kind(evaluation, kind)
        object.__setattr__(self, "training", training)
        object.__setattr__(self, "evaluation", evaluation)

    @property
    def training_kind(self) -> str:
        """``training["kind"]``: the training kind's name."""
        return self.training["kind"]

    @property
    def evaluation_kind(self) -> str:
        """``evaluation["kind"]``: the evaluation kind's name."""
        return self.evaluation["kind"]

    def training_options(self) -> dict:
        """The training table without its ``kind`` (a copy): the options its kind reads."""
        return {k: v for k, v in self.training.items() if k != "kind"}

    def evaluation_options(self) -> dict:
        """The evaluation table without its ``kind`` (a copy): the options its kind reads."""
        return {k: v for k, v in self.evaluation.items() if k != "kind"}

    def mesh_at_resolution(self) -> dict | None:
        """The mesh builder parameters at this entry's resolution, or None."""
        return (self.mesh or {}).get(self.resolution)

    def as_dict(self) -> dict:
        """The entry as the spec wrote it before it was typed (a deep copy): ``id, name, variant,
        resolution, backend, training, evaluation`` then, only where given, ``mu, mesh,
        paper_points, scaling_group``, in that order. What unit keys hash and ``_sweep.json`` stores."""
        out = {"id": self.id, "name": self.name, "variant": self.variant, "resolution": self.resolution,
               "backend": self.backend, "training": self.training, "evaluation": self.evaluation}
        out.update({k: getattr(self, k) for k in _OPTIONAL if getattr(self, k) is not None})
        return copy.deepcopy(out)

    @classmethod
    def from_dict(cls, data: Mapping) -> CaseEntry:
        """The entry of a dict form (:meth:`as_dict`, a ``_sweep.json`` case, an A/B job); a key
        that is not a field is refused, naming it."""
        if not isinstance(data, Mapping):
            raise TypeError(f"case entry = {data!r}: expected a table")
        names = [f.name for f in fields(cls)]
        for key in data:
            if key not in names:
                raise TypeError(f"case entry.{key}: unknown key (valid: {names})")
        return cls(**copy.deepcopy(dict(data)))
