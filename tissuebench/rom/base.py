"""The contract every reduced-order model follows: offline build, online start/step, outputs, reconstruction.

Two phases, the same for every method family (POD-Galerkin, ANM-POD, PODI, Grassmann,
PGD, skinning-cubature, direct time integrators, baselines), so the sweep harness
(:mod:`tissuebench.studies`) times them all the same way:

1. **Offline**: ``model = make_method(name, **options).build(training)`` reads a
   :class:`Training` (snapshots from reference runs, the operators of a backend or a 1D
   model, the parameters the snapshots belong to, linear output functionals) and returns
   an :class:`OnlineModel`. Everything expensive happens here.
2. **Online**: ``model.start(mu0, state0, dt)`` (not timed: factorisations per ``dt``
   belong here), then ``res = model.step(mu)`` per step with ``mu`` a mapping of named
   parameters (``{"load_factor": 0.4}``, ``{"load_factor": 0.4, "position": 0.3}``; a
   ``trajectory`` model reads ``{"time": t, "load_factor": history(t)}``, the load of the
   step it advances to, and keeps its state between calls) returns a :class:`StepResult`
   holding the *reduced* state ``q``. ``model.outputs(res)`` gives the monitored scalars
   (tool-tip displacement ...) without the full field. ``step`` + ``outputs`` is the
   haptic step that latency measures; neither touches a full-size vector.
3. **Reconstruction**: ``u = model.reconstruct(res)`` gives the full dof vector (n_dof,),
   including the prescribed (Dirichlet) values at that step; timed separately.
4. **Floor**: ``model.floor_ops()`` returns a zero-argument callable doing only the
   arithmetic a haptic step cannot avoid at the model's sizes (:mod:`.online`); the latency
   protocol times it beside the step and reports ``efficiency = floor / haptic median``.

A step reads the parameters its method declares (:meth:`RomMethod.reads`, ``Applies.parameters``)
and those of :meth:`OnlineModel.step_parameters`; a ``mu`` with any other key (``E``, ``nu``,
``load_scale``, a misspelt one) is refused at ``start(mu0)`` and at the first step after the
build or a ``start`` given no ``mu0``,
naming the key, the method and the keys it reads (:mod:`.reads`: installed here for every
method, checked once per run, nothing added to later steps).

``OnlineModel.kind`` says how a model is driven: ``"map"`` (a static state at any ``mu``,
in any order), ``"path"`` (a static load path followed in increasing load factor: warm
starts, continuation) or ``"trajectory"`` (time stepping from ``state0``).

A step never hides a failure: ``StepResult.status`` is ``"ok"``, ``"extrapolation"``
(the parameter lies outside the training envelope; the value is returned and flagged),
``"beyond_validity"`` (past a series' radius of validity, e.g. ANM's a_max) or
``"failed"`` (no value: ``q`` is None and ``message`` says why).

The registry :data:`METHODS` (:mod:`.registry`, below this module) maps names to classes, the
methods of other packages included (:mod:`.plugins`, above it); :func:`register` adds a class it
checks (:func:`check_method_class`); :func:`make_method` accepts a name, a ``"module:Class"``
name or a class and lists the valid names on an unknown one; :meth:`RomMethod.option_names` lists
the options a method takes (a grid over another one is refused by name).
"""
from __future__ import annotations

import functools
import inspect
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np

from . import reads
from .parameters import check_parameters
from .registry import METHOD_NAME, METHODS

__all__ = ["Training", "StepResult", "DeferredStepResult", "OnlineModel", "RomMethod", "METHODS", "register",
           "make_method", "STEP_STATUSES", "MODEL_KINDS", "check_parameters", "LinearReconstruction", "method_class",
           "Applies", "POLYNOMIAL_MATERIALS", "check_choice"]

STEP_STATUSES = ("ok", "extrapolation", "beyond_validity", "failed")
MODEL_KINDS = ("map", "path", "trajectory")
#: the materials whose equilibrium is a cubic polynomial of the displacement (ANM, the SVK tensors)
POLYNOMIAL_MATERIALS = ("linear", "svk")


@dataclass(frozen=True)
class Applies:
    """What a method needs of a scene, and the evaluation parameters its step reads.

    Declared once on each method class (``applies = Applies(...)``; the default ``Applies()``
    is: finite-element scenes, any material, mesh and loads, a step that reads only
    ``load_factor`` and ``time``). ``tissuebench methods SCENE`` and the sweep's spec load
    check it (:mod:`tissuebench.studies.applicability`) before any reference is computed, so
    a user learns what applies without waiting for a build to refuse. The analysis (static
    or dynamic) follows from the training kinds and the model kind. A need the fields cannot
    say is checked by overriding :meth:`RomMethod.why_not` (calling ``super()``).

    Attributes
    ----------
    models : tuple of str
        Scene models it builds on: ``"fe"``, ``"poisson1d"``, ``"frame2dof"``, ``"hermite_beam"``.
    materials : tuple of str, optional
        ``[material] name`` values it needs (None: any; :data:`POLYNOMIAL_MATERIALS` for the
        methods that need the SVK tensors).
    dead_loads : bool
        No follower pressure (the load may not depend on the displacement).
    homogeneous_dirichlet : bool
        No nonzero prescribed displacement.
    point_load : bool
        Exactly one ``[[load]]``, a point load on one node (a vademecum of its position).
    needs_cut : bool
        A ``[cut]`` table (an incision to follow).
    mesh_builders : tuple of str, optional
        The mesh builders whose meshes it needs (None: any mesh, a file's included).
    parameters : dict
        Per training kind, the ``mu`` keys its step reads besides ``load_factor`` and ``time``
        (``{"positions": ("position",)}``): an evaluation that changes another scene
        parameter is refused at spec load, never returned as ok.
    linear_model : bool
        A linear model (the stiffness at rest): on a nonlinear scene it applies, and says so.
    """

    models: tuple = ("fe",)
    materials: tuple | None = None
    dead_loads: bool = False
    homogeneous_dirichlet: bool = False
    point_load: bool = False
    needs_cut: bool = False
    mesh_builders: tuple | None = None
    parameters: dict = field(default_factory=dict)
    linear_model: bool = False


@dataclass
class Training:
    """What an offline build may use.

    Attributes
    ----------
    snapshots : (n_dof, n_snap) array, optional
        Full displacement vectors of reference runs (columns), Dirichlet values included.
    parameters : list of dict, optional
        The parameters of each snapshot column (same length as ``n_snap``), e.g.
        ``{"load_factor": 0.5}``, ``{"position": 0.1, "load_factor": 1.0}``,
        ``{"time": 0.01, "load_factor": 0.2}``.
    backend : Backend, optional
        Operators (f_int, K_t, loads, mass, element quantities) of the full model.
    free_dofs : (n_free,) int array, optional
        Dofs the reduced basis lives on (default: the backend problem's free dofs).
    groups : dict, optional
        Per-parameter training sets (e.g. one per stored load position for PODI and
        Grassmann): ``{key: Training}``.
    outputs : dict of str -> (n_dof,) array
        Linear output functionals ``y = c @ u`` of the scene's monitored scalars (a point
        displacement component ...); models reduce them offline (:meth:`OnlineModel.attach_outputs`).
    trajectories : (n_snap,) int array, optional
        Which run each snapshot column comes from (dynamics: one id per reference run).
    velocities : (n_dof, n_snap) array, optional
        Velocities of trajectory snapshots (dynamics).
    system : object, optional
        A dynamics system (:class:`~tissuebench.refsolvers.dynamics.SecondOrderSystem`) or a
        1D model, for methods that step in time or need M, C.
    history : callable, optional
        Load factor versus time ``history(t)`` of the training runs (dynamics).
    dt : float, optional
        Time step of the training runs [s].
    scene : Scene, optional
        The validated scene (:class:`~tissuebench.cases.scene.Scene`) the training comes from,
        for methods that build from the scene itself: the PGD vademecums (geometry, ``[cut]``,
        ``[methods.*]``) and the practitioner baselines (a coarser mesh, the integrator). The
        harness always passes it; read it with :func:`~.training_scene.scene_of`.
    info : dict
        Provenance (case, backend, resolution ...).
    """

    snapshots: np.ndarray | None = None
    parameters: list | None = None
    backend: Any = None
    free_dofs: np.ndarray | None = None
    groups: dict | None = None
    outputs: dict = field(default_factory=dict)
    trajectories: np.ndarray | None = None
    velocities: np.ndarray | None = None
    system: Any = None
    history: Any = None
    dt: float | None = None
    scene: Any = None
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
            if self.velocities is not None and np.shape(self.velocities) != S.shape:
                raise ValueError(f"velocities: shape {np.shape(self.velocities)} differs from snapshots {S.shape}")
        if self.free_dofs is None and self.backend is not None:
            self.free_dofs = np.asarray(self.backend.problem.free_dofs)
        for name, c in self.outputs.items():
            c = np.asarray(c, dtype=float)
            if c.ndim != 1 or not np.all(np.isfinite(c)):
                raise ValueError(f"outputs[{name!r}] must be a finite (n_dof,) vector, got shape {c.shape}")
            self.outputs[name] = c

    def parameter_values(self, key: str) -> np.ndarray:
        """The values of parameter ``key`` over the snapshot columns (ValueError if one lacks it)."""
        try:
            return np.array([float(p[key]) for p in (self.parameters or [])])
        except (KeyError, TypeError):
            raise ValueError(f"training.parameters need {key!r} for every snapshot") from None


@dataclass(slots=True)
class StepResult:
    """Outcome of one online step (see the module docstring for ``status``).

    ``q`` belongs to the result (a model never writes into it after returning it); ``mu`` may
    be the mapping the step was called with, not a copy (the protocol and the drivers never
    change a ``mu`` after stepping with it)."""

    q: np.ndarray | None
    status: str = "ok"
    message: str = ""
    info: dict = field(default_factory=dict)
    mu: dict | None = None

    def __post_init__(self):
        if self.status != "ok":  # the haptic path: one comparison
            if self.status not in STEP_STATUSES:
                raise ValueError(f"status = {self.status!r}: expected one of {STEP_STATUSES}")
            if self.status == "failed" and self.q is not None:
                raise ValueError("a failed step carries no state (q must be None)")

    @property
    def ok(self) -> bool:
        return self.status == "ok"


_MESSAGE = StepResult.__dict__["message"]  # the slot of StepResult.message


class DeferredStepResult(StepResult):
    """A :class:`StepResult` whose ``message`` is formatted at its first reading: ``message_of``
    (a zero-argument callable returning the text) runs then, once. A haptic loop steps past
    the training envelope at every step and rarely reads why; the message is the same as an
    eager one whenever it is read."""

    __slots__ = ("_message_of",)

    def __init__(self, q, status: str, message_of, info=None, mu=None):
        self.q, self.status, self.info, self.mu, self._message_of = q, status, {} if info is None else info, mu, \
            message_of
        if message_of is None:
            _MESSAGE.__set__(self, "")
        self.__post_init__()

    @property
    def message(self) -> str:
        f = getattr(self, "_message_of", None)
        if f is not None:
            self._message_of = None
            _MESSAGE.__set__(self, f())
        return _MESSAGE.__get__(self)

    @message.setter
    def message(self, value: str) -> None:
        self._message_of = None
        _MESSAGE.__set__(self, value)


def check_choice(who: str, name: str, value, valid) -> None:
    """Refuse an option ``value`` outside ``valid``, naming the method, the option and the value."""
    if value not in valid:
        raise ValueError(f"{who}: {name} = {value!r}; valid: {list(valid)}")


class OnlineModel(ABC):
    """The online phase of a reduced model (returned by :meth:`RomMethod.build`).

    Subclasses implement :meth:`step`, :meth:`reconstruct` and :attr:`n_reduced`; a model
    whose full field is affine in ``q`` (``u[free] = B q``, ``u[fixed] = u_D(mu)``) also
    implements :meth:`output_map`, and then :meth:`outputs` costs ``n_out x n_reduced``.
    ``info`` (a dict attribute or property, optional) is the JSON-able record of the offline
    build (modes, iterations, stop reasons, floors); a sweep stores it as ``model_info``.
    """

    #: method name (the registry key)
    name: str = ""
    #: how the model is driven: "map", "path" or "trajectory" (module docstring)
    kind: ClassVar[str] = "map"

    @property
    @abstractmethod
    def n_reduced(self) -> int:
        """Size of the reduced state ``q``."""

    def __init_subclass__(cls, **kwargs):
        # every model refuses a parameter it does not read (:mod:`.reads`): a start checks mu0 (or,
        # given none, the run's first step), a sliced variant reads what its parent reads
        super().__init_subclass__(**kwargs)
        for name, wrap in (("start", _checking_start), ("variant", _inheriting_variant)):
            own = cls.__dict__.get(name)
            if callable(own) and not getattr(own, "_tb_reads", False):
                setattr(cls, name, wrap(own))

    def start(self, mu0: Mapping[str, float] | None = None, state0: Mapping[str, np.ndarray] | None = None,
              dt: float | None = None) -> None:
        """Prepare a run: forget state kept between steps; a trajectory model projects
        ``state0`` (``{"u": (n_dof,), "v": (n_dof,)}``, default rest) and prepares for ``dt``.

        Statics: nothing. Not timed by the latency protocol. Every model's ``start`` (this one
        or an override) refuses a ``mu0`` holding a parameter the model does not read; given no
        ``mu0``, it has the run's first step checked so (:mod:`.reads`).
        """
        reads.arm(self, mu0)

    def step_parameters(self) -> tuple:
        """The ``mu`` keys this model's step reads besides ``load_factor``, ``time`` (a model stepped
        in time) and the scene parameters its method reads (:meth:`RomMethod.reads`); any other key
        is refused (:mod:`.reads`). Default: what the harness's hooks imply, ``node`` for a model
        with :meth:`contact_nodes`, ``node`` and ``cut_length`` for one with :meth:`incision_strip`.
        A model whose step reads more says so here (calling ``super()``)."""
        out = ("node",) if self.contact_nodes() is not None else ()
        return out + (("node", "cut_length") if self.incision_strip() is not None else ())

    def reset(self) -> None:
        """Alias of :meth:`start` with no arguments (kept for existing callers)."""
        self.start()

    @abstractmethod
    def step(self, mu: Mapping[str, float]) -> StepResult:
        """Reduced state for parameters ``mu`` (trajectory models: advance one step)."""

    def solve(self, mus: Sequence[Mapping[str, float]], state0=None, dt=None) -> list[StepResult]:
        """``start(mus[0], state0, dt)`` then one :meth:`step` per ``mu``."""
        mus = list(mus)
        self.start(mus[0] if mus else None, state0, dt)
        return [self.step(mu) for mu in mus]

    @abstractmethod
    def reconstruct(self, result: StepResult) -> np.ndarray:
        """Full displacement (n_dof,) of a step's reduced state, prescribed values included."""

    @property
    def envelope(self) -> dict:
        """The training envelope: ``{parameter: (min, max)}``."""
        return {}

    # ---------------------------------------------------------------- floor
    def floor_ops(self) -> Callable[[], object]:
        """A zero-argument callable doing only the arithmetic a haptic step (``step`` +
        ``outputs``) cannot avoid at this model's sizes, on preallocated arrays (:mod:`.online`).

        The latency protocol times it beside the step, in the same process; ``efficiency =
        floor / haptic median`` says how much of a step is its arithmetic and how much is
        overhead. Default: a reduced solve of size :attr:`n_reduced` with a stored factor
        and the output product (:func:`~.online.solve_floor`); a method whose step does other
        unavoidable work (a series evaluation, an interpolation, a Newton iteration) declares
        that instead.
        """
        from .online import solve_floor

        return solve_floor(self.n_reduced, len(self.output_names))

    # ---------------------------------------------------------------- outputs
    def output_map(self):
        """``(free_dofs, B)`` when ``u[free] = B @ q`` (fixed dofs: the prescribed values),
        else None (outputs then go through :meth:`reconstruct`)."""
        return None

    def prescribed(self, mu) -> tuple[np.ndarray, np.ndarray]:
        """``(fixed_dofs, values)`` of the prescribed displacements at ``mu`` (default: none)."""
        return np.zeros(0, dtype=np.int64), np.zeros(0)

    def prescribed_affine(self):
        """``(v0, v1)`` with ``prescribed(mu)[1] == v0 + mu["load_factor"] * v1`` for every
        ``mu``, or None when the values are not affine in the load factor (a motion) or not
        known to be (the default): outputs then evaluate :meth:`prescribed` at every step."""
        fixed, _ = self.prescribed(None)
        return (np.zeros(0), np.zeros(0)) if not len(fixed) else None

    def attach_outputs(self, operators: Mapping[str, np.ndarray]) -> None:
        """Offline: reduce linear output functionals ``{name: c (n_dof,)}`` (``y = c @ u``).

        With ``u[free] = B q`` (:meth:`output_map`) the outputs are one product ``C_r @ q``
        (``C_r = C[:, free] B``), plus the share of the prescribed values: ``c0 + lam c1``
        when they are affine in the load factor (:meth:`prescribed_affine`; nothing at all
        when they are zero), else ``C[:, fixed] @ prescribed(mu)`` per step.
        """
        names = list(operators)
        if not names:
            self._outputs = ((), None, None, None)
            return
        C = np.array([np.asarray(operators[n], float) for n in names]).reshape(len(names), -1)
        lin = self.output_map()
        if lin is None:
            self._outputs = (names, C, None, None)
            return
        free, B = lin
        fixed, _ = self.prescribed(None)
        fixed_part = None
        if len(fixed):
            affine = self.prescribed_affine()
            if affine is None or any(np.shape(v) != (len(fixed),) for v in affine):
                fixed_part = C[:, fixed]
            else:
                c0, c1 = C[:, fixed] @ affine[0], C[:, fixed] @ affine[1]
                fixed_part = (c0, c1) if np.any(c0) or np.any(c1) else None
        self._outputs = (names, C, np.ascontiguousarray(C[:, free] @ B), fixed_part)

    def outputs(self, result: StepResult) -> dict:
        """The attached outputs at a step (``{}`` if none attached; NaN for a failed step)."""
        names, C, C_r, fixed_part = getattr(self, "_outputs", ((), None, None, None))
        if not names:
            return {}
        q = result.q
        if q is None:
            return {n: float("nan") for n in names}
        if C_r is None:
            y = C @ self.reconstruct(result)
        else:
            y = np.dot(C_r, q)  # np.dot: less call overhead than @ at these sizes
            if fixed_part is not None:
                if type(fixed_part) is tuple:
                    c0, c1 = fixed_part
                    y += c0 + float(result.mu["load_factor"]) * c1
                else:
                    y += np.dot(fixed_part, self.prescribed(result.mu)[1])
        return dict(zip(names, y.tolist()))

    @property
    def output_names(self) -> list:
        return list(getattr(self, "_outputs", ((),))[0])

    # ---------------------------------------------------------------- optional hooks of the harness
    # What the sweep harness (tissuebench.studies) asks of some models: it calls these and reads
    # no other attribute of a model. The defaults say "not this model's".
    def contact_nodes(self) -> np.ndarray | None:
        """The mesh nodes where this model can place its contact (a point load moving over an
        accessible surface), as ``(n_c,)`` int node ids of the intact mesh; the ``contact_nodes``
        evaluation measures the model at some of them. Default None: the model has none
        (surface vademecums and the practitioner baselines built for a contact override it)."""
        return None

    def incision_strip(self):
        """The :class:`~tissuebench.rom.pgd.strip.IncisionStrip` this model cuts along
        (``max_cut_length``, ``incision(c)``, ``tip(c)``, ``depth_fraction``): the
        ``cut_lengths`` evaluation solves the full model of each cut of it. Default None: the
        model does not cut."""
        return None

    def contact_force(self) -> np.ndarray | None:
        """The ``(3,)`` force [the scene's force unit] this model's contact applies at its node at
        load factor 1 (what the ``cut_lengths`` references load the tip node with). Default None:
        no contact force of its own."""
        return None

    def variant(self, **options) -> "OnlineModel | None":
        """This model with some of its method's nested options (:attr:`RomMethod.nested`, e.g.
        fewer ``n_modes``) set to ``options``, sliced from this model's offline data without a
        new build, and the same as a fresh build with those options. Default None: this model
        cannot be sliced, the harness builds the variant afresh."""
        return None


def _checking_start(start):
    """``start`` that first refuses a ``mu0`` the model does not read and has the next step checked."""
    @functools.wraps(start)
    def checked(self, *args, **kwargs):
        reads.arm(self, args[0] if args else kwargs.get("mu0"))
        return start(self, *args, **kwargs)
    checked._tb_reads = True
    return checked


def _inheriting_variant(variant):
    """``variant`` whose sliced model reads what this one reads."""
    @functools.wraps(variant)
    def inheriting(self, *args, **kwargs):
        model = variant(self, *args, **kwargs)
        if isinstance(model, OnlineModel) and model is not self:
            reads.inherit(model, self)
        return model
    inheriting._tb_reads = True
    return inheriting


def _declaring_build(build):
    """``build`` whose model refuses a parameter it does not read (:func:`.reads.declare`) and, for a
    method with a :attr:`RomMethod.counterpart`, records it in the model's ``info`` (``"counterpart":
    [name, options]``: a sweep stores it, so a report pairs the unit where the class is not installed)."""
    @functools.wraps(build)
    def declaring(self, training, *args, **kwargs):
        model = build(self, training, *args, **kwargs)
        if isinstance(model, OnlineModel) and isinstance(training, Training):
            reads.declare(model, type(self), training)
            declared = type(self).counterpart_for((training.info or {}).get("training_kind")) \
                if type(self).counterpart is not None else None
            if declared is not None and isinstance(getattr(model, "info", None), dict):
                model.info.setdefault("counterpart", [declared[0], declared[1]])
        return model
    declaring._tb_reads = True
    return declaring


class LinearReconstruction:
    """Mixin for models with ``u[free] = B q`` and prescribed values on the fixed dofs.

    Needs attributes ``basis`` (n_free, n), ``free_dofs``, ``ndof`` and optionally
    ``problem`` (a :class:`~tissuebench.refsolvers.Problem` whose prescribed values at the
    step's load factor fill the fixed dofs).
    """

    problem = None

    def output_map(self):
        return self.free_dofs, self.basis

    def prescribed(self, mu):
        """Fixed dofs and their values at ``mu["load_factor"]`` (``mu`` None: the dofs, values at 1)."""
        pb = self.problem
        if pb is None or not len(pb.fixed_dofs):
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        lam = 1.0 if mu is None else float(mu["load_factor"])
        return pb.fixed_dofs, pb.prescribed_values(lam)

    def prescribed_affine(self):
        """Affine in the load factor unless a Dirichlet set prescribes a motion (a rotation)."""
        pb = self.problem
        if pb is None or not len(pb.fixed_dofs):
            return np.zeros(0), np.zeros(0)
        if any(getattr(d, "motion", None) is not None for d in pb.dirichlet):
            return None
        v0 = pb.prescribed_values(0.0)
        return v0, pb.prescribed_values(1.0) - v0

    def reconstruct(self, result: StepResult) -> np.ndarray:
        if result.q is None:
            raise ValueError(f"{self.name}.reconstruct: the step failed ({result.message}); no state")
        u = np.zeros(self.ndof)
        u[self.free_dofs] = self.basis @ result.q
        fixed, values = self.prescribed(None)
        if len(fixed) and np.any(values != 0.0):
            if result.mu is None:
                raise ValueError(f"{self.name}.reconstruct: the result carries no mu, so the prescribed "
                                 "displacements cannot be placed")
            u[fixed] = self.prescribed(result.mu)[1]
        return u


class RomMethod(ABC):
    """The offline phase: options in the constructor, :meth:`build` from a :class:`Training`.

    Class attributes: ``name`` (registry key), ``kind`` (of the online model), ``nested``
    (options a sweep slices from one build of their largest value, e.g. ``n_modes``: declared
    only by a method whose model's :meth:`OnlineModel.variant` slices them, which the contract
    test checks; a method that cannot slice declares none, so no parent is built for nothing),
    ``training_kinds`` (the training sets it can learn from: "path", "positions",
    "trajectory", "operators"), ``applies`` (:class:`Applies`: what it needs of a scene and
    the parameters its step reads; checked before any work), ``counterpart`` (the shipped method of
    the same family it is measured beside: :meth:`counterpart_for`).
    """

    name: ClassVar[str] = ""
    kind: ClassVar[str] = "map"
    nested: ClassVar[tuple] = ()
    training_kinds: ClassVar[tuple] = ("path",)
    applies: ClassVar[Applies] = Applies()
    #: ``(name, options)`` of the method of the same family this one is measured beside (a library's
    #: ECSW beside ``("pod_galerkin", {"hyper": "ecsw"})``), or ``{training kind: (name, options)}``
    #: where it differs by training kind; None: none. The report pairs the units of a sweep by it.
    counterpart: ClassVar[tuple | dict | None] = None
    #: options that refine a model at a fixed basis size, which ``tissuebench fit`` tries beside a
    #: larger basis once more training no longer helps: ``{option: factor}``, each refinement
    #: multiplying the option's value by ``factor`` (below 1: a tolerance tightened, ECSW's cubature
    #: ``{"ecsw_tol": 0.5}``); :meth:`refinements_for` says which change a given option set
    refinements: ClassVar[dict] = {}

    def __init_subclass__(cls, **kwargs):
        # the model of every build refuses a parameter it does not read (:mod:`.reads`)
        super().__init_subclass__(**kwargs)
        build = cls.__dict__.get("build")
        if callable(build) and not getattr(build, "__isabstractmethod__", False) and \
                not getattr(build, "_tb_reads", False):
            cls.build = _declaring_build(build)

    @classmethod
    def why_not(cls, scene, options: Mapping | None = None) -> str:
        """Why this method does not apply to ``scene`` (a validated :class:`~tissuebench.cases.scene.Scene`)
        with ``options`` (None: some option set), or ``""`` when it does: the checks of
        :attr:`applies` that need only the scene. A method with a need the declaration cannot
        say overrides it (and calls ``super()``). A method that cannot run here at all says why
        first (:meth:`unavailable`)."""
        gone = cls.unavailable()
        if gone:
            return gone
        a, model = cls.applies, getattr(scene, "model", "fe")
        if model not in a.models:
            names = {"fe": "finite-element"}
            return f"needs a {' or '.join(names.get(m, m) for m in a.models)} scene; this one is a {model} model"
        material = (getattr(scene, "material", None) or {}).get("name")
        if a.materials is not None and material not in a.materials:
            return (f"material {material!r} is not polynomial in the displacement; needs "
                    f"{' or '.join(repr(m) for m in a.materials)} (the reduced SVK tensors)"
                    if tuple(a.materials) == POLYNOMIAL_MATERIALS else
                    f"material {material!r}; needs {' or '.join(repr(m) for m in a.materials)}")
        loads = list(getattr(scene, "loads", []))
        if a.dead_loads and any(ld["type"] == "follower_pressure" for ld in loads):
            return "a follower pressure depends on the displacement; needs dead loads"
        if a.point_load and (len(loads) != 1 or loads[0]["type"] != "point"):
            return (f"needs exactly one point load (a vademecum of its position); the scene has "
                    f"{[ld['type'] for ld in loads]}")
        if a.point_load and model == "fe" and (loads[0].get("distribute") == "interpolate" or "nearest" not in
                                               loads[0]["region"] or loads[0]["region"].get("count", 1) != 1):
            return (f"needs its point load on one node (region nearest with count = 1, not interpolated); the "
                    f"scene's acts on {loads[0]['region']}")
        if a.homogeneous_dirichlet and any("motion" in d or any(v != 0.0 for v in d.get("value", []))
                                           for d in getattr(scene, "dirichlet", [])):
            return "a [[dirichlet]] entry prescribes a nonzero displacement; needs homogeneous (fixed) supports"
        if a.needs_cut and getattr(scene, "cut", None) is None:
            return "needs a [cut] table (an incision to follow); the scene has none"
        if a.mesh_builders is not None and model == "fe":
            builder = (getattr(scene, "mesh_spec", None) or {}).get("builder")
            if builder not in a.mesh_builders:
                where = f"the {builder!r} builder's" if builder not in (None, "file") else "a mesh file's"
                return (f"needs a mesh of the {' or '.join(repr(b) for b in a.mesh_builders)} builder (its layered "
                        f"anterior surface is the vademecum's parameter domain); the scene's mesh is {where}")
        return ""

    @classmethod
    def refinements_for(cls, options: Mapping) -> dict:
        """The :attr:`refinements` that change the model built with ``options`` (default: every one);
        a method whose refinement applies only with some option (ECSW's tolerance with ``hyper =
        "ecsw"``) overrides it."""
        return dict(cls.refinements)

    @classmethod
    def unavailable(cls) -> str:
        """Why this method cannot run in this Python environment (a library it wraps is not installed:
        ``"needs ezyrb, which is not installed (pip install ezyrb)"``), or ``""`` (the default). It
        applies nowhere then (:meth:`why_not`), and a sweep spec naming it skips its units, saying why,
        where a method that applies to none of a spec's cases is an error."""
        return ""

    @classmethod
    def reads(cls, scene, training_kind: str) -> tuple:
        """The scene parameters (``Scene.at`` keys) its step reads when trained as ``training_kind``
        on ``scene``, besides the load factor and the time (default: ``applies.parameters``); a
        built model refuses any key that neither this nor its ``step_parameters`` names."""
        return tuple(cls.applies.parameters.get(training_kind, ()))

    @classmethod
    def note(cls, scene) -> str:
        """What a user should know when the method applies (a linear model on a nonlinear scene)."""
        material = (getattr(scene, "material", None) or {}).get("name")
        if cls.applies.linear_model and material not in (None, "linear"):
            return f"a linear model (the stiffness at rest) of a {material} material"
        return ""

    @classmethod
    def counterpart_for(cls, training_kind: str | None = None) -> tuple[str, dict] | None:
        """``(name, options)`` of the method this one is paired with when trained as ``training_kind``
        (:attr:`counterpart`), or None; ValueError naming the class when the declaration is malformed."""
        c = cls.counterpart
        if isinstance(c, Mapping):
            c = c.get(training_kind)
        if c is None:
            return None
        if not (isinstance(c, tuple) and len(c) == 2 and isinstance(c[0], str) and c[0]
                and isinstance(c[1], Mapping)):
            raise ValueError(f"{cls.__name__}.counterpart = {cls.counterpart!r}: expected (method name, options dict), "
                             "a dict of them by training kind, or None")
        return c[0], dict(c[1])

    @classmethod
    def option_names(cls) -> list[str]:
        """The keyword options of the constructor."""
        return [p.name for p in inspect.signature(cls.__init__).parameters.values()
                if p.name != "self" and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]

    @classmethod
    def option_defaults(cls) -> dict:
        """``{option: default}`` of the constructor's keyword options that have a default."""
        return {p.name: p.default for p in inspect.signature(cls.__init__).parameters.values()
                if p.name in cls.option_names() and p.default is not p.empty}

    @classmethod
    def check_options(cls, options: Mapping) -> None:
        """ValueError naming an option the method does not take, listing the valid ones."""
        unknown = sorted(set(options) - set(cls.option_names()))
        if unknown:
            raise ValueError(f"method {cls.name!r} takes no option {unknown[0]!r}; valid: {cls.option_names()}")

    @abstractmethod
    def build(self, training: Training) -> OnlineModel:
        """Offline phase; returns the online model."""


# ------------------------------------------------------------ the registry's checks and lookups
def _where(cls) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


def check_method_class(cls, what: str = "register") -> None:
    """TypeError, naming ``what``, for a class that is not a registrable method: not a named
    :class:`RomMethod` subclass (the name must suit a folder name: letters, digits,
    ``_ . -``, starting with a letter), an unknown ``kind``, or abstract methods left."""
    if not (isinstance(cls, type) and issubclass(cls, RomMethod) and cls.name):
        raise TypeError(f"{what}: {cls!r} is not a named RomMethod subclass (tissuebench.rom.RomMethod with a "
                        "class attribute name)")
    if not isinstance(cls.name, str) or not METHOD_NAME.fullmatch(cls.name):
        raise TypeError(f"{what}: {cls.__qualname__}.name = {cls.name!r}: expected a letter then letters, digits, "
                        "'_', '.' or '-' (it names a results folder)")
    if cls.kind not in MODEL_KINDS:
        raise TypeError(f"{what}: {cls.__name__}.kind = {cls.kind!r}; valid: {MODEL_KINDS}")
    refinements = cls.refinements
    if not isinstance(refinements, dict) or not all(
            isinstance(k, str) and isinstance(f, (int, float)) and not isinstance(f, bool) and math.isfinite(f)
            and 0 < f != 1 for k, f in refinements.items()):
        raise TypeError(f"{what}: {cls.__qualname__}.refinements = {refinements!r}: expected {{option name: factor}} "
                        "with each factor finite, positive and not 1")
    if inspect.isabstract(cls):
        raise TypeError(f"{what}: {cls.__qualname__} does not implement {sorted(cls.__abstractmethods__)}")


def register(cls):
    """Class decorator: add a :class:`RomMethod` to :data:`METHODS` under ``cls.name``.

    TypeError for a class :func:`check_method_class` refuses; ValueError when another class is
    registered under that name (both named)."""
    check_method_class(cls)
    existing = dict.get(METHODS, cls.name)
    # the same class imported again (importlib.reload, a test module re-run) is the same method
    if existing is not None and existing is not cls and _where(existing) != _where(cls):
        shipped = "the shipped method" if existing.__module__.split(".")[0] == "tissuebench" else "the method"
        raise ValueError(f"method name {cls.name!r} of {_where(cls)} is taken by {shipped} {cls.name!r} "
                         f"({_where(existing)}); rename one of them")
    METHODS[cls.name] = cls
    return cls


def method_class(method) -> type:
    """The :class:`RomMethod` class of a registry name, a ``"module:Class"`` name (imported
    and registered: :func:`.plugins.load_source`) or a class."""
    if isinstance(method, type) and issubclass(method, RomMethod):
        return method
    if isinstance(method, str) and ":" in method:
        return METHODS.load_source(method)
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"unknown ROM method {method!r}; valid: {sorted(METHODS)} (or 'module:Class' of a method "
                         "in another package)")
    return METHODS[method]


def make_method(method, **options):
    """A :class:`RomMethod` from its registry name, ``"module:Class"`` name or class, with ``options``."""
    if isinstance(method, RomMethod):
        if options:
            raise TypeError("make_method: options given with an instance")
        return method
    cls = method_class(method)
    cls.check_options(options)
    return cls(**options)
