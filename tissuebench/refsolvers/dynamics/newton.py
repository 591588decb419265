"""Newton iterations for one implicit (sub)step, and a cached sparse LU.

The implicit schemes write each (sub)step as ``r(u_new) = 0`` with an effective
Jacobian ``J = c_m M + c_c C + c_k K_t(u_new)``. For a linear system J is constant,
factorised once by :class:`CachedLU`, and one solve is exact (one "iteration").
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..linear_solvers import DirectSolver, LinearSolverError
from .base import StepReport

# FE effective matrices are structurally symmetric: order K + K^T (see linear_solvers)
PERMC_SPEC = "MMD_AT_PLUS_A"
_DIRECT = DirectSolver(PERMC_SPEC)


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

    def __post_init__(self):
        for name in ("rtol", "atol", "utol"):
            val = float(getattr(self, name))
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"newton {name} must be finite and >= 0, got {val!r}")
        if self.rtol == 0 and self.atol == 0 and self.utol == 0:
            raise ValueError("newton tolerances: rtol, atol and utol are all 0")
        if int(self.max_iter) != self.max_iter or self.max_iter < 1:
            raise ValueError(f"newton max_iter must be an integer >= 1, got {self.max_iter!r}")


def newton_options(owner: str, opts: dict) -> NewtonOptions:
    """NewtonOptions from keyword options ``newton_rtol``, ``newton_atol``, ``newton_utol``,
    ``newton_max_iter``; anything else is a ValueError naming ``owner``."""
    valid = ("newton_rtol", "newton_atol", "newton_utol", "newton_max_iter")
    unknown = sorted(set(opts) - set(valid))
    if unknown:
        raise ValueError(f"{owner}: unknown option(s) {unknown}; valid Newton options: {list(valid)}")
    return NewtonOptions(**{k.removeprefix("newton_"): v for k, v in opts.items()})


class CachedLU:
    """Sparse LU of the effective matrix, kept while ``key`` does not change."""

    def __init__(self):
        self.key, self.lu = None, None

    def solve(self, key, build, rhs):
        """Solve ``build() x = rhs``, refactorising only when ``key`` changed."""
        if self.lu is None or key != self.key:
            self.lu = spla.splu(sp.csc_matrix(build()), permc_spec=PERMC_SPEC)
            self.key = key
        return self.lu.solve(rhs)


def newton(u, residual, jacobian, r_ref, opts: NewtonOptions, linear=False, lu=None):
    """Solve ``residual(u) = 0`` from the predictor ``u`` (free dofs, (n,)).

    Parameters
    ----------
    residual : callable ``u -> (n,)`` [N]
    jacobian : callable ``u -> sparse (n, n)`` [N/m]
    r_ref : float
        Force scale [N] of the step for the relative residual test.
    linear : bool
        One exact solve with a factorisation cached in ``lu`` (a :class:`CachedLU`).

    Returns
    -------
    u : (n,) array, report : StepReport (``residuals`` holds ||r|| per iteration)
    """
    u = u.copy()
    r = residual(u)
    norms = [float(np.linalg.norm(r))]
    # the predictor's residual joins the scale: a load switched on at t_{n+1} from rest
    # has r_ref = 0 (no force at t_n), and only r(predictor) then measures the step
    tol = max(opts.rtol * max(r_ref, norms[0]), opts.atol)
    if norms[0] <= tol:
        return u, StepReport(True, 0, "", norms)
    if linear:
        u += lu.solve("linear", lambda: jacobian(u), -r)
        return u, StepReport(True, 1, "", norms)
    for it in range(1, opts.max_iter + 1):
        try:
            du = _DIRECT.solve(jacobian(u), -r)[0]
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
