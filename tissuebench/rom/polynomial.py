"""Internal force of Saint Venant-Kirchhoff models as an exact cubic polynomial of u.

For SVK (and linear elasticity) with dead loads and homogeneous Dirichlet conditions,
the internal force on the free dofs is a polynomial of degree three in the
displacement. About any base state ``u0``,

    f(u0 + z) = f0 + K0 z + Q0(z, z) + C(z, z, z),

with ``K0`` the tangent at ``u0``, ``Q0`` and ``C`` symmetric bilinear / trilinear
vector-valued forms (``C`` does not depend on ``u0``; ``Q0(a, b) = Q(a, b) + 3 C(u0, a, b)``).
The forms are extracted here from evaluations of ``backend.internal_force`` only, by
polarization, so every backend works unchanged:

* ``E(z) = (f(u0+z) + f(u0-z)) / 2 - f0 = Q0(z, z)`` and
  ``D(z) = (f(u0+z) - f(u0-z)) / 2 - K0 z = C(z, z, z)`` (two evaluations give both:
  the even part of a cubic holds only the quadratic term, the odd part the linear and
  cubic ones);
* ``Q0(x, y) = [E(x+y) - E(x-y)] / 4``;
* ``C(x, x, y) = [D(x+y) - D(x-y) - 2 D(y)] / 6``;
* ``C(x, y, w) = [D(x+y+w) - D(x+y-w) - D(x-y+w) - D(-x+y+w)] / 24``
  (the 8-term polarization ``1/48 sum eps1 eps2 eps3 D(eps . (x, y, w))`` folded with
  the oddness of ``D``).

Round-off: the differences above cancel the constant and linear parts, so every
argument is rescaled to a *calibrated length* at which the nonlinear terms are as large
as the linear one (see :meth:`CubicForce.calibrate`) and the result scaled back by
multilinearity. Tensors are then exact to ~1e-13 relative for any unit system.

The reduced tensors of ANM-POD (:func:`reduced_polynomial`) are ``L_r = Phi^T K(0) Phi``,
``Q_r[i, j, k] = phi_i . Q(phi_j, phi_k)`` and ``C_r[i, j, k, l] = phi_i . C(phi_j, phi_k, phi_l)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..refsolvers.materials import LinearElastic, SaintVenantKirchhoff
from ..refsolvers.problem import FollowerPressure

__all__ = ["check_polynomial_problem", "CubicForce", "MultilinearTerms", "ReducedPolynomial",
           "reduced_polynomial"]

_POLYNOMIAL_MATERIALS = (SaintVenantKirchhoff, LinearElastic)


def check_polynomial_problem(problem, who: str = "ANM") -> None:
    """Refuse a problem whose equilibrium is not a cubic polynomial of the free dofs.

    Raises
    ------
    ValueError
        A non-polynomial material (neo-Hookean, Mooney-Rivlin, Guccione: the ANM of the
        paper is written for SVK), a follower pressure (load depends on u), or nonzero
        prescribed displacements (the series are written for ``u = 0`` on the fixed dofs).
    """
    mat = problem.material
    if not isinstance(mat, _POLYNOMIAL_MATERIALS):
        raise ValueError(f"{who}: material {mat.name!r} ({type(mat).__name__}) is not polynomial in the "
                         "displacement; the asymptotic numerical method here needs Saint Venant-Kirchhoff "
                         "(or linear) elasticity")
    if any(isinstance(ld, FollowerPressure) for ld in problem.loads):
        raise ValueError(f"{who}: follower pressure depends on the displacement; only dead loads are supported")
    for lam in (1.0, 0.5):
        if np.any(problem.prescribed_values(lam) != 0.0):
            raise ValueError(f"{who}: nonzero prescribed displacements are not supported (homogeneous "
                             "Dirichlet conditions only)")


class CubicForce:
    """f on a set of dofs about a base state, split into its polynomial parts.

    Parameters
    ----------
    backend : Backend
        Supplies ``internal_force`` and ``tangent`` (full vectors, node-major).
    u0 : (ndof,) array, optional
        Base state (zero by default); its fixed dofs must be zero.
    dofs : (n,) int array, optional
        The dofs arguments and results live on (default: the free dofs).
    project : callable, optional
        Applied to every result on ``dofs`` (e.g. ``lambda r: Phi.T @ r`` for reduced tensors).

    Attributes
    ----------
    f0 : (n,) array
        f(u0) on ``dofs`` (unprojected).
    K0 : (n, n) CSR
        Tangent at ``u0`` restricted to ``dofs``.
    n_evals : int
        Internal-force evaluations so far (offline cost counter).
    """

    def __init__(self, backend, u0=None, dofs=None, project=None):
        pb = backend.problem
        check_polynomial_problem(pb)
        self.backend = backend
        self.dofs = np.asarray(pb.free_dofs if dofs is None else dofs)
        self.u0 = np.zeros(backend.ndof) if u0 is None else np.array(backend._check_u(u0), dtype=float)
        if np.any(self.u0[pb.fixed_dofs] != 0.0):
            raise ValueError("u0: the fixed dofs of the base state must be zero")
        self.f0 = backend.internal_force(self.u0)[self.dofs]
        K = backend.tangent(self.u0)
        self.K0 = K[self.dofs][:, self.dofs].tocsr()
        self._project = project if project is not None else (lambda r: r)
        self.n_evals = 1
        self.length = None
        span = np.ptp(pb.nodes, axis=0)
        self._probe = 1e-2 * float(np.linalg.norm(span))  # a first guess only (see calibrate)

    def _f(self, z):
        u = self.u0.copy()
        u[self.dofs] += z
        self.n_evals += 1
        return self.backend.internal_force(u)[self.dofs]

    def _even_odd_raw(self, z):
        fp, fm = self._f(z), self._f(-z)
        return 0.5 * (fp + fm) - self.f0, 0.5 * (fp - fm) - self.K0 @ z

    def even_odd(self, z):
        """(Q0(z, z), C(z, z, z)), projected; two internal-force evaluations."""
        E, D = self._even_odd_raw(np.asarray(z, dtype=float))
        return self._project(E), self._project(D)

    def calibrate(self, direction) -> float:
        """Pick the argument length at which polarization loses the fewest digits.

        At length ``t`` along a unit ``direction`` the linear term grows like ``t``, the
        quadratic like ``t**2``, the cubic like ``t**3``; the differences that isolate
        ``Q0`` / ``C`` lose ``log10(linear / nonlinear)`` digits. The chosen ``t`` makes
        the larger nonlinear term equal to the linear one (from a probe evaluation).
        Linear materials keep the probe length.
        """
        d = np.asarray(direction, dtype=float)
        d = d / np.linalg.norm(d)
        t0 = self._probe
        E, D = self._even_odd_raw(t0 * d)
        lin = float(np.linalg.norm(self.K0 @ d))
        q, c = np.linalg.norm(E) / t0**2, np.linalg.norm(D) / t0**3
        # lengths where Q0, resp. C, equal the linear term (inf: that term is absent)
        t_q = lin / q if q > 1e-12 * lin / t0 else math.inf
        t_c = math.sqrt(lin / c) if c > 1e-12 * lin / t0**2 else math.inf
        t = min(t_q, t_c)
        self.length = float(np.clip(t, 1e-6 * t0, 1e6 * t0)) if math.isfinite(t) else t0
        return self.length


class MultilinearTerms:
    """``Q0`` and ``C`` between members of a growing list of vectors, evaluations cached.

    Each vector ``v_i`` is stored normalised to the calibrated length (``v_i = s_i w_i``);
    the forms are polarized on the ``w_i`` and scaled back, and every ``E``/``D`` of a
    signed combination ``w_i +- w_j (+- w_k)`` is kept, so ``C(v_i, v_i, v_j)`` and
    ``C(v_i, v_j, v_j)`` come free with ``Q0(v_i, v_j)``.
    """

    def __init__(self, force: CubicForce):
        self.force = force
        self.w, self.s = [], []
        self._cache = {}

    def add(self, v) -> int:
        """Append a vector (on the force's dofs); returns its index."""
        v = np.asarray(v, dtype=float)
        nv = float(np.linalg.norm(v))
        if nv > 0 and self.force.length is None:
            self.force.calibrate(v)
        length = self.force.length or 1.0
        self.w.append(v * (length / nv) if nv > 0 else v)
        self.s.append(nv / length)
        return len(self.w) - 1

    def _eo(self, combo):
        """(E, D) of sum(sign * w_idx) for combo = ((idx, sign), ...), sorted by idx."""
        flip = combo[0][1] < 0  # E is even, D odd: store only one sign
        key = tuple((i, -sg if flip else sg) for i, sg in combo)
        if key not in self._cache:
            z = sum(sg * self.w[i] for i, sg in key)
            self._cache[key] = self.force.even_odd(z)
        E, D = self._cache[key]
        return E, (-D if flip else D)

    def q(self, i: int, j: int):
        """Q0(v_i, v_j) (projected)."""
        i, j = min(i, j), max(i, j)
        sc = self.s[i] * self.s[j]
        if sc == 0.0:
            return 0.0
        if i == j:
            return sc * self._eo(((i, 1),))[0]
        return sc * 0.25 * (self._eo(((i, 1), (j, 1)))[0] - self._eo(((i, 1), (j, -1)))[0])

    def c(self, i: int, j: int, k: int):
        """C(v_i, v_j, v_k) (projected)."""
        i, j, k = sorted((i, j, k))
        sc = self.s[i] * self.s[j] * self.s[k]
        if sc == 0.0:
            return 0.0
        if i == j == k:
            return sc * self._eo(((i, 1),))[1]
        if i == j or j == k:
            x, y = (i, k) if i == j else (k, i)  # x repeated, y single
            a, b = sorted([(x, 1), (y, 1)]), sorted([(x, 1), (y, -1)])
            return sc * (self._eo(tuple(a))[1] - self._eo(tuple(b))[1] - 2 * self._eo(((y, 1),))[1]) / 6.0
        D = [self._eo(((i, s1), (j, s2), (k, s3)))[1] for s1, s2, s3 in ((1, 1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, 1))]
        return sc * (D[0] - D[1] - D[2] - D[3]) / 24.0


@dataclass
class ReducedPolynomial:
    """Reduced equilibrium ``L q + Q(q, q) + C(q, q, q) = lam f`` in POD coordinates.

    Attributes
    ----------
    L : (m, m) array
        Reduced tangent at the origin, ``Phi^T K_t(0) Phi`` (force / length).
    Q : (m, m, m) array
        ``Q[i, j, k] = phi_i . Q(phi_j, phi_k)``, symmetric in (j, k).
    C : (m, m, m, m) array
        ``C[i, j, k, l] = phi_i . C(phi_j, phi_k, phi_l)``, symmetric in (j, k, l).
    f : (m,) array
        Reduced external load at load factor 1, ``Phi^T f_ext``.
    n_evals : int
        Internal-force evaluations the extraction used.
    """

    L: np.ndarray
    Q: np.ndarray
    C: np.ndarray
    f: np.ndarray
    n_evals: int = 0

    @property
    def m(self) -> int:
        return len(self.f)

    def leading(self, m: int) -> "ReducedPolynomial":
        """The tensors of the first ``m`` basis vectors (POD modes are nested: no new evaluations)."""
        if not 1 <= int(m) <= self.m:
            raise ValueError(f"leading: m must lie in [1, {self.m}], got {m!r}")
        return ReducedPolynomial(self.L[:m, :m], self.Q[:m, :m, :m], self.C[:m, :m, :m, :m], self.f[:m],
                                 self.n_evals)

    def force(self, q) -> np.ndarray:
        """Reduced internal force ``Phi^T f_int(Phi q)``, shape (m,)."""
        Cq = self.C @ q
        return self.L @ q + (self.Q @ q) @ q + (Cq @ q) @ q

    def tangent(self, q) -> np.ndarray:
        """Reduced tangent ``L + 2 Q(q, .) + 3 C(q, q, .)``, shape (m, m)."""
        return self.L + 2.0 * (self.Q @ q) + 3.0 * ((self.C @ q) @ q)

    def force_and_tangent(self, q):
        """(:meth:`force`, :meth:`tangent`) at ``q`` sharing their contractions ``Q q`` and
        ``C q q`` (a Newton iteration's both); the same values as the two calls."""
        Qq, Cqq = self.Q @ q, (self.C @ q) @ q
        f = self.L @ q + Qq @ q + Cqq @ q
        K = 2.0 * Qq
        K += self.L
        K += 3.0 * Cqq
        return f, K

    def about(self, q0):
        """(K0, Q0) of the expansion about ``q0``: ``Q0 = Q + 3 C(q0, ., .)``."""
        q0 = np.asarray(q0, dtype=float)
        return self.tangent(q0), self.Q + 3.0 * (self.C @ q0)


def reduced_polynomial(backend, basis, free_dofs=None) -> ReducedPolynomial:
    """Reduced tensors of an orthonormal basis on the free dofs, by polarization.

    Parameters
    ----------
    backend : Backend
    basis : (n_free, m) array
        Orthonormal columns on ``free_dofs``.
    free_dofs : (n_free,) int array, optional
        Default: the problem's free dofs.

    Returns
    -------
    ReducedPolynomial
        Costs ``2m + 4 m(m-1)/2 + 8 m(m-1)(m-2)/6 + 3`` internal-force evaluations (m = 9: 837)
        and one tangent assembly.
    """
    Phi = np.asarray(basis, dtype=float)
    free = np.asarray(backend.problem.free_dofs if free_dofs is None else free_dofs)
    if Phi.ndim != 2 or Phi.shape[0] != len(free):
        raise ValueError(f"basis must have shape ({len(free)}, m), got {Phi.shape}")
    force = CubicForce(backend, dofs=free, project=lambda r: Phi.T @ r)
    terms = MultilinearTerms(force)
    m = Phi.shape[1]
    for j in range(m):
        terms.add(Phi[:, j])
    Q = np.zeros((m, m, m))
    C = np.zeros((m, m, m, m))
    for j in range(m):
        for k in range(j, m):
            Q[:, j, k] = Q[:, k, j] = terms.q(j, k)
            for l in range(k, m):
                C[:, j, k, l] = terms.c(j, k, l)
    # the loops filled j <= k <= l; symmetrisation copies them to every permutation
    idx = np.arange(m)
    mask = (idx[:, None, None] <= idx[None, :, None]) & (idx[None, :, None] <= idx[None, None, :])
    C = _symmetrize_from_sorted(C, mask)
    L = Phi.T @ (force.K0 @ Phi)
    f = Phi.T @ backend.external_force(np.zeros(backend.ndof), 1.0)[free]
    return ReducedPolynomial(0.5 * (L + L.T), Q, C, f, force.n_evals)


def _symmetrize_from_sorted(C, mask):
    """Fill C[:, j, k, l] for every permutation from the entries with j <= k <= l."""
    import itertools

    out = np.zeros_like(C)
    J, K, L_ = np.nonzero(mask)
    for p in itertools.permutations((J, K, L_)):
        out[:, p[0], p[1], p[2]] = C[:, J, K, L_]
    return out
