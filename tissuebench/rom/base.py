"""The contract every reduced-order model follows: offline build, online step, reconstruction.

Two phases, the same for every method family (POD-Galerkin, ANM-POD, PODI, Grassmann,
and later PGD, skinning-cubature and direct integrators), so the study harness times
them all the same way:

1. **Offline**: ``model = Method(**options).build(training)`` reads a :class:`Training`
   (snapshots from reference runs, the operators of a backend, the parameters the
   snapshots belong to) and returns an :class:`OnlineModel`. Everything expensive
   happens here.
2. **Online**: ``res = model.step(mu)`` with ``mu`` a mapping of named parameters
   (``{"load_factor": 0.4}``, ``{"load_factor": 0.4, "position": 0.3}``; a dynamic model
   reads ``"time"`` and keeps its own state between calls) returns a
   :class:`StepResult` holding the *reduced* state ``q``. This call is what latency
   measures; it never touches a full-size vector.
3. **Reconstruction**: ``u = model.reconstruct(res)`` gives the full dof vector
   (n_dof,), timed separately.

A step never hides a failure: ``StepResult.status`` is ``"ok"``, ``"extrapolation"``
(the parameter lies outside the training envelope; the value is returned and flagged),
``"beyond_validity"`` (past a series' radius of validity, e.g. ANM's a_max) or
``"failed"`` (no value: ``q`` is None and ``message`` says why).

The registry :data:`METHODS` maps names to classes; :func:`make_method` accepts a name or
a class and lists the valid names on an unknown one.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

__all__ = ["Training", "StepResult", "OnlineModel", "RomMethod", "METHODS", "register", "make_method",
           "STEP_STATUSES", "check_parameters"]

STEP_STATUSES = ("ok", "extrapolation", "beyond_validity", "failed")


@dataclass
class Training:
    """What an offline build may use.

    Attributes
    ----------
    snapshots : (n_dof, n_snap) array, optional
        Full displacement vectors of reference runs (columns).
    parameters : list of dict, optional
        The parameters of each snapshot column (same length as ``n_snap``).
    backend : Backend, optional
        Operators (f_int, K_t, loads, mass) of the full model, for Galerkin projection.
    free_dofs : (n_free,) int array, optional
        Dofs the reduced basis lives on (default: the backend problem's free dofs).
    groups : dict, optional
        Per-parameter training sets (e.g. one snapshot matrix per stored load position
        for PODI and Grassmann): ``{key: Training}``.
    info : dict
        Provenance (case, backend, resolution ...).
    """

    snapshots: np.ndarray | None = None
    parameters: list | None = None
    backend: Any = None
    free_dofs: np.ndarray | None = None
    groups: dict | None = None
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.snapshots is not None:
            S = np.asarray(self.snapshots, dtype=float)
            if S.ndim != 2:
                raise ValueError(f"snapshots must be a 2D array (n_dof, n_snap), got shape {S.shape}")
            if not np.all(np.isfinite(S)):
                raise ValueError("snapshots contain a non-finite value")
            self.snapshots = S
            if self.parameters is not None and len(self.parameters) != S.shape[1]:
                raise ValueError(f"parameters: {len(self.parameters)} entries for {S.shape[1]} snapshots")
        if self.free_dofs is None and self.backend is not None:
            self.free_dofs = np.asarray(self.backend.problem.free_dofs)


@dataclass
class StepResult:
    """Outcome of one online step (see the module docstring for ``status``)."""

    q: np.ndarray | None
    status: str = "ok"
    message: str = ""
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        if self.status not in STEP_STATUSES:
            raise ValueError(f"status = {self.status!r}: expected one of {STEP_STATUSES}")
        if self.status == "failed" and self.q is not None:
            raise ValueError("a failed step carries no state (q must be None)")

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def check_parameters(mu, required: tuple, name: str) -> dict:
    """``mu`` as a dict with finite numeric ``required`` keys; ValueError naming the key otherwise."""
    if not isinstance(mu, Mapping):
        raise TypeError(f"{name}.step: mu must be a mapping of parameters, got {type(mu).__name__}")
    out = dict(mu)
    for key in required:
        if key not in out:
            raise ValueError(f"{name}.step: parameter {key!r} missing from mu = {out}")
        v = out[key]
        if not isinstance(v, (int, float, np.floating, np.integer)) or not np.isfinite(v):
            raise ValueError(f"{name}.step: mu[{key!r}] = {v!r} is not a finite number")
    return out


class OnlineModel(ABC):
    """The online phase of a reduced model (returned by :meth:`RomMethod.build`)."""

    #: method name (the registry key)
    name: str = ""

    @property
    @abstractmethod
    def n_reduced(self) -> int:
        """Size of the reduced state ``q``."""

    @abstractmethod
    def step(self, mu: Mapping[str, float]) -> StepResult:
        """Reduced state for parameters ``mu`` (dynamic models: advance one step)."""

    @abstractmethod
    def reconstruct(self, result: StepResult) -> np.ndarray:
        """Full displacement (n_dof,) of a step's reduced state."""

    @property
    def envelope(self) -> dict:
        """The training envelope: ``{parameter: (min, max)}``."""
        return {}

    def reset(self) -> None:
        """Forget any state kept between steps (dynamic models); statics: nothing."""


class RomMethod(ABC):
    """The offline phase: options in the constructor, :meth:`build` from a :class:`Training`."""

    name: str = ""

    @abstractmethod
    def build(self, training: Training) -> OnlineModel:
        """Offline phase; returns the online model."""


METHODS: dict[str, type] = {}


def register(cls):
    """Class decorator: add a :class:`RomMethod` to :data:`METHODS` under ``cls.name``."""
    if not (isinstance(cls, type) and issubclass(cls, RomMethod) and cls.name):
        raise TypeError(f"register: {cls!r} is not a named RomMethod subclass")
    METHODS[cls.name] = cls
    return cls


def make_method(method, **options) -> RomMethod:
    """A :class:`RomMethod` from its registry name or class, with ``options``."""
    if isinstance(method, type) and issubclass(method, RomMethod):
        return method(**options)
    if isinstance(method, RomMethod):
        if options:
            raise TypeError("make_method: options given with an instance")
        return method
    if method not in METHODS:
        raise ValueError(f"unknown ROM method {method!r}; valid: {sorted(METHODS)}")
    return METHODS[method](**options)
