"""A method under check on one contract case: built once, driven once, shared by the checks.

The build is fingerprinted around it (the training's arrays and parameters before and after:
:func:`fingerprint`), the drive is the harness's own (:func:`~tissuebench.studies.protocol.drive`,
what a sweep measures), and the reduced states it returned are copied right after it, so a
later check can tell whether the model wrote into a state it had handed out.
"""
from __future__ import annotations

import hashlib
import json
import traceback
from collections import OrderedDict

import numpy as np

from ..rom import make_method
from ..studies.protocol import drive
from .cases import ContractCase, forget

__all__ = ["Subject", "subject", "fingerprint", "CheckFailure", "CheckSkipped", "raised"]


class CheckFailure(AssertionError):
    """A check found the method breaking the contract (the message says what is wrong)."""


class CheckSkipped(Exception):
    """A check that does not apply to the method (the message says why)."""


def raised(exc: BaseException) -> str:
    """``Type: message (in file:line)`` of an exception the method's code raised."""
    frames = traceback.extract_tb(exc.__traceback__)
    where = f" (in {_short(frames[-1].filename)}:{frames[-1].lineno})" if frames else ""
    return f"{type(exc).__name__}: {exc}{where}"


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


class Subject:
    """``cls`` with ``options`` on contract case ``case`` (module docstring)."""

    def __init__(self, cls, options: dict, case: ContractCase):
        self.cls, self.options, self.case = cls, dict(options), case
        self._built = None
        self._driven = None
        self.mutated: list = []

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
            except Exception as exc:  # noqa: BLE001 - the method's failure, named by the checks
                model, error = None, f"the build on case {self.case.name!r} raised {raised(exc)}"
            after = fingerprint(self.training)
            self.mutated = sorted(k for k in before if before[k] != after.get(k))
            if self.mutated:
                forget()  # the next subject builds on a fresh training
            if model is not None and self.training.outputs and hasattr(model, "attach_outputs"):
                try:
                    model.attach_outputs(self.training.outputs)
                except Exception as exc:  # noqa: BLE001
                    model, error = None, f"attach_outputs raised {raised(exc)}"
            self._built = (model, error)
        model, error = self._built
        if error:
            raise CheckFailure(error)
        return model

    def evaluation(self):
        return self.case.evaluation(self.model())

    def drive(self):
        """``(evaluation, Driven)`` of a fresh drive through the case's evaluation (the harness's)."""
        model = self.model()
        evaluation = self.evaluation()
        try:
            return evaluation, drive(model, evaluation, self.case.history(evaluation))
        except CheckFailure:
            raise
        except Exception as exc:  # noqa: BLE001
            raise CheckFailure(f"driving the model through case {self.case.name!r} ({evaluation.kind} evaluation, "
                               f"{len(evaluation.points)} points) raised {raised(exc)}") from None

    def driven(self):
        """``(evaluation, Driven, copies of the returned states)`` of the first drive (cached)."""
        if self._driven is None:
            evaluation, driven = self.drive()
            copies = [None if r is None or r.q is None else np.array(r.q, copy=True) for r in driven.results]
            self._driven = (evaluation, driven, copies)
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
