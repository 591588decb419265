"""Conjugate gradients preconditioned by smoothed-aggregation AMG, with the hierarchy reused.

pyamg's smoothed aggregation with the six rigid-body modes as near-null space ``B``
(elasticity has them as its zero-energy modes) and a symmetric Gauss-Seidel V-cycle. The
setup (aggregation, prolongator smoothing, Galerkin products, coarse factorisation)
costs about 25 V-cycles on the 22k-dof bar; Newton's tangents change little from one
iteration (and load increment) to the next, so the hierarchy is kept and only the
finest level takes the new matrix. The V-cycle stays symmetric positive definite (the
coarse operators are SPD Galerkin products of an earlier tangent), so CG remains valid;
it only converges more slowly as the hierarchy ages. The hierarchy is rebuilt when

* the sparsity pattern differs (exact comparison), or the matrix stops being symmetric;
* CG needed more than ``rebuild_factor`` times the iterations per decade of residual
  reduction it needed right after the last setup (rebuilt before the next solve);
* CG did not converge with an aged hierarchy (rebuilt and solved again at once).
"""
from __future__ import annotations

import math
import time

import numpy as np
import scipy.sparse.linalg as spla

from .solver_base import LinearSolver, LinearSolverError, SparsityPattern, canonical_csr

_GS = ("gauss_seidel", {"sweep": "symmetric"})  # reads the level matrix at call time


def rigid_body_modes(coords, free_dofs=None):
    """Translations and infinitesimal rotations of ``coords`` (n_nodes, 3), node-major dofs.

    Returns
    -------
    ndarray, shape (n_rows, 6)
        Rows ``free_dofs`` of the (3 n_nodes, 6) mode matrix (all rows if None).
    """
    coords = np.asarray(coords, dtype=float)
    x = coords - coords.mean(axis=0)
    B = np.zeros((3 * len(coords), 6))
    for c in range(3):
        B[c::3, c] = 1.0
    B[0::3, 3], B[1::3, 3] = -x[:, 1], x[:, 0]
    B[1::3, 4], B[2::3, 4] = -x[:, 2], x[:, 1]
    B[0::3, 5], B[2::3, 5] = x[:, 2], -x[:, 0]
    return B if free_dofs is None else B[np.asarray(free_dofs)]


class AmgCgSolver(LinearSolver):
    """pyamg-preconditioned CG (GMRES for non-symmetric K) with a reused hierarchy.

    Parameters
    ----------
    rtol : float or None
        Fixed relative residual ``|b - K x| / |b|``; None: the caller's ``rtol`` (Newton's
        forcing term), ``default_rtol`` when the caller gives none.
    maxiter : int
        Krylov iterations per solve.
    coords, free_dofs : array_like, optional
        Node coordinates (n_nodes, 3) and the dofs ``K`` is restricted to: the rigid-body
        near-null space. Without them pyamg's default (constant vector) is used.
    reuse : bool
        Keep the hierarchy between solves (see the module docstring).
    rebuild_factor : float
        Iterations-per-decade growth (relative to the fresh hierarchy) that triggers a rebuild.
    max_coarse : int
        Size below which pyamg stops coarsening; the coarsest level is LU-factorised.
    """

    name = "amg-cg"
    iterative = True
    default_rtol = 1e-8

    def __init__(self, rtol=None, maxiter: int = 2000, coords=None, free_dofs=None, reuse: bool = True,
                 rebuild_factor: float = 1.5, max_coarse: int = 500):
        if rtol is not None and not (0 < rtol < 1):
            raise ValueError(f"rtol must lie in (0, 1), got {rtol!r}")
        if int(maxiter) < 1:
            raise ValueError(f"maxiter must be >= 1, got {maxiter!r}")
        if not (rebuild_factor >= 1):
            raise ValueError(f"rebuild_factor must be >= 1, got {rebuild_factor!r}")
        self.rtol, self.maxiter, self.coords = rtol, int(maxiter), coords
        self.free_dofs = None if free_dofs is None else np.asarray(free_dofs)
        self.reuse, self.rebuild_factor, self.max_coarse = bool(reuse), float(rebuild_factor), int(max_coarse)
        self.reset()

    def reset(self):
        self._ml, self._M, self._pattern = None, None, SparsityPattern()
        self._symmetric, self._fresh_rate, self._stale, self.setups = None, None, False, 0

    def _near_null_space(self, n):
        if self.coords is None:
            return None
        rows = np.arange(3 * len(self.coords)) if self.free_dofs is None else self.free_dofs
        return rigid_body_modes(self.coords, rows) if len(rows) == n else None

    def _setup(self, K):
        import pyamg

        self._pattern.store(K)
        self._symmetric = self._pattern.is_symmetric(K)
        self._ml = pyamg.smoothed_aggregation_solver(
            K, B=self._near_null_space(K.shape[0]), symmetry="symmetric" if self._symmetric else "nonsymmetric",
            presmoother=_GS, postsmoother=_GS, max_coarse=self.max_coarse, coarse_solver="splu")
        self._M = self._ml.aspreconditioner(cycle="V")
        self._fresh_rate, self._stale = None, False
        self.setups += 1

    def _needs_setup(self, K):
        if self._ml is None or not self.reuse or self._stale or not self._pattern.matches(K):
            return True
        return self._pattern.is_symmetric(K) != self._symmetric

    def _krylov(self, K, b, rtol):
        count = [0]

        def cb(_):
            count[0] += 1

        with np.errstate(all="ignore"):
            if self._symmetric:
                x, flag = spla.cg(K, b, rtol=rtol, maxiter=self.maxiter, M=self._M, callback=cb)
            else:
                x, flag = spla.gmres(K, b, rtol=rtol, maxiter=self.maxiter, M=self._M, callback=cb,
                                     callback_type="pr_norm", restart=50)
        bnorm = np.linalg.norm(b)
        relres = float(np.linalg.norm(b - K @ x) / bnorm) if bnorm > 0 else 0.0
        ok = flag == 0 and np.all(np.isfinite(x))
        return x, count[0], relres, ok

    def solve(self, K, b, rtol=None):
        """Solve ``K x = b`` to ``self.rtol`` (if set), else ``rtol``, else ``default_rtol``."""
        K = canonical_csr(K)
        b = np.asarray(b, dtype=float)
        tol = self.rtol or rtol or self.default_rtol
        t0, c0 = time.perf_counter(), time.process_time()
        built = self._needs_setup(K)
        if built:
            self._setup(K)
        else:
            self._ml.levels[0].A = K  # finest level: the current tangent; coarse levels kept
        t1, factor_s, factor_cpu_s = time.perf_counter(), time.perf_counter() - t0, time.process_time() - c0
        x, its, relres, ok = self._krylov(K, b, tol)
        if not ok and not built:  # an aged hierarchy may be too weak: rebuild once
            t2, c2 = time.perf_counter(), time.process_time()
            self._setup(K)
            factor_s, factor_cpu_s = factor_s + time.perf_counter() - t2, factor_cpu_s + time.process_time() - c2
            built, t1 = True, time.perf_counter()
            x, more, relres, ok = self._krylov(K, b, tol)
            its += more
        if not ok:
            self._stale = True
            raise LinearSolverError(f"{self.name}: no convergence to rtol={tol:.1e} after {its} iterations "
                                    f"(relative residual {relres:.2e})")
        self._track_rate(its, relres, tol, built)
        return x, {"solver": "amg-cg" if self._symmetric else "amg-gmres", "iterations": its,
                   "factor_s": factor_s, "factor_cpu_s": factor_cpu_s, "solve_s": time.perf_counter() - t1, "rtol": tol,
                   "relative_residual": relres, "hierarchy": "built" if built else "reused",
                   "levels": len(self._ml.levels)}

    def _track_rate(self, its, relres, tol, built):
        """Iterations per decade of residual reduction; flag a rebuild when it has grown."""
        decades = -math.log10(max(relres, tol * 1e-3, 1e-300)) if relres < 1 else 0.0
        if decades <= 0.5:  # too little reduction asked for to measure a rate
            return
        rate = its / decades
        if built or self._fresh_rate is None:
            self._fresh_rate = rate
        elif rate > self.rebuild_factor * self._fresh_rate:
            self._stale = True
