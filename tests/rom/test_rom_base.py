"""The ROM contract: registry, step results, parameter checks, training data."""
import numpy as np
import pytest

from tissuebench.rom import METHODS, RomMethod, StepResult, Training, check_parameters, make_method, register


def test_unknown_method_lists_the_valid_ones():
    with pytest.raises(ValueError, match=r"unknown ROM method 'nope'; valid: \["):
        make_method("nope")


def test_register_refuses_what_is_not_a_named_method():
    with pytest.raises(TypeError):
        register(int)

    class Unnamed(RomMethod):
        def build(self, training):
            return None
    with pytest.raises(TypeError):
        register(Unnamed)


def test_a_class_is_accepted_as_well_as_a_name():
    class Toy(RomMethod):
        name = "toy_for_test"

        def __init__(self, k=1):
            self.k = k

        def build(self, training):
            return None
    assert make_method(Toy, k=3).k == 3
    register(Toy)
    try:
        assert isinstance(make_method("toy_for_test"), Toy)
    finally:
        METHODS.pop("toy_for_test")


def test_step_result_statuses():
    assert StepResult(np.zeros(2)).ok
    assert not StepResult(np.zeros(2), "extrapolation").ok
    with pytest.raises(ValueError, match="status = 'weird'"):
        StepResult(np.zeros(2), "weird")
    with pytest.raises(ValueError, match="no state"):
        StepResult(np.zeros(2), "failed")


def test_parameters_are_checked_by_name():
    assert check_parameters({"load_factor": 0.5}, ("load_factor",), "m") == {"load_factor": 0.5}
    with pytest.raises(ValueError, match="'load_factor' missing"):
        check_parameters({}, ("load_factor",), "m")
    with pytest.raises(ValueError, match=r"mu\['load_factor'\] = nan"):
        check_parameters({"load_factor": float("nan")}, ("load_factor",), "m")
    with pytest.raises(TypeError):
        check_parameters(0.5, ("load_factor",), "m")


def test_training_data_is_validated():
    with pytest.raises(ValueError, match="2D array"):
        Training(snapshots=np.zeros(3))
    with pytest.raises(ValueError, match="non-finite"):
        Training(snapshots=np.array([[np.nan]]))
    with pytest.raises(ValueError, match="2 entries for 3 snapshots"):
        Training(snapshots=np.zeros((4, 3)), parameters=[{}, {}])


def test_deferred_message_is_formatted_once_when_read():
    from tissuebench.rom.base import DeferredStepResult

    calls = []

    def message():
        calls.append(1)
        return "load factor 3 is 2 above the range"

    res = DeferredStepResult(np.zeros(2), "beyond_validity", message, {"a": 1.0})
    assert isinstance(res, StepResult) and not calls  # nothing formatted on the haptic path
    assert res.message == "load factor 3 is 2 above the range" and res.message.startswith("load") and len(calls) == 1
    res.message = "replaced"
    assert res.message == "replaced" and len(calls) == 1
    assert DeferredStepResult(np.zeros(1), "extrapolation", None).message == ""
    with pytest.raises(ValueError, match="no state"):
        DeferredStepResult(np.zeros(1), "failed", message)
    with pytest.raises(ValueError, match="expected one of"):
        DeferredStepResult(np.zeros(1), "weird", message)


@pytest.mark.parametrize("kind", ["path", "operators"])
def test_every_training_the_harness_builds_carries_its_scene_in_the_declared_field(kind):
    """``Training.scene`` is the plug point for methods that build from the scene (PGD, the
    practitioner baselines): the harness fills it for every kind, and ``scene_of`` reads it before
    loading a catalogue case by name, so a modified scene is never swapped for the catalogue's."""
    import dataclasses

    from tissuebench.rom.training_scene import scene_of
    from tissuebench.studies.case_entry import CaseEntry
    from tissuebench.studies.training import build_training

    name = "cube_tension_twist" if kind == "path" else "heat1d_source"
    evaluation = {"kind": "path" if kind == "path" else "map"}
    entry = CaseEntry.from_dict({"id": name, "name": name, "resolution": "ci", "backend": "skfem",
                                 "training": {"kind": kind}, "evaluation": evaluation})
    training = build_training(entry)
    assert training.scene is not None and training.scene.content_hash() == training.info["scene_hash"]
    assert "scene" not in training.info
    assert scene_of(training, "test") is training.scene
    other = dataclasses.replace(training, scene=None)  # by name: the catalogue's, its hash checked
    assert scene_of(other, "test").content_hash() == training.scene.content_hash()
    with pytest.raises(ValueError, match="Training.scene"):
        scene_of(Training(info={}), "test", required=True)
