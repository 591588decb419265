"""The two ways a full FE baseline is stepped: a static load path by Newton, a trajectory by an integrator.

* :class:`NewtonPathModel` (``kind = "path"``): each step solves the static equilibrium at
  the step's load factor by Newton-Raphson (:func:`~tissuebench.refsolvers.newton.newton_solve`)
  from the last converged state; an increment that does not converge is cut (down to
  ``min_increment`` of the target), a step that still fails is ``"failed"`` and the state
  stays at the last converged one. ``mu["node"]`` (a contact moved onto a mesh node, the
  ``contact_nodes`` evaluation) restarts the path from rest with the problem's single point
  load on that node.
* :class:`TrajectoryModel` (``kind = "trajectory"``): one step of a time integrator of
  :mod:`~tissuebench.refsolvers.dynamics` per call, on the baseline's own
  :class:`~tissuebench.refsolvers.dynamics.SecondOrderSystem` (a linear system is factorised
  once; a nonlinear one does Newton iterations per step).

Both return the solving problem's free displacements as ``q`` (see :class:`.common.FeModel`).
"""
from __future__ import annotations

import numpy as np

from ...refsolvers.dynamics import INTEGRATORS, SecondOrderSystem, make_integrator
from ...refsolvers.newton import newton_solve
from ...refsolvers.sparse_direct import NGSOLVE_MIN_DOFS, factorized
from ..base import StepResult, check_parameters
from .common import DeadLoads, FeModel

__all__ = ["NewtonPathModel", "TrajectoryModel", "newton_options", "dynamic_system", "integrator_choice",
           "first_step_time", "start_binding_holds",
           "load_history", "with_atol", "ScaledHistory"]


def newton_options(who, rtol, max_iterations, min_increment, linear_solver, n_free) -> dict:
    """Keyword options of :func:`newton_solve` for a baseline, checked (ValueError naming the option)."""
    if not (isinstance(rtol, (int, float)) and np.isfinite(rtol) and rtol > 0):
        raise ValueError(f"{who}: rtol must be a finite number > 0, got {rtol!r}")
    if isinstance(max_iterations, bool) or not isinstance(max_iterations, (int, np.integer)) or max_iterations < 1:
        raise ValueError(f"{who}: max_iterations must be a positive integer, got {max_iterations!r}")
    if not (isinstance(min_increment, (int, float)) and 0 < min_increment <= 1):
        raise ValueError(f"{who}: min_increment must lie in (0, 1], got {min_increment!r}")
    if linear_solver == "auto":
        linear_solver = "cholesky" if n_free >= NGSOLVE_MIN_DOFS else "direct"
    if linear_solver not in ("direct", "cholesky", "amg-cg"):
        raise ValueError(f"{who}: linear_solver = {linear_solver!r}; valid: ['auto', 'direct', 'cholesky', 'amg-cg']")
    return {"rtol": float(rtol), "max_iterations": int(max_iterations), "min_increment": float(min_increment),
            "linear_solver": linear_solver}


class NewtonPathModel(FeModel):
    """Static equilibrium by Newton at every step, warm-started along the path (module docstring).

    Parameters
    ----------
    name : str
    backend : Backend
        Operators of the solving problem (its loads are the path's, unless ``contact``).
    fmap : FieldMap
    info : dict
    options : dict
        Keyword options of :func:`newton_solve` (:func:`newton_options`).
    contact : callable ``node -> (n_solve_dof,)``, optional
        The dead force of the contact moved onto a (fine-mesh) node, for ``mu["node"]``.
    """

    kind = "path"

    def __init__(self, name, backend, fmap, info, options, contact=None):
        super().__init__(name, fmap, info)
        self.backend, self.options, self._contact = backend, dict(options), contact
        self._loaded = backend
        self.start()

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Back to rest (the next step starts from u = 0, load factor 0)."""
        self._u = np.zeros(self.backend.ndof)
        self._node = None

    def _on_node(self, node):
        if node == self._node:
            return
        if self._contact is None:
            raise ValueError(f"{self.name}.step: mu['node'] given but this model has no movable contact load")
        self._loaded = DeadLoads(self.backend, self._contact(node))
        self._u = np.zeros(self.backend.ndof)
        self._node = node

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("load_factor",), self.name)
        lam = float(mu["load_factor"])
        out = {"load_factor": lam}
        if "node" in mu:
            self._on_node(int(mu["node"]))
            out["node"] = int(mu["node"])
        u0 = self._u if lam != 0.0 else None
        res = newton_solve(self._loaded, lam, u0=u0, n_increments=1, store_states=False, **self.options)
        iterations = sum(inc.iterations for inc in res.increments)
        if res.status != "success":
            return StepResult(None, "failed", f"{self.name}: {res.message}", {"iterations": iterations}, mu=out)
        self._u = res.u
        return StepResult(res.u[self.fmap.free], "ok", "", {"iterations": iterations}, mu=out)

    def floor_ops(self):
        """The step's unavoidable arithmetic: one Newton iteration at the current state (the
        force and tangent assembled, the tangent factorised and solved); a converged step
        takes at least one."""
        be, free = self.backend, self.fmap.free
        solver = be.make_linear_solver(self.options["linear_solver"], **_solver_options(be, self.options))

        def floor():
            f, K = be.internal_force_and_tangent(self._u)
            solver.solve(K[free][:, free], f[free])
        return floor


def with_atol(name, options: dict, atol: float) -> dict:
    """Integrator ``options`` with Newton's absolute force tolerance ``newton_atol`` (implicit schemes)."""
    if not make_integrator(name).implicit or "newton_atol" in options:
        return dict(options)
    return {**options, "newton_atol": float(atol)}


def _solver_options(backend, options) -> dict:
    if options["linear_solver"] != "amg-cg":
        return {}
    return {"coords": backend.problem.nodes, "free_dofs": backend.problem.free_dofs}


def integrator_choice(who, integrator, scene) -> tuple[str, dict]:
    """``(name, options)``: ``integrator`` None takes the scene's (with its options); a named one
    takes the scene's options only when it is the scene's own; no scene: backward Euler."""
    analysis = getattr(scene, "analysis", None) or {}
    own, own_opts = analysis.get("integrator"), dict(analysis.get("integrator_options", {}))
    if integrator is None:
        return (own, own_opts) if own else ("backward_euler", {})

    if integrator not in INTEGRATORS:
        raise ValueError(f"{who}: integrator = {integrator!r}; valid: {sorted(INTEGRATORS)} (or None: the scene's)")
    return integrator, (own_opts if integrator == own else {})


class ScaledHistory:
    """The load factor the baseline's system is driven with: ``scale * history(t)``.

    A trajectory step receives its load factor in ``mu`` (``load_scale`` folded in, see
    :mod:`tissuebench.studies.evaluation`); the integrators evaluate the load at times inside
    the step (Bathe's mid-step, HHT's weighted ends), so the step sets ``scale`` from the
    driven value at the step's end and the history's shape carries it in between: exact for a
    run whose loads are a constant multiple of the training's."""

    def __init__(self, history):
        self.history, self.scale = history, 1.0

    def __call__(self, t):
        return self.scale * self.history(t)

    def drive(self, t: float, load_factor: float) -> str:
        """Set the scale so that the load factor at ``t`` is ``load_factor``; returns ``""`` or, where
        the history is zero at ``t`` and the driven value is not (no multiple represents it), why."""
        base = float(self.history(t))
        if abs(base) > 1e-300:
            self.scale = load_factor / base
            return ""
        if abs(load_factor) > 1e-300:
            return (f"load factor {load_factor:g} at t = {t:.6g}, where the training's history is 0: driven with "
                    f"the last scale {self.scale:g}")
        return ""


def first_step_time(mu0, dt) -> float | None:
    """The time of a run's first step when ``start`` knows it (``mu0``, the start state's
    parameters, holds ``"time"``: that time plus ``dt``), else None. A trajectory model binds its
    integrator and primes it there (:meth:`~tissuebench.refsolvers.dynamics.base.Integrator.prime`):
    the integrator's start is work of the run's start, untimed, not of its first step, which would
    otherwise miss a haptic frame (10 of the 20 samples beyond the p99 of a 2000-step timing that
    restarts its 200-step trajectory)."""
    return float(mu0["time"]) + float(dt) if mu0 is not None and "time" in mu0 else None


def start_binding_holds(bound_for: float, dt: float, t: float, history) -> bool:
    """Whether the integrator bound by ``start`` for a first step at ``bound_for`` (with the history's
    scale 1) is the one the step at ``t`` would bind after its drive: the step is the one foreseen,
    and the scale does not reach the start state (its load factor is 0, or the scale is still 1)."""
    if t != bound_for:
        return False
    if not isinstance(history, ScaledHistory) or history.scale == 1.0:
        return True
    return float(history.history(bound_for - dt)) == 0.0


def load_history(training, scene) -> ScaledHistory:
    """The load factor versus time of a dynamic case: the training's, else the scene's, scaled
    by the driven load factor of each step (:class:`ScaledHistory`)."""
    history = training.history if training.history is not None else getattr(scene, "history", None)
    if history is None:
        raise ValueError("a trajectory baseline needs the load history (training.history or the scene's)")
    return ScaledHistory(history)


def dynamic_system(backend, training, name: str, linear: bool, history) -> SecondOrderSystem:
    """The baseline's semi-discrete system on ``backend`` (its loads and Dirichlet data), with the
    training system's mass kind (lumped when its M is diagonal) and Rayleigh coefficients, and
    the load ``history``. Without a training system (operators): lumped mass only for an
    explicit ``name`` of integrator."""
    ref = training.system
    if ref is not None:
        lumped = ref.M.nnz == ref.M.shape[0]
        alpha_m, beta_k = ref.alpha_m, ref.beta_k
    else:
        lumped, alpha_m, beta_k = not make_integrator(name).implicit, 0.0, 0.0
    return SecondOrderSystem.from_backend(backend, history, lumped=lumped, alpha_m=alpha_m, beta_k=beta_k,
                                          linear=linear)


class TrajectoryModel(FeModel):
    """One integrator step per call (module docstring).

    Parameters
    ----------
    name : str
    system : SecondOrderSystem
        On the solving problem's dofs.
    integrator : (str, dict)
        Registry name and options (:func:`integrator_choice`).
    fmap : FieldMap
    info : dict
    history : callable
        Load factor versus time (the step's ``mu["load_factor"]`` when it has none).
    """

    kind = "trajectory"

    def __init__(self, name, system, integrator, fmap, info, history):
        super().__init__(name, fmap, info)
        self.system, (self.integrator_name, self.integrator_options) = system, integrator
        self.history = history
        self.info.update(integrator=self.integrator_name, integrator_options=dict(self.integrator_options))
        self._integ = self._pending = self._stopped = self._bound_for = None

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Prepare a run at ``dt`` from ``state0`` (default rest). The integrator is bound at the
        start time ``mu0["time"]`` and primed (:func:`first_step_time`); without a time in ``mu0``,
        at the first step, at ``mu["time"] - dt``."""
        if dt is None:
            raise ValueError(f"{self.name}.start: a trajectory model needs the time step dt")
        u0 = v0 = None
        if state0 is not None:
            u0, v0 = self._initial(state0.get("u")), self._initial(state0.get("v"))
        self._pending, self._integ, self._stopped = (u0, v0, float(dt)), None, None
        if isinstance(self.history, ScaledHistory):
            self.history.scale = 1.0
        self._bound_for = first_step_time(mu0, dt)
        if self._bound_for is not None:
            self._bind(self._bound_for)

    def _bind(self, t):
        u0, v0, dt = self._pending
        self._integ = make_integrator(self.integrator_name, **self.integrator_options)
        self._integ.start(self.system, u0, v0, dt, t - dt)
        self._integ.prime()

    def _initial(self, x):
        if x is None:
            return None
        x = np.asarray(x, dtype=float)
        if self.fmap.same:
            return x
        if np.any(x != 0.0):
            raise ValueError(f"{self.name}.start: a non-rest initial state of the fine mesh cannot be put on the "
                             "coarser mesh (only a start from rest is supported)")
        return None

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("time",), self.name)
        t = float(mu["time"])
        unrepresented = ""
        if "load_factor" in mu and isinstance(self.history, ScaledHistory):  # the driven load (load_scale folded
            # in) reaches the system, not the training's; before the first step binds the integrator (its a0)
            unrepresented = self.history.drive(t, float(mu["load_factor"]))
        if getattr(self, "_bound_for", None) is not None:  # bound by start: for this step, else again here
            if not start_binding_holds(self._bound_for, self._pending[2], t, self.history):
                self._integ = None
            self._bound_for = None
        if self._integ is None:
            if getattr(self, "_pending", None) is None:
                raise RuntimeError(f"{self.name}: call start(mu0, state0, dt) before step()")
            self._bind(t)
        integ = self._integ
        if self._stopped is not None:  # a failed step left the state behind: the run has ended there
            return StepResult(None, "failed", self._stopped, {"iterations": 0}, mu=dict(mu))
        if abs(t - (integ.t + integ.dt)) > 1e-6 * integ.dt:
            raise ValueError(f"{self.name}.step: mu['time'] = {t!r} is not the next step {integ.t + integ.dt!r} "
                             f"(dt = {integ.dt!r})")
        out = {"time": t, "load_factor": float(mu["load_factor"]) if "load_factor" in mu else float(self.history(t))}
        rep = integ.step()
        if not rep.converged:
            self._stopped = f"{self.name}: stopped at t = {integ.t + integ.dt:.6g}: {rep.message}"
            return StepResult(None, "failed", f"{self.name}: {rep.message}", {"iterations": rep.iterations}, mu=out)
        status = "extrapolation" if unrepresented else "ok"
        return StepResult(integ.u, status, unrepresented and f"{self.name}: {unrepresented}",
                          {"fixed": integ.uc, "iterations": rep.iterations}, mu=out)

    def floor_ops(self):
        """The step's unavoidable arithmetic, built at its first call (the step size is known once
        the model has been started): a linear system, one solve with a factorised effective
        matrix ``M / dt^2 + K`` (the integrators' own has the same pattern and cost); a nonlinear
        one, an iteration of Newton: the tangent assembled at the current state, factorised, solved."""
        sys, state = self.system, {}

        def floor():
            if "dt" not in state:
                state["dt"] = self._integ.dt if self._integ is not None else self._pending[2]
                state["b"] = np.ones(len(sys.free))
                if sys.linear:
                    state["solve"] = factorized(sys.M_ff / state["dt"] ** 2 + sys.K0_ff)
            if sys.linear:
                state["solve"](state["b"])
                return
            u = self._integ.full_u() if self._integ is not None else np.zeros(sys.n)
            J = sys.M_ff / state["dt"] ** 2 + sys.K_t(u[sys.free], None, u[sys.fixed])
            factorized(J)(state["b"])
        return floor
