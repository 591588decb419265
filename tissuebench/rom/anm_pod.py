"""ANM-POD (anm-pod-large-deformations §4, eqs. 39-45): the registered ``"anm_pod"`` ROM.

The ANM series of :mod:`.anm` in the coordinates of a POD basis ``Phi``, with the reduced
tensors ``L_r, Q_r, C_r`` of the SVK force computed offline by polarization
(:mod:`.polynomial`), so an online series (or the evaluation of a precomputed
continuation) never touches a full-size vector.
"""
from __future__ import annotations

import bisect
import math
import time

import numpy as np

from .anm import AnmPath, AnmSeries, reduced_path, reduced_series
from .base import DeferredStepResult, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training, register
from .online import parameter
from .pod import pod_basis
from .polynomial import check_polynomial_problem, reduced_polynomial

__all__ = ["AnmPod", "AnmPodModel"]


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
    kind = "path"
    nested = ("n_modes", "order")
    training_kinds = ("path",)

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
            model._refresh(tabulate=True)
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


class AnmPodModel(LinearReconstruction, OnlineModel):
    """Online ANM-POD: ``step({"load_factor": lam})`` -> reduced coordinates q (m,)."""

    name = "anm_pod"
    kind = "path"

    def __init__(self, basis, free_dofs, ndof, poly, options: AnmPod, envelope):
        self.basis, self.free_dofs, self.ndof, self.poly = basis, free_dofs, ndof, poly
        self.options = options
        self._env = envelope
        self._path = AnmPath()
        self._ends = []
        self._top, self._fixed_path = -math.inf, False
        self._ok = (envelope[0] - 1e-12, envelope[1] + 1e-12)
        self.info = {}

    @property
    def n_reduced(self) -> int:
        return self.poly.m

    @property
    def envelope(self) -> dict:
        return {"load_factor": self._env}

    @property
    def path(self) -> AnmPath:
        """The continuation segments built so far (the first is the series from the origin)."""
        return self._path

    def _refresh(self, tabulate: bool = False):
        """After the continuation changed: its ends, and (``tabulate``: a precomputed one, stepped
        again and again) the root tables of its segments (:meth:`AnmSeries.prepare_roots`)."""
        self._ends = self._path.load_factor_ends
        if tabulate:
            for seg in self._path:
                if seg._table is None:
                    seg.prepare_roots()
        o = self.options
        # the haptic path: a kept continuation that covers lam, or that no step may extend
        self._top = self._ends[-1] if (self._ends and o.cache) else -math.inf
        self._fixed_path = o.cache and len(self._path) >= o.max_segments

    def variant(self, n_modes: int | None = None, **options) -> "AnmPodModel":
        """The same offline data with fewer modes (leading POD modes, sliced tensors) and/or other
        options (``order``, ``eps``, ``max_segments`` ...): sweeps pay the tensors once."""
        import inspect

        m = self.n_reduced if n_modes is None else min(int(n_modes), self.n_reduced)
        names = inspect.signature(AnmPod).parameters
        opts = AnmPod(**{**{k: getattr(self.options, k) for k in names}, **options, "n_modes": m})
        model = AnmPodModel(self.basis[:, :m], self.free_dofs, self.ndof, self.poly.leading(m), opts, self._env)
        if opts.precompute:
            model._path = reduced_path(model.poly, opts.lam_max or self._env[1], opts.order, opts.eps,
                                       opts.max_segments, opts.correct)
            model._refresh(tabulate=True)
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
        lam = parameter(mu, "load_factor", self.name)
        if self._fixed_path or lam <= self._top:  # the continuation covers lam or cannot grow
            path, ends = self._path, self._ends
        else:
            path = self._segments_for(lam)
            ends = self._ends if path is self._path else path.load_factor_ends
        k = 0 if lam <= path[0].lam0 else bisect.bisect_left(ends, lam)
        if k < len(path):
            s = path[k]
            a = s.root(lam)
            if a is not None:
                q = s.state(a)
                lo, hi = self._ok
                if lo <= lam <= hi:
                    return StepResult(q, "ok", "", {"segment": k, "a": a})
                lo, hi = self._env
                return DeferredStepResult(q, "extrapolation", lambda: f"load factor {lam:.6g} outside the training "
                                          f"envelope [{lo:.6g}, {hi:.6g}]", {"segment": k, "a": a})
        return self._beyond(path, lam)

    def floor_ops(self):
        """The series evaluation (powers of ``a``, the (order + 1) x m coefficient product) and the
        output product: what a step does once ``a`` is known (the scalar root of ``lam(a)``,
        a few flops, is not counted)."""
        s = self._path[0] if self._path else self.series_at(None, 0.0)
        Z = np.ascontiguousarray(s._Z)
        exps, pw, q = s._exps, np.empty(Z.shape[0]), np.empty(Z.shape[1])
        C_r = getattr(self, "_outputs", (None, None, None))[2]
        a = 0.5 * s.a_end if s.a_end is not None and math.isfinite(s.a_end) else 0.1
        if C_r is None:
            return lambda: np.dot(np.power(a, exps, out=pw), Z, out=q)
        y = np.empty(C_r.shape[0])

        def floor():
            np.dot(np.power(a, exps, out=pw), Z, out=q)
            np.dot(C_r, q, out=y)
        return floor

    def _beyond(self, path, lam):
        """Past the last (or before the first) series: extrapolate it and say by how much."""
        first = lam <= path[0].lam0
        s = path[0] if first else path[-1]
        covered = (path[0].load_factor(-path[0].a_end) if first else
                   (self._ends[-1] if path is self._path and self._ends else s.load_factor(s.a_end)))
        a = s.root(lam, math.inf)
        solved = a is not None
        if not solved:
            a = -s.a_end if first else s.a_end
        q = s.state(a)
        if not math.isfinite(q.sum()) and not np.all(np.isfinite(q)):
            return StepResult(None, "failed", f"load factor {lam:.6g}: the extrapolated series overflowed")
        n_seg, max_seg = len(path), self.options.max_segments

        def message():
            tail = (f" {'below' if first else 'above'} the range covered by {n_seg} ANM segment(s) "
                    f"(max_segments={max_seg}, ends at {covered:.6g})")
            extra = (f"; the series is extrapolated to a = {a:.4g} ({abs(a) / s.a_end:.3g} a_max)" if solved else
                     f"; no solution of lam(a) = {lam:.6g}: the state at the range end is returned")
            return f"load factor {lam:.6g} is {abs(lam - covered):.3g}{tail}{extra}"
        return DeferredStepResult(q, "beyond_validity", message, {"segment": 0 if first else len(path) - 1, "a": a})
