"""A static step continued along the load path, within a budget, on the descent of the potential energy.

:class:`ContinuationPathModel` is :class:`~.stepping.NewtonPathModel` (one static equilibrium
per step, warm-started) with three changes, measured on corotational FE under a point load
(issue 52: a 4.5k-node kidney, a 4.5k-node half ellipsoid at nu = 0.49), where the equilibrium
inverts the cells under the load and snaps through as they go:

* **from the last converged load factor**: a step goes from the last converged state and its
  load factor to the step's, in increments (one first, halved on a failure down to
  ``min_increment`` of the step, grown by 1.5 after an easy one). The base model cuts from load
  factor 0 (a step from 0.7 to 0.75 was cut back to 0.375 from the state at 0.7), which leaves a
  branch that snapped through. A step that fails keeps its converged part: the next one starts
  there.
* **a budget**: a step spends at most :attr:`ContinuationPathModel.budget` Newton iterations
  (``max_iterations`` for its increment and for each of its ``log2(1 / min_increment)`` cuts:
  75 by default) and is then a failed step; the base model's failing steps took up to 139
  (the kidney past load factor 1.25, each increment's successes resetting its cuts) where ~75
  were promised, and a dense check stepping past the model's limit crawled.
* **Newton on the energy** (dead loads: point, traction, gravity, with Dirichlet data): the
  equilibrium is a minimum of the potential energy ``Pi = W(u) - f . u``, and a Newton step is
  taken only where it lowers ``Pi`` by at least a tenth of the decrease its quadratic model
  predicts; otherwise the tangent is shifted by ``tau diag(K_0)`` (Levenberg-Marquardt, ``K_0``
  the tangent at rest) until it does, ``tau`` relaxed after good steps. Where the tangent is
  positive definite near the solution the shift is 0 and Newton is quadratic; where a cell
  snaps through the tangent is indefinite and plain Newton wanders (measured: residual
  1.5e1, 5.9e1, 1.2e1, 1.4e3 ... 4.9e4 in 15 iterations on a 196-node block at nu = 0.49, from
  load factor 0.7 to 0.8), the shifted one reaches the other branch (12 iterations, to 2e-8).
  A follower load (pressure) has no potential: its steps take plain Newton
  (:func:`~tissuebench.refsolvers.newton.newton_solve`).

Every linear solve counts as an iteration of the budget. Converged means what it means for
:func:`~tissuebench.refsolvers.newton.newton_solve`: the free residual within
``rtol * f_ref + atol`` (or its round-off floor) and the last increment within ``utol`` of ``u``.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

from ...refsolvers.newton import NewtonOptions, _Equilibrium, newton_solve, scaled_norm
from ...refsolvers.solver_base import LinearSolverError
from ..base import StepResult, check_parameters
from .stepping import NewtonPathModel, _solver_options

__all__ = ["ContinuationPathModel", "energy_increment"]

#: the shift ``tau`` starts here after a refused step, grows by 4 on each refusal, shrinks by 4
#: after a step that does as its model predicts (ratio above 0.75) and is dropped below TAU_MIN
TAU_START, TAU_MIN = 1e-3, 1e-5


class _SpanProblem:
    """``problem`` whose prescribed values at ``t`` are its own at the load factor ``lo + t (hi - lo)``."""

    def __init__(self, problem, lo, hi):
        self._problem, self._lo, self._hi = problem, lo, hi

    def __getattr__(self, name):
        return getattr(self._problem, name)

    def prescribed_values(self, t):
        return self._problem.prescribed_values(self._lo + t * (self._hi - self._lo))


class _Span:
    """``backend`` with its load parameter ``t`` in [0, 1] standing for the load factor ``lo + t (hi - lo)``:
    a solve at ``t = 1`` from the state at ``lo`` is the increment from ``lo`` to ``hi``."""

    def __init__(self, backend, lo, hi):
        self._backend, self._lo, self._hi = backend, lo, hi
        self.problem = _SpanProblem(backend.problem, lo, hi)

    def __getattr__(self, name):
        return getattr(self._backend, name)

    def external_force(self, u, t):
        return self._backend.external_force(u, self._lo + t * (self._hi - self._lo))

    def external_tangent(self, u, t):
        return self._backend.external_tangent(u, self._lo + t * (self._hi - self._lo))


def energy_increment(backend, solver, u_start, opts: NewtonOptions, shift,
                     limit: int | None = None) -> tuple[bool, np.ndarray, int, str]:
    """Equilibrium at the load parameter 1 of ``backend`` (dead loads) from ``u_start``, by Newton kept
    on the descent of the potential energy (module docstring).

    Parameters
    ----------
    backend : Backend
        Its ``external_force`` must not depend on ``u`` (dead loads).
    solver : LinearSolver
        ``backend.make_linear_solver(...)``.
    u_start : (ndof,) array
    opts : NewtonOptions
        ``rtol``, ``atol``, ``utol`` and ``max_iterations`` (linear solves, shifted ones included).
    shift : (n_free,) array
        The positive diagonal the shift scales (``diag(K_0)`` on the free dofs).
    limit : int, optional
        Iterations an increment that is converging may go on to past ``max_iterations`` (its last
        step cut the residual 4-fold): one that converges late is not thrown away for a cut,
        which brings the load closer to where the branch folds.

    Returns
    -------
    (converged, u, iterations, message)
        ``u`` the last accepted state (``u_start`` or better), ``message`` why it did not converge.
    """
    eq = _Equilibrium(backend, 1.0)
    u = u_start.copy()
    du_c = backend.problem.prescribed_values(1.0) - u[eq.fixed]
    f_ext = backend.external_force(u, 1.0)
    D = sp.diags(shift)
    # a material not defined through inversion (log J) refuses an inverted state, as newton_solve does
    invertible = getattr(getattr(backend.problem, "material", None), "invertible", False)

    def energy(v):
        w, work = backend.strain_energy(v), float(f_ext @ v)
        return w - work, np.finfo(float).eps * 1e3 * (abs(w) + abs(work))  # (Pi, its round-off)

    r, f_ref, K_ff, K_fc = eq.residual_and_tangent(u)
    E = energy(u)
    tau, its, last_step, res_prev = 0.0, 0, None, math.inf
    limit = max(int(limit or 0), opts.max_iterations)
    while True:
        res = scaled_norm(r)
        # converging (the last step cut the residual 4-fold): the increment may go on to ``limit``
        converging, res_prev = res <= 0.25 * res_prev, res
        if not math.isfinite(res):
            return False, u, its, "non-finite residual"
        tol = max(opts.rtol * f_ref + opts.atol, eq.floor)
        if last_step is not None and res <= tol and last_step <= opts.utol * max(scaled_norm(u), 1e-300):
            return True, u, its, ""
        if its >= opts.max_iterations and not (its < limit and converging):
            return False, u, its, f"no convergence in {its} iterations (residual {res:.3e}, shift {tau:.2g})"
        rhs = -r - K_fc @ du_c if du_c.any() else -r
        its += 1
        try:
            du = solver.solve(K_ff + tau * D if tau else K_ff, rhs)[0]
        except LinearSolverError:
            du = None
        if du is None or not np.all(np.isfinite(du)):
            tau = TAU_START if tau == 0.0 else 4.0 * tau
            continue
        trial = u.copy()
        trial[eq.free] += du
        trial[eq.fixed] += du_c
        if not invertible and backend.min_jacobian(trial) <= 0:
            tau = TAU_START if tau == 0.0 else 4.0 * tau
            continue
        r_t, _ = eq.residual(trial)
        E_t = energy(trial)
        if not du_c.any():  # the prescribed values' jump changes the constraint: no energy to compare across it
            predicted = -(r @ du + 0.5 * du @ (K_ff @ du))
            actual = E[0] - E_t[0]
            noise = E[1] + E_t[1]
            if abs(actual) <= noise and abs(predicted) <= noise:  # at round-off: the residual decides
                good = scaled_norm(r_t) <= res
            else:
                good = predicted > 0 and actual >= 0.1 * predicted
            if not (good and math.isfinite(E_t[0])):
                tau = TAU_START if tau == 0.0 else 4.0 * tau
                continue
            if predicted > 0 and actual >= 0.75 * predicted:
                tau = 0.0 if tau / 4.0 < TAU_MIN else tau / 4.0
        u, E, du_c, last_step = trial, E_t, np.zeros_like(du_c), math.hypot(scaled_norm(du), scaled_norm(du_c))
        r, f_ref, K_ff, K_fc = eq.residual_and_tangent(u)


class ContinuationPathModel(NewtonPathModel):
    """:class:`~.stepping.NewtonPathModel` continued from the last converged load factor, with a step
    budget, on the descent of the potential energy for dead loads (module docstring)."""

    def start(self, mu0=None, state0=None, dt=None) -> None:
        super().start(mu0, state0, dt)
        self._at = 0.0

    def _on_node(self, node):
        if node != self._node:
            self._at = 0.0
        super()._on_node(node)

    @property
    def budget(self) -> int:
        """Newton iterations a step may spend: ``max_iterations`` for the increment and each of its cuts."""
        cuts = math.ceil(math.log2(1.0 / self.options["min_increment"]) - 1e-9)
        return self.options["max_iterations"] * (1 + max(cuts, 0))

    def _shift(self) -> np.ndarray:
        if getattr(self, "_diag", None) is None:
            free = self.backend.problem.free_dofs
            d = np.asarray(self.backend.tangent(np.zeros(self.backend.ndof))[free][:, free].diagonal(), float)
            self._diag = np.where(d > 0, d, d[d > 0].mean() if np.any(d > 0) else 1.0)
        return self._diag

    def _increment(self, lo, hi, left) -> tuple[bool, np.ndarray, int, str]:
        """``(converged, u, iterations spent, message)`` of the increment from the state at ``lo`` to ``hi``,
        at most ``left`` iterations."""
        iterations = min(self.options["max_iterations"], left)
        span = _Span(self._loaded, lo, hi)
        if span.external_tangent(self._u, 1.0) is None:  # dead loads: the energy is the potential
            opts = NewtonOptions(rtol=self.options["rtol"], atol=self.options.get("atol", 0.0),
                                 max_iterations=iterations, linear_solver=self.options["linear_solver"])
            if getattr(self, "_solver", None) is None:  # kept: its ordering serves every increment
                self._solver = self.backend.make_linear_solver(self.options["linear_solver"],
                                                               **_solver_options(self.backend, self.options))
            return energy_increment(span, self._solver, self._u, opts, self._shift(), limit=left)
        opts = {k: v for k, v in self.options.items() if k not in ("max_iterations", "min_increment")}
        res = newton_solve(span, 1.0, u0=self._u, n_increments=1, store_states=False, min_increment=1.0,
                           max_iterations=iterations, **opts)
        inc = res.increments[-1]
        return res.success, res.u, inc.iterations, inc.message

    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("load_factor",), self.name)
        target = float(mu["load_factor"])
        out = {"load_factor": target}
        if "node" in mu:
            self._on_node(int(mu["node"]))
            out["node"] = int(mu["node"])
        if target == 0.0:  # from rest, as the base model
            self._u, self._at = np.zeros(self.backend.ndof), 0.0
        budget, spent = self.budget, 0
        lo, t, dt = self._at, 0.0, 1.0
        while True:
            t_try = 1.0 if t + dt >= 1.0 - 1e-12 else t + dt
            a, b = lo + t * (target - lo), lo + t_try * (target - lo)
            ok, u, its, message = self._increment(a, b, budget - spent)
            spent += its
            if ok:
                self._u, self._at, t = u, b, t_try
                if t >= 1.0:
                    return StepResult(self._u[self.fmap.free], "ok", "", {"iterations": spent}, mu=out)
                if its <= 6:
                    dt *= 1.5
            else:
                dt *= 0.5
            if spent >= budget:
                why = f"the step's budget of {budget} Newton iterations is spent"
            elif dt < self.options["min_increment"]:
                why = f"the increment is below min_increment = {self.options['min_increment']:g} of the step"
            else:
                continue
            last = "" if ok else f"; the increment to {b:.6g}: {message}"
            return StepResult(None, "failed", f"{self.name}: Newton stopped at load factor {self._at:.6g} on the way "
                              f"from {lo:.6g} to {target:.6g}: {why}{last}", {"iterations": spent}, mu=out)
