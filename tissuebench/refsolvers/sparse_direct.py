"""Sparse direct solvers that keep their symbolic analysis while the sparsity pattern stays.

Newton and the implicit integrators factorise a sequence of matrices with one and the
same CSR pattern (the mesh does not change, only the values). The ordering and the
symbolic factorisation can then be computed once and reused; a matrix whose pattern
differs (another problem, a follower load added, a different free set) is detected by an
exact comparison of ``indptr`` and ``indices`` and gets a fresh analysis.

* :class:`DirectSolver` (``"direct"`` on scikit-fem): SciPy's SuperLU, LU with a
  minimum-degree ordering of K + K^T. SuperLU has no numeric-only refactorisation; what is
  reused is the column ordering (the matrix is permuted once and factorised with
  ``NATURAL``), worth about 5 % of a factorisation on the 22k-dof bar.
* :class:`NgsolveSparseSolver` (``"cholesky"`` on both backends, ``"direct"`` on
  NGSolve): NGSolve's sparse LDL^T (UMFPACK for non-symmetric K), refactorised in place by
  ``Update()`` on the same ordering; on the bar about half of SuperLU's time.
* :func:`factorized`: one matrix factorised once for many right-hand sides (offline ROM
  operators, the linear references of the cutting model): NGSolve from
  :data:`NGSOLVE_MIN_DOFS` unknowns, SuperLU below (where NGSolve's setup costs more).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse.linalg as spla

from .solver_base import (LinearSolver, LinearSolverError, SparsityPattern, canonical_csr, is_symmetric,
                          idle_core)


__all__ = ["NGSOLVE_MIN_DOFS", "DirectSolver", "NgsolveSparseSolver", "factorized"]

# From here on NGSolve's sparse factorisation beats SuperLU on 3D FE matrices by far: the
# paper-size ventricle's backward-Euler matrix (45 042 dofs) 1.5 s against 210 s (MMD);
# the paper cornea's stiffness (23 k dofs) 0.25 s against 3.5 s (COLAMD)
NGSOLVE_MIN_DOFS = 1000


def factorized(K):
    """``solve(b) = K^-1 b`` for a sparse square ``K``, factorised once.

    NGSolve's sparse LDL^T (UMFPACK when K is not symmetric) from :data:`NGSOLVE_MIN_DOFS`
    unknowns on, SciPy's SuperLU (COLAMD) below. ``b`` has shape (n,) or (n, k); a singular
    K raises :class:`LinearSolverError`.
    """
    K = canonical_csr(K)
    if K.shape[0] < NGSOLVE_MIN_DOFS:
        try:
            lu = spla.splu(K.tocsc())
        except RuntimeError as exc:  # "Factor is exactly singular"
            raise LinearSolverError(f"factorized: {exc}") from None
        return lu.solve
    apply = NgsolveSparseSolver(reuse=False, taskmanager=False).factorize(K)[0]

    def solve(b):
        b = np.asarray(b, dtype=float)
        x = apply(b) if b.ndim == 1 else np.column_stack([apply(col) for col in b.T]).reshape(b.shape)
        if not np.all(np.isfinite(x)):
            raise LinearSolverError("factorized: non-finite solution (singular matrix?)")
        return x
    return solve


class _OrderedLU:
    """SuperLU factors of ``K[q][:, q]``; ``solve`` works in the original numbering."""

    def __init__(self, lu, q):
        self.lu, self.q = lu, q

    def solve(self, b):
        b = np.asarray(b, dtype=float)
        if self.q is None:
            return self.lu.solve(b)
        y = self.lu.solve(b[self.q])
        x = np.empty_like(y)
        x[self.q] = y
        return x


class DirectSolver(LinearSolver):
    """SuperLU with a fill-reducing ordering computed once per sparsity pattern.

    Parameters
    ----------
    permc_spec : str
        SuperLU ordering for a new pattern (``"MMD_AT_PLUS_A"``: FE tangents are
        structurally symmetric; 0.8 s against 1.9 s with COLAMD on the 22k-dof bar).
    reuse_ordering : bool
        Reuse the ordering of the previous matrix when the pattern is identical.
    """

    name = "direct"
    keeps_factors = True

    def __init__(self, permc_spec: str = "MMD_AT_PLUS_A", reuse_ordering: bool = True):
        self.permc_spec, self.reuse_ordering = permc_spec, bool(reuse_ordering)
        self.reset()

    def reset(self):
        self._pattern, self._q, self._last = SparsityPattern(), None, None

    def solve_again(self, b):
        if self._last is None:
            raise LinearSolverError("direct solver: no factors yet (solve first)")
        return self._last.solve(np.asarray(b, float))

    def factorize(self, K):
        """LU factors of ``K`` with ``.solve(b)``, reusing the ordering if the pattern matches."""
        return self._factorize(K)[0]

    def _factorize(self, K):
        """(factors, ``"reused"`` or ``"computed"`` ordering)."""
        K = canonical_csr(K)
        reuse = self.reuse_ordering and self._q is not None and self._pattern.matches(K)
        try:
            if reuse:
                lu = spla.splu(K[self._q][:, self._q].tocsc(), permc_spec="NATURAL")
                return _OrderedLU(lu, self._q), "reused"
            lu = spla.splu(K.tocsc(), permc_spec=self.permc_spec)
        except RuntimeError as exc:  # SuperLU: "Factor is exactly singular"
            raise LinearSolverError(f"direct solver: {exc}") from None
        if self.reuse_ordering:
            # L U = Pr K Pc with Pc[i, perm_c[i]] = 1, so K Pc = K[:, q] for q = argsort(perm_c);
            # K[q][:, q] factorised with NATURAL has the same fill (checked by the tests)
            self._q = np.argsort(lu.perm_c)
            self._pattern.store(K)
        return _OrderedLU(lu, None), "computed"

    def solve(self, K, b, rtol=None):
        t0, c0 = time.perf_counter(), time.process_time()
        self._last = None
        lu, symbolic = self._factorize(K)
        self._last = lu
        t1, c1 = time.perf_counter(), time.process_time()
        x = lu.solve(np.asarray(b, float))
        return x, {"solver": "scipy-splu", "iterations": 1, "factor_s": t1 - t0, "factor_cpu_s": c1 - c0,
                   "solve_s": time.perf_counter() - t1, "symbolic": symbolic}


class NgsolveSparseSolver(LinearSolver):
    """NGSolve's sparse direct solvers on SciPy CSR systems, refactorised in place.

    Parameters
    ----------
    symmetric : bool or None
        None: test ``|K - K^T| <= 1e-12 |K|`` (max norms) whenever the pattern is new.
    inverse : str or None
        Force an NGSolve inverse type; default ``"sparsecholesky"`` (LDL^T) for symmetric
        K, else ``"umfpack"`` (falls back to ``"sparsecholesky"`` if unavailable).
    reuse : bool
        Keep the NGSolve matrix and its factorisation object; a matrix with the same
        pattern is copied into it and refactorised by ``Update()`` (same ordering).
    taskmanager : bool or None
        Factorise inside NGSolve's TaskManager (threads of ``ngsolve.SetNumThreads``);
        None: for systems of at least :attr:`TASKMANAGER_MIN_DOFS` unknowns, and only while
        a core is idle (:func:`~tissuebench.refsolvers.solver_base.idle_core`; entering it
        costs 0.1 s on a loaded machine, more than a 600-dof factorisation).
    """

    name = "cholesky"
    keeps_factors = True
    TASKMANAGER_MIN_DOFS = 20000

    def __init__(self, symmetric=None, inverse=None, reuse: bool = True, taskmanager=None):
        self.symmetric, self.inverse = symmetric, inverse
        self.reuse, self.taskmanager = bool(reuse), taskmanager
        self.reset()

    def reset(self):
        self._pattern, self._A, self._inv = SparsityPattern(), None, None
        self._kind = self._requested = None

    def _inverse_type(self, K, same_pattern):
        if self.inverse:
            return self.inverse
        sym = self.symmetric
        if sym is None:
            if same_pattern:
                sym = self._pattern.is_symmetric(K)
            else:
                sym = is_symmetric(K)
        return "sparsecholesky" if sym else "umfpack"

    def _factorise(self, K):
        """Refactorise in place (same pattern and inverse type) or build matrix and inverse anew."""
        import ngsolve as ngs

        if self.taskmanager is None:
            use_tm = K.shape[0] >= self.TASKMANAGER_MIN_DOFS and idle_core()
        else:
            use_tm = self.taskmanager
        tm = ngs.TaskManager() if use_tm else _Null()
        same = self.reuse and self._inv is not None and self._pattern.matches(K)
        if self.reuse and self._inv is not None and not same and self._pattern.shape == K.shape:
            # SciPy drops entries that come out exactly zero, so the tangents of one mesh
            # differ by a few entries: written on the stored pattern when K fits in it, else
            # factorised on the union of both, which the next ones then fit in (the paper-mesh
            # ventricle factorised every one of its tangents anew before)
            embedded = self._pattern.embed(K)
            if embedded is not None:
                K, same = embedded, True
            else:
                K = self._pattern.widened(K)
        kind = self._inverse_type(K, same)
        if same and kind == self._requested:
            self._A.AsVector().FV().NumPy()[:] = K.data
            with tm:
                self._inv.Update()
            return "reused"
        n = K.shape[0]
        rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(K.indptr))
        # Python lists, not numpy arrays: CreateFromCOO converts arrays element by element
        # (0.47 s for the paper cornea's 1.6 M entries, against 0.12 s + 0.11 s of tolist)
        A = ngs.la.SparseMatrixd.CreateFromCOO(rows.tolist(), K.indices.tolist(), K.data.astype(float).tolist(), n, n)
        self._requested = kind
        with tm:
            try:
                inv = A.Inverse(inverse=kind)
            except Exception:  # noqa: BLE001 -- umfpack missing in this build (NgException)
                kind = "sparsecholesky"
                inv = A.Inverse(inverse=kind)
        self._A, self._inv, self._kind = A, inv, kind
        # the vectors every application of these factors fills (CG applies them once per iteration)
        self._bv, self._xv = A.CreateColVector(), A.CreateColVector()
        self._pattern.clear()
        if self.reuse:
            # the in-place refill writes K.data into NGSolve's value array: valid only if
            # NGSolve stores the entries in the same (row-sorted CSR) order as SciPy
            _, cols, rowptr = A.CSR()
            if np.array_equal(np.asarray(rowptr), K.indptr) and np.array_equal(np.asarray(cols), K.indices):
                self._pattern.store(K)
        return "computed"

    def factorize(self, K):
        """Factorise ``K`` (in place when the pattern is the last one's) and return
        ``(apply, "reused" | "computed")`` with ``apply(b) -> K^-1 b`` for b of shape (n,)."""
        K = canonical_csr(K)
        try:
            symbolic = self._factorise(K)
        except Exception as exc:  # noqa: BLE001 -- NGSolve raises its own type on a zero pivot
            self.reset()
            raise LinearSolverError(f"{self.name} solver: {exc}") from None
        inv, bv, xv = self._inv, self._A.CreateColVector(), self._A.CreateColVector()

        def apply(b):
            bv.FV().NumPy()[:] = b
            xv.data = inv * bv
            return xv.FV().NumPy().copy()
        return apply, symbolic

    def solve(self, K, b, rtol=None):
        """Return ``(x, info)`` for square CSR ``K`` and ``b`` of shape (n,) or (n, k)."""
        K = canonical_csr(K)
        n = K.shape[0]
        t0, c0 = time.perf_counter(), time.process_time()
        try:
            symbolic = self._factorise(K)
        except Exception as exc:  # noqa: BLE001 -- NGSolve raises its own type on a zero pivot
            self.reset()
            raise LinearSolverError(f"{self.name} solver: {exc}") from None
        factor_s, factor_cpu_s = time.perf_counter() - t0, time.process_time() - c0
        bb = np.asarray(b, dtype=float)
        cols = bb.reshape(n, -1)
        x = np.empty_like(cols)
        for j in range(cols.shape[1]):
            x[:, j] = self._apply_factors(cols[:, j])
        if not np.all(np.isfinite(x)):
            raise LinearSolverError(f"{self.name} solver: non-finite solution (singular matrix?)")
        info = {"solver": "ngsolve-direct", "iterations": 1, "factor_s": factor_s, "factor_cpu_s": factor_cpu_s,
                "inverse": self._kind,
                "solve_s": time.perf_counter() - t0 - factor_s, "symbolic": symbolic}
        return x.reshape(bb.shape), info

    def _apply_factors(self, b):
        """``K^-1 b`` (n,) with the current factors."""
        self._bv.FV().NumPy()[:] = b
        self._xv.data = self._inv * self._bv
        return self._xv.FV().NumPy().copy()

    def solve_again(self, b):
        if self._inv is None:
            raise LinearSolverError(f"{self.name} solver: no factors yet (solve first)")
        x = self._apply_factors(np.asarray(b, dtype=float))
        if not np.all(np.isfinite(x)):
            raise LinearSolverError(f"{self.name} solver: non-finite solution (singular matrix?)")
        return x


class _Null:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False
