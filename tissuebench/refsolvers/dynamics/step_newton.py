"""Newton iterations for one implicit (sub)step, and the sparse solver of its Jacobian.

The implicit schemes write each (sub)step as ``r(u_new) = 0`` with an effective
Jacobian ``J = c_m M + c_c C + c_k K_t(u_new)``. For a linear system J is constant,
factorised once by :class:`StepSolver`, and one solve is exact (one "iteration").

Which direct solver (:func:`step_solver_name`): SciPy's SuperLU for small systems, NGSolve's
sparse LDL^T (UMFPACK when J is not symmetric, e.g. follower loads) refactorised in place from
:data:`NGSOLVE_MIN_DOFS` unknowns. On the paper-size ventricle's backward-Euler matrix (45 042
free dofs) SuperLU took 210 s per factorisation and NGSolve 1.5 s (0.9 s refactorised in
place); on the ci ventricle (2 619 dofs) 24 ms against 10 ms.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from ..linear_solvers import DirectSolver, LinearSolverError, NgsolveSparseSolver
from ..sparse_direct import NGSOLVE_MIN_DOFS
from .base import StepReport

#: the Jacobian solvers an integrator accepts as its ``linear_solver`` option
STEP_SOLVERS = ("auto", "direct", "cholesky")
# NGSOLVE_MIN_DOFS (sparse_direct): from this many free dofs on, "auto" takes NGSolve


@dataclass
class NewtonOptions:
    """Tolerances of the per-step Newton loop.

    Converged when ``||r|| <= max(rtol * r_ref, atol)`` (r_ref: the largest force term
    of the step, in N) or when ``||du|| <= utol * max(||u||, 1e-300)`` [m].
    """

    rtol: float = 1e-10
    atol: float = 0.0
    utol: float = 1e-12
    max_iter: int = 25
    linear_solver: str = "auto"

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


def newton_options(owner: str, opts: dict) -> NewtonOptions:
    """NewtonOptions from keyword options ``newton_rtol``, ``newton_atol``, ``newton_utol``,
    ``newton_max_iter`` and ``linear_solver`` (one of :data:`STEP_SOLVERS`); anything else
    is a ValueError naming ``owner``."""
    valid = ("newton_rtol", "newton_atol", "newton_utol", "newton_max_iter", "linear_solver")
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
        self.key, self._apply = None, None

    def _for(self, n):
        if self._solver is None:
            self.name = step_solver_name(self.choice, n)
            self._solver = DirectSolver() if self.name == "direct" else NgsolveSparseSolver(taskmanager=False)
        return self._solver

    def solve(self, J, rhs):
        """``J^-1 rhs`` for sparse J (n, n); LinearSolverError if J is singular."""
        J = sp.csr_matrix(J)
        return self._for(J.shape[0]).solve(J, rhs)[0]

    def solve_cached(self, key, build, rhs):
        """Solve ``build() x = rhs``, refactorising only when ``key`` changed."""
        if self._apply is None or key != self.key:
            J = sp.csr_matrix(build())
            solver = self._for(J.shape[0])
            if isinstance(solver, DirectSolver):
                self._apply = solver.factorize(J).solve
            else:
                self._apply = solver.factorize(J)[0]
            self.key = key
        return self._apply(rhs)


def newton(u, residual, jacobian, r_ref, opts: NewtonOptions, linear=False, solver=None):
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

    Returns
    -------
    u : (n,) array, report : StepReport (``residuals`` holds ||r|| per iteration)
    """
    solver = StepSolver(opts.linear_solver) if solver is None else solver
    u = u.copy()
    r = residual(u)
    norms = [float(np.linalg.norm(r))]
    # the predictor's residual joins the scale: a load switched on at t_{n+1} from rest
    # has r_ref = 0 (no force at t_n), and only r(predictor) then measures the step
    tol = max(opts.rtol * max(r_ref, norms[0]), opts.atol)
    if norms[0] <= tol:
        return u, StepReport(True, 0, "", norms)
    if linear:
        u += solver.solve_cached("linear", lambda: jacobian(u), -r)
        return u, StepReport(True, 1, "", norms)
    for it in range(1, opts.max_iter + 1):
        try:
            du = solver.solve(jacobian(u), -r)
        except LinearSolverError as exc:  # singular effective matrix
            return u, StepReport(False, it, f"singular Newton matrix: {exc}", norms)
        u += du
        r = residual(u)
        norms.append(float(np.linalg.norm(r)))
        if not (np.isfinite(norms[-1]) and np.all(np.isfinite(u))):
            return u, StepReport(False, it, f"non-finite residual in Newton iteration {it}", norms)
        small_du = np.linalg.norm(du) <= opts.utol * max(np.linalg.norm(u), 1e-300)
        if norms[-1] <= tol or small_du:
            return u, StepReport(True, it, "", norms)
    return u, StepReport(False, opts.max_iter,
                         f"Newton did not converge in {opts.max_iter} iterations "
                         f"(||r|| = {norms[-1]:.3e} N, tolerance {tol:.3e} N)", norms)
