"""The parameters a model's step reads, rule by rule on plain objects (issue 50, item 10: the
mutation testing of rom/reads.py): the training kind each training says it is, the keys declared
from the method's reads, the model's own step parameters and the time, the refusal's message, and
the first step's check putting back exactly the step the model had. The contract's use of it on
every shipped method: tests/rom/test_step_reads.py."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from tissuebench.rom import reads


@pytest.mark.parametrize("fields, kind", [
    ({"info": {"training_kind": "positions"}, "trajectories": [0]}, "positions"),  # what the harness recorded
    ({"info": {"training_kind": 3}, "trajectories": [0]}, "trajectory"),  # not a name: the fields decide
    ({"info": None, "trajectories": [0], "groups": [1]}, "trajectory"),
    ({"groups": [1], "snapshots": None}, "positions"),
    ({"groups": [], "snapshots": None}, "operators"),
    ({"snapshots": [[0.0]]}, "path"),
    ({}, "operators"),
])
def test_training_kind(fields, kind):
    assert reads.training_kind(SimpleNamespace(**fields)) == kind


class _Model:
    """A model whose step returns what it was given, with its own step parameters."""

    def __init__(self, kind="map", own=()):
        self.kind, self._own, self.steps = kind, own, []

    def step_parameters(self):
        return self._own

    def step(self, mu):
        self.steps.append(dict(mu))
        return "stepped"


class _Method:
    name = "toy"
    applies = SimpleNamespace(parameters={"path": ("E",), "trajectory": ("nu",)})
    asked = []

    @classmethod
    def reads(cls, scene, kind):
        cls.asked.append((scene, kind))
        return ("position",)


@pytest.mark.parametrize("model_kind, training, keys", [
    ("map", {"snapshots": [[0.0]]}, {"load_factor", "E", "node"}),  # no scene: the applies' parameters of the kind
    ("map", {"trajectories": [0]}, {"load_factor", "nu", "time", "node"}),  # trained on trajectories: the time
    ("trajectory", {"snapshots": [[0.0]]}, {"load_factor", "E", "time", "node"}),  # stepped in time: the time
    ("map", {"snapshots": [[0.0]], "scene": "S"}, {"load_factor", "position", "node"}),  # the method's reads
])
def test_declare_records_the_keys_and_the_method(model_kind, training, keys):
    _Method.asked = []
    model = _Model(model_kind, own=("node",))
    reads.declare(model, _Method, SimpleNamespace(**training))
    assert reads.reads_of(model) == frozenset(keys) and model._tb_reads[1] == "toy"
    assert _Method.asked == ([("S", "path")] if "scene" in training else [])
    assert isinstance(model.step, reads._FirstStep)  # the next step is checked


def _declared(keys=("load_factor",), model=None):
    model = model or _Model()
    object.__setattr__(model, reads._DECLARED, (frozenset(keys), "toy"))
    return model


def test_refuse_unread_names_the_first_unread_key_its_value_and_what_the_method_reads():
    model = _declared(("load_factor", "time", 7))
    reads.refuse_unread(model, {"load_factor": 0.5, "time": 1.0}, "step")  # read: nothing said
    reads.refuse_unread(model, [("E", 1.0)], "step")  # not a mapping: the step's own parsing refuses it
    reads.refuse_unread(_Model(), {"E": 1.0}, "step")  # nothing declared: nothing checked
    with pytest.raises(ValueError) as err:
        reads.refuse_unread(model, {"load_factor": 0.5, "nu": 0.3, "E": 6000.0}, "start")
    assert str(err.value) == (
        "toy.start: mu['nu'] = 0.3, a parameter this model does not read: method 'toy' reads [7, 'load_factor', "
        "'time'], so its answer would ignore it (a scene parameter such as E, nu or another load position is set on "
        "the scene the model is trained on, a case's mu; load_scale multiplies the load_factor)")


def test_the_first_step_is_checked_then_the_class_step_is_back():
    model = _declared()
    reads.arm(model)
    with pytest.raises(ValueError, match=r"toy\.step: mu\['E'\] = 1\.0"):
        model.step({"load_factor": 0.5, "E": 1.0})
    assert isinstance(model.step, reads._FirstStep) and model.steps == []  # refused before it stepped
    assert model.step({"load_factor": 0.5}) == "stepped" and model.steps == [{"load_factor": 0.5}]
    assert "step" not in vars(model) and model.step.__func__ is _Model.step  # the class's own step
    assert model.step({"load_factor": 0.5, "E": 1.0}) == "stepped"  # later steps: unchecked


def test_a_step_of_the_instance_is_put_back_and_a_first_step_that_raises_leaves_the_next_checked():
    model = _declared()
    calls = []

    def own(mu):
        calls.append(mu)
        if mu.get("load_factor") < 0:
            raise ValueError("negative")
        return "own"

    object.__setattr__(model, "step", own)
    reads.arm(model)
    reads.arm(model)  # armed twice: one check, the instance's step kept underneath
    assert isinstance(model.step, reads._FirstStep) and model.step.own is own
    with pytest.raises(ValueError, match="negative"):
        model.step({"load_factor": -1.0})
    assert isinstance(model.step, reads._FirstStep) and model.step.own is own  # checked again
    with pytest.raises(ValueError, match=r"mu\['E'\]"):
        model.step({"load_factor": 1.0, "E": 2.0})
    assert model.step({"load_factor": 1.0}) == "own" and model.step is own
    assert calls == [{"load_factor": -1.0}, {"load_factor": 1.0}]


def test_arm_with_mu0_checks_it_and_leaves_the_step_alone():
    model = _declared()
    with pytest.raises(ValueError, match=r"toy\.start: mu\['E'\] = 3"):
        reads.arm(model, {"load_factor": 0.1, "E": 3})
    reads.arm(model, {"load_factor": 0.1})
    assert "step" not in vars(model)
    bare = _Model()
    reads.arm(bare)  # nothing declared: no check installed
    assert "step" not in vars(bare)


def test_a_sliced_model_inherits_the_parents_keys_and_is_checked():
    parent, child, orphan = _declared(("load_factor", "time")), _Model(), _Model()
    reads.inherit(child, parent)
    assert reads.reads_of(child) == frozenset({"load_factor", "time"}) and isinstance(child.step, reads._FirstStep)
    reads.inherit(orphan, _Model())  # a parent with nothing declared: nothing inherited
    assert reads.reads_of(orphan) is None and "step" not in vars(orphan)


class _AltModel(_Model):
    def alt(self, mu):
        self.steps.append(("alt", dict(mu)))
        return "alt"


class _StepLess:
    """A model class without a step method of its own: its instances are given one."""

    kind = "map"

    def __init__(self):
        self.steps = []

    def step_parameters(self):
        return ()

    def alt(self, mu):
        self.steps.append(dict(mu))
        return "alt"


@pytest.mark.parametrize("cls", [_AltModel, _StepLess])
def test_a_bound_method_other_than_the_class_step_is_put_back(cls):
    """The instance's step is another method of the model (``model.alt``): bound to the model, yet not
    the class's step, so it is what the first step puts back (a class without a step of its own too)."""
    model = _declared(model=cls())
    object.__setattr__(model, "step", model.alt)
    reads.arm(model)
    assert model.step({"load_factor": 0.5}) == "alt"
    assert model.step == model.alt and model.step({"load_factor": 0.6}) == "alt"


class _DictModel(dict):
    """A model whose instance step is a builtin method bound to it (``__self__`` without ``__func__``)."""

    kind = "map"

    def step(self, mu):
        return "class step"


def test_a_builtin_method_bound_to_the_model_is_put_back():
    model = _declared(model=_DictModel(load_factor="from get"))
    object.__setattr__(model, "step", model.get)
    reads.arm(model)
    assert model.step("load_factor") == "from get" and model.step == model.get
