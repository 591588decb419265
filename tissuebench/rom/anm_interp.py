"""Interpolated ANM-POD for a load position that was not stored (anm-pod-large-deformations §5).

Offline, one ANM-POD model (POD basis ``A_k`` (n_free, m), reduced tensors ``L_k, Q_k, C_k,
f_k``) is built per stored load position ``s_k`` (a 1D lattice). Online, at a position
``s``, the reduced tensors (§5.3, the "f_nl terms": piecewise-linear, the weights of
:func:`.interpolation_weights`) are interpolated from the two neighbouring positions and
the reduced ANM series (eqs. 44-45) is built from the origin: the step stays in m-space.
The basis (§5.1 Grassmann or §5.2 PODI), the only full-size interpolation (O(n m^2)),
is interpolated when the field is reconstructed.

Alignment. Reduced quantities of two positions can only be averaged if their
coordinates mean the same thing: the POD modes of each position come with arbitrary
signs, may swap order, and rotate within nearly degenerate pairs. Each stored basis is
therefore rotated, ``A_k' = A_k R_k`` (R_k orthogonal (m, m)), and its tensors with it
(``L' = R^T L R``, ``Q'_ijk = R_ai R_bj R_ck Q_abc``, ``C'`` likewise, ``f' = R^T f``; the
reduced model is unchanged: ``A_k' q' = A_k q``). ``R_k`` aligns ``A_k`` to its *left
neighbour*, already aligned (a chain from the first position): piecewise-linear
interpolation only ever mixes neighbours, and a neighbour is close, whereas a global
reference far from ``s_k`` (the load is elsewhere) may be nearly orthogonal to it and
fixes R poorly. ``align="procrustes"`` (default) takes the rotation closest to the
neighbour, so the reduced coordinates move as little as possible between positions and
the tensors vary most slowly; ``"modes"`` keeps mode-by-mode pairing (sign/permutation).

Coordinates of the interpolated basis. The tensors interpolated in aligned coordinates
describe the basis ``B = sum_k w_k A_k'`` (the plain PODI sum) to O(h^2). PODI returns
the orthonormal basis nearest to B (its polar factor, which unlike QR treats all columns
alike). Grassmann's exp map gives the geodesic subspace in coordinates of its own (the
paper's form rotates them by V); it is rotated (Procrustes) onto B, so both variants
express their subspace in the coordinates the tensors are written in. With
``align="procrustes"`` that rotation is the identity (``G^T B`` is symmetric positive:
the exp form of :func:`.grassmann_exp` ends on the Procrustes-aligned neighbour) and
PODI is the same geodesic at another speed; with ``"modes"`` it is not, and skipping it
costs accuracy (cantilever tests: mean error x1.26 at the finer lattice); the paper's
``A0 V cos + U sin`` without it is meaningless (error ~140 %).

Choice of modes: POD modes of tiny singular value are poorly determined and turn by
tens of degrees between neighbouring positions (``info["neighbour_angles"]``); their
interpolated coordinates and tensors are then wrong, and more modes can be *worse*.
"""
from __future__ import annotations

import bisect
import math
import time
from collections import OrderedDict

import numpy as np

from .anm_pod import AnmPod, AnmPodModel
from .base import POLYNOMIAL_MATERIALS, Applies, OnlineModel, RomMethod, StepResult, Training, register
from .online import parameter
from .interp_outputs import InterpolatedOutputs
from .interpolation import grassmann_interpolate, match_modes, principal_angles, procrustes_align
from .pod import pod_basis
from .polynomial import ReducedPolynomial, check_polynomial_problem, reduced_polynomial

__all__ = ["AnmPodInterp", "AnmPodInterpModel", "rotate_polynomial"]

BASIS_INTERPOLATIONS = ("podi", "grassmann")
ALIGNMENTS = {"procrustes": procrustes_align, "modes": match_modes}


def rotate_polynomial(poly: ReducedPolynomial, R) -> ReducedPolynomial:
    """The tensors of the basis ``A R`` from those of ``A`` (R orthogonal (m, m)).

    ``L' = R^T L R``, ``Q'_ijk = R_ai R_bj R_ck Q_abc``, ``C'_ijkl = R_ai R_bj R_ck R_dl C_abcd``,
    ``f' = R^T f``: the reduced force of ``q' = R^T q`` is ``R^T`` times that of ``q``.
    """
    R = np.asarray(R, float)
    Q = np.einsum("abc,ai,bj,ck->ijk", poly.Q, R, R, R, optimize=True)
    C = np.einsum("abcd,ai,bj,ck,dl->ijkl", poly.C, R, R, R, R, optimize=True)
    return ReducedPolynomial(R.T @ poly.L @ R, Q, C, R.T @ poly.f, poly.n_evals)


@register
class AnmPodInterp(RomMethod):
    """ANM-POD interpolated between stored load positions (paper §5-6.1).

    Parameters
    ----------
    n_modes : int, optional
        POD modes per position (default: 0.999 energy); all positions use the smallest
        size found (m = min over positions; POD modes are nested).
    order, eps, max_segments
        Series order, tolerance of ``a_max`` and most continuation segments, as
        :class:`.AnmPod` (``max_segments=1``: the paper's single series from the origin).
    basis_interpolation : {"podi", "grassmann"}
    align : {"procrustes", "modes"}
        How each stored basis is rotated onto its neighbour (module docstring).

    ``build(training)`` reads ``training.groups = {position s (float): Training}``, each
    with full-dof snapshots, ``parameters`` (``load_factor``) and a backend whose problem
    has the load at ``s``. Online: ``step({"load_factor": lam, "position": s})``.
    """

    name = "anm_pod_interp"
    kind = "map"
    training_kinds = ("positions",)
    applies = Applies(materials=POLYNOMIAL_MATERIALS, dead_loads=True, homogeneous_dirichlet=True,
                      parameters={"positions": ("position",)})
    cache_size = 16  # interpolated models kept (LRU): a position that repeats costs one series

    def __init__(self, n_modes: int | None = None, order: int = 6, eps: float = 1e-4,
                 basis_interpolation: str = "podi", max_segments: int = 100, align: str = "procrustes"):
        if basis_interpolation not in BASIS_INTERPOLATIONS:
            raise ValueError(f"anm_pod_interp: basis_interpolation={basis_interpolation!r}; "
                             f"valid: {list(BASIS_INTERPOLATIONS)}")
        if align not in ALIGNMENTS:
            raise ValueError(f"anm_pod_interp: align={align!r}; valid: {list(ALIGNMENTS)}")
        AnmPod(n_modes=n_modes, order=order, eps=eps, max_segments=max_segments)  # validates the shared options
        self.n_modes, self.order, self.eps, self.max_segments = n_modes, int(order), float(eps), int(max_segments)
        self.basis_interpolation, self.align = basis_interpolation, align

    def build(self, training: Training) -> "AnmPodInterpModel":
        groups = training.groups
        if not isinstance(groups, dict) or len(groups) < 2:
            raise ValueError(f"{self.name}: training.groups must map >= 2 load positions to Trainings")
        s = np.array(sorted(float(k) for k in groups), float)
        if not np.all(np.isfinite(s)) or np.any(np.diff(s) <= 0):
            raise ValueError(f"{self.name}: positions must be distinct finite numbers, got {s}")
        t0 = time.perf_counter()
        trainings = [groups[k] for k in sorted(groups, key=float)]
        bases, lams, free, ndof = [], [], None, None
        for pos, tr in zip(s, trainings):
            f, n = _check_group(tr, pos, free, ndof, self.name)
            free, ndof = f, n
            bases.append(pod_basis(tr.snapshots[free], n_modes=self.n_modes).modes)
            lams += [float(p["load_factor"]) for p in tr.parameters]
        m = min(b.shape[1] for b in bases)
        t1 = time.perf_counter()
        polys = [reduced_polynomial(tr.backend, b[:, :m], free) for tr, b in zip(trainings, bases)]
        t2 = time.perf_counter()
        aligned, rotations = _align_chain([b[:, :m] for b in bases], self.align)
        polys = [rotate_polynomial(p, R) for p, R in zip(polys, rotations)]
        model = AnmPodInterpModel(s, np.array(aligned), polys, free, ndof, self, (min(lams), max(lams)))
        model.name = self.name
        model.info = {"n_modes": m, "positions": s.tolist(), "n_evals": sum(p.n_evals for p in polys),
                      "pod_s": t1 - t0, "tensors_s": t2 - t1, "offline_s": time.perf_counter() - t0,
                      "rotations": rotations,
                      "neighbour_angles": [principal_angles(a, b) for a, b in zip(aligned, aligned[1:])]}
        return model


def _align_chain(bases, align):
    """(aligned bases, rotations): ``A_k' = A_k R_k`` aligned to ``A_{k-1}'`` (``R_0 = I``)."""
    aligned, rotations = [bases[0]], [np.eye(bases[0].shape[1])]
    for A in bases[1:]:
        R = A.T @ ALIGNMENTS[align](A, aligned[-1])  # A^T (A R) = R: the rotation applied
        if align == "modes":
            R = np.round(R)  # a signed permutation: exact
        rotations.append(R)
        aligned.append(A @ R)
    return aligned, rotations


def _check_group(tr, pos, free, ndof, who="anm_pod_interp"):
    """(free dofs, ndof) of one stored position's training; the same mesh and supports everywhere."""
    if not isinstance(tr, Training) or tr.snapshots is None or tr.backend is None or not tr.parameters:
        raise ValueError(f"{who}: position {pos:g} needs a Training with snapshots, parameters "
                         "(load_factor) and a backend")
    check_polynomial_problem(tr.backend.problem, who)
    f = np.asarray(tr.free_dofs)
    if tr.snapshots.shape[0] != tr.backend.ndof:
        raise ValueError(f"{who}: position {pos:g}: snapshots have {tr.snapshots.shape[0]} rows, "
                         f"the backend {tr.backend.ndof} dofs")
    if free is not None and (tr.backend.ndof != ndof or not np.array_equal(f, free)):
        raise ValueError(f"{who}: position {pos:g} has other dofs than the first position "
                         "(the bases must live on one mesh with the same supports)")
    if any("load_factor" not in p for p in tr.parameters):
        raise ValueError(f"{who}: position {pos:g}: every parameter needs a 'load_factor'")
    return f, tr.backend.ndof


class AnmPodInterpModel(OnlineModel):
    """Online interpolated ANM-POD: ``step({"load_factor", "position"})`` -> q (m,).

    ``result.info`` holds the ``position``, ``distance`` to the nearest stored position
    (position units), ``position_extrapolation``, neighbour ``indices``/``weights``, the
    ANM ``segment``/``a``, and ``timings`` (seconds: ``tensors``, ``series``,
    ``evaluation``; a cached position costs no tensors, and no series unless the load
    factor lies past the continuation built so far). The step never touches a full-size
    array: the basis is interpolated by :meth:`reconstruct` (:meth:`basis_at`, cached).
    """

    name = "anm_pod_interp"
    kind = "map"

    def __init__(self, positions, bases, polys, free_dofs, ndof, options: AnmPodInterp, lam_envelope):
        self.positions, self.bases = positions, bases  # (k,), (k, n_free, m) aligned
        self.free_dofs, self.ndof, self.options = free_dofs, ndof, options
        # stacked tensors: interpolation is one tensordot per tensor
        self._L = np.array([p.L for p in polys])
        self._Q = np.array([p.Q for p in polys])
        self._C = np.array([p.C for p in polys])
        self._f = np.array([p.f for p in polys])
        # ... and all four side by side, flattened: one product interpolates them all
        self._T = np.ascontiguousarray(np.hstack([T.reshape(len(polys), -1) for T in (self._L, self._Q, self._C,
                                                                                     self._f)]))
        m = bases.shape[2]
        cuts = np.cumsum([m * m, m ** 3, m ** 4])
        self._shapes = [((m, m), slice(0, cuts[0])), ((m, m, m), slice(cuts[0], cuts[1])),
                        ((m, m, m, m), slice(cuts[1], cuts[2])), ((m,), slice(cuts[2], None))]
        self._pos = [float(x) for x in positions]
        self._reduced_outputs = None
        self._lam_env = lam_envelope
        # what every interpolated model runs: series built online at first need, then kept
        self._series = AnmPod(n_modes=bases.shape[2], order=options.order, eps=options.eps,
                              max_segments=options.max_segments, precompute=False, cache=True)
        self._cache: OrderedDict = OrderedDict()
        self.info = {}

    @property
    def n_reduced(self) -> int:
        return self.bases.shape[2]

    @property
    def envelope(self) -> dict:
        return {"load_factor": self._lam_env, "position": (float(self.positions[0]), float(self.positions[-1]))}

    def model_at(self, s: float):
        """(AnmPodModel at position s, interpolation record, timings); cached per position.

        Only reduced quantities are interpolated here; the basis, which only
        :meth:`reconstruct` needs, is interpolated there (:meth:`basis_at`), off the step.
        """
        if s in self._cache:
            self._cache.move_to_end(s)
            return (*self._cache[s], {"tensors": 0.0})
        t0 = time.perf_counter()
        idx, w, extra, dist = self._weights(s)
        flat = w @ self._T[idx]
        poly = ReducedPolynomial(*(flat[sl].reshape(shape) for shape, sl in self._shapes))
        t1 = time.perf_counter()
        model = AnmPodModel(None, self.free_dofs, self.ndof, poly, self._series, self._lam_env)
        record = {"indices": idx, "weights": w, "position_extrapolation": extra, "distance": dist}
        self._cache[s] = (model, record)
        if len(self._cache) > self.options.cache_size:
            self._cache.popitem(last=False)
        return model, record, {"tensors": t1 - t0}

    def _weights(self, s: float):
        """:func:`.interpolation_weights` of the stored positions (sorted, 1D) at ``s``: the hat
        functions of its interval, without the checks and the sort of the general function."""
        ps = self._pos
        j = min(max(bisect.bisect_left(ps, s) - 1, 0), len(ps) - 2)
        t = (s - ps[j]) / (ps[j + 1] - ps[j])
        w0, w1 = 1.0 - t, t
        extra = w0 < -1e-12 or w1 < -1e-12
        dist = min(abs(p - s) for p in ps)
        if abs(w0) <= 1e-14:
            return np.array([j + 1]), np.array([w1]), extra, dist
        if abs(w1) <= 1e-14:
            return np.array([j]), np.array([w0]), extra, dist
        return np.array([j, j + 1]), np.array([w0, w1]), extra, dist

    def attach_outputs(self, operators) -> None:
        """Outputs reduced offline to m-sized operators of every interpolated basis (:mod:`.interp_outputs`)."""
        super().attach_outputs(operators)
        names, C = self._outputs[0], self._outputs[1]
        self._reduced_outputs = None if not len(names) else InterpolatedOutputs(
            C[:, self.free_dofs], self.bases, self.options.basis_interpolation)

    def outputs(self, result: StepResult) -> dict:
        """The attached outputs: ``C B(s) q`` with ``C B(s)`` from m-sized quantities (kept per
        cached position); the full reconstruction only where those degenerate or the result
        carries its own basis."""
        names = self._outputs[0] if hasattr(self, "_outputs") else ()
        info, q = result.info, result.q
        if not names or q is None or self._reduced_outputs is None or info.get("basis") is not None:
            return super().outputs(result)
        s = info["position"]
        entry = self._cache.get(s)
        rec = entry[1] if entry is not None else {"indices": info["indices"], "weights": info["weights"]}
        CB = rec.get("outputs")
        if CB is None:
            CB = rec["outputs"] = self._reduced_outputs.operator(rec["indices"], rec["weights"])
            if CB is None:
                return super().outputs(result)
        return dict(zip(names, np.dot(CB, q).tolist()))

    def floor_ops(self):
        """A step at a new position, written with the fewest products: the tensors interpolated
        (one product over the stacked L, Q, C, f), the reduced series of the chosen order from
        the origin (per order: the pair and triple convolutions of the known coefficients, two
        tensor contractions, the solve with the inverse of L), its radius and its value at one
        ``a``, and the output operator of the interpolated basis (:mod:`.interp_outputs`). The
        scalar root of ``lam(a)`` is not counted."""
        m, N = self.n_reduced, self.options.order
        s = 0.5 * (self._pos[0] + self._pos[1])
        idx, w, _, _ = self._weights(s)
        T, flat = np.ascontiguousarray(self._T[idx]), np.empty(self._T.shape[1])
        (_, sl_L), (_, sl_Q), (_, sl_C), (_, sl_f) = self._shapes
        Z, WS = np.zeros((N + 1, m)), np.zeros((N + 1, m * m))
        exps, q = np.arange(N + 1, dtype=float), np.empty(m)
        ops = self._reduced_outputs

        def floor():
            np.dot(w, T, out=flat)
            L, Q2, C3, f = flat[sl_L].reshape(m, m), flat[sl_Q].reshape(m, m * m), flat[sl_C].reshape(m, m ** 3), \
                flat[sl_f]
            Kinv = np.linalg.inv(L)
            u = Kinv @ f
            lam1 = 1.0 / math.sqrt(1.0 + u @ u)
            Z[1] = lam1 * u
            for p in range(2, N + 1):
                W = Z[1:p].T @ Z[p - 1:0:-1]
                WS[p] = W.ravel()
                R = Q2 @ WS[p]
                if p >= 3:
                    R += C3 @ (Z[1:p - 1].T @ WS[p - 1:1:-1]).ravel()
                u_nl = Kinv @ -R
                Z[p] = (-(u_nl @ Z[1])) * Z[1] + u_nl
            np.linalg.norm(Z[1]), np.linalg.norm(Z[N])
            np.dot(np.power(0.1, exps), Z, out=q)
            if ops is not None:
                ops.operator(idx, w) @ q
        return floor

    def basis_at(self, s: float) -> np.ndarray:
        """Interpolated orthonormal basis (n_free, m) at position ``s`` in the aligned
        coordinates (module docstring); computed once per cached position."""
        _, record, _ = self.model_at(float(s))
        if "basis" not in record:
            record["basis"] = self._basis(float(s), record["indices"], record["weights"])
        return record["basis"]

    def _basis(self, s, idx, w):
        B = sum(wi * self.bases[i] for wi, i in zip(w, idx))  # the plain PODI sum
        if len(idx) == 1:
            return B  # a stored position: its own aligned basis
        if self.options.basis_interpolation == "grassmann":
            G = grassmann_interpolate(self.bases, self.positions, s).value
            return procrustes_align(G, B)
        return _polar(B)

    def step(self, mu) -> StepResult:
        """Reduced state at ``mu["load_factor"]`` for the load at ``mu["position"]``.

        Status ``"extrapolation"`` when the position lies outside the stored range or
        the load factor outside the training envelope (value returned);
        ``"beyond_validity"`` past the ``max_segments`` series (as :class:`.AnmPodModel`).
        """
        lam, s = parameter(mu, "load_factor", self.name), parameter(mu, "position", self.name)
        model, rec, timings = self.model_at(s)
        t0 = time.perf_counter()
        model._segments_for(lam)  # build/extend the continuation (timed apart from the evaluation)
        t1 = time.perf_counter()
        res = model.step({"load_factor": lam})
        t2 = time.perf_counter()
        timings.update(series=t1 - t0, evaluation=t2 - t1)
        info = {**res.info, **{k: v for k, v in rec.items() if k not in ("basis", "outputs")}, "position": s,
                "timings": timings}
        status, msg = res.status, res.message
        if rec["position_extrapolation"]:
            lo, hi = self.envelope["position"]
            note = (f"position {s:.6g} outside the stored positions [{lo:.6g}, {hi:.6g}] "
                    f"(distance {rec['distance']:.3g} to the nearest)")
            status = "extrapolation" if status == "ok" else status
            msg = f"{msg}; {note}" if msg else note
        return StepResult(res.q, status, msg, info, mu={"load_factor": lam, "position": s})

    def reconstruct(self, result: StepResult) -> np.ndarray:
        """Full displacement (ndof,): the interpolated basis at the step's position times q
        (``result.info["basis"]``, when set, overrides it), zero on the fixed dofs.

        Raises ValueError for a failed step, or when the Grassmann log map between the
        neighbouring bases does not exist (a principal angle of pi/2).
        """
        if result.q is None:
            raise ValueError(f"{self.name}: cannot reconstruct a failed step ({result.message})")
        basis = result.info.get("basis")
        if basis is None:
            basis = self.basis_at(result.info["position"])
        u = np.zeros(self.ndof)
        u[self.free_dofs] = basis @ result.q
        return u


def _polar(B):
    """The orthonormal basis nearest to B (n, m): ``B (B^T B)^{-1/2}``.

    Through the m x m Gram matrix: two O(n m^2) products, ~5x cheaper than a thin SVD of
    B; squaring the condition number is harmless for neighbours at principal angles
    below 90 deg (eigenvalues >= 1/2), the SVD takes over for a nearly singular B.
    """
    lam, V = np.linalg.eigh(B.T @ B)
    if lam[0] <= 1e-8 * lam[-1]:
        U, _, Vt = np.linalg.svd(B, full_matrices=False)
        return U @ Vt
    return B @ ((V / np.sqrt(lam)) @ V.T)
