"""Newton iterations for one implicit (sub)step, and the sparse solver of its Jacobian.

The implicit schemes write each (sub)step as ``r(u_new) = 0`` with an effective
Jacobian ``J = c_m M + c_c C + c_k K_t(u_new)``. For a linear system J is constant,
factorised once by :class:`StepSolver`, and one solve is exact (one "iteration").

Which direct solver (:func:`step_solver_name`): SciPy's SuperLU for small systems, NGSolve's
sparse LDL^T (UMFPACK when J is not symmetric, e.g. follower loads) refactorised in place from
:data:`NGSOLVE_MIN_DOFS` unknowns. On the paper-size ventricle's backward-Euler matrix (45 042
free dofs) SuperLU took 210 s per factorisation and NGSolve 1.5 s (0.9 s refactorised in
place); on the ci ventricle (2 619 dofs) 24 ms against 10 ms. A dense ``J`` (a reduced model's
few unknowns) is factorised by LAPACK: SuperLU's sparse setup would cost more than the solve.

When the Jacobian is formed (``tangent``, :data:`NEWTON_TANGENTS`): at every iteration (Newton),
or kept factorised across iterations and steps and formed again only when an iteration reduces
the residual by less than :data:`REFRESH_RATIO` (modified Newton; an iteration of a kept matrix
that does not reduce it is discarded and done again with a fresh one). A kept dense matrix
(a reduced model's, refactorised in microseconds) is moreover corrected by Broyden's secant
update after every iteration, and formed again only below a contraction of
``REFRESH_RATIO_SECANT``: on the neo-Hookean liver's 20-mode ECSW model (119 elements) its
reduced tangent was formed twice in 200 steps (2.2 iterations a step), against 11 times
without the updates. ``"auto"`` keeps it from
:data:`REUSE_MIN_DOFS` unknowns on, where forming and factorising ``J`` costs many residuals: on
the neo-Hookean liver (7911 free dofs, HHT, dt 5 ms) a tangent assembly took 0.33 s and its
factorisation 0.30 s against 0.06 s for a residual.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import lapack

from ..linear_solvers import DirectSolver, LinearSolverError, NgsolveSparseSolver
from ..newton import scaled_norm
from ..sparse_direct import NGSOLVE_MIN_DOFS
from .report import StepReport

#: the Jacobian solvers an integrator accepts as its ``linear_solver`` option
STEP_SOLVERS = ("auto", "direct", "cholesky")
# NGSOLVE_MIN_DOFS (sparse_direct): from this many free dofs on, "auto" takes NGSolve
#: when the Newton matrix is formed: "iteration" (Newton), "reuse" (modified Newton), "auto" (module docstring)
NEWTON_TANGENTS = ("auto", "iteration", "reuse")
#: modified Newton forms the matrix again after an iteration that reduced the residual by less than this;
#: a dense matrix (a reduced model's) follows the iterates by Broyden updates in between, and pays later
REFRESH_RATIO, REFRESH_RATIO_SECANT = 0.05, 0.2
#: "auto" keeps the Newton matrix (modified Newton) from this many unknowns on
REUSE_MIN_DOFS = NGSOLVE_MIN_DOFS


@dataclass
class NewtonOptions:
    """Tolerances of the per-step Newton loop.

    Converged when ``||r|| <= max(rtol * r_ref, atol, floor)`` (r_ref: the largest force
    term of the step, in N; floor: the system's round-off floor, see :func:`newton`) or when
    ``||du|| <= utol * max(||u||, 1e-300)`` [m]. Norms are scaled (no underflow below 1e-154 N).
    ``tangent``: when the Newton matrix is formed (:data:`NEWTON_TANGENTS`).
    ``iterations``: None, iterate to the tolerance (at most ``max_iter``); an integer k, every
    step does exactly k iterations, as a real-time loop does to keep its frame (a step's cost then
    does not depend on its state): the step is accepted after them, converged or not, and its
    report says when the residual was still above the tolerance (``within_tolerance``); what
    that costs in accuracy is the model's error against the reference.
    """

    rtol: float = 1e-10
    atol: float = 0.0
    utol: float = 1e-12
    max_iter: int = 25
    linear_solver: str = "auto"
    tangent: str = "auto"
    iterations: int | None = None

    def __post_init__(self):
        for name in ("rtol", "atol", "utol"):
            val = float(getattr(self, name))
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"newton {name} must be finite and >= 0, got {val!r}")
        if self.rtol == 0 and self.atol == 0 and self.utol == 0:
            raise ValueError("newton tolerances: rtol, atol and utol are all 0")
        if int(self.max_iter) != self.max_iter or self.max_iter < 1:
            raise ValueError(f"newton max_iter must be an integer >= 1, got {self.max_iter!r}")
        if self.linear_solver not in STEP_SOLVERS:
            raise ValueError(f"linear_solver must be one of {list(STEP_SOLVERS)}, got {self.linear_solver!r}")
        if self.tangent not in NEWTON_TANGENTS:
            raise ValueError(f"newton_tangent must be one of {list(NEWTON_TANGENTS)}, got {self.tangent!r}")
        it = self.iterations
        if it is not None and (isinstance(it, bool) or not isinstance(it, (int, np.integer)) or it < 1):
            raise ValueError(f"newton_iterations must be None or an integer >= 1, got {it!r}")


def newton_options(owner: str, opts: dict) -> NewtonOptions:
    """NewtonOptions from keyword options ``newton_rtol``, ``newton_atol``, ``newton_utol``,
    ``newton_max_iter``, ``newton_tangent``, ``newton_iterations`` and ``linear_solver`` (one of
    :data:`STEP_SOLVERS`); anything else is a ValueError naming ``owner``."""
    valid = ("newton_rtol", "newton_atol", "newton_utol", "newton_max_iter", "newton_tangent", "newton_iterations",
             "linear_solver")
    unknown = sorted(set(opts) - set(valid))
    if unknown:
        raise ValueError(f"{owner}: unknown option(s) {unknown}; valid Newton options: {list(valid)}")
    return NewtonOptions(**{k.removeprefix("newton_"): v for k, v in opts.items()})


def step_solver_name(choice: str, n: int) -> str:
    """``"direct"`` (SuperLU) or ``"cholesky"`` (NGSolve) for ``choice`` and ``n`` unknowns."""
    if choice == "auto":
        return "cholesky" if n >= NGSOLVE_MIN_DOFS else "direct"
    return choice


class StepSolver:
    """Direct solves of one (sub)step's effective matrices, for the life of one integration.

    The solver keeps its analysis while the sparsity pattern stays (the Newton matrices of a
    mesh); :meth:`solve_cached` keeps the factors themselves while ``key`` does not change
    (a linear system's constant matrix).
    """

    def __init__(self, choice: str = "auto"):
        self.choice, self.name, self._solver = choice, None, None
        self.key, self._apply, self._dense = None, None, None

    def _for(self, n):
        if self._solver is None:
            self.name = step_solver_name(self.choice, n)
            self._solver = DirectSolver() if self.name == "direct" else NgsolveSparseSolver(taskmanager=False)
        return self._solver

    def solve(self, J, rhs):
        """``J^-1 rhs`` for sparse or dense J (n, n); LinearSolverError if J is singular."""
        if isinstance(J, np.ndarray):
            return _dense_factor(J)(rhs)
        J = sp.csr_matrix(J)
        return self._for(J.shape[0]).solve(J, rhs)[0]

    def solve_cached(self, key, build, rhs):
        """Solve ``build() x = rhs``, refactorising only when ``key`` changed (or after :meth:`refresh`)."""
        if self._apply is None or key != self.key:
            J = build()
            self._dense = None
            if isinstance(J, np.ndarray):
                self._apply, self._dense = _dense_factor(J), np.array(J, dtype=float)
            else:
                J = sp.csr_matrix(J)
                solver = self._for(J.shape[0])
                if isinstance(solver, DirectSolver):
                    self._apply = solver.factorize(J).solve
                else:
                    self._apply = solver.factorize(J)[0]
            self.key = key
        return self._apply(rhs)

    @property
    def has_factors(self) -> bool:
        return self._apply is not None

    @property
    def dense(self) -> bool:
        """The kept factors are a dense matrix's (:meth:`secant_update` applies)."""
        return self._dense is not None

    def refresh(self):
        """Forget the kept factors: the next :meth:`solve_cached` factorises again."""
        self._apply, self.key, self._dense = None, None, None

    def secant_update(self, du, dr) -> bool:
        """Broyden's update of a kept *dense* matrix, ``J += (dr - J du) du^T / (du . du)`` (the
        secant condition ``J du = dr`` of the last iteration), refactorised; False, nothing done,
        for sparse factors (or a zero ``du``)."""
        dd = float(du @ du)
        if self._dense is None or not dd > 0:
            return False
        J = self._dense + np.outer(dr - self._dense @ du, du / dd)
        self._apply, self._dense = _dense_factor(J), J
        return True


def _dense_factor(J):
    """``b -> J^-1 b`` by LAPACK's LU (getrf / getrs called directly: SciPy's ``lu_solve`` wrapper
    costs 9 us a call against 1 us, at a reduced model's 20 unknowns); LinearSolverError if J is
    singular."""
    lu, piv, info = lapack.dgetrf(np.asarray(J, float))
    d = np.abs(np.diag(lu))
    if info != 0 or not np.all(np.isfinite(lu)) or d.min(initial=np.inf) <= 1e-14 * d.max(initial=0.0):
        raise LinearSolverError("dense LU: singular matrix")
    return lambda b: lapack.dgetrs(lu, piv, b)[0]


def newton(u, residual, jacobian, r_ref, opts: NewtonOptions, linear=False, solver=None, floor=0.0, peak=0.0):
    """Solve ``residual(u) = 0`` from the predictor ``u`` (free dofs, (n,)).

    Parameters
    ----------
    residual : callable ``u -> (n,)`` [N]
    jacobian : callable ``u -> sparse (n, n)`` [N/m]
    r_ref : float
        Force scale [N] of the step for the relative residual test.
    linear : bool
        One exact solve with the factorisation cached in ``solver``.
    solver : StepSolver, optional
        Solver of the Jacobians (default: a new one for ``opts.linear_solver``); pass the
        integrator's to keep its analysis and factors from step to step.
    floor : float
        The residual's round-off floor [N]
        (:attr:`~tissuebench.refsolvers.dynamics.system.SecondOrderSystem.round_off_floor`):
        the tolerance is never below it (no iteration gets under it), and a step all of whose
        forces lie under it, as do ``peak``'s, fails at once, said (its strains are below
        double precision).
    peak : float
        The largest force [N] of the run so far: a motion that was resolved and has decayed
        below the floor is converged at the floor, not refused.

    Returns
    -------
    u : (n,) array, report : StepReport (``residuals`` holds ||r|| per iteration)
    """
    solver = StepSolver(opts.linear_solver) if solver is None else solver
    u = u.copy()
    r = residual(u)
    norms = [scaled_norm(r)]
    # the predictor's residual joins the scale: a load switched on at t_{n+1} from rest
    # has r_ref = 0 (no force at t_n), and only r(predictor) then measures the step
    scale = max(r_ref, norms[0])
    if norms[0] > 0 and max(scale, peak) <= floor:  # iterating cannot help: the forces are round-off
        return u, StepReport(False, 0, _below_round_off(scale, floor), norms)
    tol = max(opts.rtol * scale, opts.atol, floor)
    if norms[0] <= tol:
        return u, StepReport(True, 0, "", norms)
    if linear:
        u += solver.solve_cached("linear", lambda: jacobian(u), -r)
        return u, StepReport(True, 1, "", norms)
    if opts.tangent == "reuse" or (opts.tangent == "auto" and len(u) >= REUSE_MIN_DOFS):
        return _modified(u, r, norms, tol, residual, jacobian, opts, solver, floor)
    budget = opts.iterations or opts.max_iter
    for it in range(1, budget + 1):
        try:
            du = solver.solve(jacobian(u), -r)
        except LinearSolverError as exc:  # singular effective matrix
            return u, StepReport(False, it, f"singular Newton matrix: {exc}", norms)
        u += du
        r = residual(u)
        norms.append(scaled_norm(r))
        if not (np.isfinite(norms[-1]) and np.all(np.isfinite(u))):
            return u, StepReport(False, it, f"non-finite residual in Newton iteration {it}", norms)
        small_du = scaled_norm(du) <= opts.utol * max(scaled_norm(u), 1e-300)
        if opts.iterations is None and (norms[-1] <= tol or small_du):
            return u, StepReport(True, it, "", norms)
    if opts.iterations is not None:
        return u, _budget_spent(opts.iterations, norms, tol)
    return u, StepReport(False, opts.max_iter, _not_converged("Newton", opts.max_iter, norms[-1], tol, floor), norms)


def _budget_spent(k, norms, tol) -> StepReport:
    """The report of a step that did its fixed ``k`` iterations (:class:`NewtonOptions`)."""
    if norms[-1] <= tol:
        return StepReport(True, k, "", norms)
    return StepReport(True, k, f"fixed budget of {k} Newton iterations spent with ||r|| = {norms[-1]:.3e} N above "
                      f"the tolerance {tol:.3e} N (the step is accepted: newton_iterations = {k})", norms,
                      within_tolerance=False)


def _below_round_off(scale, floor) -> str:
    """The message of a step whose forces all lie below the residual's round-off floor."""
    return (f"the step's forces are below round-off: the largest, {scale:.3e} N, is under the round-off floor "
            f"{floor:.3e} N of the internal force (machine epsilon x the force of a unit strain of the body), so "
            "the strains they cause are below double precision: a load far too small for the body's stiffness "
            "(is its length or load unit right?)")


def _not_converged(what, max_iter, res, tol, floor) -> str:
    text = f"{what} did not converge in {max_iter} iterations (||r|| = {res:.3e} N, tolerance {tol:.3e} N"
    return text + (f", round-off floor {floor:.3e} N)" if floor > 0 else ")")


def _modified(u, r, norms, tol, residual, jacobian, opts: NewtonOptions, solver: StepSolver, floor=0.0):
    """Modified Newton (module docstring): the factors kept in ``solver`` under the key
    ``"newton"``, formed again after a poor contraction; an iteration of kept factors that does
    not reduce the residual is discarded (it counts) and done again with fresh ones."""
    refresh = not (solver.has_factors and solver.key == "newton")
    fixed = opts.iterations is not None
    for it in range(1, (opts.iterations or opts.max_iter) + 1):
        if refresh:
            solver.refresh()
        fresh = refresh
        try:
            du = solver.solve_cached("newton", lambda u=u: jacobian(u), -r)
        except LinearSolverError as exc:
            return u, StepReport(False, it, f"singular Newton matrix: {exc}", norms)
        u_new = u + du
        r_new = residual(u_new)
        n_new = scaled_norm(r_new)
        finite = np.isfinite(n_new) and np.all(np.isfinite(u_new))
        if not fresh and not (finite and n_new < norms[-1]):
            refresh = True
            continue
        if not finite:
            return u, StepReport(False, it, f"non-finite residual in Newton iteration {it}", norms)
        dr = r_new - r
        u, r = u_new, r_new
        norms.append(n_new)
        if not fixed and (n_new <= tol or scaled_norm(du) <= opts.utol * max(scaled_norm(u), 1e-300)):
            return u, StepReport(True, it, "", norms)
        refresh = n_new > (REFRESH_RATIO_SECANT if solver.dense else REFRESH_RATIO) * norms[-2]
        if not refresh:  # a kept dense matrix (a reduced model's) follows the iterates by secant updates
            solver.secant_update(du, dr)
    if fixed:
        return u, _budget_spent(opts.iterations, norms, tol)
    return u, StepReport(False, opts.max_iter, _not_converged("modified Newton", opts.max_iter, norms[-1], tol, floor),
                         norms)
