"""The PGD algorithm of :mod:`tissuebench.rom.separated` (greedy enrichment, alternating
directions, stopping criteria); see that module's docstring for the method and the
criteria. Public entry point: :func:`pgd_solve` (of the types of :mod:`.separated`)."""
from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..refsolvers.sparse_direct import factorized
from .separated import SeparatedOperator, SeparatedSolution, SeparatedVector

__all__ = ["pgd_solve"]

_STAGNATION_FLOOR = 1e-6  # below it the Gram-evaluated residual is round-off (module docstring)


class _DimSolver:
    """Solves ``(sum_t c_t A_t[d]) v = rhs`` for one dimension.

    When every term shares one matrix (``A = K ⊗ W``: the matrix is ``(sum c) K``), its
    factorisation is computed once and reused by every sweep of every mode; otherwise the
    combination is assembled and solved directly, or handed to a user ``solver(matrix, rhs)``.
    """

    def __init__(self, mats, custom):
        self.mats, self.custom, self._factor = mats, custom, None
        self.shared = all(m is mats[0] for m in mats)

    @staticmethod
    def _factorise(M):
        """A ``solve(b)`` of the matrix M, factorised once (sparse: NGSolve or SuperLU by
        size, :func:`~tissuebench.refsolvers.sparse_direct.factorized`; dense: LU)."""
        if sp.issparse(M):

            return factorized(M)
        lu = sla.lu_factor(np.asarray(M, float))
        return lambda b: sla.lu_solve(lu, b)

    def _solve_one(self, M, rhs):
        if sp.issparse(M):
            return spla.spsolve(sp.csc_matrix(M), rhs)
        return np.linalg.solve(np.asarray(M, float), rhs)

    def __call__(self, c, rhs):
        if self.custom is not None:
            return np.asarray(self.custom(self._combine(c), rhs), float).ravel()
        if self.shared:
            if self._factor is None:
                self._factor = self._factorise(self.mats[0])
            return self._factor(rhs) / float(np.sum(c))
        return np.asarray(self._solve_one(self._combine(c), rhs), float).ravel()

    def _combine(self, c):
        out = None
        for ct, M in zip(c, self.mats):
            term = ct * (M.tocsr() if sp.issparse(M) else np.asarray(M, float))
            out = term if out is None else out + term
        return out


class _Residual:
    """``|f - A u| / |f|`` in separated form, updated mode by mode (Gram blocks per dimension)."""

    def __init__(self, F):
        self.F = F  # per dimension (n_d, T_f)
        G = None
        for Fd in F:
            g = Fd.T @ Fd
            G = g if G is None else (G.multiply(g) if sp.issparse(G) else
                                     (g.multiply(G) if sp.issparse(g) else G * g))
        self.f2 = float(G.sum())
        self.cross = [np.zeros((Fd.shape[1], 0)) for Fd in F]   # f-terms x (A u)-terms
        self.gram = [np.zeros((0, 0)) for _ in F]                # (A u)-terms x (A u)-terms
        self.cols = [np.zeros((Fd.shape[0], 0)) for Fd in F]

    def add(self, new_cols):
        """Append the columns ``A_t[d] F_new[d]`` (one per operator term) of a new mode."""
        for d, N in enumerate(new_cols):
            old = self.cols[d]
            x = np.asarray(self.F[d].T @ N)
            self.cross[d] = np.hstack([self.cross[d], x])
            b = old.T @ N
            self.gram[d] = np.block([[self.gram[d], b], [b.T, N.T @ N]])
            self.cols[d] = np.hstack([old, N])

    def relative(self) -> float:
        fu = np.prod(self.cross, axis=0).sum()
        uu = np.prod(self.gram, axis=0).sum()
        r2 = self.f2 - 2.0 * fu + uu
        return float(np.sqrt(max(r2, 0.0) / self.f2)) if self.f2 > 0 else 0.0


def _check(A, f, max_modes, tol, max_fixed_point, fixed_point_tol, dims_solvers, residual_tol, patience):
    if not isinstance(A, SeparatedOperator):
        raise TypeError(f"pgd_solve: A must be a SeparatedOperator, got {type(A).__name__}")
    if not isinstance(f, SeparatedVector):
        raise TypeError(f"pgd_solve: f must be a SeparatedVector, got {type(f).__name__}")
    if A.shape != f.shape:
        raise ValueError(f"pgd_solve: A has dimension sizes {A.shape}, f has {f.shape}")
    for name, v in (("max_modes", max_modes), ("max_fixed_point", max_fixed_point), ("patience", patience)):
        if name == "patience" and v is None:
            continue
        if isinstance(v, bool) or int(v) != v or v < 1:
            raise ValueError(f"pgd_solve: {name} must be a positive integer, got {v!r}")
    for name, v in (("tol", tol), ("fixed_point_tol", fixed_point_tol), ("residual_tol", residual_tol)):
        if v is not None and not (np.isfinite(v) and v >= 0):
            raise ValueError(f"pgd_solve: {name} must be a finite number >= 0, got {v!r}")
    if dims_solvers is not None and (len(dims_solvers) != A.ndim or
                                     any(s is not None and not callable(s) for s in dims_solvers)):
        raise ValueError(f"pgd_solve: dims_solvers must hold {A.ndim} entries, each None or callable(matrix, rhs)")


def _sweep(r, d, ctx):
    """Solve dimension d with the others frozen (Galerkin); returns the new factor."""
    D, F, ops, AFm, Ar = ctx["D"], ctx["F"], ctx["ops"], ctx["AFm"], ctx["Ar"]
    others = [e for e in range(D) if e != d]
    c = np.array([np.prod([r[e] @ Ar[e][t] for e in others]) for t in range(len(ops))])
    cf = np.prod([np.asarray(F[e].T @ r[e]).ravel() for e in others], axis=0)
    rhs = np.asarray(F[d] @ cf).ravel()
    n = AFm[d][0].shape[1]
    if n:
        for t in range(len(ops)):
            cm = np.prod([AFm[e][t].T @ r[e] for e in others], axis=0)
            rhs = rhs - AFm[d][t] @ cm
    return ctx["solvers"][d](c, rhs)


def _new_mode(rng, ctx, max_fixed_point, fixed_point_tol):
    """One greedy mode by alternating directions: (factors or None, sweeps, converged, zero)."""
    D, ops = ctx["D"], ctx["ops"]
    r = [rng.standard_normal(n) for n in ctx["shape"]]
    r = [v / np.linalg.norm(v) for v in r]
    ctx["Ar"] = [[ops[t][e] @ r[e] for t in range(len(ops))] for e in range(D)]
    change = np.inf
    for it in range(1, max_fixed_point + 1):
        old, change = [v.copy() for v in r], 0.0
        for d in range(D):
            v = np.asarray(_sweep(r, d, ctx), float).ravel()
            nv = np.linalg.norm(v)
            if not np.isfinite(nv):
                return None, it, False, False
            if nv == 0.0:
                return r, it, True, True
            if d < D - 1:  # unit factors except the last; sign kept along the iterations
                v = v / nv if v @ old[d] >= 0 else -v / nv
            r[d] = v
            ctx["Ar"][d] = [ops[t][d] @ v for t in range(len(ops))]
            change = max(change, np.linalg.norm(v - old[d]) / nv if d == D - 1 else np.linalg.norm(v - old[d]))
        if change <= fixed_point_tol:
            return r, it, True, False
    return r, max_fixed_point, False, False


def _update_last(modes, ctx):
    """Galerkin re-solve of every mode's last factor with the other factors frozen
    (the "update" step of PGD): ``sum_t A_t[L] V C_t^T = R`` for V = [F_1[L] .. F_n[L]]."""
    ops, F, L = ctx["ops"], ctx["F"], ctx["D"] - 1
    n = len(modes)
    C = []
    for t in range(len(ops)):
        Ct = np.ones((n, n))
        for e in range(L):
            Fe = np.column_stack([m[e] for m in modes])
            Ct = Ct * (Fe.T @ np.asarray(ops[t][e] @ Fe))
        C.append(Ct)
    cf = np.ones((n, F[0].shape[1]))
    for e in range(L):
        cf = cf * np.asarray(F[e].T @ np.column_stack([m[e] for m in modes])).T
    R = np.asarray(F[L] @ cf.T)  # (n_L, n): column i = projected load of test mode i
    solver = ctx["solvers"][L]
    if solver.shared and solver.custom is None:
        V = np.column_stack([solver(np.ones(1), R[:, i]) for i in range(n)]) @ np.linalg.inv(sum(C)).T
    else:
        B = sum(sp.kron(sp.csr_matrix(Ct), sp.csr_matrix(ops[t][L])) for t, Ct in enumerate(C))
        V = np.asarray(spla.spsolve(B.tocsc(), R.T.ravel())).reshape(n, -1).T
    return [tuple(m[:L]) + (V[:, i].copy(),) for i, m in enumerate(modes)]


def _record(out, ctx, res_factory):
    """Operator images of every mode, residual history entry and amplitudes (after an update)."""
    D, ops = ctx["D"], ctx["ops"]
    ctx["AFm"] = [[np.column_stack([ops[t][d] @ m[d] for m in out.modes]) for t in range(len(ops))]
                  for d in range(D)]
    res = res_factory()
    for m in out.modes:
        res.add([np.column_stack([ops[t][d] @ m[d] for t in range(len(ops))]) for d in range(D)])
    out.amplitudes = [float(np.prod([np.linalg.norm(v) for v in m])) for m in out.modes]
    return res


def pgd_solve(A: SeparatedOperator, f: SeparatedVector, max_modes: int = 20, tol: float = 1e-6,
              max_fixed_point: int = 50, fixed_point_tol: float = 1e-8, dims_solvers=None, rng=None,
              residual_tol: float | None = None, patience: int | None = 5, update_last: bool = False
              ) -> SeparatedSolution:
    """Separated solution of ``A u = f`` by greedy PGD (see :mod:`tissuebench.rom.separated`).

    Parameters
    ----------
    A : SeparatedOperator
        D-dimensional operator (Galerkin: meant symmetric positive definite, e.g. a
        stiffness times parameter-space mass matrices).
    f : SeparatedVector
        Right-hand side, same dimension sizes.
    max_modes : int
        Largest number of modes.
    tol : float
        Amplitude criterion: stop once a mode's amplitude <= tol x the first mode's.
    max_fixed_point : int
        Alternating-direction sweeps allowed per mode.
    fixed_point_tol : float
        Largest change of a (unit) factor between two sweeps for convergence.
    dims_solvers : sequence of (callable or None), optional
        Per dimension, ``solver(matrix, rhs) -> v`` replacing the default direct solve
        (``matrix`` is the assembled ``sum_t c_t A_t[d]``).
    rng : int or numpy.random.Generator, optional
        Seed of the random initial factors (None: 0).
    residual_tol : float, optional
        Stop once ``|f - A u| / |f| <= residual_tol`` (None: not used).
    patience : int or None
        Modes without a 0.1 % improvement of the best residual before ``"stagnation"``
        (None: no stagnation stop; for point-load families the Euclidean residual falls by
        less than 0.1 % per mode while the modes still improve the solution).
    update_last : bool
        After each new mode, re-solve the last-dimension factors of all modes jointly
        (Galerkin, other factors frozen): better accuracy per mode when A has several
        terms, but the first n modes of a build then differ from an n-mode build (the
        spans of the other dimensions stay nested). Without it the modes are nested.

    Returns
    -------
    SeparatedSolution
        Modes and the per-mode record (sweeps, convergence, amplitude, residual) and the
        stop reason. Nothing is raised for a non-converging fixed point or a breakdown.
    """
    _check(A, f, max_modes, tol, max_fixed_point, fixed_point_tol, dims_solvers, residual_tol, patience)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(0 if rng is None else rng)
    D, ops = A.ndim, A.terms
    F = [f.stacked(d) for d in range(D)]
    ctx = {"D": D, "shape": A.shape, "F": F, "ops": ops,
           "AFm": [[np.zeros((A.shape[d], 0)) for _ in ops] for d in range(D)],
           "solvers": [_DimSolver([t[d] for t in ops], None if dims_solvers is None else dims_solvers[d])
                       for d in range(D)]}
    res = _Residual(F)
    out = SeparatedSolution([], stop_reason="max_modes")
    best, since_best = np.inf, 0
    for n in range(int(max_modes)):
        r, it, ok, zero = _new_mode(rng, ctx, int(max_fixed_point), fixed_point_tol)
        if r is None or zero:
            out.stop_reason = "breakdown" if r is None else "zero_mode"
            break
        out.modes.append(tuple(v.copy() for v in r))
        out.fixed_point_iterations.append(it)
        out.converged.append(ok)
        out.amplitudes.append(float(np.prod([np.linalg.norm(v) for v in r])))
        cols = [np.column_stack([ops[t][d] @ r[d] for t in range(len(ops))]) for d in range(D)]
        for d in range(D):
            for t in range(len(ops)):
                ctx["AFm"][d][t] = np.column_stack([ctx["AFm"][d][t], cols[d][:, t]])
        if update_last and n > 0:
            out.modes = _update_last(out.modes, ctx)
            res = _record(out, ctx, lambda: _Residual(F))
        else:
            res.add(cols)
        out.residuals.append(res.relative())
        since_best = 0 if out.residuals[-1] < 0.999 * best else since_best + 1
        best = min(best, out.residuals[-1])
        if out.amplitudes[-1] <= tol * out.amplitudes[0]:
            out.stop_reason = "amplitude"
        elif residual_tol is not None and out.residuals[-1] <= residual_tol:
            out.stop_reason = "residual"
        elif patience is not None and since_best >= patience and out.residuals[-1] > _STAGNATION_FLOOR:
            out.stop_reason = "stagnation"
        else:
            continue
        break
    n_bad = out.converged.count(False)
    out.message = (f"{out.n_modes} modes, stop: {out.stop_reason}; relative residual "
                   f"{out.residuals[-1] if out.residuals else float('nan'):.3e}; fixed point not converged "
                   f"in {n_bad} mode(s) (iterations {out.fixed_point_iterations})")
    return out
