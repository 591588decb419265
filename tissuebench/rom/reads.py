"""The parameters an online model's step reads, and the refusal of any other one.

A step given a parameter it does not read answers at the parameters it does read, with status
ok: ``model.step({"load_factor": 0.3, "E": 6000})`` returned the state at 0.3 whatever ``E``
(and so for ``nu``, ``load_scale``, a ``position`` of a model trained on one load position, a
misspelt key). A sweep refuses such an evaluation when its spec loads
(:mod:`tissuebench.studies.applicability`); through the Python API every model a method builds
refuses it too, installed once for all methods by the contract (:class:`~.base.RomMethod` wraps
``build``, :class:`~.base.OnlineModel` wraps ``start`` and ``variant``; no method has code of
its own for it):

* after the build, :func:`declare` records the keys the model's step reads: ``load_factor``;
  ``time`` for a model stepped in time (kind ``trajectory``, or trained on trajectories); the
  scene parameters its method reads for its training kind (:meth:`~.base.RomMethod.reads`,
  ``Applies.parameters``); and what the model's step reads besides
  (:meth:`~.base.OnlineModel.step_parameters`: a contact's ``node``, a scalpel's
  ``cut_length``, the keys of a baseline's training parameters). A model sliced by ``variant``
  inherits its parent's (:func:`inherit`).
* ``start(mu0)`` refuses a ``mu0`` holding another key, and so does the first step after the
  build or after a ``start`` given no ``mu0``: a ValueError naming the key, the method and the
  keys it reads (:func:`refuse_unread`).

No other step is checked: the check of a step is an instance attribute ``step`` that puts the
model's own step back before it steps, so every later step is the class's, with nothing added
to the haptic path (a step is timed in microseconds). A run that announces its parameters
(``start(mu0)``, as the harness always does) is checked at its start and leaves its steps
alone: the latency protocol restarts its sequence, untimed, between timed passes, and a checked
first step of every pass would be timed. The attributes are set and deleted as attributes,
never through the instance's ``__dict__`` (reading it makes CPython trade the instance's inline
attribute values for a dict, and every attribute read of a step slower).
"""
from __future__ import annotations

from collections.abc import Mapping

__all__ = ["training_kind", "declare", "inherit", "arm", "reads_of", "refuse_unread"]

_DECLARED = "_tb_reads"  # instance attribute: (frozenset of the keys the step reads, method name)


def training_kind(training) -> str:
    """The kind a :class:`~.base.Training` was built as: ``info["training_kind"]`` (what the harness
    records), else what its fields say: ``trajectory`` (trajectory ids), ``positions`` (groups),
    ``operators`` (no snapshots), else ``path``."""
    kind = (getattr(training, "info", None) or {}).get("training_kind")
    if isinstance(kind, str):
        return kind
    if getattr(training, "trajectories", None) is not None:
        return "trajectory"
    if getattr(training, "groups", None):
        return "positions"
    return "operators" if getattr(training, "snapshots", None) is None else "path"


def declare(model, method, training) -> None:
    """Record the keys ``model`` (built by method class ``method`` from ``training``) reads at a
    step (module docstring), and check its first step."""
    kind = training_kind(training)
    scene = getattr(training, "scene", None)
    reads = method.reads(scene, kind) if scene is not None else method.applies.parameters.get(kind, ())
    keys = {"load_factor", *reads, *model.step_parameters()}
    if model.kind == "trajectory" or kind == "trajectory":
        keys.add("time")
    object.__setattr__(model, _DECLARED, (frozenset(keys), str(method.name)))
    arm(model)


def inherit(model, parent) -> None:
    """``model`` (sliced from ``parent`` by ``variant``) reads what ``parent`` reads."""
    declared = getattr(parent, _DECLARED, None)
    if declared is not None:
        object.__setattr__(model, _DECLARED, declared)
        arm(model)


def reads_of(model) -> frozenset | None:
    """The keys ``model``'s step reads, or None when no method's build declared them (a model
    constructed directly)."""
    declared = getattr(model, _DECLARED, None)
    return None if declared is None else declared[0]


def refuse_unread(model, mu, where: str) -> None:
    """ValueError when ``mu`` holds a key ``model`` does not read (nothing declared: nothing checked;
    not a mapping: the step's own parsing refuses it)."""
    declared = getattr(model, _DECLARED, None)
    if declared is None or not isinstance(mu, Mapping):
        return
    keys, method = declared
    if keys.issuperset(mu):
        return
    key = next(k for k in mu if k not in keys)
    raise ValueError(f"{method}.{where}: mu[{key!r}] = {mu[key]!r}, a parameter this model does not read: method "
                     f"{method!r} reads {sorted(keys, key=str)}, so its answer would ignore it (a scene parameter such "
                     "as E, nu or another load position is set on the scene the model is trained on, a case's mu; "
                     "load_scale multiplies the load_factor)")


class _FirstStep:
    """The ``step`` of a model whose run has not stepped yet: checks ``mu``, then puts the model's
    own step back (its class's, or an instance attribute it had) and steps."""

    __slots__ = ("model", "own")

    def __init__(self, model, own):
        self.model, self.own = model, own

    def __call__(self, mu):
        model = self.model
        refuse_unread(model, mu, "step")
        if self.own is None:
            object.__delattr__(model, "step")
        else:
            object.__setattr__(model, "step", self.own)
        try:
            return model.step(mu)
        except BaseException:
            arm(model)  # a first step that raised (a NaN, a missing key) leaves the next one checked
            raise


def arm(model, mu0=None) -> None:
    """Refuse ``mu0`` holding a key ``model`` does not read; without ``mu0``, check its next step."""
    if getattr(model, _DECLARED, None) is None:
        return
    if mu0 is not None:
        refuse_unread(model, mu0, "start")
        return
    own = model.step
    if isinstance(own, _FirstStep):
        return
    if getattr(own, "__self__", None) is model and getattr(own, "__func__", None) is getattr(type(model), "step", None):
        own = None  # the class's step: no instance attribute to put back
    object.__setattr__(model, "step", _FirstStep(model, own))
