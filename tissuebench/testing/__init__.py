"""The method contract as a public battery of named checks, for a method of any package.

In the style of scikit-learn's ``check_estimator`` and ``parametrize_with_checks``
(``sklearn.utils.estimator_checks``)::

    from tissuebench.testing import check_method, parametrize_with_checks

    check_method(MyRom)                       # raises MethodCheckError naming every failed check
    results = check_method("myrom", raise_on_failure=False)   # [CheckResult(check, status, message, case)]

    @parametrize_with_checks([MyRom, (MyRom, {"n_modes": 3})])
    def test_tissuebench_contract(method, check):   # one pytest test per (method, check)
        check(method)

A method is checked on small built-in trainings, catalogue scenes at ci resolution built by the
harness itself (:mod:`.cases`: references from the content-hashed cache, kept in the process),
or on a [[case]] table of a spec given as ``training``. The checks (:data:`CHECKS`, in the order
they run) are the rules the sweep relies on, each named, each saying what is wrong:
``options_are_constructor_keywords``, ``applies_is_declared_and_consistent``,
``builds_an_online_model``, ``build_does_not_mutate_training``, ``step_does_not_mutate_mu``,
``steps_return_reduced_states`` (a finite ``(n_reduced,)`` array, or status failed),
``reconstruct_is_the_full_field`` (shape ``(n_dof,)``, prescribed values included),
``outputs_agree_with_reconstruct``, ``steps_inside_are_ok`` (status ok, finite), ``floor_ops_runs``,
``step_is_deterministic``, ``extrapolation_is_flagged``, ``failure_is_reported``,
``harness_hooks_answer`` and ``parameters_are_honoured`` (every evaluation parameter,
``load_scale`` included, changes the result, is flagged, or is refused when the spec loads; and
through the Python API, a misspelt key or a scene parameter given at a step is refused naming
it, flagged, or changes the answer; a non-finite answer with status ok is none of these).
The shipped methods' contract test runs this battery (``tests/rom/test_rom_contract.py``).

An exception the method's code raises fails the check it was raised in, naming it, and the
battery goes on: ``SystemExit`` and ``KeyboardInterrupt`` too (``raised SystemExit(7)``; a
plugin is third-party code, and a sweep fails its unit the same way). A real Ctrl-C still
stops ``check_method``: while it runs, SIGINT's handler records the signal first
(:func:`tissuebench.exits.user_signals`).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..rom import RomMethod, method_class
from .cases import CONTRACT_CASES
from .checks import CHECK_FUNCTIONS, Context
from .subject import CheckFailure, CheckSkipped, raised, stops, user_signals

__all__ = ["check_method", "parametrize_with_checks", "CHECKS", "CONTRACT_CASES", "CheckResult", "MethodCheckError",
           "MethodCheck"]

#: the names of the checks, in the order they run
CHECKS = tuple(CHECK_FUNCTIONS)


@dataclass(frozen=True)
class CheckResult:
    """The outcome of one check: ``status`` is ``"passed"``, ``"failed"`` or ``"skipped"``;
    ``message`` says what is wrong (or why the check does not apply)."""

    check: str
    status: str
    message: str = ""

    def line(self) -> str:
        return f"{self.check}: {self.status.upper()}" + (f": {self.message}" if self.message else "")


class MethodCheckError(AssertionError):
    """A method broke the contract: the message names every failed check and what is wrong."""

    def __init__(self, method: str, failures: list):
        self.method, self.failures = method, failures
        lines = "\n".join("  " + f.line() for f in failures)
        super().__init__(f"method {method!r} fails {len(failures)} contract check(s):\n{lines}")


def _run(ctx: Context, name: str) -> CheckResult:
    try:
        CHECK_FUNCTIONS[name](ctx)
    except CheckSkipped as why:
        return CheckResult(name, "skipped", str(why))
    except CheckFailure as exc:
        return CheckResult(name, "failed", str(exc))
    except BaseException as exc:  # noqa: BLE001 - the method's code raised inside a check (an exit too): it fails
        if stops(exc):  # a real Ctrl-C, a test runner's own exception
            raise
        return CheckResult(name, "failed", f"raised {raised(exc)}")
    return CheckResult(name, "passed")


def _check_training(training) -> None:
    if isinstance(training, str) and training not in CONTRACT_CASES:
        raise ValueError(f"training = {training!r}: not a built-in contract case; valid: {list(CONTRACT_CASES)}, or "
                         "a [[case]] table")
    if training is not None and not isinstance(training, (str, dict)) or isinstance(training, dict) and \
            "name" not in training:
        raise TypeError(f"training = {training!r}: expected None, a built-in case name ({list(CONTRACT_CASES)}) "
                        "or a [[case]] table (a mapping with a name: a catalogue scene or a scene file)")


def _class(method) -> type:
    if isinstance(method, RomMethod):
        raise TypeError(f"check_method: got an instance of {type(method).__name__}; give its class (options go in "
                        "options=)")
    return method_class(method)


def check_method(method, training=None, options: dict | None = None, checks=None,
                 raise_on_failure: bool = True) -> list[CheckResult]:
    """Run the contract's checks on ``method`` (a class, a registry name or ``"module:Class"``).

    Parameters
    ----------
    method : type or str
        The :class:`~tissuebench.rom.RomMethod` subclass (registered or not), or its name.
    training : None, str or dict
        What it is built on: None, the built-in case it applies to first (:data:`CONTRACT_CASES`,
        in the order of its ``training_kinds``); a built-in case's name; or a spec's [[case]] table
        (``{"name": "liver_palpation", "training": {"kind": "path"}}``, ci resolution by default).
    options : dict, optional
        The method's options for every build (default: its defaults).
    checks : iterable of str, optional
        The checks to run (default: all of :data:`CHECKS`, in order).
    raise_on_failure : bool
        Raise :class:`MethodCheckError` naming every failed check (default); else return the results.

    Returns
    -------
    list of CheckResult
        One per check run, in order.

    Notes
    -----
    An exception the method's code raises fails the check it was raised in (``raised
    SystemExit(7) (in method.py:12)``) and the next checks run: ``SystemExit`` and a
    ``KeyboardInterrupt`` raised by the code included. A real Ctrl-C (SIGINT) stops the checks
    with ``KeyboardInterrupt``.
    """
    cls = _class(method)
    names = list(CHECKS if checks is None else checks)
    unknown = [n for n in names if n not in CHECK_FUNCTIONS]
    if unknown:
        raise ValueError(f"checks: unknown check {unknown[0]!r}; valid: {list(CHECKS)}")
    if options is not None and not isinstance(options, dict):
        raise TypeError(f"options = {options!r}: expected a dict of the method's options")
    _check_training(training)
    ctx = Context(cls, options, training)
    with user_signals():
        results = [_run(ctx, n) for n in names]
    failures = [r for r in results if r.status == "failed"]
    if failures and raise_on_failure:
        raise MethodCheckError(cls.name, failures)
    return results


class MethodCheck:
    """One named check bound to its options and training: ``check(method)`` runs it, failing
    (an AssertionError saying what is wrong) or skipping (``pytest.skip``) as the check says."""

    def __init__(self, name: str, options: dict | None = None, training=None):
        _check_training(training)
        self.name, self.options, self.training = name, dict(options or {}), training

    def __call__(self, method) -> None:
        with user_signals():
            result = _run(Context(_class(method), self.options, self.training), self.name)
        if result.status == "skipped":
            import pytest  # lazy: only a pytest run skips

            pytest.skip(result.message)
        if result.status == "failed":
            raise MethodCheckError(_class(method).name, [result])

    def __repr__(self) -> str:
        return self.name


def parametrize_with_checks(methods, options: dict | None = None, training=None, checks=None, marks=None):
    """A ``pytest.mark.parametrize("method, check", ...)`` of every (method, check) pair, with ids
    ``"<method name>-<check name>"``.

    ``methods``: classes, names, or ``(class or name, options)`` pairs; ``options``: per method
    name, the options of the methods given without (``{"pod_linear": {"n_modes": 3}}``);
    ``training``: as :func:`check_method`'s; ``checks``: a subset of :data:`CHECKS`; ``marks``:
    ``{(method name, check name): mark}`` (e.g. ``pytest.mark.slow``; check name ``"*"``: all of
    the method's checks)."""
    import pytest  # lazy: the helper of a pytest suite

    names = list(CHECKS if checks is None else checks)
    params = []
    for entry in methods:
        method, opts = entry if isinstance(entry, tuple) else (entry, None)
        cls = _class(method)
        opts = opts if opts is not None else (options or {}).get(cls.name, {})
        # (class, options) pairs of one class: told apart by their options
        suffix = "[" + ",".join(f"{k}={v}" for k, v in sorted(opts.items())) + "]" if isinstance(entry, tuple) and \
            opts else ""
        for name in names:
            mark = (marks or {}).get((cls.name, name)) or (marks or {}).get((cls.name, "*"))
            params.append(pytest.param(method, MethodCheck(name, opts, training), id=f"{cls.name}{suffix}-{name}",
                                       marks=[mark] if mark is not None else []))
    return pytest.mark.parametrize("method, check", params)
