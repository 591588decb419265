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

ANM-POD (eqs. 39-45, ``"anm_pod"``): the same series in the coordinates of a POD basis
``Phi``, with the reduced tensors ``L_r, Q_r, C_r`` computed offline by polarization, so an
online series (or the evaluation of a precomputed continuation) never touches a
full-size vector.
"""
from __future__ import annotations

import bisect
import math
import time
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla
import scipy.sparse.linalg as spla

from .base import OnlineModel, RomMethod, StepResult, Training, check_parameters, register
from .pod import pod_basis
from .polynomial import CubicForce, MultilinearTerms, check_polynomial_problem, reduced_polynomial

__all__ = ["AnmSeries", "AnmPath", "anm_series", "anm_path", "reduced_series", "reduced_path",
           "AnmPod", "AnmPodModel"]


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
        self._mono = {}

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
        """(u(a), lam(a)): state in the series' space, shape (n,), and load factor."""
        pw = np.array([a ** p for p in range(len(self._c))])
        return pw @ self._Z, self.load_factor(a)

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
        if lim not in self._mono:
            self._mono[lim] = self._monotone(lim)
        if self._mono[lim]:
            a = _newton_root(self._c, lam_star)
            if a is not None and abs(a) <= lim * (1 + 1e-12):
                return a  # lam' > 0 on the interval: the root there is unique
        return _robust_root(self._c, lam_star, lim)

    def _monotone(self, lim):
        """lam'(a) > 0 on [-lim, lim] (then the root is unique and Newton finds it)."""
        d = np.arange(1, len(self._c)) * np.asarray(self._c[1:])
        if len(d) == 1 or not np.any(d[1:]):
            return d[0] > 0
        if not math.isfinite(lim):
            return False
        r = _real_roots(d, lim)
        return d[0] > 0 and not np.any(np.abs(r) <= lim)


def _newton_root(c, target):
    """Root of sum c_k a^k = target by Newton from the linear guess (Python floats); None if it stalls."""
    if c[1] == 0.0:
        return None
    a = (target - c[0]) / c[1]
    for _ in range(50):
        v, d = c[-1], 0.0
        for ck in reversed(c[:-1]):
            d = d * a + v
            v = v * a + ck
        if d == 0.0:
            return None
        step = (v - target) / d
        a -= step
        if abs(step) <= 1e-15 * abs(a) or step == 0.0:
            return a
    return None


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
    from ..refsolvers.newton import newton_solve

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
    q0 = np.zeros(m) if q0 is None else np.asarray(q0, dtype=float)
    K, Q0 = poly.about(q0)
    lu = sla.lu_factor(K)
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

    U, lam = _series_core(lambda b: sla.lu_solve(lu, b), poly.f, rhs, add, order)
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


# ============================================================================ ANM-POD ROM
@register
class AnmPod(RomMethod):
    """ANM-POD (paper §4): POD basis + reduced polynomial tensors + reduced ANM series.

    Parameters
    ----------
    n_modes : int, optional
        Number of POD modes (default: the energy criterion).
    energy : float
        Energy fraction of the criterion, ``sum(s[:m]**2) / sum(s**2) >= energy``.
    order : int
        Truncation order of the series (paper: 1..6).
    eps : float
        Tolerance of the validity range ``a_max`` of each series. The criterion is
        conservative at low order (cornea_pinch ci, order 2: 78 segments to lam = 1 at
        1e-4, 777 at 1e-5, error vs Newton 2e-8 / 2e-10).
    tangent : {"origin"}
        The first expansion uses the reduced tangent at the undeformed state (the paper's
        choice; with ``max_segments=1`` this *is* the paper's method). A continuation
        segment is expanded with the reduced tangent at its own start (m x m, free):
        an ANM series needs the tangent at its expansion point.
    max_segments : int
        Most continuation segments; a load factor past them is ``"beyond_validity"``.
    lam_max : float, optional
        Offline, the continuation is precomputed up to this load factor (default: the
        top of the training envelope); online steps beyond it extend it lazily.
    precompute : bool
        Build the continuation offline (online: locate segment + evaluate polynomial).
        False: segments are built online, at the first step that needs them.
    cache : bool
        Keep segments built online between steps. False rebuilds the series from the
        origin at every step (the paper's per-step cost; for timing).
    correct : bool
        Reduced Newton correction at each segment end (off: pure ANM).
    """

    name = "anm_pod"

    def __init__(self, n_modes: int | None = None, energy: float = 0.999, order: int = 6, eps: float = 1e-4,
                 tangent: str = "origin", max_segments: int = 100, lam_max: float | None = None,
                 precompute: bool = True, cache: bool = True, correct: bool = False):
        if n_modes is not None and (int(n_modes) != n_modes or n_modes < 1):
            raise ValueError(f"anm_pod: n_modes must be a positive integer, got {n_modes!r}")
        if not 0.0 < energy <= 1.0:
            raise ValueError(f"anm_pod: energy must lie in (0, 1], got {energy!r}")
        if int(order) != order or not 1 <= order <= 40:
            raise ValueError(f"anm_pod: order must be an integer in [1, 40], got {order!r}")
        if not 0.0 < eps < 1.0:
            raise ValueError(f"anm_pod: eps must lie in (0, 1), got {eps!r}")
        if tangent != "origin":
            raise ValueError(f"anm_pod: tangent={tangent!r}; valid: ['origin']")
        if int(max_segments) != max_segments or max_segments < 1:
            raise ValueError(f"anm_pod: max_segments must be a positive integer, got {max_segments!r}")
        if lam_max is not None and not (math.isfinite(lam_max) and lam_max > 0):
            raise ValueError(f"anm_pod: lam_max must be a finite number > 0, got {lam_max!r}")
        self.n_modes, self.energy, self.order, self.eps = n_modes, energy, int(order), float(eps)
        self.tangent, self.max_segments, self.lam_max = tangent, int(max_segments), lam_max
        self.precompute, self.cache, self.correct = bool(precompute), bool(cache), bool(correct)

    def build(self, training: Training) -> "AnmPodModel":
        if training.snapshots is None or training.backend is None:
            raise ValueError("anm_pod: training needs snapshots and a backend")
        be = training.backend
        check_polynomial_problem(be.problem, "anm_pod")
        free = np.asarray(training.free_dofs)
        S = training.snapshots
        if S.shape[0] != be.ndof:
            raise ValueError(f"anm_pod: snapshots have {S.shape[0]} rows, the backend {be.ndof} dofs")
        lo, hi = _envelope(training, self.lam_max)
        t0 = time.perf_counter()
        basis = pod_basis(S[free], self.energy, self.n_modes)
        Phi, captured = basis.modes, basis.energy_captured
        t1 = time.perf_counter()
        poly = reduced_polynomial(be, Phi, free)
        t2 = time.perf_counter()
        model = AnmPodModel(Phi, free, be.ndof, poly, self, (lo, hi))
        if self.precompute:
            model._path = reduced_path(poly, self.lam_max or hi, self.order, self.eps, self.max_segments,
                                       self.correct)
            model._refresh()
        t3 = time.perf_counter()
        model.info = {"n_modes": Phi.shape[1], "energy_captured": captured, "pod_message": basis.message,
                      "rank": basis.rank, "n_evals": poly.n_evals,
                      "pod_s": t1 - t0, "tensors_s": t2 - t1, "path_s": t3 - t2, "offline_s": t3 - t0,
                      "segments": len(model._path)}
        return model


def _envelope(training, lam_max):
    """(min, max) training load factor (parameters, else [0, lam_max])."""
    if training.parameters:
        try:
            lams = [float(p["load_factor"]) for p in training.parameters]
        except (KeyError, TypeError):
            raise ValueError("anm_pod: training.parameters need a 'load_factor' per snapshot") from None
        return min(lams), max(lams)
    if lam_max is None:
        raise ValueError("anm_pod: give training.parameters (load factors) or lam_max")
    return 0.0, float(lam_max)


class AnmPodModel(OnlineModel):
    """Online ANM-POD: ``step({"load_factor": lam})`` -> reduced coordinates q (m,)."""

    name = "anm_pod"

    def __init__(self, basis, free_dofs, ndof, poly, options: AnmPod, envelope):
        self.basis, self.free_dofs, self.ndof, self.poly = basis, free_dofs, ndof, poly
        self.options = options
        self._env = envelope
        self._path = AnmPath()
        self._ends = []
        self.info = {}

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    @property
    def envelope(self) -> dict:
        return {"load_factor": self._env}

    def _refresh(self):
        self._ends = self._path.load_factor_ends

    def variant(self, n_modes: int | None = None, **options) -> "AnmPodModel":
        """The same offline data with fewer modes (leading POD modes, sliced tensors) and/or other
        options (``order``, ``eps``, ``max_segments`` ...): sweeps pay the tensors once."""
        import inspect

        m = self.n_reduced if n_modes is None else min(int(n_modes), self.n_reduced)
        names = inspect.signature(AnmPod).parameters
        opts = AnmPod(**{**{k: getattr(self.options, k) for k in names}, **options})
        model = AnmPodModel(self.basis[:, :m], self.free_dofs, self.ndof, self.poly.leading(m), opts, self._env)
        if opts.precompute:
            model._path = reduced_path(model.poly, opts.lam_max or self._env[1], opts.order, opts.eps,
                                       opts.max_segments, opts.correct)
            model._refresh()
        model.info = {**self.info, "n_modes": m, "segments": len(model._path)}
        return model

    def series_at(self, q0, lam0: float) -> AnmSeries:
        """A reduced series about a given reduced state (the paper's online building block)."""
        s = reduced_series(self.poly, q0, lam0, self.options.order)
        s.a_end = s.a_max(self.options.eps)
        return s

    def _segments_for(self, lam):
        """The continuation covering ``lam`` if max_segments allow (built/extended as needed)."""
        o = self.options
        if not o.cache:
            return reduced_path(self.poly, max(lam, 1e-300), o.order, o.eps, o.max_segments, o.correct)
        if lam > (self._ends[-1] if self._ends else -math.inf) and len(self._path) < o.max_segments:
            reduced_path(self.poly, lam, o.order, o.eps, o.max_segments, o.correct, path=self._path)
            self._refresh()
        return self._path

    def step(self, mu) -> StepResult:
        """Reduced state at ``mu["load_factor"]``: locate the segment, solve lam(a) = lam, evaluate.

        ``info`` holds the segment index and ``a``. Status ``"extrapolation"`` outside the
        training envelope, ``"beyond_validity"`` past the segments ``max_segments`` allow
        (the last series is extrapolated and the message says how far).
        """
        lam = float(check_parameters(mu, ("load_factor",), self.name)["load_factor"])
        path = self._segments_for(lam)
        ends = self._ends if path is self._path else path.load_factor_ends
        k = 0 if lam <= path[0].lam0 else bisect.bisect_left(ends, lam)
        if k < len(path):
            s = path[k]
            a = s.load_factor_to_a(lam)
            if a is not None:
                q = s.evaluate(a)[0]
                lo, hi = self._env
                if lo - 1e-12 <= lam <= hi + 1e-12:
                    return StepResult(q, "ok", info={"segment": k, "a": a})
                return StepResult(q, "extrapolation", f"load factor {lam:.6g} outside the training envelope "
                                  f"[{lo:.6g}, {hi:.6g}]", {"segment": k, "a": a})
        return self._beyond(path, lam)

    def _beyond(self, path, lam):
        """Past the last (or before the first) series: extrapolate it and say by how much."""
        first = lam <= path[0].lam0
        s = path[0] if first else path[-1]
        covered = (path[0].load_factor(-path[0].a_end) if first else s.load_factor(s.a_end))
        a = s.load_factor_to_a(lam, a_limit=math.inf)
        extra = "" if a is None else f"; the series is extrapolated to a = {a:.4g} ({abs(a) / s.a_end:.3g} a_max)"
        if a is None:
            a = -s.a_end if first else s.a_end
            extra = f"; no solution of lam(a) = {lam:.6g}: the state at the range end is returned"
        q = s.evaluate(a)[0]
        if not np.all(np.isfinite(q)):
            return StepResult(None, "failed", f"load factor {lam:.6g}: the extrapolated series overflowed")
        side = "below" if first else "above"
        msg = (f"load factor {lam:.6g} is {abs(lam - covered):.3g} {side} the range covered by "
               f"{len(path)} ANM segment(s) (max_segments={self.options.max_segments}, ends at {covered:.6g})"
               f"{extra}")
        return StepResult(q, "beyond_validity", msg, {"segment": 0 if first else len(path) - 1, "a": a})

    def reconstruct(self, result: StepResult) -> np.ndarray:
        """Full displacement (ndof,): ``Phi q`` on the free dofs, zero on the fixed ones."""
        if result.q is None:
            raise ValueError(f"anm_pod: cannot reconstruct a failed step ({result.message})")
        u = np.zeros(self.ndof)
        u[self.free_dofs] = self.basis @ result.q
        return u
