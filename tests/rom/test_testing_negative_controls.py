"""Negative controls of the shipped battery (:mod:`tissuebench.testing`, issue 38): for every named
check a deliberately broken method that it catches, saying what is wrong, beside a sound method
(the positive control) that passes every check, so neither side is vacuous. The wrong-length
``reconstruct`` of the issue (654 of the cornea's 657 dofs, which failed only inside a sweep with
a broadcasting error) is caught by ``check_method`` before any sweep.

Issue 50's blind spots of the battery have theirs too: a state of another length than
``n_reduced``, a list or NaN state, a NaN answer at a changed parameter, a step writing into its
``mu``, and a method's code raising ``SystemExit`` or ``KeyboardInterrupt`` (a failed check,
the battery going on; a real Ctrl-C still stops it)."""
from __future__ import annotations

import signal
import threading

import numpy as np
import pytest

from tissuebench.rom import Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, check_parameters
from tissuebench.testing import CHECKS, MethodCheck, MethodCheckError, check_method, parametrize_with_checks
from tissuebench.testing.cases import contract_case
from tissuebench.testing.subject import stops


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


class RefinesNoOption(Sound):
    refinements = {"tolerance": 0.5}  # no such option: the fit could not set it


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


# ------------------------------------------------------------------ issue 50: the blind spots
class _Fewer(_Model):
    @property
    def n_reduced(self) -> int:  # one less than the states it returns
        return len(self.lams) - 1


class MisstatesItsSize(Sound):
    model = _Fewer


class _Listed(_Model):
    def step(self, mu):
        res = super().step(mu)
        res.q = res.q.tolist()  # reconstruct's basis @ q takes a list too
        return res


class ListState(Sound):
    model = _Listed


class _Rounded(_Model):
    def step(self, mu):
        res = super().step(mu)
        res.q = np.rint(res.q).astype(np.int64)
        return res


class IntegerState(Sound):
    model = _Rounded


class _NaN(_Model):
    def step(self, mu):
        res = super().step(mu)
        res.q = np.full_like(res.q, np.nan)  # status kept: "ok" inside the training
        return res


class NanState(Sound):
    model = _NaN


class _Stateless(_Model):
    def step(self, mu):
        res = super().step(mu)
        return StepResult(None, res.status, res.message, mu=res.mu)  # a status that is not failed, no state


class NoStateNotFailed(Sound):
    model = _Stateless


class _NanAtAnUnknownKey(_Model):
    def step(self, mu):
        res = super().step(mu)
        if set(mu) - {"load_factor"}:
            res.q = np.full_like(res.q, np.nan)
        return res


class NanForAnUnknownParameter(_ForgetsSuper):
    """Escapes the contract's refusal of unread keys (:class:`_ForgetsSuper`) and answers NaN."""

    model = _NanAtAnUnknownKey

    def build(self, training):
        return self.model(training, self.name, self.gain)


class _Scribbler(_Model):
    def step(self, mu):
        res = super().step(mu)  # res.mu is check_parameters' copy
        mu["load_factor"] = -1.0  # "consumed": written into the harness's own mapping
        return res


class WritesIntoItsMu(Sound):
    model = _Scribbler


class _ScribblingPessimist(_Scribbler):
    def step(self, mu):
        res = super().step(mu)
        return StepResult(res.q, "extrapolation", "always unsure", mu=res.mu)


class WritesIntoItsMuAndNeverOk(Sound):
    model = _ScribblingPessimist


class _ScribblingOptimist(_Scribbler):
    def step(self, mu):
        res = super().step(mu)
        return StepResult(res.q, "ok", "", mu=res.mu)


class WritesIntoItsMuAndNeverFlags(Sound):
    model = _ScribblingOptimist


class ExitsInBuild(Sound):
    def build(self, training):
        raise SystemExit(7)


class _ExitsInStep(_Model):
    def step(self, mu):
        raise SystemExit(7)


class ExitsInStep(Sound):
    model = _ExitsInStep


class _InterruptsInFloor(_Model):
    def floor_ops(self):
        raise KeyboardInterrupt  # raised by the code, no signal


class InterruptsInFloor(Sound):
    model = _InterruptsInFloor


class _CtrlC(_Model):
    def step(self, mu):
        signal.raise_signal(signal.SIGINT)  # what a user's Ctrl-C does, in the middle of a step
        return super().step(mu)


class CtrlCInStep(Sound):
    model = _CtrlC


NEGATIVE = [
    ("options_are_constructor_keywords", NoDefault, "options ['gain'] have no default"),
    ("options_are_constructor_keywords", RefinesNoOption, "refinements = {'tolerance': 0.5}: not all are options"),
    ("applies_is_declared_and_consistent", ParametersOfAnotherKind, "names training kind 'positions'"),
    ("builds_an_online_model", BuildsNothing, "build returned dict, not a tissuebench.rom.OnlineModel"),
    ("build_does_not_mutate_training", MutatesItsTraining, "the build changed its training: snapshots"),
    ("step_does_not_mutate_mu", WritesIntoItsMu, "step(mu) changed the parameters it was given at "
                                                 "{'load_factor': 0.0001953125}: left {'load_factor': -1.0}"),
    ("steps_return_reduced_states", MisstatesItsSize, "has shape (6,); n_reduced = 5 after that step"),
    ("steps_return_reduced_states", ListState, "is a list: expected a numpy array of shape (n_reduced,) = (6,)"),
    ("steps_return_reduced_states", IntegerState, "has dtype int64: expected a floating array"),
    ("steps_return_reduced_states", NanState, "is not finite: q[0] = nan"),
    ("steps_return_reduced_states", NoStateNotFailed, "returned no state (q None): only a failed step has none"),
    ("reconstruct_is_the_full_field", WrongLength, "reconstruct returned shape (654,)"),
    ("reconstruct_is_the_full_field", ForgetsPrescribedValues, "misses the prescribed (Dirichlet) values case "
                                                                "'prescribed'"),
    ("outputs_agree_with_reconstruct", OutputsOff, "the functional applied to reconstruct() gives"),
    ("steps_inside_are_ok", NeverOk, "returned status 'extrapolation': always unsure"),
    ("steps_inside_are_ok", NanState, "non-finite state"),
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
    ("parameters_are_honoured", NanState, "non-finite"),
    ("parameters_are_honoured", NanForAnUnknownParameter, "bogus_parameter = 1.5 at a step (Python API): accepted, "
                                                          "a non-finite answer, status ok"),
    # the method's code exiting or interrupting fails the check it ran in, naming the exception
    ("builds_an_online_model", ExitsInBuild, "the build on case 'path' raised SystemExit(7)"),
    ("steps_inside_are_ok", ExitsInStep, "raised SystemExit(7)"),
    ("floor_ops_runs", InterruptsInFloor, "floor_ops() raised KeyboardInterrupt()"),
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


# ------------------------------------------------------------------ issue 50: beyond one check each
@pytest.mark.parametrize("broken", [ListState, NanState])
def test_a_list_or_nan_state_is_not_called_a_changed_state(broken):
    """A list or NaN state returned anew each step is deterministic: step_is_deterministic passes
    (steps_return_reduced_states names what is wrong), as the array reused across steps does not."""
    [result] = check_method(broken, checks=["step_is_deterministic"], raise_on_failure=False)
    assert result.status == "passed", result
    [result] = check_method(ReusesItsState, checks=["step_is_deterministic"], raise_on_failure=False)
    assert result.status == "failed" and "changed the state it returned" in result.message, result


def test_a_step_writing_into_its_mu_is_judged_and_quoted_at_the_asked_parameters():
    """The later checks see the mapping as it was asked (the mutation put back): the step at 0.000195
    is inside the training and named so, not judged at the -1.0 the step wrote; the contract case's
    evaluation, shared by every method checked in the process, is left as it was."""
    points = contract_case("path").evaluation().points
    asked = [dict(p.mu) for p in points]
    results = {r.check: r for r in check_method(WritesIntoItsMuAndNeverOk, raise_on_failure=False, checks=[
        "step_does_not_mutate_mu", "steps_inside_are_ok", "step_is_deterministic"])}
    assert results["step_does_not_mutate_mu"].status == "failed"
    inside = results["steps_inside_are_ok"]
    assert inside.status == "failed" and "({'load_factor': 0.0001953125}, case 'path') returned status " \
        "'extrapolation'" in inside.message and "-1.0" not in inside.message, inside
    assert results["step_is_deterministic"].status == "passed", results["step_is_deterministic"]
    assert [dict(p.mu) for p in contract_case("path").evaluation().points] == asked
    [far] = check_method(WritesIntoItsMuAndNeverFlags, checks=["extrapolation_is_flagged"], raise_on_failure=False)
    assert far.status == "failed" and far.message.startswith("a step at {'load_factor': 12.0}, far outside"), far


def test_an_exit_of_the_method_fails_its_checks_and_the_battery_goes_on():
    """sys.exit(7) in every step: each check that steps fails naming it, every check runs, and the
    checks that do not step pass."""
    results = check_method(ExitsInStep, raise_on_failure=False)
    assert [r.check for r in results] == list(CHECKS)
    status = {r.check: r for r in results}
    for name in ("options_are_constructor_keywords", "builds_an_online_model", "harness_hooks_answer"):
        assert status[name].status == "passed", status[name]
    for name in ("step_does_not_mutate_mu", "reconstruct_is_the_full_field", "extrapolation_is_flagged",
                 "parameters_are_honoured"):
        assert status[name].status == "failed" and "SystemExit(7)" in status[name].message, status[name]


@pytest.fixture
def sigint_raises():
    """SIGINT's handler as an interactive Python has it (a test run in the background may have it
    ignored), put back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals reach the main thread only")
    before = signal.getsignal(signal.SIGINT)
    signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_a_keyboard_interrupt_the_code_raises_is_a_failed_check(sigint_raises):
    with pytest.raises(MethodCheckError, match=r"floor_ops_runs: FAILED: floor_ops\(\) raised KeyboardInterrupt\(\)"):
        check_method(InterruptsInFloor, checks=["builds_an_online_model", "floor_ops_runs"])
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler put back


def test_a_real_ctrl_c_still_stops_the_checks(sigint_raises):
    with pytest.raises(KeyboardInterrupt):
        check_method(CtrlCInStep, checks=["steps_inside_are_ok", "floor_ops_runs"])
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with pytest.raises(KeyboardInterrupt):  # through the check parametrize_with_checks gives a suite too
        MethodCheck("steps_inside_are_ok")(CtrlCInStep)


def test_outside_the_checks_a_keyboard_interrupt_stops():
    """``stops``: with no check running, a KeyboardInterrupt is the user's; SystemExit and errors are
    the code's; a test runner's own BaseException always stops."""
    assert stops(KeyboardInterrupt()) and stops(GeneratorExit())
    assert not stops(SystemExit(7)) and not stops(ValueError("x"))


def test_with_sigint_ignored_a_keyboard_interrupt_the_code_raises_is_a_failed_check():
    """A suite run as a background job of a script has SIGINT ignored: no Ctrl-C can reach it, so
    a KeyboardInterrupt is the code's and fails its check (the battery is not aborted)."""
    if threading.current_thread() is not threading.main_thread():
        pytest.skip("signals reach the main thread only")
    before = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with pytest.raises(MethodCheckError, match=r"floor_ops_runs: FAILED: floor_ops\(\) raised KeyboardInterrupt"):
            check_method(InterruptsInFloor, checks=["builds_an_online_model", "floor_ops_runs"])
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, before)


def test_a_refinement_of_an_option_passes_and_one_of_no_option_fails():
    """Both sides of the refinements rule: a declared option passes, an undeclared one fails."""
    class RefinesGain(Sound):
        refinements = {"gain": 0.5}

    [ok] = check_method(RefinesGain, checks=["options_are_constructor_keywords"], raise_on_failure=False)
    [bad] = check_method(RefinesNoOption, checks=["options_are_constructor_keywords"], raise_on_failure=False)
    assert ok.status == "passed" and bad.status == "failed"
