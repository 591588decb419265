"""Helpers of the online phase: parameters read without a copy, reduced solves through LAPACK,
and the arithmetic floor of a haptic step.

A haptic step of a reduced model does little arithmetic (an m x m solve, a short series, a
few rows of a basis): at tens of unknowns one NumPy or LAPACK call costs about as much as
its flops, so what a step does *around* its linear algebra (copying ``mu``, validating it,
scipy's argument checks, temporaries, result objects) decides its latency. The helpers
here keep that overhead small:

* :func:`parameter` reads ``mu[key]`` as a float with one type test; anything else (an int,
  a NumPy scalar, a missing key, NaN) goes through :func:`~.base.check_parameters`, which
  converts it or raises naming the key and the value.
* :class:`ReducedSolver` factorises a small dense matrix once and solves with the raw LAPACK
  routine (``potrs`` / ``getrs`` from :func:`scipy.linalg.get_lapack_funcs`, no finiteness
  scan), or with a precomputed inverse up to :data:`INVERSE_MAX` unknowns, where one
  matrix-vector product costs less than the call into LAPACK.
* The **floor** of a step (:meth:`~.base.OnlineModel.floor_ops`): a zero-argument callable
  doing only the arithmetic the step cannot avoid at its sizes, on preallocated arrays, with
  the fewest calls. The latency protocol times it beside the step (``floor_s``) and reports
  ``efficiency = floor_s / haptic_median_s``: 1 is a step that is nothing but its arithmetic.
  :func:`solve_floor` is the default (a reduced solve with the stored factor and the output
  matrix-vector product); the methods declare their own.
"""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla

from .parameters import check_parameters

__all__ = ["parameter", "ReducedSolver", "INVERSE_MAX", "solve_floor", "matvec_floor", "compose"]

#: up to this size a reduced solve is a product with the inverse computed offline
INVERSE_MAX = 32


def parameter(mu, key: str, who: str) -> float:
    """``mu[key]`` as a finite float; a Python float is returned as is and a Python int converted
    (the haptic path), any other value is converted or refused by :func:`~.parameters.check_parameters` (ValueError or
    TypeError naming ``who``, the key and the value)."""
    try:
        v = mu[key]
    except (KeyError, TypeError, IndexError):
        v = None
    if type(v) is float and v - v == 0.0:  # finite: inf - inf and nan - nan are nan
        return v
    if type(v) is int:  # a node index, a cut length (bool is not int's type)
        return float(v)
    return float(check_parameters(mu, (key,), who)[key])


class ReducedSolver:
    """``solve(b) = K^{-1} b`` of a small dense matrix factorised once.

    Parameters
    ----------
    K : (n, n) array
    spd : bool, optional
        Try Cholesky (LAPACK ``potrf`` / ``potrs``) first; LU (``getrf`` / ``getrs``) when it
        fails or when False.
    inverse_max : int
        Sizes up to this use the explicit inverse (one matrix-vector product per solve;
        accurate for the well-conditioned reduced matrices of the ROMs here).

    Attributes
    ----------
    kind : str
        ``"inverse"``, ``"cholesky"`` or ``"lu"``.
    """

    def __init__(self, K, spd: bool = True, inverse_max: int = INVERSE_MAX):
        K = np.array(K, dtype=float, order="F")
        if K.ndim != 2 or K.shape[0] != K.shape[1] or not np.all(np.isfinite(K)):
            raise ValueError(f"ReducedSolver: K must be a finite square matrix, got shape {K.shape}")
        self.n = K.shape[0]
        if self.n <= inverse_max:
            self.kind, self._inv = "inverse", np.linalg.inv(K)
            self.solve = self._inv.__matmul__
            return
        if spd:
            potrf, potrs = sla.get_lapack_funcs(("potrf", "potrs"), (K,))
            c, info = potrf(K, lower=True)
            if info == 0:
                self.kind = "cholesky"
                self.solve = lambda b: potrs(c, b, lower=True)[0]
                return
        getrf, getrs = sla.get_lapack_funcs(("getrf", "getrs"), (K,))
        lu, piv, info = getrf(K)
        if info != 0:
            raise np.linalg.LinAlgError(f"ReducedSolver: singular matrix (getrf info {info})")
        self.kind = "lu"
        self.solve = lambda b: getrs(lu, piv, b)[0]

    def __call__(self, b):
        return self.solve(b)


def compose(*kernels):
    """One zero-argument callable running ``kernels`` in order (the parts of a floor)."""
    kernels = tuple(kernels)
    if len(kernels) == 1:
        return kernels[0]

    def run():
        for k in kernels:
            k()
    return run


def matvec_floor(A, n_right: int | None = None):
    """A product ``A @ x`` into a preallocated vector (A (m, n); x a fixed random vector)."""
    A = np.ascontiguousarray(A, dtype=float)
    x = np.random.default_rng(0).standard_normal(A.shape[1] if n_right is None else n_right)
    y = np.empty(A.shape[0])
    return lambda: np.dot(A, x, out=y)


def solve_floor(n: int, n_out: int):
    """The default floor: a reduced solve of size ``n`` with a stored factor (:class:`ReducedSolver`,
    an SPD matrix) and the ``n_out x n`` output product."""
    n, n_out = max(int(n), 1), max(int(n_out), 1)
    rng = np.random.default_rng(0)
    A = rng.standard_normal((n, n))
    solver = ReducedSolver(A @ A.T + n * np.eye(n))
    b, C, y = rng.standard_normal(n), rng.standard_normal((n_out, n)), np.empty(n_out)
    solve = solver.solve

    def floor():
        np.dot(C, solve(b), out=y)
    return floor
