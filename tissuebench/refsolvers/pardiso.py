"""Intel MKL PARDISO (through pypardiso) for the large tangent systems.

NGSolve's sparse LDL^T orders the unknowns by minimum degree. On a 3D mesh a nested-dissection
ordering (METIS, which PARDISO uses) fills far less, and PARDISO factorises the supernodes
on both cores. On the 5k-node organ refined to h/2 with average nodal pressure tetrahedra
(102 318 unknowns, 19.8 M entries: the convergence check's heaviest system) PARDISO's factors
take 2.5 GB and 38-45 s, a solve with them 0.2-0.3 s; NGSolve's took 147 s and 1.42 s
(``docs/explanation/nearly-incompressible.md``). The statics' ``"auto"`` solver keeps
PARDISO's factors from :data:`~tissuebench.refsolvers.linear_solvers.KEPT_FACTORS_MIN_DOFS`
unknowns on where MKL is installed (:func:`why_no_pardiso`), NGSolve's elsewhere.

A symmetric ``K`` is factorised as symmetric indefinite (``mtype = -2``: Bunch-Kaufman
pivoting within the supernodes, upper triangle stored), anything else as real unsymmetric
(``mtype = 11``). A pivot PARDISO had to perturb (a singular or nearly singular ``K``) is
checked at the solve: a solution whose residual is not small raises :class:`LinearSolverError`,
as NGSolve's zero pivot does.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp

from .solver_base import LinearSolver, LinearSolverError, SparsityPattern, canonical_csr, is_symmetric

__all__ = ["PardisoSolver", "why_no_pardiso"]

_AVAILABLE: list = []


def why_no_pardiso() -> str:
    """Why MKL's PARDISO cannot be used here, or ``""`` when pypardiso finds it (checked once)."""
    if not _AVAILABLE:
        try:
            import pypardiso

            pypardiso.PyPardisoSolver()  # finds libmkl_rt, or raises ImportError
            _AVAILABLE.append("")
        except Exception as exc:  # noqa: BLE001 -- no pypardiso, no MKL on this platform
            _AVAILABLE.append(f"MKL PARDISO is not available here ({type(exc).__name__}: {exc})")
    return _AVAILABLE[0]


class PardisoSolver(LinearSolver):
    """MKL PARDISO on SciPy CSR systems; the ordering is computed again for a new pattern only.

    Parameters
    ----------
    symmetric : bool, optional
        Factorise as symmetric indefinite (True) or unsymmetric (False); None: decided from
        ``K`` (symmetric to 1e-12 of its largest entry).
    """

    name = "pardiso"
    keeps_factors = True
    #: a solve whose factorisation perturbed pivots must reach this relative residual
    PERTURBED_RTOL = 1e-8

    def __init__(self, symmetric: bool | None = None):
        why = why_no_pardiso()
        if why:
            raise LinearSolverError(f"{self.name} solver: {why}")
        self.symmetric = symmetric
        self._solver, self._pattern = None, SparsityPattern()
        self.reset()

    def reset(self):
        if self._solver is not None:
            self._solver.free_memory(everything=True)
        self._solver, self._A, self._K, self._mtype = None, None, None, None
        self.perturbed_pivots = self.negative_pivots = 0
        self._pattern.clear()

    def __del__(self):
        try:
            self.reset()
        except Exception:  # noqa: BLE001 -- interpreter shutdown: MKL may already be gone
            pass

    def _new_solver(self, mtype):
        import pypardiso

        solver = pypardiso.PyPardisoSolver(mtype=mtype)
        solver.set_iparm(1, 1)  # the iparm below, not PARDISO's defaults
        solver.set_iparm(2, 2)  # METIS nested dissection (serial: the same ordering on every run)
        if mtype == -2:
            # pivots below 1e-8 |K| perturbed, no scaling or matching (a tangent is not far from definite)
            solver.set_iparm(10, 8)
            solver.set_iparm(11, 0)
            solver.set_iparm(13, 0)
        else:
            solver.set_iparm(10, 13)
            solver.set_iparm(11, 1)
            solver.set_iparm(13, 1)
        solver.set_iparm(24, 1)  # the two-level factorisation: the supernodes over both cores
        return solver

    def _stored(self, K):
        """``(matrix PARDISO reads, mtype)``: the upper triangle of a symmetric ``K`` with every diagonal
        entry stored (PARDISO requires it), else ``K``."""
        symmetric = is_symmetric(K) if self.symmetric is None else bool(self.symmetric)
        if symmetric:
            upper = canonical_csr(sp.triu(K, format="csr"))
            # each row's first stored entry is its diagonal (no empty row, none missing)
            if (np.diff(upper.indptr) > 0).all() and np.array_equal(upper.indices[upper.indptr[:-1]],
                                                                    np.arange(K.shape[0])):
                return upper, -2
        return K, 11

    def _call(self, phase, A, b):
        """PARDISO's ``phase`` on ``A`` (pypardiso's call: its ``factorize`` analyses again at every
        call, and the memory of each analysis stays allocated: 165 MB more per factorisation on the
        5k-node organ at h, 10 GB over the h/2 run)."""
        self._solver.set_phase(phase)
        try:
            return self._solver._call_pardiso(A, b)
        except Exception as exc:  # noqa: BLE001 -- PyPardisoError with PARDISO's error code
            self.reset()
            raise LinearSolverError(f"{self.name} solver: phase {phase} failed ({exc})") from None

    def _factorise(self, K) -> str:
        A, mtype = self._stored(K)
        same = self._solver is not None and self._mtype == mtype and self._pattern.matches(A)
        none = np.zeros(A.shape[0])
        if not same:
            self.reset()
            self._solver, self._mtype = self._new_solver(mtype), mtype
            self._call(11, A, none)  # the ordering and symbolic factorisation, once per pattern
            self._pattern.store(A)
        self._call(22, A, none)
        self._A, self._K = A, K
        self.perturbed_pivots = int(self._solver.get_iparm(14))
        self.negative_pivots = int(self._solver.get_iparm(23)) if mtype == -2 else 0
        return "reused" if same else "computed"

    def _apply(self, b):
        x = np.asarray(self._call(33, self._A, np.array(b, dtype=float, order="F")), dtype=float).reshape(b.shape)
        if not np.all(np.isfinite(x)):
            raise LinearSolverError(f"{self.name} solver: non-finite solution (singular matrix?)")
        if self.perturbed_pivots:
            r = np.linalg.norm(self._K @ x - b)
            if not r <= self.PERTURBED_RTOL * max(np.linalg.norm(b), 1e-300):
                raise LinearSolverError(f"{self.name} solver: singular matrix ({self.perturbed_pivots} pivots "
                                        f"perturbed, relative residual {r / max(np.linalg.norm(b), 1e-300):.3g})")
        return x

    def solve(self, K, b, rtol=None):
        """``(x, info)`` for square CSR ``K`` and ``b`` of shape (n,) or (n, k); ``rtol`` is ignored."""
        K = canonical_csr(K)
        if K.shape[0] != K.shape[1]:
            raise ValueError(f"{self.name} solver: K must be square, got shape {K.shape}")
        t0, c0 = time.perf_counter(), time.process_time()
        symbolic = self._factorise(K)
        factor_s, factor_cpu_s = time.perf_counter() - t0, time.process_time() - c0
        bb = np.asarray(b, dtype=float)
        cols = bb.reshape(K.shape[0], -1)
        x = np.column_stack([self._apply(cols[:, j]) for j in range(cols.shape[1])])
        info = {"solver": self.name, "iterations": 1, "factor_s": factor_s, "factor_cpu_s": factor_cpu_s,
                "solve_s": time.perf_counter() - t0 - factor_s, "symbolic": symbolic,
                "perturbed_pivots": self.perturbed_pivots, "negative_pivots": self.negative_pivots}
        return x.reshape(bb.shape), info

    def solve_again(self, b):
        if self._solver is None or self._A is None:
            raise LinearSolverError(f"{self.name} solver: no factors yet (solve first)")
        return self._apply(np.asarray(b, dtype=float))
