"""Parameter domains and their 1D meshes (pgd-pod-direct-integration §4.2, Remark 2).

Every parameter of the vademecum (each reduced coordinate of the previous state, and the
load factor of the step) lives on an interval discretised by a uniform 1D mesh of P1
elements; the paper uses 100 nodes and recommends uniform meshes for the convergence of
the PGD. The interval is the range seen in the training runs widened by a stated margin
(:func:`parameter_domain`); a value outside it is an extrapolation, reported per step.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["ParameterMesh", "parameter_domain"]


def parameter_domain(values, margin: float, symmetric: bool = True, min_radius: float = 0.0) -> tuple[float, float]:
    """Interval of one parameter from its training values, widened by ``margin``.

    Parameters
    ----------
    values : array_like
        Training values of one parameter (a reduced coordinate [m, m/s ... in the POD
        norm] or a load factor [-]).
    margin : float, >= 0
        Relative widening. ``symmetric``: ``[-R, R]`` with ``R = (1 + margin) max |v|``
        (the paper's intervals of initial conditions, ``[-3, 3]`` m/s). Otherwise
        ``[lo - margin s, hi + margin s]`` with ``s = max(hi - lo, |lo|, |hi|)`` (a value
        constant in training, e.g. a step load, gets relative width ``2 margin``).
    symmetric : bool
        Intervals centred on zero make the one-step map of a linear system (no constant
        term) a sum of L2-orthogonal terms, which greedy PGD recovers with one mode per
        parameter; off-centre intervals add a constant part that it approximates slowly
        (measured: 30 modes for a 1 % error on a rank-3 map).
    min_radius : float, >= 0
        Smallest half-width of a symmetric interval (a coordinate with tiny training
        values still gets room for the small deviations of a reduced trajectory).

    Returns
    -------
    (lo, hi) : floats with lo < hi

    Raises
    ------
    ValueError
        No finite values, a negative ``margin``, or only zeros (no interval can be inferred).
    """
    v = np.asarray(values, dtype=float).ravel()
    if v.size == 0 or not np.all(np.isfinite(v)):
        raise ValueError(f"parameter_domain: values must be a non-empty finite array (got {v.size} values)")
    if not (np.isfinite(margin) and margin >= 0):
        raise ValueError(f"parameter_domain: margin must be finite and >= 0, got {margin!r}")
    lo, hi = float(v.min()), float(v.max())
    span = max(hi - lo, abs(lo), abs(hi))
    if span == 0.0:
        raise ValueError("parameter_domain: every training value is zero; the interval is undefined")
    if symmetric:
        r = max((1.0 + margin) * max(abs(lo), abs(hi)), float(min_radius))
        return -r, r
    if margin == 0.0 and hi == lo:
        raise ValueError(f"parameter_domain: constant values {lo!r} with margin 0 give an empty interval")
    return lo - margin * span, hi + margin * span


@dataclass(frozen=True)
class ParameterMesh:
    """Uniform P1 mesh of ``[lo, hi]`` with ``n_nodes`` nodes.

    Attributes
    ----------
    lo, hi : float
        Interval ends (unit of the parameter).
    n_nodes : int, >= 2
    """

    lo: float
    hi: float
    n_nodes: int

    def __post_init__(self):
        if not (np.isfinite(self.lo) and np.isfinite(self.hi) and self.lo < self.hi):
            raise ValueError(f"ParameterMesh: need finite lo < hi, got [{self.lo!r}, {self.hi!r}]")
        if isinstance(self.n_nodes, bool) or int(self.n_nodes) != self.n_nodes or self.n_nodes < 2:
            raise ValueError(f"ParameterMesh: n_nodes must be an integer >= 2, got {self.n_nodes!r}")

    @property
    def h(self) -> float:
        """Element length."""
        return (self.hi - self.lo) / (self.n_nodes - 1)

    @property
    def nodes(self) -> np.ndarray:
        """Node coordinates, shape (n_nodes,)."""
        return np.linspace(self.lo, self.hi, int(self.n_nodes))

    def mass(self) -> sp.csr_matrix:
        """Consistent P1 mass matrix (n_nodes, n_nodes): the L2 inner product of nodal functions."""
        n, h = int(self.n_nodes), self.h
        main = np.full(n, 2.0 * h / 3.0)
        main[[0, -1]] = h / 3.0
        off = np.full(n - 1, h / 6.0)
        return sp.diags([off, main, off], [-1, 0, 1], format="csr")

    def locate(self, x):
        """Element index and local coordinate of ``x`` (scalar or array).

        Returns
        -------
        k : int array
            Left node of the element, clipped to ``0 .. n_nodes - 2``.
        w : float array
            ``(x - node_k) / h``: in [0, 1] inside the domain, outside it when ``x`` lies
            beyond an end (linear extrapolation of the end element).
        inside : bool array
            ``lo <= x <= hi`` up to a relative round-off of 1e-12.
        """
        x = np.asarray(x, dtype=float)
        s = (x - self.lo) / self.h
        k = np.clip(np.floor(s), 0, self.n_nodes - 2).astype(np.int64)
        tol = 1e-12 * (self.n_nodes - 1)
        return k, s - k, (s >= -tol) & (s <= self.n_nodes - 1 + tol)

    def interpolate(self, values, x) -> np.ndarray:
        """P1 interpolant of nodal ``values`` (n_nodes, ...) at ``x`` (linear extrapolation outside)."""
        values = np.asarray(values, dtype=float)
        k, w, _ = self.locate(x)
        w = w.reshape(w.shape + (1,) * (values.ndim - 1))
        return values[k] * (1.0 - w) + values[k + 1] * w
