"""The built-in trainings :func:`~tissuebench.testing.check_method` runs on: small catalogue
scenes at ci resolution, built by the harness itself (:func:`~tissuebench.studies.training.build_training`,
references from the content-hashed cache) and kept in this process once built.

Each contract case is a spec's ``[[case]]`` table with the evaluation the checks drive a model
through. A method is checked on the first case it applies to (:func:`primary_case`), in the
order of its ``training_kinds`` (a method that learns trajectories on a trajectory first, as
the sweep's dynamic scenes measure it), and its reconstruction also on ``prescribed`` (a cube
stretched by a prescribed displacement) when it applies there. The parameter contract runs on
the first of :data:`PARAMETER_BASES` it applies to.
"""
from __future__ import annotations

import copy
import functools
import json
from dataclasses import dataclass

from ..studies.applicability import evaluation_why_not, why_not
from ..studies.case_entry import CaseEntry
from ..studies.evaluation import NEEDS_MODEL, build_evaluation
from ..studies.training import build_training, case_scene

__all__ = ["CONTRACT_CASES", "PARAMETER_BASES", "ContractCase", "contract_case", "user_case", "primary_case",
           "parameter_base", "applies_to", "scene_of", "entry_dict", "forget"]

_PATH = {"name": "cornea_pinch", "training": {"kind": "path", "every": 2}}
_POSITIONS = {"name": "cornea_pinch", "training": {"kind": "positions", "positions": 3, "max_load_factor": 1.0,
                                                    "load_steps": 2}}
#: name -> the [[case]] table (its evaluation included) of every built-in contract case
CONTRACT_CASES = {
    "path": {**_PATH, "evaluation": {"kind": "path"}},  # a SVK cornea pinched: 657 dofs, 6 snapshots
    "prescribed": {"name": "cube_tension_twist", "variant": "tension", "training": {"kind": "path"},
                   "evaluation": {"kind": "path"}},  # a Mooney-Rivlin cube stretched by its supports
    "positions": {**_POSITIONS, "evaluation": {"kind": "map", "mus": [{"position": 0.5}]}},
    "operators": {"name": "heat1d_source", "training": {"kind": "operators"},
                  "evaluation": {"kind": "map", "mus": [{"position": 0.5}]}},
    "cut": {"name": "cornea_cut", "training": {"kind": "operators"},
            "evaluation": {"kind": "cut_lengths", "steps_per_length": 1}},
    "contact": {"name": "cornea_cut", "training": {"kind": "operators"},
                "evaluation": {"kind": "contact_nodes", "count": 1}},
    # the first 40 of the block's 400 steps: a Newton solve per step (corotational_fe) times 400, twice, is minutes
    "trajectory": {"name": "wave_block", "variant": "linear", "training": {"kind": "trajectory"},
                   "evaluation": {"kind": "trajectory", "t_end": 0.05}},
    "trajectory_1d": {"name": "frame_2dof", "training": {"kind": "trajectory"}, "evaluation": {"kind": "trajectory"}},
    "operators_dynamic": {"name": "wave_block", "variant": "linear", "training": {"kind": "operators"},
                          "evaluation": {"kind": "trajectory"}},
}
# per training kind, the contract cases a method learning from it is checked on, in order
_BY_KIND = {"path": ("path",), "positions": ("positions",), "trajectory": ("trajectory", "trajectory_1d"),
            "operators": ("operators", "cut", "contact", "operators_dynamic")}
#: the bases of the parameter contract, in order: (case table, its base evaluation); a changed
#: parameter is evaluated as a map (a trajectory: at another load_scale or t_end)
PARAMETER_BASES = [
    ({**_PATH}, {"kind": "map", "mus": [{}]}),
    ({**_POSITIONS}, {"kind": "map", "mus": [{"position": 0.5}]}),
    ({"name": "heat1d_source", "training": {"kind": "operators"}}, {"kind": "map", "mus": [{"position": 0.5}]}),
    ({"name": "cornea_cut", "training": {"kind": "operators"}}, {"kind": "cut_lengths", "steps_per_length": 1}),
    ({"name": "cornea_cut", "training": {"kind": "operators"}}, {"kind": "contact_nodes", "count": 1}),
    ({"name": "frame_2dof", "training": {"kind": "trajectory"}}, {"kind": "trajectory"}),
    ({"name": "wave_block", "variant": "linear", "training": {"kind": "operators"}}, {"kind": "trajectory"}),
    ({"name": "wave_block", "variant": "linear", "training": {"kind": "trajectory"}}, {"kind": "trajectory"}),
]


def entry_dict(table: dict) -> dict:
    """A [[case]] table in the dict form of a :class:`CaseEntry` (id "c", ci, skfem by default)."""
    return {"id": "c", "variant": None, "resolution": "ci", "backend": "skfem", **copy.deepcopy(table)}


@dataclass
class ContractCase:
    """A case the checks run on: its entry, scene and training (shared, never to be changed)."""

    name: str
    entry: CaseEntry
    scene: object
    training: object

    def evaluation(self, model=None):
        """The case's evaluation (a fresh one: the kinds measured at a model's nodes need it)."""
        if self.entry.evaluation_kind in NEEDS_MODEL:
            return build_evaluation(self.entry, self.scene, model)
        return _evaluation(self.name) if self.name in CONTRACT_CASES else build_evaluation(self.entry, self.scene)

    def history(self, evaluation):
        """The load history the harness drives ``evaluation`` with (:func:`~.units.run_unit`)."""
        return evaluation.history or self.training.history or (self.scene.history if evaluation.kind == "trajectory"
                                                               else None)


@functools.lru_cache(maxsize=None)
def _built(name: str) -> ContractCase:
    entry = CaseEntry.from_dict(entry_dict(CONTRACT_CASES[name]))
    scene = case_scene(entry)
    return ContractCase(name, entry, scene, build_training(entry, scene))


@functools.lru_cache(maxsize=None)
def _evaluation(name: str):
    case = _built(name)
    return build_evaluation(case.entry, case.scene)


def contract_case(name: str) -> ContractCase:
    """The built-in case ``name`` (:data:`CONTRACT_CASES`), built once per process."""
    if name not in CONTRACT_CASES:
        raise ValueError(f"training = {name!r}: not a built-in contract case; valid: {list(CONTRACT_CASES)}, or a "
                         "[[case]] table (a mapping: name, variant, training, evaluation)")
    return _built(name)


def forget() -> None:
    """Drop the built cases (a build changed a training: the next check gets fresh ones)."""
    _built.cache_clear()
    _evaluation.cache_clear()
    _user.cache_clear()


def user_case(table) -> ContractCase:
    """A contract case of a user's [[case]] table (a catalogue scene or a scene file, ci by default),
    built once per process."""
    if not isinstance(table, dict) or "name" not in table:
        raise TypeError(f"training = {table!r}: expected None, a built-in case name ({list(CONTRACT_CASES)}) or a "
                        "[[case]] table (a mapping with a name: a catalogue scene or a scene file)")
    return _user(json.dumps(table, sort_keys=True))


@functools.lru_cache(maxsize=4)
def _user(text: str) -> ContractCase:
    entry = CaseEntry.from_dict(entry_dict(json.loads(text)))
    scene = case_scene(entry)
    return ContractCase("user", entry, scene, build_training(entry, scene))


def applies_to(cls, table: dict, options=None) -> bool:
    """Whether method ``cls`` with ``options`` can be checked on the [[case]] ``table``: it learns
    from its training kind on its scene, represents its evaluation, and (cut lengths, contact
    nodes) is a model the evaluation is measured at."""
    entry = CaseEntry.from_dict(entry_dict(table))
    scene = _scene(entry)
    if why_not(cls, scene, entry.training_kind, options) or evaluation_why_not(cls, entry, scene):
        return False
    if entry.evaluation_kind in ("cut_lengths", "contact_nodes"):
        return entry.evaluation_kind == ("cut_lengths" if cls.applies.needs_cut else "contact_nodes")
    return True


def _scene(entry: CaseEntry):
    return _scenes(entry.name, entry.variant)


def scene_of(table: dict):
    """The scene of a [[case]] table (kept in this process)."""
    return _scene(CaseEntry.from_dict(entry_dict(table)))


@functools.lru_cache(maxsize=None)
def _scenes(name, variant):
    return case_scene(CaseEntry.from_dict(entry_dict({"name": name, "variant": variant})))


def primary_case(cls, options=None) -> str | None:
    """The built-in case a method is checked on (module docstring), or None when it applies to none."""
    kinds = list(cls.training_kinds)
    if "trajectory" in kinds:
        kinds.remove("trajectory")
        kinds.insert(0, "trajectory")
    for kind in kinds:
        for name in _BY_KIND.get(kind, ()):
            if applies_to(cls, CONTRACT_CASES[name], options):
                return name
    return None


def parameter_base(cls, options=None) -> tuple[dict, dict] | None:
    """The first of :data:`PARAMETER_BASES` the method applies to, or None."""
    for table, evaluation in PARAMETER_BASES:
        if applies_to(cls, {**table, "evaluation": evaluation}, options):
            return entry_dict(table), dict(evaluation)
    return None
