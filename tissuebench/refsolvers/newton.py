"""Backend-neutral Newton-Raphson for quasi-static equilibrium with load stepping.

Solves ``f_int(u) = f_ext(u, lam)`` on the free dofs for ``lam`` going from 0 to
``load_factor``, with prescribed displacements scaled by ``lam``. A load increment whose
Newton iteration fails (divergence, too many iterations, inverted element, failed linear
solve) is cut in half and retried; when the increment gets below ``min_increment`` the
run stops and returns the last converged load factor as data (the Newton convergence
radius), unless ``strict=True``, which raises :class:`NewtonError`.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .solver_base import LinearSolverError, forcing_term


class NewtonError(RuntimeError):
    """Raised in strict mode when the requested load factor is not reached."""

    def __init__(self, result):
        super().__init__(result.message)
        self.result = result


@dataclass(frozen=True)
class NewtonOptions:
    """Tolerances and stepping controls.

    Converged when ``||r_free|| <= max(rtol * f_ref + atol, floor)`` and
    ``||du|| <= utol * ||u||``, with ``f_ref`` the larger of the external-load norm and the
    reaction norm, and ``floor`` the residual's round-off floor: machine epsilon times the
    nodal forces of a unit strain of the body (``||K_f X||``, :data:`ROUND_OFF_FACTOR`), below
    which no iteration can go. Both terms scale with the problem (its unit of length, its
    stiffness, its load), so the test is scale-free; an increment whose whole load lies below
    the floor fails at once, said (its strains are below double precision).
    Iterative linear solvers (``amg-cg``) stop at the Eisenstat-Walker forcing term
    (:func:`~tissuebench.refsolvers.solver_base.forcing_term`), at most ``forcing_max``.
    """

    rtol: float = 1e-9
    atol: float = 1e-14
    utol: float = 1e-4
    max_iterations: int = 25
    n_increments: int = 1
    min_increment: float = 1.0 / 4096
    max_increment: float | None = None
    growth: float = 1.5
    easy_iterations: int = 6
    line_search: bool = False
    strict: bool = False
    linear_solver: str = "auto"
    linear_solver_options: dict = field(default_factory=dict)
    forcing_max: float = 1e-4

    def __post_init__(self):
        if not (isinstance(self.forcing_max, (int, float)) and 0 < self.forcing_max < 1):
            raise ValueError(f"forcing_max must lie in (0, 1), got {self.forcing_max!r}")
        for name in ("rtol", "utol", "min_increment", "growth"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
        if self.atol < 0 or not math.isfinite(self.atol):
            raise ValueError(f"atol must be a finite number >= 0, got {self.atol!r}")
        if int(self.max_iterations) < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations!r}")
        if int(self.n_increments) < 1:
            raise ValueError(f"n_increments must be >= 1, got {self.n_increments!r}")


@dataclass
class Increment:
    """One attempted load increment.

    Times in seconds: ``assembly_s`` residual and tangent at the iterates, ``solve_s``
    the linear solves, of which ``factor_s`` factorisation or preconditioner setup,
    ``residual_s`` the residual and det F check at each trial state, ``wall_s`` all.
    """

    load_factor: float
    converged: bool
    iterations: int
    residual_norms: list
    increment_norms: list
    assembly_s: float = 0.0
    solve_s: float = 0.0
    factor_s: float = 0.0
    residual_s: float = 0.0
    wall_s: float = 0.0
    linear_iterations: int = 0
    message: str = ""
    round_off_floor: float = 0.0  # the residual norm round-off hides equilibrium below (_Equilibrium)
    below_round_off: bool = False  # the increment's whole load is below that floor: not solvable in float64
    force_scale: float = 0.0  # f_ref: the larger of the external-load and reaction norms
    round_off_limited: bool = False  # converged with the floor, not rtol * f_ref + atol, the larger tolerance


@dataclass
class StaticResult:
    """Outcome of :func:`newton_solve`.

    ``u`` is the last converged displacement (ndof,), never NaN; ``load_factor`` the last
    converged load factor; ``states`` the converged displacement after each accepted
    increment (if stored); ``increments`` every attempt, accepted or cut.
    """

    status: str
    message: str
    u: np.ndarray
    load_factor: float
    target_load_factor: float
    increments: list
    states: list = field(default_factory=list)

    @property
    def success(self) -> bool:
        return self.status == "success"

    @property
    def converged_increments(self):
        return [inc for inc in self.increments if inc.converged]

    def increment_rows(self, on_converged) -> tuple[list, list]:
        """``(stored, rows)``: one row per attempted increment (step, load factor, Newton
        iterations, converged, wall/assembly/solve time, final residual, message); for each
        converged increment ``on_converged(state, load_factor) -> (stored_state, {name: value})``
        gives what to store and the values added to its row (a scene's monitors)."""
        stored, rows, states = [], [], iter(self.states)
        for inc in self.increments:
            row = {"step": len(rows) + 1, "load_factor": inc.load_factor, "newton_iterations": inc.iterations,
                   "converged": inc.converged, "wall_s": inc.wall_s, "assembly_s": inc.assembly_s,
                   "solve_s": inc.solve_s,
                   "final_residual": inc.residual_norms[-1] if inc.residual_norms else np.nan, "message": inc.message}
            if inc.converged:
                state, values = on_converged(next(states), inc.load_factor)
                stored.append(state)
                row.update(values)
            rows.append(row)
        return stored, rows

    def table(self) -> pd.DataFrame:
        """One row per attempted increment."""
        rows = [{"load_factor": i.load_factor, "converged": i.converged, "newton_iterations": i.iterations,
                 "final_residual": i.residual_norms[-1] if i.residual_norms else np.nan,
                 "assembly_s": i.assembly_s, "solve_s": i.solve_s, "factor_s": i.factor_s,
                 "residual_s": i.residual_s, "wall_s": i.wall_s,
                 "linear_iterations": i.linear_iterations, "message": i.message} for i in self.increments]
        return pd.DataFrame(rows)


def scaled_norm(x) -> float:
    """The Euclidean norm of ``x`` without underflow or overflow: ``s ||x / s||`` with s the
    largest ``|x_i|``. ``np.linalg.norm`` squares the entries, so a residual of 1e-200 N has
    norm 0 (a step would "converge" before any iteration) and one of 1e200 N norm inf; 0, inf
    and nan come back as such."""
    x = np.asarray(x, dtype=float).ravel()
    if x.size == 0:
        return 0.0
    s = float(np.max(np.abs(x)))
    if not 0.0 < s < math.inf:  # 0, inf or nan: the norm is that
        return s
    return s * float(np.linalg.norm(x / s))


_norm = scaled_norm


#: the round-off floor of a residual, in machine epsilons of the force of a unit strain (see
#: :meth:`_Equilibrium.round_off_floor`); measured floors lie at 0.01-0.5 of it (P1/P2/Q1, nu 0.3-0.49)
ROUND_OFF_FACTOR = 1.0


def unit_dilation(nodes, ndof: int) -> np.ndarray:
    """The displacement (ndof,) of a unit dilation of ``nodes`` (n, 3) about their centre, zero on
    any dof beyond the nodes' (a pressure): the round-off floors' unit strain (:data:`ROUND_OFF_FACTOR`)."""
    nodes = np.asarray(nodes, dtype=float)
    x = np.zeros(ndof)
    x[:nodes.size] = (nodes - nodes.mean(axis=0)).ravel()
    return x


class _Equilibrium:
    """Residual and tangent at a fixed load factor (free/fixed partition of the dofs)."""

    def __init__(self, backend, lam):
        self.b, self.lam = backend, lam
        pb = backend.problem
        self.free, self.fixed = pb.free_dofs, pb.fixed_dofs
        self._last = (None, None)  # (state, f_int) of the last residual evaluation
        self._dilation = unit_dilation(pb.nodes, backend.ndof)

    def round_off_floor(self, K_f) -> float:
        """The residual norm below which round-off hides the equilibrium: ``ROUND_OFF_FACTOR`` x
        eps x ``||K_f X||``, the free rows of the tangent times a unit dilation ``X`` (the nodal
        forces of a strain of 1, i.e. the material's stiffness times the body's area). The
        stresses are sums of terms of this size that cancel near the reference state, so their
        round-off does not shrink with the load: a load tiny against the body's stiffness (a mesh
        in mm declared in m, a body of 1e6 m) has a residual floor far above ``rtol * f_ref``."""
        return ROUND_OFF_FACTOR * np.finfo(float).eps * _norm(K_f @ self._dilation)

    def residual(self, u):
        """(free residual, reference force norm): f_ref = max(|f_ext|, |reactions|)."""
        f_int = self.b.internal_force(u)
        self._last = (u, f_int)  # the next tangent is taken at this state: keep f_int
        r, f_ext = self._residual(u, f_int)
        return r[self.free], max(_norm(f_ext), _norm(r[self.fixed]))

    def _residual(self, u, f_int):
        f_ext = self.b.external_force(u, self.lam)
        return f_int - f_ext, f_ext

    def residual_and_tangent(self, u):
        """(free residual, f_ref, K_ff, K_fc) with K = K_t - d f_ext / du."""
        if self._last[0] is u:
            f_int, K = self._last[1], self.b.tangent(u)
        else:
            f_int, K = self.b.internal_force_and_tangent(u)
        r, f_ext = self._residual(u, f_int)
        K_ext = self.b.external_tangent(u, self.lam)
        if K_ext is not None:
            K = K - K_ext
        K_f = K[self.free]
        self.floor = self.round_off_floor(K_f)
        return r[self.free], max(_norm(f_ext), _norm(r[self.fixed])), K_f[:, self.free], K_f[:, self.fixed]


def _newton_increment(backend, solver, u_start, lam, opts):
    """Newton iterations at load factor ``lam`` from the converged state ``u_start``.

    The change of the prescribed values enters the first iteration through the
    tangent (``-K_fc du_c`` on the right-hand side), so the interior follows the
    boundary instead of a boundary layer of cells being inverted by a jump.
    """
    eq = _Equilibrium(backend, lam)
    pb = backend.problem
    u = u_start.copy()
    du_c = pb.prescribed_values(lam) - u[eq.fixed]
    inc = Increment(lam, False, 0, [], [])
    t_start = time.perf_counter()
    res_prev = eta = None
    for it in range(1, opts.max_iterations + 1):
        t0 = time.perf_counter()
        r, f_ref, K_ff, K_fc = eq.residual_and_tangent(u)
        t1 = time.perf_counter()
        inc.assembly_s += t1 - t0
        res = _norm(r)
        if it == 1:
            inc.residual_norms.append(res)
        if not math.isfinite(res):
            inc.message = "non-finite residual"
            break
        tol = max(opts.rtol * f_ref + opts.atol, eq.floor)
        inc.round_off_limited = eq.floor > opts.rtol * f_ref + opts.atol  # meaningful once converged
        inc.round_off_floor, inc.force_scale = eq.floor, f_ref
        if it > 1 and res <= tol and inc.increment_norms[-1] <= opts.utol * max(_norm(u), 1e-300):
            inc.converged = True
            break
        rhs = -r - K_fc @ du_c if du_c.any() else -r
        if it == 1 and 0.0 < max(f_ref, _norm(rhs)) <= eq.floor:  # halving the increment cannot help
            inc.below_round_off = True
            inc.message = (f"the load is below round-off: its force {max(f_ref, _norm(rhs)):.3g} is under the "
                           f"round-off floor {eq.floor:.3g} of the internal force (machine epsilon x the force of a "
                           "unit strain of the body), so the strains it causes are below double precision: a body "
                           "far too large or too stiff for its load (is its length unit right?)")
            break
        try:
            if getattr(solver, "iterative", False):
                eta = forcing_term(res, res_prev, eta, tol, opts.forcing_max)
                du, info = solver.solve(K_ff, rhs, rtol=eta)
            else:
                du, info = solver.solve(K_ff, rhs)
        except LinearSolverError as exc:
            inc.message = str(exc)
            break
        t2 = time.perf_counter()
        inc.solve_s += t2 - t1
        inc.factor_s += float(info.get("factor_s", 0.0))
        inc.linear_iterations += int(info.get("iterations", 1))
        inc.iterations = it
        res_prev = _norm(rhs)  # at the first iteration the prescribed-value jump is the residual
        u_new, res_new, step = _update(backend, eq, u, du, du_c, res, opts)
        inc.residual_s += time.perf_counter() - t2
        if u_new is None:
            inc.message = ("inverted element (det F <= 0)" if res_new is None
                           else f"line search failed (residual {res_new:.3e} >= {res:.3e})")
            break
        inc.increment_norms.append(step * math.hypot(_norm(du), _norm(du_c)))
        u, du_c = u_new, np.zeros_like(du_c)
        inc.residual_norms.append(res_new)
        # the first update absorbs the jump of the prescribed values: measure growth after it
        if not math.isfinite(res_new) or res_new > 1e8 * max(max(inc.residual_norms[:2]), tol):
            inc.message = f"diverged (residual {res_new:.3e})"
            break
        if res_new <= tol and inc.increment_norms[-1] <= opts.utol * max(_norm(u), 1e-300):
            inc.converged = True
            break
    else:
        inc.message = f"no convergence in {opts.max_iterations} iterations (residual {inc.residual_norms[-1]:.3e})"
    inc.wall_s = time.perf_counter() - t_start
    return inc, u


def _update(backend, eq, u, du, du_c, res, opts):
    """Apply the Newton step, halving it (line search) or refusing an inverted state.

    Returns (new state or None, its residual norm or None, step length).
    """
    step, res_new = 1.0, None
    # a material defined through inversion (corotational: its equilibrium may invert cells) is not refused there
    invertible = getattr(getattr(backend.problem, "material", None), "invertible", False)
    for _ in range(6 if opts.line_search else 1):
        trial = u.copy()
        trial[eq.free] += step * du
        trial[eq.fixed] += step * du_c
        if invertible or backend.min_jacobian(trial) > 0:
            res_new = _norm(eq.residual(trial)[0])
            if not opts.line_search or res_new <= (1 - 1e-4 * step) * res or du_c.any():
                return trial, res_new, step
        step *= 0.5
    return None, res_new, step


def newton_solve(backend, load_factor: float = 1.0, options: NewtonOptions | None = None,
                 u0=None, store_states: bool = True, progress=None, **kwargs) -> StaticResult:
    """Load-stepped Newton-Raphson from ``u0`` (zero by default) up to ``load_factor``.

    Parameters
    ----------
    backend : Backend
        Supplies f_int, K_t, loads and the problem's Dirichlet data.
    load_factor : float
        Target load factor (prescribed displacements and loads scale with it).
    options : NewtonOptions, optional
        Tolerances and stepping; keyword arguments override its fields.
    progress : callable, optional
        Called as ``progress(load_factor, target)`` after each accepted increment. When it also
        has an ``increment`` method, that is called as ``progress.increment(inc, target)`` after
        every attempted increment, accepted or cut (its :class:`Increment`: Newton iterations,
        residuals, time), before ``progress`` itself: a log of a long solve says how each went.
    """
    if not (isinstance(load_factor, (int, float)) and math.isfinite(load_factor)):
        raise ValueError(f"load_factor must be finite, got {load_factor!r}")
    opts = options or NewtonOptions()
    if kwargs:
        opts = NewtonOptions(**{**opts.__dict__, **kwargs})
    u = np.zeros(backend.ndof) if u0 is None else np.array(backend._check_u(u0), dtype=float)
    if not np.all(np.isfinite(u)):
        raise ValueError("u0 contains a non-finite value")
    solver_opts = dict(opts.linear_solver_options)
    if opts.linear_solver == "amg-cg":
        solver_opts.setdefault("coords", backend.problem.nodes)
        solver_opts.setdefault("free_dofs", backend.problem.free_dofs)
    solver = backend.make_linear_solver(opts.linear_solver, **solver_opts)
    on_increment = getattr(progress, "increment", None)
    lam, target = 0.0, float(load_factor)
    d_lam = target / opts.n_increments
    d_max = abs(opts.max_increment * target) if opts.max_increment else abs(target)
    increments, states = [], []
    status, message = "success", "converged"
    while abs(target - lam) > 1e-14 * max(1.0, abs(target)):
        lam_try = lam + d_lam if abs(target - lam - d_lam) > 1e-12 * abs(target) else target
        inc, u_try = _newton_increment(backend, solver, u, lam_try, opts)
        increments.append(inc)
        if on_increment is not None:
            on_increment(inc, target)
        if inc.converged:
            lam, u = lam_try, u_try
            if store_states:
                states.append(u.copy())
            if progress:
                progress(lam, target)
            if inc.iterations <= opts.easy_iterations:
                d_lam = math.copysign(min(abs(d_lam) * opts.growth, d_max), d_lam)
            d_lam = math.copysign(min(abs(d_lam), abs(target - lam)), d_lam) if lam != target else d_lam
            continue
        d_lam *= 0.5
        if abs(d_lam) < opts.min_increment * abs(target) or inc.below_round_off:
            status = "stalled"
            message = (f"Newton stopped converging at load factor {lam_try:.6g} ({inc.message}); "
                       f"last converged load factor {lam:.6g} of {target:.6g}")
            break
    limited = [inc for inc in increments if inc.converged and inc.round_off_limited]
    if limited:
        worst = max(inc.residual_norms[-1] / inc.force_scale for inc in limited)
        message += (f"; {len(limited)} of {sum(inc.converged for inc in increments)} increments only to the "
                    f"round-off floor of the residual (relative residual up to {worst:.2g}): the load is small "
                    "against the body's stiffness")
    result = StaticResult(status, message, u, lam, target, increments, states)
    if opts.strict and not result.success:
        raise NewtonError(result)
    return result
