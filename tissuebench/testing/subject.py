"""A method under check on one contract case: built once, driven once, shared by the checks.

The build is fingerprinted around it (the training's arrays and parameters before and after:
:func:`fingerprint`), the drive is the harness's own (:func:`~tissuebench.studies.protocol.drive`,
what a sweep measures), and the reduced states it returned are copied right after it, so a
later check can tell whether the model wrote into a state it had handed out. The drive sees
the model through :class:`Watched`: a mapping of parameters the model changed at ``start`` or
``step`` is recorded and put back as it was asked, and ``n_reduced`` is read right after each
step.

The method's code is third-party code: an exception it raises fails the check it was raised
in, ``SystemExit`` and ``KeyboardInterrupt`` included (``sys.exit(7)`` in a step: "raised
SystemExit(7)"); only a real Ctrl-C stops the checks (:func:`tissuebench.exits.user_signals`
records it while the checks run, :func:`tissuebench.exits.stops` tells the two apart).
"""
from __future__ import annotations

import copy
import hashlib
import json
import traceback
from collections import OrderedDict

import numpy as np

from ..rom import make_method
from ..exits import EXIT_TYPES, stops, user_signals
from ..studies.protocol import drive
from .cases import ContractCase, forget

__all__ = ["Subject", "subject", "fingerprint", "CheckFailure", "CheckSkipped", "raised", "stops",
           "user_signals", "Watched"]

class CheckFailure(AssertionError):
    """A check found the method breaking the contract (the message says what is wrong)."""


class CheckSkipped(Exception):
    """A check that does not apply to the method (the message says why)."""


def raised(exc: BaseException) -> str:
    """``Type: message (in file:line)`` of an exception the method's code raised; an exit-type
    one as written (``SystemExit(7)``: its message alone, an exit code, would not say what it is)."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (in {_short(frames[-1].filename)}:{frames[-1].lineno})" if frames else ""
    what = repr(exc) if isinstance(exc, EXIT_TYPES) else f"{type(exc).__name__}: {exc}"
    return f"{what}{where}"


def _short(path: str) -> str:
    parts = path.replace("\\", "/").split("/")
    return "/".join(parts[-2:])


def _digest(value) -> str:
    if value is None:
        return "none"
    if isinstance(value, np.ndarray):
        return hashlib.sha256(np.ascontiguousarray(value).tobytes() + str((value.dtype, value.shape)).encode()
                              ).hexdigest()
    if isinstance(value, dict):
        return json.dumps({str(k): _digest(v) for k, v in value.items()}, sort_keys=True)
    if isinstance(value, (list, tuple)):
        return json.dumps([_digest(v) for v in value])
    return repr(value)


def fingerprint(training) -> dict:
    """Digests of what a build must leave as it found it: the snapshots, their parameters, the free
    dofs, the output functionals, the velocities, trajectory ids, dt, info and every group's."""
    out = {k: _digest(getattr(training, k)) for k in ("snapshots", "parameters", "free_dofs", "outputs",
                                                      "velocities", "trajectories", "dt", "info")}
    for key, group in (training.groups or {}).items():
        out.update({f"groups[{key!r}].{k}": v for k, v in fingerprint(group).items()})
    return out


class Watched:
    """``model`` as a drive under check sees it (module docstring): its own ``start`` and ``step``,
    given the harness's own mappings; one the model changed is put back as it was asked, right
    after the call (the harness keeps stepping with the evaluation's points and reports a
    result's ``mu``: the later checks judge and quote the asked values), and recorded in
    ``changed`` as ``(call, asked, left)``; ``steps`` holds ``(mu, result, n_reduced)`` of every
    step as the model returned it, before the harness reads it (and may record it otherwise),
    ``n_reduced`` read right after the step (a cut model's grows as it cuts), or the exception
    reading it raised."""

    def __init__(self, model):
        self.model, self.changed, self.steps = model, [], []

    def __getattr__(self, name):
        return getattr(self.model, name)

    def start(self, mu0=None, *args, **kwargs):
        return self._kept("start", mu0, self.model.start, mu0, *args, **kwargs)

    def step(self, mu):
        res = self._kept("step", mu, self.model.step, mu)
        try:
            n = self.model.n_reduced
        except Exception as exc:  # noqa: BLE001 - the model's property: named by the check that reads it
            n = exc
        self.steps.append((dict(mu) if isinstance(mu, dict) else mu, res, n))
        return res

    def _kept(self, call, mu, method, *args, **kwargs):
        if not isinstance(mu, dict):
            return method(*args, **kwargs)
        asked = copy.deepcopy(mu)
        try:
            return method(*args, **kwargs)
        finally:
            if _digest(mu) != _digest(asked):
                self.changed.append((call, asked, dict(mu)))
                mu.clear()
                mu.update(asked)


class Subject:
    """``cls`` with ``options`` on contract case ``case`` (module docstring)."""

    def __init__(self, cls, options: dict, case: ContractCase):
        self.cls, self.options, self.case = cls, dict(options), case
        self._built = None
        self._driven = None
        self.mutated: list = []
        #: the :class:`Watched` of the first drive (what the model changed, its steps as returned)
        self.watched: Watched | None = None

    @property
    def training(self):
        return self.case.training

    def model(self):
        """The built model (outputs attached, as the harness does); CheckFailure naming the build's error."""
        if self._built is None:
            before = fingerprint(self.training)
            try:
                model = make_method(self.cls, **self.options).build(self.training)
                error = None
            except BaseException as exc:  # noqa: BLE001 - the method's failure (an exit too), named by the checks
                if stops(exc):
                    raise
                model, error = None, f"the build on case {self.case.name!r} raised {raised(exc)}"
            after = fingerprint(self.training)
            self.mutated = sorted(k for k in before if before[k] != after.get(k))
            if self.mutated:
                forget()  # the next subject builds on a fresh training
            if model is not None and self.training.outputs and hasattr(model, "attach_outputs"):
                try:
                    model.attach_outputs(self.training.outputs)
                except BaseException as exc:  # noqa: BLE001
                    if stops(exc):
                        raise
                    model, error = None, f"attach_outputs raised {raised(exc)}"
            self._built = (model, error)
        model, error = self._built
        if error:
            raise CheckFailure(error)
        return model

    def evaluation(self):
        return self.case.evaluation(self.model())

    def drive(self, watched: Watched | None = None):
        """``(evaluation, Driven)`` of a fresh drive through the case's evaluation (the harness's),
        the model seen through ``watched`` (a :class:`Watched` of it, or a new one)."""
        model = self.model()
        evaluation = self.evaluation()
        try:
            return evaluation, drive(watched or Watched(model), evaluation, self.case.history(evaluation))
        except CheckFailure:
            raise
        except BaseException as exc:  # noqa: BLE001 - the method's code raised (an exit too)
            if stops(exc):
                raise
            raise CheckFailure(f"driving the model through case {self.case.name!r} ({evaluation.kind} evaluation, "
                               f"{len(evaluation.points)} points) raised {raised(exc)}") from None

    def driven(self):
        """``(evaluation, Driven, copies of the returned states)`` of the first drive (cached; what
        the model did to its parameters, its steps as returned: :attr:`watched`)."""
        if self._driven is None:
            watched = Watched(self.model())
            evaluation, driven = self.drive(watched)
            copies = [None if r is None or r.q is None else np.array(r.q, copy=True) for r in driven.results]
            self._driven, self.watched = (evaluation, driven, copies), watched
        return self._driven


_SUBJECTS: OrderedDict = OrderedDict()


def subject(cls, options: dict, case: ContractCase) -> Subject:
    """The subject of ``(cls, options, case)``, kept for the next checks (the last few only)."""
    key = (cls, json.dumps(options, sort_keys=True, default=str), case.name, id(case))
    if key not in _SUBJECTS:
        _SUBJECTS[key] = Subject(cls, options, case)
        while len(_SUBJECTS) > 3:
            _SUBJECTS.popitem(last=False)
    _SUBJECTS.move_to_end(key)
    return _SUBJECTS[key]
