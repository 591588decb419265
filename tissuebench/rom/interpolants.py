"""Online evaluators of interpolated coefficients (``pod_interp``): one parameter point per call,
no per-call setup.

scipy's interpolators are built for many points per call; at one point their argument
checks and chunking cost ten times the arithmetic. These evaluators do the same arithmetic
for one point on arrays prepared offline:

* :class:`Linear1D`: ``np.interp`` of every coefficient at once (the same formula,
  ``slope * (x - x_j) + a_j``, with the slopes of each interval precomputed).
* :class:`LinearSimplex`: ``scipy.interpolate.LinearNDInterpolator`` on its own Delaunay
  triangulation: the barycentric coordinates of the point in every simplex (vectorised),
  the first simplex that contains it within scipy's tolerance, the barycentric blend of its
  vertices' values. Outside the hull: None (the caller falls back, as on scipy's NaN).
* :class:`RbfAtPoint`: ``scipy.interpolate.RBFInterpolator``: scipy's own compiled kernel
  vector (``_rbfinterp_pythran._build_evaluation_coefficients``) times the fitted coefficients, checked
  offline against the public call (any mismatch, or a scipy without that routine, and the
  public call is used).

Each returns the coefficient vector (m,) at the scaled parameter ``x`` (d,), and offers a
``floor(x)`` kernel: its arithmetic on preallocated arrays (:mod:`.online`).
"""
from __future__ import annotations

import bisect

import numpy as np

__all__ = ["Linear1D", "LinearSimplex", "RbfAtPoint"]

_EPS = 100 * np.finfo(float).eps  # scipy's find_simplex tolerance on barycentric coordinates


class Linear1D:
    """``np.interp(x, xs, A[:, i])`` for every column i at once (xs increasing)."""

    def __init__(self, xs, A):
        xs, A = np.asarray(xs, float), np.asarray(A, float)
        self.xs = xs.tolist()
        self.A = np.ascontiguousarray(A)
        self.slopes = np.ascontiguousarray((A[1:] - A[:-1]) / (xs[1:] - xs[:-1])[:, None])

    def __call__(self, x) -> np.ndarray:
        x = float(x[0])
        xs = self.xs
        j = bisect.bisect_right(xs, x) - 1
        if j < 0:
            return self.A[0].copy()
        if j >= len(xs) - 1:
            return self.A[-1].copy()
        if x == xs[j]:
            return self.A[j].copy()
        q = self.slopes[j] * (x - xs[j])
        q += self.A[j]
        return q

    def floor(self, x):
        """The blend of one interval (the locating bisection is a few comparisons)."""
        j = min(max(bisect.bisect_right(self.xs, float(x[0])) - 1, 0), max(len(self.xs) - 2, 0))
        S, a, dx = self.slopes[j] if len(self.slopes) else self.A[0] * 0, self.A[j], float(x[0]) - self.xs[j]
        q = np.empty_like(a)

        def run():
            np.multiply(S, dx, out=q)
            q.__iadd__(a)
        return run


class LinearSimplex:
    """``LinearNDInterpolator(points, A)`` at one point (module docstring).

    The barycentric coordinates ``c = T (x - r)``, ``c_d = 1 - sum c`` of every simplex are
    affine in ``x``: one stacked product ``G [x; 1]`` gives them all (round-off apart, scipy's
    coordinates). The simplex with the largest smallest coordinate contains ``x`` when that
    coordinate is ``>= -100 eps`` (scipy's tolerance); on a shared face either neighbour gives
    the same value.
    """

    def __init__(self, tri, A):
        T = np.asarray(tri.transform, float)  # (ns, d + 1, d): inverse of each simplex's edges, origin
        ns, d = T.shape[0], T.shape[2]
        Ti, r = T[:, :d, :], T[:, d, :]
        G = np.empty((ns, d + 1, d + 1))
        G[:, :d, :d] = Ti
        G[:, :d, d] = -np.einsum("sij,sj->si", Ti, r)
        G[:, d, :] = -G[:, :d, :].sum(axis=1)
        G[:, d, d] += 1.0
        valid = np.isfinite(G).all(axis=(1, 2))  # a degenerate simplex has a NaN transform
        G[~valid] = 0.0
        G[~valid, :, d] = -1.0  # never contains anything
        self.d, self.G = d, np.ascontiguousarray(G.reshape(ns * (d + 1), d + 1))
        self.V = np.ascontiguousarray(np.asarray(A, float)[tri.simplices])  # (ns, d + 1, m)
        self._x = np.ones(d + 1)
        self._c = np.empty(ns * (d + 1))

    def barycentric(self, x) -> np.ndarray:
        """(ns, d + 1) barycentric coordinates of ``x`` (d,) in every simplex."""
        self._x[:self.d] = x
        return np.dot(self.G, self._x, out=self._c).reshape(-1, self.d + 1)

    def __call__(self, x):
        c = self.barycentric(x)
        k = int(c.min(axis=1).argmax())
        if not c[k].min() >= -_EPS:
            return None
        return np.dot(c[k], self.V[k])

    def floor(self, x):
        """The barycentric coordinates in every simplex, the containing one, the blend."""
        q = np.empty(self.V.shape[2])

        def run():
            c = self.barycentric(x)
            k = c.min(axis=1).argmax()
            np.dot(c[k], self.V[k], out=q)
        return run


class RbfAtPoint:
    """``RBFInterpolator`` at one point (module docstring); ``fast`` says which path is used."""

    def __init__(self, rbf):
        self.rbf, self.fast = rbf, False
        try:
            from scipy.interpolate._rbfinterp_pythran import _build_evaluation_coefficients as build
        except ImportError:
            return
        try:
            self._args = (np.ascontiguousarray(rbf.y, dtype=float), rbf.kernel, float(rbf.epsilon),
                          np.ascontiguousarray(rbf.powers), np.asarray(rbf._shift, float),
                          np.asarray(rbf._scale, float))
            self._coeffs = np.ascontiguousarray(rbf._coeffs, dtype=float)
            self._build = build
            y = self._args[0]
            probes = np.vstack([y[:1], y.mean(axis=0, keepdims=True), y[-1:] + 0.37 * (y.max(0) - y.min(0))])
            for p in probes:
                got, want = self._eval(p[None, :]), np.asarray(rbf(p[None, :]), float).reshape(-1)
                if not np.allclose(got, want, rtol=1e-12, atol=1e-14 * max(np.abs(want).max(), 1e-300)):
                    return
        except Exception:  # noqa: BLE001 - another scipy's internals: the public call stays
            return
        self.fast = True

    def _eval(self, X):
        y, kernel, eps, powers, shift, scale = self._args
        return np.dot(self._build(X, y, kernel, eps, powers, shift, scale), self._coeffs).reshape(-1)

    def __call__(self, x) -> np.ndarray:
        X = x.reshape(1, -1)
        if self.fast:
            return self._eval(X)
        return np.asarray(self.rbf(X), float).reshape(-1)

    def floor(self, x):
        """The kernel and monomial vector at the point (n_snap + n_mono) and the coefficient product."""
        X = np.array(x, float).reshape(1, -1)
        if not self.fast:
            return lambda: self.rbf(X)
        y, kernel, eps, powers, shift, scale = self._args
        build, coeffs, q = self._build, self._coeffs, np.empty((1, self._coeffs.shape[1]))
        return lambda: np.dot(build(X, y, kernel, eps, powers, shift, scale), coeffs, out=q)
