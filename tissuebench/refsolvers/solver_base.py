"""What every linear solver shares: the interface, pattern checks and Newton's forcing term.

A solver is an object with ``solve(K, b, rtol=None) -> (x, info)`` for a square SciPy
CSR ``K`` (free dofs only) and ``b`` of shape (n,) (direct solvers also (n, k)).
``info`` holds at least ``solver``, ``iterations``, ``factor_s`` (seconds spent on
factorisation or preconditioner setup; ``factor_cpu_s`` the process CPU time of it) and
``solve_s`` (the rest). ``rtol`` is the
relative residual a Krylov solver must reach (Newton's forcing term); direct solvers
ignore it. Solvers keep state between calls (orderings, factorisations, AMG
hierarchies) and ``reset()`` drops it.
"""
from __future__ import annotations

import math
import os

import numpy as np
import scipy.sparse as sp


class LinearSolverError(RuntimeError):
    """The linear solve failed (singular matrix, no Krylov convergence)."""


class LinearSolver:
    """Base class of the solvers in :data:`~tissuebench.refsolvers.linear_solvers.LINEAR_SOLVERS`."""

    name = ""
    #: True for solvers that stop at a relative residual (they take Newton's forcing term)
    iterative = False

    def solve(self, K, b, rtol=None):
        raise NotImplementedError

    #: True for solvers that keep the factors of their last :meth:`solve` (:meth:`solve_again`)
    keeps_factors = False

    def solve_again(self, b):
        """``K^-1 b`` with the factors of the last :meth:`solve` (modified Newton: the tangent kept
        across iterations); only where :attr:`keeps_factors`."""
        raise LinearSolverError(f"{self.name or type(self).__name__} solver keeps no factors to solve again with")

    def reset(self):
        """Forget cached orderings, factors or hierarchies."""


def is_symmetric(K, tol: float = 1e-12) -> bool:
    """``max |K - K^T| <= tol max |K|`` for a sparse square ``K`` (compared entry by entry; a
    :class:`SparsityPattern` that holds ``K``'s pattern answers faster)."""
    return K.nnz == 0 or abs(K - K.T).max() <= tol * abs(K).max()


def canonical_csr(K) -> sp.csr_matrix:
    """``K`` as CSR with sorted column indices and no duplicates (copied only if needed)."""
    K = sp.csr_matrix(K)
    if not K.has_canonical_format:
        K = K.copy()
        K.sum_duplicates()
    return K


class SparsityPattern:
    """A stored CSR pattern (copies of ``indptr`` and ``indices``), compared exactly.

    Reusing an ordering, a symbolic factorisation or an AMG hierarchy is valid only for a
    matrix with the very same pattern; anything else (size, number of entries, any index)
    is a new pattern.
    """

    def __init__(self):
        self.clear()

    def clear(self):
        self.shape, self.indptr, self.indices, self._tperm, self._keys = None, None, None, None, None
        self._last_embedded = None

    def store(self, K):
        self.shape, self.indptr, self.indices = K.shape, K.indptr.copy(), K.indices.copy()
        self._tperm = self._keys = self._last_embedded = None

    def _transpose_permutation(self):
        """``perm`` with ``K.T.data == K.data[perm]`` for this pattern, or -1 if not symmetric."""
        if self._tperm is None:
            n = self.shape[0]
            rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(self.indptr))
            keys = rows * n + self.indices  # increasing: canonical CSR
            perm = np.searchsorted(keys, self.indices.astype(np.int64) * n + rows)
            found = perm < len(keys)
            found[found] = keys[perm[found]] == (self.indices.astype(np.int64) * n + rows)[found]
            self._tperm = perm if found.all() else np.array([-1])
        return self._tperm

    def is_symmetric(self, K, tol=1e-12) -> bool:
        """``max |K - K^T| <= tol max |K|`` for a ``K`` that :meth:`matches` this pattern."""
        if K.nnz == 0:
            return True
        scale = np.abs(K.data).max()
        if self.shape[0] != self.shape[1]:
            return False
        perm = self._transpose_permutation()
        if perm[0] < 0:  # structurally non-symmetric: compare explicitly
            return is_symmetric(K, tol)
        return np.abs(K.data - K.data[perm]).max() <= tol * scale

    def matches(self, K) -> bool:
        return (self.shape == K.shape and len(self.indices) == len(K.indices)
                and np.array_equal(self.indptr, K.indptr) and np.array_equal(self.indices, K.indices))

    def widened(self, K):
        """``K`` written on the union of this pattern and its own (zeros where only this one
        has entries)."""
        def ones(indices, indptr):
            return sp.csr_matrix((np.ones(len(indices)), indices, indptr), shape=K.shape)
        union = canonical_csr(ones(self.indices, self.indptr) + ones(K.indices, K.indptr))
        pattern = SparsityPattern()
        pattern.store(union)
        return pattern.embed(K)

    def embed(self, K):
        """``K`` (canonical CSR) written on this pattern, zeros where it has no entry, or None
        when K has an entry outside it.

        SciPy drops the entries of a sum or product that come out exactly zero, so a tangent
        assembled on a fixed mesh can lose a few entries from one Newton iteration to the
        next (the ventricle: 2 to 16 of 1.34 million). Written on the stored pattern it keeps
        the factorisation that pattern has.
        """
        if self.indptr is None or self.shape != K.shape or K.nnz > len(self.indices):
            return None
        last = self._last_embedded  # (indptr, indices, positions): patterns repeat in Newton
        if last is not None and np.array_equal(last[0], K.indptr) and np.array_equal(last[1], K.indices):
            pos = last[2]
        else:
            n = np.int64(self.shape[1])
            if self._keys is None:
                rows = np.repeat(np.arange(self.shape[0], dtype=np.int64), np.diff(self.indptr))
                self._keys = rows * n + self.indices
            rows = np.repeat(np.arange(K.shape[0], dtype=np.int64), np.diff(K.indptr))
            keys = rows * n + K.indices
            pos = np.searchsorted(self._keys, keys)
            if np.any(pos >= len(self._keys)) or not np.array_equal(self._keys[pos], keys):
                return None
            self._last_embedded = (K.indptr.copy(), K.indices.copy(), pos)
        data = np.zeros(len(self.indices), dtype=K.dtype)
        data[pos] = K.data
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape)


def forcing_term(res, res_prev, eta_prev, tol, eta_max=1e-2, gamma=0.9):
    """Relative tolerance of the linear solve in one inexact-Newton iteration.

    Eisenstat-Walker choice 2 with their safeguard (Kelley 1995, eq. 6.18):
    ``eta = gamma (res / res_prev)^2``, not below ``gamma eta_prev^2`` when that exceeds 0.1,
    capped by ``eta_max``; floored at ``0.5 tol / res`` so the last iteration does not solve
    more accurately than Newton's own tolerance needs.

    Parameters
    ----------
    res, res_prev : float
        Residual norms of this and the previous Newton iterate (``res_prev`` None at the
        first iteration of an increment: then ``eta_max``).
    eta_prev : float or None
        Forcing term of the previous iteration.
    tol : float
        Newton's absolute residual tolerance.
    """
    if res_prev is None or eta_prev is None or not res_prev > 0:
        eta = eta_max
    else:
        eta = gamma * (res / res_prev) ** 2
        if gamma * eta_prev**2 > 0.1:
            eta = max(eta, gamma * eta_prev**2)
        eta = min(eta, eta_max)
    if res > 0 and math.isfinite(res):
        eta = max(eta, 0.5 * tol / res)
    return float(min(eta, eta_max))


def idle_core() -> bool:
    """True if the 1-minute load average leaves a core idle for a second thread.

    NGSolve's TaskManager helps only then: on a loaded machine its workers wait for cores
    and spin (measured on the 2-core machine at load ~10: the bar's tangent 1.6 s wall
    serial, 2.6 s inside the TaskManager).
    """
    try:
        return os.getloadavg()[0] <= (os.cpu_count() or 1) - 1
    except OSError:  # no load average on this platform
        return True
