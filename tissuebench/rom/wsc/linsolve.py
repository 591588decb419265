"""Solves with the step matrix ``H = c_m M_z + (1 + alpha) K_z`` (the L-BFGS initial inverse
Hessian and the linearised predictor of :mod:`.stepper`), the kind chosen by measured cost.

Kinds (``H`` symmetric positive definite, dense, n = free reduced dofs):

* ``"dense"``: the inverse from the Cholesky factor (LAPACK potrf + potri), applied with
  BLAS symv, which reads the upper triangle only (n^2 / 2 entries a solve).
* ``"cholesky"``: the Cholesky factor, two triangular solves a solve (potrs).
* ``"sparse"``: SuperLU of the sparse ``H`` (its fill decides).

The dense kinds factor the Jacobi-scaled ``D H D`` (``D = diag(H)^-1/2``; the affine
coordinates of a handle -- translation, and gradients multiplied by coordinates -- differ in
scale by the body's size), so the rounding of a single-precision operator acts on the
scaled matrix. A solve reads the whole operator, so its cost is memory traffic (paper cube, 364 handles,
n = 4374, one core: stored full inverse 16 ms (gemv), symmetric inverse 8 ms, the same in
single precision 3.7 ms, potrs 32 ms: the triangular solves do not stream). ``"auto"``
builds every kind and keeps the fastest by its fastest of timed solves taken in turns
(``info`` keeps the measured costs), instead of a fixed size threshold; SuperLU is tried only for a matrix at
most ``SPARSE_MAX_DENSITY`` dense.

Precision ``"single"`` stores the operator in float32 (half the traffic). The operator only
preconditions L-BFGS and predicts; every residual the convergence test sees is computed in
double, so the converged state does not depend on it beyond the tolerance. What rounding can
change is how well it preconditions: with ``P`` the single-precision inverse, L-BFGS starts
from the Hessian ``P^-1`` instead of ``H``, and the preconditioned step matrix ``P H`` has its
eigenvalues in ``[1 - rho, 1 + rho]``, ``rho`` the spectral radius of ``P H - I`` (``P H`` is
similar to the symmetric ``H^1/2 P H^1/2``, so its eigenvalues are real). Single precision is
accepted when ``rho <= SINGLE_TOL``, ``rho`` estimated by power iteration on ``P H - I``
(seeded; the iterate converges to the dominant eigendirection, so a stiff direction lost to
rounding shows even where random solutions average it away), **and** the relative error of
seeded solutions (``info["single_error"]``; ci cube, 10 handles: 1.1e-4) is within
``SINGLE_TOL`` too; else the operator stays in double and ``info`` says why. The power
iteration alone is not enough: the operator rounds its input to float32, so where ``H`` is
ill-conditioned beyond ``1 / eps32`` the soft components of ``H v`` are lost below the
rounding of the stiff ones and the iterate never reaches the soft directions that rounding
ruins (a 60 x 60 ``H`` of condition 1e13: triangular float32 solves, estimate 0.03 against an
``eigvals`` radius of 1.2e4 and a solution error of 2e4).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import blas, lapack

__all__ = ["KINDS", "POWER_ITERATIONS", "PRECISIONS", "SINGLE_TOL", "SPARSE_MAX_DENSITY", "StepMatrix"]

KINDS = ("auto", "dense", "cholesky", "sparse")
KINDS_BUILT = ("dense", "cholesky", "sparse")  # what "auto" chooses from
PRECISIONS = ("single", "double")
#: ``auto`` times SuperLU only for a step matrix at most this dense (paper cube, 364 handles:
#: 24 % dense, SuperLU 24-31 ms a solve against 2.7 ms for the single-precision inverse, and
#: its factorisation takes longer than the dense one)
SPARSE_MAX_DENSITY = 0.1
#: largest spectral radius of ``P H - I`` accepted for the single-precision ``P`` (module
#: docstring): the preconditioned step matrix then has a condition number <= 1.1 / 0.9 = 1.22,
#: and a linearised iteration contracts by rho at worst (the tangent's change over a step moves
#: it more: the step matrix is the start state's); rounding loses a stiff direction when rho
#: nears 1 (condition numbers past ~1e7 in single precision)
SINGLE_TOL = 0.1
#: power iterations of the ``rho`` estimate (a solve and a product with ``H`` each, at build)
POWER_ITERATIONS = 30


class _Dense:
    """``H^-1 = D Hs^-1 D`` applied with symv, ``Hs`` the factored matrix (see :class:`StepMatrix`)."""

    def __init__(self, c, d, dtype):
        inv, info = lapack.dpotri(c, lower=0)
        if info != 0:
            raise np.linalg.LinAlgError(f"potri failed (info {info})")
        self.a, self.d = np.asfortranarray(np.triu(inv).astype(dtype)), d
        self.symv = blas.ssymv if dtype == np.float32 else blas.dsymv
        self.dtype = dtype

    def solve(self, b):
        return self.d * self.symv(1.0, self.a, (self.d * b).astype(self.dtype, copy=False), lower=0)


class _Cholesky:
    def __init__(self, c, d, dtype):
        self.c, self.d = np.asfortranarray(np.triu(c).astype(dtype)), d
        self.potrs = lapack.spotrs if dtype == np.float32 else lapack.dpotrs
        self.dtype = dtype

    def solve(self, b):
        x, info = self.potrs(self.c, (self.d * b).astype(self.dtype, copy=False), lower=0)
        return self.d * x


class _Sparse:
    def __init__(self, H):
        self.lu = spla.splu(sp.csc_matrix(H), permc_spec="MMD_AT_PLUS_A")

    def solve(self, b):
        return self.lu.solve(np.asarray(b, dtype=float))


def _rounding_radius(op, H, v) -> float:
    """Spectral radius of ``A = P H - I`` (``P``: ``op.solve``, symmetric) by power iteration
    from ``v``. ``A`` is self-adjoint in the ``H`` inner product, so the ``H``-norm ratios
    ``|A v|_H / |v|_H`` increase towards rho; the last one is returned."""
    Hv = H @ v
    v, Hv = v / np.sqrt(v @ Hv), Hv / np.sqrt(v @ Hv)
    ratio = 0.0
    for _ in range(POWER_ITERATIONS):
        w = op.solve(Hv) - v
        Hw = H @ w
        nw2 = float(w @ Hw)
        if not np.isfinite(nw2):
            return float("inf")
        if nw2 <= 0.0:
            break
        ratio = np.sqrt(nw2)
        v, Hv = w / ratio, Hw / ratio
    return float(ratio)


def _fastest_solve_s(ops, rhs) -> dict:
    """The fastest of ``len(rhs)`` timed solves of every operator, taken in turns (a load spike
    on a shared machine then hits every candidate alike, and the minimum ignores it)."""
    times = {name: [] for name in ops}
    for op in ops.values():
        op.solve(rhs[0])
    for b in rhs:
        for name, op in ops.items():
            t0 = time.perf_counter()
            op.solve(b)
            times[name].append(time.perf_counter() - t0)
    return {name: float(min(t)) for name, t in times.items()}


def _candidate(name, c, d, H, precision, exact):
    """``(operator, (error, rho) or None)``: the ``name`` solve of ``H`` in single precision when
    asked and both the spectral radius of ``P H - I`` of that operator and its relative error
    on the seeded ``exact`` solutions are within :data:`SINGLE_TOL`, else in double."""
    if name == "sparse":
        return _Sparse(H), None
    cls = _Dense if name == "dense" else _Cholesky
    if precision != "single":
        return cls(c, d, np.float64), None
    trial = cls(c, d, np.float32)
    err = max(np.linalg.norm(trial.solve(H @ x) - x) / np.linalg.norm(x) for x in exact)
    rho = _rounding_radius(trial, H, exact[0])
    accepted = rho <= SINGLE_TOL and err <= SINGLE_TOL
    return (trial if accepted else cls(c, d, np.float64)), (float(err), float(rho))


class StepMatrix:
    """Solves with a symmetric positive definite ``H`` (see the module docstring).

    Parameters
    ----------
    H : (n, n) array
    kind : {"auto", "dense", "cholesky", "sparse"}
    precision : {"single", "double"}
        Of the dense operators (SuperLU is double).
    timing_solves : int
        Timed solves per candidate when ``kind = "auto"`` (the fastest counts).

    Attributes
    ----------
    kind, precision : str
        What was built.
    info : dict
        ``solve_ms`` per candidate (auto), ``single_rho`` (spectral radius of ``P H - I``,
        the acceptance test) and ``single_error`` (relative error of seeded solutions),
        ``kind``, ``precision``, ``n``, ``build_s``.
    """

    def __init__(self, H, kind="auto", precision="single", timing_solves=15):
        if kind not in KINDS:
            raise ValueError(f"step-matrix kind = {kind!r}: expected one of {KINDS}")
        if precision not in PRECISIONS:
            raise ValueError(f"step-matrix precision = {precision!r}: expected one of {PRECISIONS}")
        tic = time.perf_counter()
        H = np.asarray(H, dtype=float)
        diag = np.diag(H)
        if not np.all(np.isfinite(H)) or not np.all(diag > 0):  # the scaling's sqrt would hide it as NaN factors
            bad = int(np.argmin(np.where(np.isfinite(diag), diag, -np.inf)))
            raise np.linalg.LinAlgError(f"diagonal entry {bad} is {float(diag[bad]):.6g}"
                                        if np.all(np.isfinite(H)) else "non-finite entries")
        d = 1.0 / np.sqrt(diag)  # Jacobi scaling: the affine coordinates' scales differ by the body size
        c = sla.cho_factor(d[:, None] * H * d[None, :], lower=False, check_finite=False)[0]
        rng = np.random.default_rng(0)
        rhs = rng.standard_normal((max(3, int(timing_solves)), len(H)))
        exact = rng.standard_normal((3, len(H)))  # solutions with every eigendirection present
        self.info = {}
        names = [kind] if kind != "auto" else list(KINDS_BUILT)
        density = np.count_nonzero(H) / H.size
        if kind == "auto" and density > SPARSE_MAX_DENSITY:  # not worth its factorisation time (module docstring)
            names.remove("sparse")
            self.info["sparse_skipped"] = f"density {density:.2f} > {SPARSE_MAX_DENSITY}"
        ops, checks = {}, {}
        for name in names:
            ops[name], checks[name] = _candidate(name, c, d, H, precision, exact)
        if kind == "auto":
            cost = _fastest_solve_s(ops, rhs)
            kind = min(cost, key=cost.get)
            self.info["solve_ms"] = {name: round(1e3 * s, 4) for name, s in cost.items()}
        self._op, self.kind = ops[kind], kind
        # what was built, not what was asked: the single-precision test is of this very operator
        self.precision = "single" if getattr(self._op, "dtype", np.float64) == np.float32 else "double"
        if checks[kind] is not None:
            err, rho = checks[kind]
            self.info.update(single_error=err, single_rho=rho)
            if rho > SINGLE_TOL:
                self.info["single_refused"] = (f"single-precision {kind} solve: spectral radius of P H - I {rho:.2e} "
                                               f"(> {SINGLE_TOL:g})")
            elif err > SINGLE_TOL:
                self.info["single_refused"] = (f"single-precision {kind} solve: relative error of seeded solutions "
                                               f"{err:.2e} (> {SINGLE_TOL:g})")
        self.info.update(kind=kind, precision=self.precision, n=len(H), build_s=round(time.perf_counter() - tic, 4))

    def solve(self, b) -> np.ndarray:
        """``H^{-1} b`` (n,) in double precision."""
        return self._op.solve(b)
