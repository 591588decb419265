"""Asymptotic numerical method (ANM) and ANM-POD (anm-pod-large-deformations §3-4).

The equilibrium path ``f_int(u) = lam f`` of an SVK model (dead loads, homogeneous
Dirichlet conditions) is sought about a known state ``(u0, lam0)`` as power series of a
path parameter ``a``,

    u(a) = u0 + sum_p a^p u_p,    lam(a) = lam0 + sum_p a^p lam_p,

with the pseudo-arclength definition ``a = <u - u0, u_1> + (lam - lam0) lam_1``. Since
``f(u0 + v) = f(u0) + K0 v + Q0(v, v) + C(v, v, v)`` exactly (:mod:`.polynomial`), order p
of the series is one linear solve with the same tangent ``K0 = K_t(u0)`` (eqs. 37-38):

* order 1: ``K0 u_hat = f``, ``lam_1 = 1 / sqrt(1 + |u_hat|^2)``, ``u_1 = lam_1 u_hat``;
* order p: ``K0 u_nl = f_p^nl = -[sum_{r+s=p} Q0(u_r, u_s) + sum_{r+s+t=p} C(u_r, u_s, u_t)]``
  (ordered sums over indices >= 1), ``lam_p = -lam_1 <u_nl, u_1>``,
  ``u_p = (lam_p / lam_1) u_1 + u_nl``.

The series is trusted for ``|a| <= a_max = (eps |u_1| / |u_N|)^(1/(N-1))`` (order 1: the
linear solution, no estimate, ``a_max = inf``). Continuation starts a new expansion at
``(u(a_max), lam(a_max))`` (optionally corrected by Newton; off by default, so the small
residual left at each segment end is carried on, as in the classical ANM).

The reduced series (:func:`reduced_series`, :func:`reduced_path`) are the same in the
coordinates of a POD basis; the ANM-POD ROM built on them is in :mod:`.anm_pod`.
"""
from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse.linalg as spla

from ..refsolvers.newton import newton_solve
from .polynomial import CubicForce, MultilinearTerms, check_polynomial_problem

__all__ = ["AnmSeries", "AnmPath", "anm_series", "anm_path", "reduced_series", "reduced_path"]


# ============================================================================ series
@dataclass
class AnmSeries:
    """One truncated asymptotic expansion of the equilibrium path.

    Attributes
    ----------
    u0 : (n,) array
        Expansion point: free-dof displacement (full-order) or reduced coordinates.
    lam0 : float
        Load factor at the expansion point.
    u : (order, n) array
        ``u_1 .. u_N`` (length / a^p).
    lam : (order,) array
        ``lam_1 .. lam_N``.
    a_end : float or None
        Where a continuation handed over to the next series (its ``a_max``).
    info : dict
        Counters (internal-force evaluations, wall time).
    """

    u0: np.ndarray
    lam0: float
    u: np.ndarray
    lam: np.ndarray
    a_end: float | None = None
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        # Horner tables, kept as Python floats for the microsecond root search
        self._Z = np.vstack([self.u0[None, :], self.u])
        self._c = [float(self.lam0), *map(float, self.lam)]
        self._rc = tuple(reversed(self._c))  # highest order first: Horner's order
        self._exps = np.arange(len(self._c), dtype=float)
        self._mono = None  # (lo, hi): lam'(a) > 0 on (lo, hi) around 0, computed at first use
        self._table = None  # (lam values, a values) of prepare_roots: the brackets of the fast root
        self._table_far = None  # the same for the search without limit (a step past the last series)

    @property
    def order(self) -> int:
        return len(self.lam)

    def a_max(self, eps: float = 1e-6) -> float:
        """Radius of validity ``(eps |u_1| / |u_N|)^(1/(N-1))``; inf at order 1 or if u_N = 0."""
        if not 0.0 < eps < 1.0:
            raise ValueError(f"eps must lie in (0, 1), got {eps!r}")
        n1, nN = np.linalg.norm(self.u[0]), np.linalg.norm(self.u[-1])
        if self.order == 1 or nN == 0.0:
            return math.inf
        return float((eps * n1 / nN) ** (1.0 / (self.order - 1)))

    def truncated(self, order: int) -> "AnmSeries":
        """The same series cut at a lower order (orders 1..N do not depend on N)."""
        if not 1 <= order <= self.order:
            raise ValueError(f"order must lie in [1, {self.order}], got {order!r}")
        return AnmSeries(self.u0, self.lam0, self.u[:order], self.lam[:order], info=dict(self.info))

    def load_factor(self, a: float) -> float:
        """lam(a)."""
        v = 0.0
        for ck in reversed(self._c):
            v = v * a + ck
        return v

    def evaluate(self, a: float):
        """(u(a), lam(a)): state in the series' space, shape (n,), and load factor (the offline
        form: a continuation expands its next series about this state, so its arithmetic is kept
        as it was; :meth:`state` is the online one, equal to round-off)."""
        pw = np.array([a ** p for p in range(len(self._c))])
        return pw @ self._Z, self.load_factor(a)

    def state(self, a: float) -> np.ndarray:
        """u(a) (n,): the powers ``a^0 .. a^N`` times the coefficient rows (one product)."""
        return np.dot(a ** self._exps, self._Z)

    def prepare_roots(self, n: int = 257, n_far: int = 4097) -> bool:
        """Tabulate lam(a) on ``n`` points of the bracket :meth:`load_factor_to_a` searches
        (the monotone interval around 0 within ``a_end``), so :meth:`root` starts Newton from
        the linear interpolant of the inverse inside one table interval: one or two Horner
        steps instead of a search from 0 (the online step of a precomputed continuation).
        A second table, on ``n_far`` points, covers the search without limit (the monotone
        interval, cut at 64 ``a_end`` where it is unbounded): the extrapolation of a step past
        the last series. The tables are evaluated by the same Horner scheme as the search, so
        their brackets hold in floating point. False (no table) when the bracket is empty or
        unbounded.
        """
        lim = self.a_end if self.a_end is not None else math.inf
        lo, hi = self.monotone_interval()
        self._table = self._tabulate(max(lo, -lim), min(hi, lim), n)
        if math.isfinite(lim):
            far = 64.0 * lim
            self._table_far = self._tabulate(max(lo, -far), min(hi, far), n_far)
        return self._table is not None

    def _tabulate(self, a_lo: float, a_hi: float, n: int):
        if not (a_lo < a_hi and math.isfinite(a_lo) and math.isfinite(a_hi)):
            return None
        A = np.linspace(a_lo, a_hi, int(n)).tolist()
        A[0], A[-1] = a_lo, a_hi
        L = [_horner(self._c, a)[0] for a in A]
        if not all(x < y for x, y in zip(L, L[1:])) or not all(map(math.isfinite, L)):
            return None
        return L, A

    def root(self, lam_star: float, a_limit: float | None = None):
        """:meth:`load_factor_to_a`, from the tables of :meth:`prepare_roots` when they bracket
        ``lam_star`` (``a_limit``: None, the default limit, or inf): the same root (the unique
        one of the monotone bracket) to the last bits of Newton's convergence test."""
        rc = self._rc
        if len(rc) == 2 and rc[0] > 0.0 and (a_limit is None or a_limit == math.inf):
            a = (lam_star - rc[1]) / rc[0]  # order 1: lam = lam0 + lam1 a
            if a_limit is not None or self.a_end is None or abs(a) <= self.a_end:
                return a
        t = self._table if a_limit is None else self._table_far if a_limit == math.inf else None
        if t is not None:
            L, A = t
            j = bisect.bisect_right(L, lam_star) - 1
            if 0 <= j < len(L) - 1:
                l0, a0, a1 = L[j], A[j], A[j + 1]
                return _newton_in(rc, lam_star, a0, a1, a0 + (a1 - a0) * (lam_star - l0) / (L[j + 1] - l0))
        return self.load_factor_to_a(lam_star, a_limit)

    def load_factor_to_a(self, lam_star: float, a_limit: float | None = None):
        """The ``a`` with ``lam(a) = lam_star`` nearest to 0 on the side of ``lam_star - lam0``.

        Parameters
        ----------
        lam_star : float
        a_limit : float, optional
            Roots with ``|a| > a_limit`` are ignored (default: :attr:`a_end`, else inf).

        Returns
        -------
        float or None
            None when no root lies within the limit.
        """
        lim = (self.a_end if self.a_end is not None else math.inf) if a_limit is None else a_limit
        lo, hi = self._monotone_within(lim)
        if lo < hi:  # lam increases on (lo, hi): a root there is the one nearest 0, and unique
            c = self._c
            if lam_star >= c[0]:
                a = _bracketed_root(c, lam_star, 0.0, min(hi, lim))
            else:
                a = _bracketed_root(c, lam_star, max(lo, -lim), 0.0)
            if a is not None:
                return a
            if (lam_star >= c[0] and hi >= lim) or (lam_star < c[0] and lo <= -lim):
                return None  # monotone up to the limit and the target is not reached there
        return _robust_root(self._c, lam_star, lim)

    def _monotone_within(self, lim: float) -> tuple[float, float]:
        """:meth:`monotone_interval`, or ``(-lim, lim)`` when ``lam' > 0`` provably holds on
        ``[-lim, lim]`` (``lam_1 > sum_k k |lam_k| lim^(k-1)``): the search then brackets the same
        way and a series built for one step needs no roots of ``lam'`` (a companion-matrix
        eigenvalue problem)."""
        if self._mono is None and math.isfinite(lim) and len(self._c) > 2:
            c = self._c
            bound, p = 0.0, 1.0
            for k in range(2, len(c)):
                p *= lim
                bound += k * abs(c[k]) * p
            if c[1] > bound:
                return -lim, lim
        return self.monotone_interval()

    def monotone_interval(self) -> tuple[float, float]:
        """``(lo, hi)`` around 0 on which ``lam'(a) > 0`` (the roots of lam' nearest 0, or
        +-inf); ``(0, 0)`` when ``lam'(0) <= 0``. Computed once per series."""
        if self._mono is None:
            d = np.arange(1, len(self._c)) * np.asarray(self._c[1:])
            if d[0] <= 0:
                self._mono = (0.0, 0.0)
            else:
                r = _real_roots(d, math.inf)
                pos, neg = r[r > 0], r[r < 0]
                self._mono = (float(neg.max()) if neg.size else -math.inf, float(pos.min()) if pos.size else math.inf)
        return self._mono


def _horner(c, a):
    """(p(a), p'(a)) of ``sum c_k a^k`` (Python floats: microseconds for the online step)."""
    v, d = c[-1], 0.0
    for ck in reversed(c[:-1]):
        d = d * a + v
        v = v * a + ck
    return v, d


def _bracketed_root(c, target, lo, hi):
    """The root of ``p(a) = target`` in [lo, hi] where p increases (None if p does not reach
    ``target`` there): Newton safeguarded by bisection; an infinite end is first bracketed by
    doubling from the linear guess."""
    f_lo = _horner(c, lo)[0] - target if math.isfinite(lo) else -math.inf
    f_hi = _horner(c, hi)[0] - target if math.isfinite(hi) else math.inf
    if not math.isfinite(hi) or not math.isfinite(lo):
        step = abs((target - c[0]) / c[1]) if c[1] else 1.0
        step = step or 1.0
        for _ in range(200):
            if not math.isfinite(hi):
                b = 2.0 * step
                if _horner(c, b)[0] >= target:
                    hi, f_hi = b, _horner(c, b)[0] - target
                step *= 2.0
            if not math.isfinite(lo):
                b = -2.0 * step
                if _horner(c, b)[0] <= target:
                    lo, f_lo = b, _horner(c, b)[0] - target
                step *= 2.0
            if math.isfinite(lo) and math.isfinite(hi):
                break
        else:
            return None
    if f_lo > 0 or f_hi < 0:
        return None
    if f_lo == 0:
        return lo
    a = 0.0 if lo <= 0.0 <= hi else 0.5 * (lo + hi)
    for _ in range(100):
        v, d = _horner(c, a)
        v -= target
        if v == 0.0:
            return a
        if v < 0:
            lo = a
        else:
            hi = a
        nxt = a - v / d if d > 0 else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - a) <= 1e-15 * max(abs(nxt), 1e-300) or hi - lo <= 1e-15 * max(abs(hi), abs(lo)):
            return nxt
        a = nxt
    return a


def _newton_in(rc, target, lo, hi, a):
    """The root of ``p(a) = target`` in [lo, hi] where p increases and changes sign, from ``a``:
    Newton safeguarded by bisection, the convergence test of :func:`_bracketed_root`
    (``rc``: coefficients, highest order first)."""
    top, rest = rc[0], rc[1:]
    for _ in range(100):
        v, d = top, 0.0
        for ck in rest:
            d = d * a + v
            v = v * a + ck
        v -= target
        if v == 0.0:
            return a
        if v < 0:
            lo = a
        else:
            hi = a
        nxt = a - v / d if d > 0 else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - a) <= 1e-15 * max(abs(nxt), 1e-300) or hi - lo <= 1e-15 * max(abs(hi), abs(lo)):
            return nxt
        a = nxt
    return a


def _real_roots(c, scale):
    """Real roots of sum c_k a^k, computed in the variable a / scale (balances the companion matrix)."""
    c = np.trim_zeros(np.asarray(c, dtype=float), "b")
    if len(c) < 2:
        return np.zeros(0)
    s = scale if math.isfinite(scale) and scale > 0 else 1.0
    r = np.polynomial.polynomial.polyroots(c * s ** np.arange(len(c))) * s
    return r[np.abs(r.imag) <= 1e-7 * np.maximum(1.0, np.abs(r.real)) * s].real


def _robust_root(c, target, lim):
    """Like :meth:`AnmSeries.load_factor_to_a` through the companion matrix (any polynomial)."""
    cc = np.array(c, dtype=float)
    cc[0] -= target
    if cc[0] == 0.0:
        return 0.0
    scale = lim if math.isfinite(lim) else abs(cc[0] / cc[1]) if cc[1] else 1.0
    r = _real_roots(cc, scale)
    want = r[(r > 0) if target > c[0] else (r < 0)]
    want = want[np.abs(want) <= lim * (1 + 1e-12)]
    if not len(want):
        return None
    return float(want[np.argmin(np.abs(want))])


def _series_core(solve, f, rhs, add, order):
    """Orders 1..N of eqs. 37-38 / 44-45 with a factorised tangent ``solve``.

    ``rhs(p)`` returns ``sum Q0 + sum C`` of order p from the vectors passed to ``add``.
    """
    if int(order) != order or order < 1:
        raise ValueError(f"order must be a positive integer, got {order!r}")
    u_hat = solve(f)
    lam1 = 1.0 / math.sqrt(1.0 + float(u_hat @ u_hat))
    U, lams = [lam1 * u_hat], [lam1]
    add(U[0])
    for p in range(2, int(order) + 1):
        u_nl = solve(-rhs(p))
        lam_p = -lam1 * float(u_nl @ U[0])
        U.append((lam_p / lam1) * U[0] + u_nl)
        lams.append(lam_p)
        add(U[-1])
    return np.array(U), np.array(lams)


def _ordered_sums(p):
    """(pairs, triples) with multiplicities: sum over ordered r+s=p, r+s+t=p as sorted tuples."""
    pairs = [((r, p - r), 1.0 if 2 * r == p else 2.0) for r in range(1, p // 2 + 1)]
    triples = []
    for r in range(1, p // 3 + 1):
        for s in range(r, (p - r) // 2 + 1):
            t = p - r - s
            triples.append(((r, s, t), 1.0 if r == t else 3.0 if (r == s or s == t) else 6.0))
    return pairs, triples


# ============================================================================ full order
def anm_series(backend, u0=None, lam0: float = 0.0, order: int = 10) -> AnmSeries:
    """Full-order ANM series about ``(u0, lam0)`` on the free dofs.

    Parameters
    ----------
    backend : Backend
        SVK or linear material, dead loads, homogeneous Dirichlet conditions.
    u0 : (ndof,) array, optional
        Expansion point (zero by default; fixed dofs must be zero).
    lam0 : float
    order : int
        Truncation order N (>= 1; 15 and more are fine).

    Returns
    -------
    AnmSeries
        Coefficients on ``backend.problem.free_dofs``; one tangent factorisation and
        O(N^3 / 9) internal-force evaluations (polarization, :mod:`.polynomial`).
    """
    t0 = time.perf_counter()
    pb = backend.problem
    check_polynomial_problem(pb)
    free = pb.free_dofs
    force = CubicForce(backend, u0)
    lu = spla.splu(force.K0.tocsc())
    f = backend.external_force(np.zeros(backend.ndof), 1.0)[free]
    terms = MultilinearTerms(force)

    def rhs(p):
        pairs, triples = _ordered_sums(p)
        R = sum(w * terms.q(r - 1, s - 1) for (r, s), w in pairs)
        return R + sum(w * terms.c(r - 1, s - 1, t - 1) for (r, s, t), w in triples)

    U, lam = _series_core(lu.solve, f, rhs, terms.add, order)
    return AnmSeries(force.u0[free].copy(), float(lam0), U, lam,
                     info={"n_evals": force.n_evals, "wall_s": time.perf_counter() - t0})


class AnmPath(list):
    """A continuation: a list of :class:`AnmSeries`, each valid on ``[0, a_end]``.

    Attributes
    ----------
    target : float
        Load factor the continuation was asked to reach.
    reached : bool
        The last series covers ``target`` within its ``a_end``.
    """

    target: float = math.nan
    reached: bool = False

    @property
    def load_factor_ends(self) -> list:
        """lam(a_end) of each series."""
        return [s.load_factor(s.a_end) if math.isfinite(s.a_end) else math.inf for s in self]

    def locate(self, lam: float):
        """(series index, a) for ``lam``, or None outside the covered range."""
        if not self:
            return None
        ends = self.load_factor_ends
        k = 0 if lam <= self[0].lam0 else bisect.bisect_left(ends, lam)
        if k >= len(self):
            return None
        a = self[k].load_factor_to_a(lam)
        return None if a is None else (k, a)

    def evaluate(self, lam: float):
        """State (in the series' space) at ``lam``; ValueError outside the covered range."""
        loc = self.locate(lam)
        if loc is None:
            raise ValueError(f"load factor {lam!r} outside the range covered by the continuation "
                             f"[{self[0].lam0 if self else 0:.6g}, {self.load_factor_ends[-1] if self else 0:.6g}]")
        return self[loc[0]].evaluate(loc[1])[0]


def anm_path(backend, lam_target: float, order: int = 10, eps: float = 1e-6, max_steps: int = 50,
             correct: bool = False) -> AnmPath:
    """Full-order ANM continuation from the undeformed state to ``lam_target``.

    Parameters
    ----------
    backend : Backend
    lam_target : float
        Load factor to reach (> 0).
    order, eps : int, float
        Truncation order and the tolerance of ``a_max``.
    max_steps : int
        Most series; the path stops there (``reached`` False) if the target is not covered.
    correct : bool
        Newton-correct each segment end before expanding again (off: pure ANM).

    Returns
    -------
    AnmPath
        Series with free-dof coefficients; ``path.evaluate(lam)`` gives u on the free dofs.
    """

    if not (math.isfinite(lam_target) and lam_target > 0):
        raise ValueError(f"lam_target must be a finite number > 0, got {lam_target!r}")
    free = backend.problem.free_dofs
    path, u, lam = AnmPath(), np.zeros(backend.ndof), 0.0
    path.target = float(lam_target)
    for _ in range(int(max_steps)):
        s = anm_series(backend, u, lam, order)
        s.a_end = s.a_max(eps)
        path.append(s)
        if s.load_factor_to_a(lam_target) is not None:
            path.reached = True
            break
        u_end, lam_end = s.evaluate(s.a_end)
        if not lam_end > lam:
            break  # a limit point: the load factor no longer grows along the path
        u = np.zeros(backend.ndof)
        u[free] = u_end
        if correct:
            u = newton_solve(backend, lam_end, u0=u, n_increments=1).u
        lam = lam_end
    return path


# ============================================================================ reduced order
def reduced_series(poly, q0=None, lam0: float = 0.0, order: int = 6) -> AnmSeries:
    """ANM series in POD coordinates (eqs. 44-45) about ``(q0, lam0)``: m-sized work only.

    Parameters
    ----------
    poly : ReducedPolynomial
    q0 : (m,) array, optional
    lam0 : float
    order : int

    Returns
    -------
    AnmSeries
        Reduced coefficients ``zeta_p`` (m,), tangent ``K_r(q0)`` factorised once.
    """
    m = poly.m
    if q0 is None:  # the expansion about the origin: K_t(0) = L, Q0 = Q (about(0) adds zeros)
        q0, K, Q0 = np.zeros(m), poly.L, poly.Q
    else:
        q0 = np.asarray(q0, dtype=float)
        K, Q0 = poly.about(q0)
    # m x m with m <= ~30: an explicit inverse costs less than the LAPACK wrappers' call
    # overhead (about 15 us per lu_solve) and is accurate for the well-conditioned K_r
    solve = (np.linalg.inv(K).__matmul__ if m <= 32 else
             (lambda lu: (lambda b: sla.lu_solve(lu, b)))(sla.lu_factor(K)))
    Z, Qz, Cz, M = [], [], [], {}

    def add(z):
        Z.append(z)
        Qz.append(Q0 @ z)      # (m, m): Q0(., z)
        Cz.append(poly.C @ z)  # (m, m, m): C(., ., z)

    def pair_c(k):
        # M_k = sum_{s+t=k} C(., z_s, z_t) as an (m, m) matrix acting on the third slot
        if k not in M:
            M[k] = sum(Cz[t - 1] @ Z[k - t - 1] for t in range(1, k))
        return M[k]

    def rhs(p):
        R = sum(Qz[p - r - 1] @ Z[r - 1] for r in range(1, p))
        if p >= 3:
            R = R + sum(pair_c(p - r) @ Z[r - 1] for r in range(1, p - 1))
        return R

    U, lam = _series_core(solve, poly.f, rhs, add, order)
    return AnmSeries(q0.copy(), float(lam0), U, lam)


def _reduced_newton(poly, q, lam, iterations=8):
    """Reduced Newton correction of a segment end (m x m)."""
    for _ in range(iterations):
        r = poly.force(q) - lam * poly.f
        dq = np.linalg.solve(poly.tangent(q), -r)
        q = q + dq
        if np.linalg.norm(dq) <= 1e-13 * max(np.linalg.norm(q), 1e-300):
            break
    return q


def reduced_path(poly, lam_target: float, order: int = 6, eps: float = 1e-4, max_segments: int = 100,
                 correct: bool = False, path: AnmPath | None = None) -> AnmPath:
    """Reduced ANM continuation up to ``lam_target`` (extends ``path`` if given)."""
    path = AnmPath() if path is None else path
    path.target = float(lam_target)
    while len(path) < max_segments:
        if path:
            last = path[-1]
            if last.load_factor_to_a(lam_target) is not None:
                path.reached = True
                return path
            q, lam = last.evaluate(last.a_end)
            if not lam > last.lam0:
                break
            if correct:
                q = _reduced_newton(poly, q, lam)
        else:
            q, lam = None, 0.0
        s = reduced_series(poly, q, lam, order)
        s.a_end = s.a_max(eps)
        path.append(s)
    path.reached = bool(path) and path[-1].load_factor_to_a(lam_target) is not None
    return path
