"""Negative controls of the shipped battery (:mod:`tissuebench.testing`, issue 38): for every named
check a deliberately broken method that it catches, saying what is wrong, beside a sound method
(the positive control) that passes every check, so neither side is vacuous. The wrong-length
``reconstruct`` of the issue (654 of the cornea's 657 dofs, which failed only inside a sweep with
a broadcasting error) is caught by ``check_method`` before any sweep."""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.rom import Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, check_parameters
from tissuebench.testing import CHECKS, MethodCheckError, check_method, parametrize_with_checks


class _Model(LinearReconstruction, OnlineModel):
    """The training's snapshots linearly interpolated in the load factor (exact at them, flagged
    outside their range); prescribed values from the problem (LinearReconstruction)."""

    kind = "map"

    def __init__(self, training, name, gain):
        lams = training.parameter_values("load_factor")
        order = np.argsort(lams)
        self.name, self.gain, self.lams = name, gain, lams[order]
        self.free_dofs, self.problem, self.ndof = training.free_dofs, training.backend.problem, \
            training.snapshots.shape[0]
        self.basis = training.snapshots[self.free_dofs][:, order]

    @property
    def n_reduced(self) -> int:
        return len(self.lams)

    def weights(self, lam):
        q = np.zeros(len(self.lams))
        k = int(np.clip(np.searchsorted(self.lams, lam) - 1, 0, len(self.lams) - 2))
        t = (lam - self.lams[k]) / (self.lams[k + 1] - self.lams[k])
        q[k], q[k + 1] = 1.0 - t, t
        return self.gain * q

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("load_factor",), self.name)
        lam = mu["load_factor"]
        if self.lams[0] <= lam <= self.lams[-1]:
            return StepResult(self.weights(lam), mu=mu)
        return StepResult(self.weights(lam), "extrapolation", f"load_factor = {lam:g} outside the training's "
                          f"[{self.lams[0]:g}, {self.lams[-1]:g}]", mu=mu)


class Sound(RomMethod):
    """The positive control: keeps every rule."""

    name = "sound_toy"
    kind = "map"
    training_kinds = ("path",)
    applies = Applies(dead_loads=True)
    model = _Model

    def __init__(self, gain: float = 1.0):
        self.gain = float(gain)

    def build(self, training):
        return self.model(training, self.name, self.gain)


# ------------------------------------------------------------------ one broken rule each
class NoDefault(Sound):
    def __init__(self, gain: float):
        self.gain = float(gain)


class ParametersOfAnotherKind(Sound):
    applies = Applies(dead_loads=True, parameters={"positions": ("position",)})


class BuildsNothing(Sound):
    def build(self, training):
        return {"snapshots": training.snapshots}


class MutatesItsTraining(Sound):
    def build(self, training):
        training.snapshots[0, 0] += 1e-9  # "normalising" the shared training in place
        return super().build(training)


class _Short(_Model):
    def reconstruct(self, result):
        return super().reconstruct(result)[:-3]


class WrongLength(Sound):
    model = _Short


class _NoPrescribed(_Model):
    def reconstruct(self, result):
        u = super().reconstruct(result)
        u[self.problem.fixed_dofs] = 0.0
        return u


class ForgetsPrescribedValues(Sound):
    model = _NoPrescribed


class _OffOutputs(_Model):
    def outputs(self, result):
        return {k: 1.01 * v for k, v in super().outputs(result).items()}


class OutputsOff(Sound):
    model = _OffOutputs


class _Pessimist(_Model):
    def step(self, mu):
        res = super().step(mu)
        return StepResult(res.q, "extrapolation", "always unsure", mu=res.mu)


class NeverOk(Sound):
    model = _Pessimist


class _NoFloor(_Model):
    def floor_ops(self):
        return None


class NoFloor(Sound):
    model = _NoFloor


class _Noisy(_Model):
    def step(self, mu):
        res = super().step(mu)
        res.q = res.q + np.random.default_rng().normal(scale=1e-6, size=res.q.shape)  # unseeded
        return res


class Noisy(Sound):
    model = _Noisy


class _OneBuffer(_Model):
    def step(self, mu):
        res = super().step(mu)
        if not hasattr(self, "_buffer"):
            self._buffer = np.empty_like(res.q)
        self._buffer[:] = res.q  # handed out, written again at the next step
        res.q = self._buffer
        return res


class ReusesItsState(Sound):
    model = _OneBuffer


class _Optimist(_Model):
    def step(self, mu):
        res = super().step(mu)
        return StepResult(res.q, "ok", "", mu=res.mu)


class NeverFlags(Sound):
    model = _Optimist


class _FieldOfFailure(_Model):
    def reconstruct(self, result):
        if result.q is None:
            return np.zeros(self.ndof)
        return super().reconstruct(result)


class FailureAsField(Sound):
    model = _FieldOfFailure


class DeclaresNestedItCannotSlice(Sound):
    nested = ("gain",)


class _TopOnly(_Model):
    def step(self, mu):
        res = super().step(mu)
        if res.status == "ok":  # inside the training: its top state, whatever the load factor
            res.q = self.weights(self.lams[-1])
        return res


class IgnoresTheLoadFactor(Sound):
    model = _TopOnly


class _ForgetsSuper(Sound):
    """A plugin's base class keeping a registry of its own, whose ``__init_subclass__`` forgets
    ``super()``: its subclasses' builds escape the contract's wrapping (tissuebench.rom.reads), so
    their models check no parameter they are given."""

    registry: dict = {}

    def __init_subclass__(cls, **kwargs):
        _ForgetsSuper.registry[cls.__name__] = cls


class IgnoresAnUnknownParameter(_ForgetsSuper):
    def build(self, training):
        return self.model(training, self.name, self.gain)


class _ClaimsToReadE(_Model):
    def step_parameters(self):
        return ("E",) + super().step_parameters()


class DeclaresWhatItIgnores(Sound):
    model = _ClaimsToReadE


NEGATIVE = [
    ("options_are_constructor_keywords", NoDefault, "options ['gain'] have no default"),
    ("applies_is_declared_and_consistent", ParametersOfAnotherKind, "names training kind 'positions'"),
    ("builds_an_online_model", BuildsNothing, "build returned dict, not a tissuebench.rom.OnlineModel"),
    ("build_does_not_mutate_training", MutatesItsTraining, "the build changed its training: snapshots"),
    ("reconstruct_is_the_full_field", WrongLength, "reconstruct returned shape (654,)"),
    ("reconstruct_is_the_full_field", ForgetsPrescribedValues, "misses the prescribed (Dirichlet) values case "
                                                                "'prescribed'"),
    ("outputs_agree_with_reconstruct", OutputsOff, "the functional applied to reconstruct() gives"),
    ("steps_inside_are_ok", NeverOk, "returned status 'extrapolation': always unsure"),
    ("floor_ops_runs", NoFloor, "floor_ops() returned NoneType, not a zero-argument callable"),
    ("step_is_deterministic", Noisy, "two drives from the same start gave different states"),
    ("step_is_deterministic", ReusesItsState, "changed the state it returned"),
    ("extrapolation_is_flagged", NeverFlags, "returned status 'ok' with message ''"),
    ("failure_is_reported", FailureAsField, "reconstruct of a failed step returned a field"),
    ("harness_hooks_answer", DeclaresNestedItCannotSlice, "nested = ['gain'] but variant"),
    ("parameters_are_honoured", IgnoresTheLoadFactor, "load_scale = 0.5: the same result, every step ok"),
    ("parameters_are_honoured", IgnoresAnUnknownParameter, "bogus_parameter = 1.5 at a step (Python API): accepted, "
                                                           "the same answer, status ok"),
    ("parameters_are_honoured", DeclaresWhatItIgnores, "at a step (Python API): declared as read (step_parameters), "
                                                       "the same answer, status ok"),
]


def test_every_check_has_a_negative_control():
    assert sorted({c for c, _, _ in NEGATIVE}) == sorted(CHECKS)


@pytest.mark.parametrize("check, broken, says", NEGATIVE, ids=[f"{c}-{b.__name__}" for c, b, _ in NEGATIVE])
def test_each_check_catches_its_broken_method(check, broken, says):
    [result] = check_method(broken, checks=[check], raise_on_failure=False)
    assert result.status == "failed" and says in result.message, result


@parametrize_with_checks([Sound])
def test_the_sound_method_passes_every_check(method, check):
    """The positive control, through the pytest helper a plugin's suite uses."""
    check(method)


def test_the_wrong_length_reconstruct_is_caught_before_any_sweep():
    with pytest.raises(MethodCheckError) as caught:
        check_method(WrongLength)
    text = str(caught.value)
    assert "method 'sound_toy' fails 1 contract check(s):" in text
    assert "reconstruct_is_the_full_field: FAILED: reconstruct returned shape (654,) case 'path'" in text
    assert "the full field has shape (657,)" in text


def test_check_method_refuses_bad_arguments_naming_them():
    with pytest.raises(ValueError, match="checks: unknown check 'nope'; valid: "):
        check_method(Sound, checks=["nope"])
    with pytest.raises(TypeError, match="got an instance of Sound; give its class"):
        check_method(Sound())
    with pytest.raises(ValueError, match="training = 'nope': not a built-in contract case"):
        check_method(Sound, training="nope", checks=["builds_an_online_model"])
    with pytest.raises(TypeError, match="options = 3: expected a dict"):
        check_method(Sound, options=3)
