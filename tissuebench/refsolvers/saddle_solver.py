"""Linear solver for the tangent of the mixed u-p formulation (a saddle-point matrix).

``K = [[A, B^T], [B, C]]`` with the pressure block C zero (incompressible) or negative
(perturbed Lagrangian). Sparse LU with partial pivoting (SuperLU) solves it but is slow
(20 times fill on the 17k-dof ventricle: 6-9 s per factorisation). The tangent is
symmetric whenever the loads are conservative (a follower pressure whose loaded surface
has its rim fixed, the ventricle), so here

1. the symmetric part regularised on the pressure block, ``P = sym K - delta I_p``, is
   factorised by NGSolve's sparse LDL^T (``sparsecholesky``, no pivoting: the regularised
   matrix is quasi-definite when A is positive definite, and has no zero pivot in practice
   beyond). The NGSolve matrix and its ordering are kept: a tangent with the same pattern
   is copied into it and refactorised in place (:class:`~.sparse_direct.NgsolveSparseSolver`);
2. GMRES on K with P as preconditioner removes both the regularisation and any
   asymmetry. delta must be small against the pressure Schur complement B A^-1 B^T, not
   only against A: on the ventricle (17k dofs, guccione, diag(A) ~ 500, Schur diagonal
   7e-4 .. 4e-2) delta = 1e-5 took 33-37 iterations per solve, 1e-9 takes 3 (relative
   residual 1e-12);
3. anything failing (non-finite pivots, no GMRES convergence) falls back to SuperLU with a
   COLAMD ordering, which pivoting does not spoil (20k-dof beam: COLAMD 3.5 s, minimum
   degree on A + A^T > 5 min, NGSolve's UMFPACK 19 s).

With steps 1-2 as they are (and the NGSolve tangent on one structural pattern), the
ventricle's refinement table (``examples/lv_mixed_refinement.py``; 77 Newton iterations at ci)
went from 85 s to 32 s on the ci mesh and from 2122 s to 981 s on the paper mesh (135 574
dofs). Before, 22 s of the ci run had gone into building the NGSolve matrix from COO, 20 s
into fresh factorisations and 28 s into GMRES; on the paper mesh every tangent had a new
pattern (exact zeros at small strain dropped by SciPy) and was factorised anew.

Without NGSolve only step 3 runs.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .linear_solvers import DirectSolver
from .solver_base import LinearSolverError


def schur_scale(K, n_p: int) -> float:
    """Mean diagonal of the pressure Schur complement estimate ``B diag(A)^-1 B^T`` of
    ``K = [[A, B^T], [B, C]]`` (the last ``n_p`` unknowns are pressures), the scale the
    pressure-block regularisation must be small against. It is not the scale of A: with SI
    units on a soft organ (E = 3 kPa, cells of 5 mm) diag(A) ~ 10 and the Schur diagonal
    ~ 1e-8, so a regularisation relative to A (1e-9 x 10) swamped the Schur complement and
    GMRES took 86-118 iterations per solve, some falling back to SuperLU."""
    K = sp.csr_matrix(K)
    n_u = K.shape[0] - int(n_p)
    diag_a = np.abs(K.diagonal()[:n_u])
    if n_u == 0 or not np.all(diag_a > 0):
        return 1.0
    B = K[n_u:, :n_u]
    s = np.asarray(B.multiply(B) @ (1.0 / diag_a)).ravel()
    scale = float(s.mean())
    return scale if np.isfinite(scale) and scale > 0 else 1.0


class SaddlePointSolver:
    """``solve(K, b) -> (x, info)`` for a mixed tangent whose last ``n_p`` unknowns are pressures.

    Parameters
    ----------
    n_p : int
        Number of pressure unknowns (the trailing rows/columns of every K solved).
    rtol : float
        Relative residual GMRES must reach (else: SuperLU).
    delta : float
        Pressure-block regularisation relative to the mean diagonal of the pressure Schur
        complement estimate (:func:`schur_scale`), so independent of the units.
    use_ngsolve : bool
        Try the NGSolve LDL^T preconditioner first (default: when NGSolve imports).
    """

    name = "saddle"

    def __init__(self, n_p: int, rtol: float = 1e-11, delta: float = 1e-6, use_ngsolve: bool | None = None):
        if int(n_p) < 1:
            raise ValueError(f"n_p must be >= 1, got {n_p!r}")
        if not 0 < rtol < 1 or not 0 < delta < 1:
            raise ValueError(f"rtol and delta must lie in (0, 1), got {rtol!r}, {delta!r}")
        self.n_p, self.rtol, self.delta = int(n_p), float(rtol), float(delta)
        if use_ngsolve is None:
            try:
                import ngsolve  # noqa: F401
                use_ngsolve = True
            except ImportError:
                use_ngsolve = False
        self.use_ngsolve = use_ngsolve
        self.fallback = DirectSolver(permc_spec="COLAMD")
        self._ldlt_solver = None

    def _ldlt(self, K):
        """NGSolve LDL^T of sym K - delta I_p (kept, refactorised in place): (r -> P^-1 r, "reused" | "computed")."""
        from .sparse_direct import NgsolveSparseSolver

        if self._ldlt_solver is None:
            self._ldlt_solver = NgsolveSparseSolver(symmetric=True, inverse="sparsecholesky")
        n = K.shape[0]
        n_u = n - self.n_p
        reg = np.r_[np.zeros(n_u), np.full(self.n_p, -self.delta * schur_scale(K, self.n_p))]
        # values that come out zero change P's pattern: the solver keeps its factorisation on
        # the union of the patterns it has seen (:meth:`NgsolveSparseSolver._factorise`)
        return self._ldlt_solver.factorize(0.5 * (K + K.T) + sp.diags(reg))

    def solve(self, K, b):
        K = sp.csr_matrix(K)
        b = np.asarray(b, float)
        t0 = time.perf_counter()
        if self.use_ngsolve and b.ndim == 1:
            try:
                apply, symbolic = self._ldlt(K)
                t1 = time.perf_counter()
                count = [0]
                pre = spla.LinearOperator(K.shape, matvec=apply, dtype=float)  # no probing matvec
                x, _ = spla.gmres(K, b, M=pre, rtol=self.rtol, atol=0.0, restart=40, maxiter=3,
                                  callback=lambda _r: count.__setitem__(0, count[0] + 1), callback_type="pr_norm")
                res = np.linalg.norm(K @ x - b)
                if np.all(np.isfinite(x)) and res <= 10 * self.rtol * np.linalg.norm(b):
                    return x, {"solver": "ldlt-gmres", "iterations": count[0], "factor_s": t1 - t0,
                               "solve_s": time.perf_counter() - t1, "symbolic": symbolic}
            except (RuntimeError, ValueError, np.linalg.LinAlgError, LinearSolverError):
                pass  # non-finite pivots or breakdown: the pivoting LU below
        x, info = self.fallback.solve(K, b)  # LinearSolverError if singular
        info = dict(info, solver="scipy-splu-colamd", factor_s=time.perf_counter() - t0 - info.get("solve_s", 0.0))
        return x, info
