"""Newton's tangent systems solved by conjugate gradients preconditioned with kept factors.

On a large mesh a sparse factorisation costs far more than a solve with its factors: on the
5k-node organ refined to h/2 (107 805 dofs, P1, nu = 0.499) NGSolve's LDL^T takes 13.5 s and a
solve with it 0.42 s. The tangents of a load-stepped Newton change little from one iteration
(or increment) to the next, so the factors of an earlier tangent are an excellent
preconditioner for the current one: a few CG iterations reach Newton's forcing term (inexact
Newton, :func:`~tissuebench.refsolvers.solver_base.forcing_term`), for the price of a few
solves. The factors are computed again (and the system solved with them, exactly) when CG does
not reach the tolerance within :attr:`KeptFactorSolver.max_iterations`, breaks down (an
indefinite tangent near a limit point) or costs more than :attr:`KeptFactorSolver.refactor_share`
of a factorisation: the next system then starts from fresh factors.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse.linalg as spla

from .pardiso import PardisoSolver, why_no_pardiso
from .solver_base import LinearSolver, canonical_csr
from .sparse_direct import NgsolveSparseSolver

__all__ = ["KeptFactorSolver", "large_system_solver"]


def large_system_solver(**ngsolve_options) -> LinearSolver:
    """The direct solver whose factors are kept on a large system: MKL PARDISO where it is
    installed (:mod:`.pardiso`: nested dissection, 3.5 times faster than NGSolve's LDL^T on the
    5k-node organ's ANP tangent at h/2), else NGSolve's LDL^T with ``ngsolve_options``."""
    return PardisoSolver() if not why_no_pardiso() else NgsolveSparseSolver(**ngsolve_options)


class KeptFactorSolver(LinearSolver):
    """CG on ``K`` preconditioned by the kept factors of an earlier ``K`` (module docstring).

    Parameters
    ----------
    inner : LinearSolver, optional
        A direct solver with :attr:`~.solver_base.LinearSolver.keeps_factors` (its
        :meth:`~.solver_base.LinearSolver.solve_again` applies the kept factors); default
        :func:`large_system_solver` (PARDISO where MKL is installed, else NGSolve's LDL^T).
    max_iterations : int
        CG iterations before the system is factorised afresh and solved directly.
    refactor_share : float
        A CG solve that took longer than this share of the last factorisation makes the next
        call factorise again (the kept factors have drifted too far from the tangent).
    """

    name = "kept-factor-cg"
    iterative = True
    keeps_factors = True

    def __init__(self, inner: LinearSolver | None = None, max_iterations: int = 30, refactor_share: float = 0.5):
        inner = large_system_solver() if inner is None else inner
        if not getattr(inner, "keeps_factors", False):
            raise TypeError(f"KeptFactorSolver: inner solver {type(inner).__name__} keeps no factors")
        if int(max_iterations) != max_iterations or max_iterations < 1:
            raise ValueError(f"KeptFactorSolver: max_iterations must be an integer >= 1, got {max_iterations!r}")
        if not 0 < refactor_share:
            raise ValueError(f"KeptFactorSolver: refactor_share must be > 0, got {refactor_share!r}")
        self.inner, self.max_iterations, self.refactor_share = inner, int(max_iterations), float(refactor_share)
        self.reset()

    def reset(self):
        self.inner.reset()
        self._shape, self._factor_s, self._stale = None, 0.0, True
        self.counts = {"factorisations": 0, "cg_solves": 0, "cg_iterations": 0, "cg_failures": 0}

    def solve_again(self, b):
        return self.inner.solve_again(b)

    def _direct(self, K, b, why):
        t0 = time.perf_counter()
        x, info = self.inner.solve(K, b)
        self._factor_s = float(info.get("factor_s", time.perf_counter() - t0))
        self._shape, self._stale = K.shape, False
        self.counts["factorisations"] += 1
        return x, {**info, "iterations": 1, "factorised": why}

    def solve(self, K, b, rtol=None):
        """``(x, info)`` for square ``K`` and ``b`` of shape (n,): CG to ``rtol`` (relative
        residual; None: 1e-10) with the kept factors, else a fresh factorisation."""
        K = canonical_csr(K)
        b = np.asarray(b, dtype=float)
        if self._stale or self._shape != K.shape:
            return self._direct(K, b, "no kept factors" if self._shape is None else "refresh")
        tol = 1e-10 if rtol is None else float(rtol)
        M = spla.LinearOperator(K.shape, matvec=self.inner.solve_again, dtype=float)
        count = [0]

        def counted(_xk):
            count[0] += 1

        t0 = time.perf_counter()
        with np.errstate(all="ignore"):
            x, flag = spla.cg(K, b, rtol=tol, atol=0.0, maxiter=self.max_iterations, M=M, callback=counted)
        cg_s = time.perf_counter() - t0
        self.counts["cg_solves"] += 1
        self.counts["cg_iterations"] += count[0]
        res = np.linalg.norm(K @ x - b) if np.all(np.isfinite(x)) else np.inf
        b_norm = max(np.linalg.norm(b), 1e-300)
        if flag != 0 or not res <= tol * b_norm * 1.01:
            self.counts["cg_failures"] += 1
            x, info = self._direct(K, b, f"CG with kept factors: relative residual {res / b_norm:.3g} "
                                         f"after {count[0]} iterations")
            return x, {**info, "cg_iterations": count[0]}
        self._stale = cg_s > self.refactor_share * self._factor_s
        return x, {"solver": self.name, "iterations": count[0], "factor_s": 0.0, "solve_s": cg_s}
