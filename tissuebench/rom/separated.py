"""Proper generalised decomposition of a linear problem in separated (tensor) form.

Solves ``A u = f`` where the operator and the right-hand side are sums of Kronecker
products over D dimensions (space, parameters, time ...),

    A = sum_t kron(A_t[0], ..., A_t[D-1]),     f = sum_t kron(f_t[0], ..., f_t[D-1]),

for ``u ≈ sum_i kron(F_i[0], ..., F_i[D-1])`` without ever forming a full tensor
(pgd-vademecum-cutting §2 and Appendix A; Chinesta, Keunings & Leygue 2014, ch. 2):

* **Greedy enrichment**: mode ``n+1`` is sought with modes ``1..n`` fixed.
* **Alternating directions** (fixed point): all factors but dimension ``d`` are frozen
  and the Galerkin projection of the problem on ``kron(r_0, .., v, .., r_{D-1})``,
  ``v`` free, is solved: ``(sum_t c_t A_t[d]) v = rhs`` with scalars
  ``c_t = prod_{e != d} r_e^T A_t[e] r_e``. Dimensions are swept 0, 1, ..., D-1, so
  the last dimension is always the exact projection given the others (for the
  vademecum u(x, s) the parameter functions S are exact given X, which the srb/prb
  identities of the paper rely on). Factors of dimensions 0..D-2 are kept at unit
  Euclidean norm; the amplitude lives in the last one.
* **Fixed-point convergence**: ``max_d |r_d - r_d_old| / |r_d|`` (signs aligned)
  ``<= fixed_point_tol``; not converging in ``max_fixed_point`` sweeps is recorded in
  :attr:`SeparatedSolution.converged` (the mode is kept), never raised.
* **Stopping** (checked after each mode, reason in ``stop_reason``):
  ``"amplitude"`` mode amplitude ``prod_d |F_i[d]|`` <= ``tol`` times that of the first
  mode; ``"residual"`` relative residual ``|f - A u| / |f|`` <= ``residual_tol``;
  ``"stagnation"`` the residual has not gone below 0.99 times its best value for
  ``patience`` modes in a row (modes that stop improving); ``"zero_mode"`` the projected
  right-hand side vanished (u already solves the problem in the projected sense);
  ``"breakdown"`` a non-finite factor (the mode is dropped); ``"max_modes"``.

The residual norm is evaluated exactly in separated form through the Gram matrices of
the terms, ``|r|^2 = c^T (G_0 ∘ ... ∘ G_{D-1}) c``; being a difference of squares it is
reliable down to ~1e-7 relative (round-off), hence the amplitude criterion for tight
tolerances. All norms are Euclidean (plain coefficient vectors); scale the factors (or
use an orthonormal basis per dimension) if another norm is wanted.

Initial factors are random (``rng``: an int seed or a ``numpy.random.Generator``;
``None`` means seed 0), so builds are reproducible.

This module holds the separated types; the algorithm, :func:`~.separated_solver.pgd_solve`, is
:mod:`.separated_solver`, which imports them (``separated.pgd_solve`` works for one release, with a
DeprecationWarning).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from .._moved import moved

__all__ = ["SeparatedOperator", "SeparatedVector", "SeparatedSolution"]

# pgd_solve, the algorithm, imports these types: it lives in .separated_solver, above this module (issue 55)
__getattr__ = moved(__name__, {"pgd_solve": "tissuebench.rom.separated_solver"})

STOP_REASONS = ("amplitude", "residual", "stagnation", "zero_mode", "breakdown", "max_modes")


def _check_terms(terms, what, square):
    if not isinstance(terms, (list, tuple)) or not terms:
        raise ValueError(f"{what}.terms must be a non-empty list of tuples, got {terms!r}")
    D, shape = None, None
    for k, term in enumerate(terms):
        if not isinstance(term, tuple) or not term:
            raise ValueError(f"{what}.terms[{k}] must be a non-empty tuple of factors, got {type(term).__name__}")
        D = len(term) if D is None else D
        if len(term) != D:
            raise ValueError(f"{what}.terms[{k}] has {len(term)} factors, terms[0] has {D}")
        dims = []
        for d, a in enumerate(term):
            s = a.shape if (sp.issparse(a) or isinstance(a, np.ndarray)) else np.shape(a)
            if square and (len(s) != 2 or s[0] != s[1]):
                raise ValueError(f"{what}.terms[{k}][{d}] must be a square matrix, got shape {s}")
            if not square and not (len(s) == 1 or (len(s) == 2 and 1 in s)):
                raise ValueError(f"{what}.terms[{k}][{d}] must be a vector, got shape {s}")
            dims.append(s[0] if square else int(np.prod(s)))
        shape = tuple(dims) if shape is None else shape
        if tuple(dims) != shape:
            raise ValueError(f"{what}.terms[{k}] has factor sizes {tuple(dims)}, terms[0] has {shape}")
    return D, shape


@dataclass
class SeparatedOperator:
    """``A = sum_t kron(A_t[0], ..., A_t[D-1])``; each factor a square (n_d, n_d) matrix,
    scipy sparse or dense."""

    terms: list

    def __post_init__(self):
        self.terms = [tuple(t) for t in self.terms] if isinstance(self.terms, (list, tuple)) else self.terms
        self.ndim, self.shape = _check_terms(self.terms, "SeparatedOperator", square=True)

    def to_dense(self) -> np.ndarray:
        """The assembled ``(prod n_d, prod n_d)`` matrix (small cases and tests only)."""
        out = 0.0
        for term in self.terms:
            k = np.ones((1, 1))
            for a in term:
                k = np.kron(k, a.toarray() if sp.issparse(a) else np.asarray(a, float))
            out = out + k
        return out


@dataclass
class SeparatedVector:
    """``f = sum_t kron(f_t[0], ..., f_t[D-1])``; each factor a vector of size n_d
    (1D array, or a sparse (n_d, 1) column)."""

    terms: list

    def __post_init__(self):
        self.terms = [tuple(t) for t in self.terms] if isinstance(self.terms, (list, tuple)) else self.terms
        self.ndim, self.shape = _check_terms(self.terms, "SeparatedVector", square=False)

    @classmethod
    def from_columns(cls, columns) -> "SeparatedVector":
        """From one (n_d, T) matrix per dimension (sparse or dense), term t = column t."""
        cols = [c.tocsc() if sp.issparse(c) else np.asarray(c, float) for c in columns]
        T = {c.shape[1] for c in cols}
        if len(T) != 1:
            raise ValueError(f"SeparatedVector.from_columns: column counts differ {sorted(T)}")
        return cls([tuple(c[:, [t]] if sp.issparse(c) else c[:, t] for c in cols) for t in range(T.pop())])

    def stacked(self, d: int):
        """(n_d, T) matrix of the dimension-d factors (sparse if any factor is)."""
        fs = [self.terms[t][d] for t in range(len(self.terms))]
        if any(sp.issparse(f) for f in fs):
            return sp.hstack([sp.csc_matrix(f).reshape(-1, 1) for f in fs], format="csc")
        return np.column_stack([np.asarray(f, float).ravel() for f in fs])

    def to_dense(self) -> np.ndarray:
        out = 0.0
        for term in self.terms:
            k = np.ones(1)
            for f in term:
                k = np.kron(k, f.toarray().ravel() if sp.issparse(f) else np.asarray(f, float).ravel())
            out = out + k
        return out


@dataclass
class SeparatedSolution:
    """``u ≈ sum_i prod_d F_i[d]``: ``modes[i][d]`` is a (n_d,) vector.

    Attributes
    ----------
    modes : list of tuple of (n_d,) arrays
    fixed_point_iterations : list of int, sweeps used by each mode
    converged : list of bool, whether each mode's fixed point met ``fixed_point_tol``
    amplitudes : list of float, ``prod_d |F_i[d]|`` of each mode
    stop_reason : str, one of ``STOP_REASONS`` (module docstring)
    residuals : list of float, ``|f - A u_n| / |f|`` after each mode n
    message : str, human-readable summary
    """

    modes: list
    fixed_point_iterations: list = field(default_factory=list)
    converged: list = field(default_factory=list)
    amplitudes: list = field(default_factory=list)
    stop_reason: str = ""
    residuals: list = field(default_factory=list)
    message: str = ""

    @property
    def n_modes(self) -> int:
        return len(self.modes)

    @property
    def ndim(self) -> int:
        return len(self.modes[0]) if self.modes else 0

    def mode_matrix(self, d: int) -> np.ndarray:
        """(n_d, n_modes): the dimension-d factors as columns."""
        return np.column_stack([m[d] for m in self.modes])

    def truncated(self, n: int) -> "SeparatedSolution":
        """The first ``n`` modes (greedy modes are nested: the same as a build stopped at n)."""
        if not 0 < int(n) <= self.n_modes:
            raise ValueError(f"truncated: n = {n!r} outside 1..{self.n_modes}")
        n = int(n)
        return SeparatedSolution(self.modes[:n], self.fixed_point_iterations[:n], self.converged[:n],
                                 self.amplitudes[:n], "truncated", self.residuals[:n], f"first {n} modes")

    def evaluate(self, dim, index_or_weights):
        """Partial evaluation of one or more dimensions.

        Parameters
        ----------
        dim : int or sequence of int
            Dimension(s) to evaluate.
        index_or_weights : int, (n_d,) array, or a sequence of those (one per ``dim``)
            A node index, or interpolation weights ``w`` (the value is ``w @ F_i[d]``).

        Returns
        -------
        float if every dimension is evaluated; (n_r,) array if one remains; else a
        :class:`SeparatedSolution` over the remaining dimensions (scalars folded into
        their first factor).
        """
        dims = [dim] if np.ndim(dim) == 0 else list(dim)
        pts = [index_or_weights] if np.ndim(dim) == 0 else list(index_or_weights)
        if len(pts) != len(dims) or len(set(dims)) != len(dims) or any(not 0 <= d < self.ndim for d in dims):
            raise ValueError(f"evaluate: dims {dims} with {len(pts)} points for a {self.ndim}-D solution")
        scale = np.ones(self.n_modes)
        for d, p in zip(dims, pts):
            F = self.mode_matrix(d)
            if np.ndim(p) == 0:
                if not -F.shape[0] <= int(p) < F.shape[0]:
                    raise ValueError(f"evaluate: index {p!r} outside dimension {d} of size {F.shape[0]}")
                scale = scale * F[int(p)]
            else:
                w = np.asarray(p, float)
                if w.shape != (F.shape[0],):
                    raise ValueError(f"evaluate: weights of shape {w.shape} for dimension {d} of size {F.shape[0]}")
                scale = scale * (w @ F)
        rest = [d for d in range(self.ndim) if d not in dims]
        if not rest:
            return float(scale.sum())
        if len(rest) == 1:
            return self.mode_matrix(rest[0]) @ scale
        modes = [tuple(m[d] * (scale[i] if k == 0 else 1.0) for k, d in enumerate(rest))
                 for i, m in enumerate(self.modes)]
        return SeparatedSolution(modes, list(self.fixed_point_iterations), list(self.converged),
                                 [float(np.prod([np.linalg.norm(v) for v in m])) for m in modes],
                                 self.stop_reason, list(self.residuals), f"evaluated in dims {dims}")

    def to_dense(self) -> np.ndarray:
        """The full ``prod n_d`` vector (small cases and tests only)."""
        out = 0.0
        for m in self.modes:
            k = np.ones(1)
            for v in m:
                k = np.kron(k, v)
            out = out + k
        return out
