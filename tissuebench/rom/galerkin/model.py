"""The online POD-Galerkin model (trajectory kind): one step of the reference's integrator in
the reduced space per call.

``start`` projects the initial state on the basis; the first ``step`` binds the integrator
(HHT, Newmark, Bathe or backward Euler of :mod:`~tissuebench.refsolvers.dynamics`) to the
:class:`~.system.ReducedSystem` at ``mu["time"] - dt``; every step then advances it to
``mu["time"]`` with the load factor ``mu["load_factor"]`` (the driven load: another amplitude
reaches the model through it, :class:`~..fe_baselines.stepping.ScaledHistory`). The step result
holds ``q`` (``u_free = V q``; the prescribed dofs at the step's load factor), so outputs cost
``n_out x r``.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from ...refsolvers.dynamics import make_integrator
from ..base import LinearReconstruction, OnlineModel, StepResult, check_parameters
from ..fe_baselines.stepping import first_step_time, start_binding_holds

__all__ = ["GalerkinModel"]


class GalerkinModel(LinearReconstruction, OnlineModel):
    """See the module docstring.

    Parameters
    ----------
    basis : (n_free, r) array
    free : (n_free,) int array
    backend : Backend
    system : ReducedSystem
    integrator : (str, dict)
        Registry name and options (Newton's included).
    history : ScaledHistory
    projector : (r, n_free) array
        ``q = projector @ u_free`` (the basis' inner product).
    envelope : dict
        ``{"load_factor": (lo, hi)}`` of the training runs.
    info : dict
    """

    name = "pod_galerkin"
    kind = "trajectory"

    def __init__(self, basis, free, backend, system, integrator, history, projector, envelope, info):
        self.basis, self.free_dofs, self.ndof = basis, np.asarray(free), backend.ndof
        self.problem, self.system, self.history = backend.problem, system, history
        self.integrator_name, self.integrator_options = integrator
        self.projector, self._envelope, self.info = projector, dict(envelope), info
        self._integ = self._pending = self._stopped = self._bound_for = None
        #: steps accepted after a fixed Newton budget with the residual still above rtol (since start)
        self.steps_above_tolerance = 0

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    @property
    def envelope(self) -> dict:
        return dict(self._envelope)

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Project ``state0`` (``{"u", "v"}`` on every dof; default rest) and prepare steps of ``dt``."""
        if dt is None:
            raise ValueError(f"{self.name}.start: a trajectory model needs the time step dt")
        x0 = v0 = None
        sys = self.system
        if state0 is not None:
            parts = []
            for key in ("u", "v"):
                x = state0.get(key)
                if x is None:
                    parts.append(None)
                    continue
                x = np.asarray(x, float)
                if x.shape != (self.ndof,):
                    raise ValueError(f"{self.name}.start: state0[{key!r}] has shape {x.shape}, expected ({self.ndof},)")
                parts.append(np.concatenate([self.projector @ x[self.free_dofs],
                                             x[sys.full_fixed] if sys.has_prescribed
                                             else np.zeros(0)]))
            x0, v0 = parts
        self._pending, self._integ, self._stopped = (x0, v0, float(dt)), None, None
        self.steps_above_tolerance = 0
        self.history.scale = 1.0
        self._bound_for = first_step_time(mu0, dt)  # the integrator's start: work of the run's start
        if self._bound_for is not None:
            self._bind(self._bound_for)

    def _bind(self, t):
        x0, v0, dt = self._pending
        sys = self.system
        if x0 is not None and sys.has_prescribed:  # the integrator checks the prescribed values itself
            x0 = x0.copy()
            x0[sys.r:] = sys.prescribed_values(t - dt)
        self._integ = make_integrator(self.integrator_name, **self.integrator_options)
        self._integ.start(sys, x0, v0, dt, t - dt)
        self._integ.prime()

    def _status(self, lam, unrepresented):
        if unrepresented:
            return "extrapolation", f"{self.name}: {unrepresented}"
        lo, hi = self._envelope.get("load_factor", (-np.inf, np.inf))
        tol = 1e-9 * max(abs(lo), abs(hi), 1e-300)
        if lo - tol <= lam <= hi + tol:
            return "ok", ""
        return "extrapolation", f"{self.name}: load factor {lam:.6g} outside the training runs' [{lo:.6g}, {hi:.6g}]"

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("time",), self.name)
        t = float(mu["time"])
        unrepresented = self.history.drive(t, float(mu["load_factor"])) if "load_factor" in mu else ""
        if self._bound_for is not None:  # bound by start: for this step, else bound again here
            if not start_binding_holds(self._bound_for, self._pending[2], t, self.history):
                self._integ = None
            self._bound_for = None
        if self._integ is None:
            if self._pending is None:
                raise RuntimeError(f"{self.name}: call start(mu0, state0, dt) before step()")
            self._bind(t)
        integ = self._integ
        lam = float(mu["load_factor"]) if "load_factor" in mu else float(self.history(t))
        out = {"time": t, "load_factor": lam}
        if self._stopped is not None:  # a failed step left the state behind: the run has ended there
            return StepResult(None, "failed", self._stopped, {"iterations": 0}, mu=out)
        if abs(t - (integ.t + integ.dt)) > 1e-6 * integ.dt:
            raise ValueError(f"{self.name}.step: mu['time'] = {t!r} is not the next step {integ.t + integ.dt!r} "
                             f"(dt = {integ.dt!r})")
        rep = integ.step()
        if not rep.converged:
            self._stopped = f"{self.name}: stopped at t = {t:.6g}: {rep.message}"
            return StepResult(None, "failed", f"{self.name}: {rep.message}", {"iterations": rep.iterations}, mu=out)
        status, message = self._status(lam, unrepresented)
        info = {"iterations": rep.iterations}
        # a fixed Newton budget (newton_iterations) left the residual above rtol
        if not getattr(rep, "within_tolerance", True):
            self.steps_above_tolerance += 1
            info["within_tolerance"] = False
            message = "; ".join(m for m in (message, f"{self.name}: {rep.message}") if m)
        return StepResult(integ.u.copy(), status, message, info, mu=out)

    def floor_ops(self):
        """One reduced Newton iteration on the sampled elements: the reduced force at the current
        state, a solve with the Newton matrix ``c M_r + K_r`` and the outputs' product. Modified
        Newton (``newton_tangent = "reuse"``) keeps the matrix factorised, so it is factorised here,
        once; with ``"iteration"`` the iteration forms the tangent and factorises it too."""
        sys = self.system
        names, _, C_r, _ = getattr(self, "_outputs", ((), None, None, None))
        every = self.integrator_options.get("newton_tangent") == "iteration"
        state = {}

        def matrix(q, uc):
            return lapack.dgetrf(state["c"] * sys.M_ff + sys.forces.tangent(q, uc))

        def floor():
            if not state:
                integ = self._integ
                dt = integ.dt if integ is not None else self._pending[2]
                state["c"] = 4.0 / (dt * dt)  # the trapezoidal rule's mass factor (the order of HHT's)
                state["q"] = integ.u.copy() if integ is not None else np.zeros(self.n_reduced)
                state["uc"] = integ.uc.copy() if integ is not None and sys.has_prescribed else None
                state["lu"] = matrix(state["q"], state["uc"])[:2]
            q, uc = state["q"], state["uc"]
            f = sys.forces.force(q, uc)
            lu, piv = matrix(q, uc)[:2] if every else state["lu"]
            dq = lapack.dgetrs(lu, piv, f)[0]
            if C_r is not None:
                np.dot(C_r, dq)
        return floor
