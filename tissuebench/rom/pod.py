"""Proper orthogonal decomposition (anm-pod-large-deformations §2) and two POD-Galerkin statics ROMs.

* :func:`pod_basis` extracts an orthonormal (or W-orthonormal) basis from a snapshot
  matrix with the energy criterion of the paper.
* ``"pod_linear"`` (:class:`PodLinear`): the paper's reduced linear model, eq. (13), with
  the tangent at the origin, ``A^T K(0) A zeta = lam A^T F``.
* ``"pod_newton"`` (:class:`PodNewton`): reduced Newton-Raphson with full assembly and
  projection, the accuracy ceiling of a basis (it touches full-size vectors online, so
  it is a reference for ROMs, not a real-time method).

Eigenvalue normalisation: the paper's eigenvalues are those of the two-point correlation
``c = Q Q^T`` (eqs. 5-7) *without* a 1/P factor, i.e. the squared singular values
``s_i**2`` of the snapshot matrix; :attr:`PodBasis.eigenvalues` returns exactly these.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla

from .base import (Applies, LinearReconstruction, OnlineModel, RomMethod, StepResult, Training, check_parameters,
                   register)
from .online import parameter
from ..refsolvers.newton import ROUND_OFF_FACTOR, scaled_norm, unit_dilation

__all__ = ["PodBasis", "pod_basis", "PodLinear", "PodNewton"]

_INNER = ("euclidean", "mass", "stiffness")


@dataclass
class PodBasis:
    """Outcome of :func:`pod_basis`.

    Attributes
    ----------
    modes : (n_dof, n) array
        Orthonormal columns (W-orthonormal with an inner-product matrix W), by decreasing energy.
    singular_values : (min(n_dof, n_snap),) array
        All singular values of the snapshot matrix (in the W norm), decreasing.
    energy_captured : float
        ``sum(s[:n]**2) / sum(s**2)``.
    rank : int
        Numerical rank of the snapshot set.
    rank_deficient : bool
        Fewer independent snapshots than the requested ``n_modes``.
    message : str
    """

    modes: np.ndarray
    singular_values: np.ndarray
    energy_captured: float
    rank: int
    rank_deficient: bool
    message: str

    @property
    def n_modes(self) -> int:
        return self.modes.shape[1]

    @property
    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of ``c = Q Q^T`` (paper eq. 7, no 1/P factor): ``s**2``."""
        return self.singular_values**2


def _svd_in_inner(S, W):
    """(left vectors, singular values) of S in the inner product W (W-orthonormal vectors).

    Euclidean: thin SVD. With W: thin QR ``S = Q R``, Cholesky of the small Gram matrix
    ``Q^T W Q = L L^T``, SVD ``L^T R = Z s V^T``, vectors ``Q L^{-T} Z``. Then
    ``S^T W S = V s^2 V^T`` (the method of snapshots' correlation) but its eigenvalues are
    never formed, so small singular values keep full precision; eigh of ``S^T W S``
    loses half the digits (a smooth Newton path of 8 states came out rank 5, not 8).
    W itself is never factored.
    """
    if W is None:
        U, s, _ = np.linalg.svd(S, full_matrices=False)
        return U, s
    if W.shape != (S.shape[0], S.shape[0]):
        raise ValueError(f"pod_basis: inner has shape {W.shape}, expected ({S.shape[0]}, {S.shape[0]})")
    Q, R = np.linalg.qr(S)
    G = Q.T @ (W @ Q)
    try:
        L = np.linalg.cholesky(0.5 * (G + G.T))
    except np.linalg.LinAlgError:
        raise ValueError("pod_basis: inner is not positive definite on the span of the snapshots") from None
    Z, s, _ = np.linalg.svd(L.T @ R)
    return sla.solve_triangular(L, Q.T, lower=True).T @ Z, s  # Q L^{-T} Z


def pod_basis(snapshots, energy: float = 0.999, n_modes: int | None = None, inner=None,
              rtol_rank: float = 1e-12) -> PodBasis:
    """POD basis of a snapshot matrix (paper §2.1, eqs. 1-8).

    Parameters
    ----------
    snapshots : (n_dof, n_snap) array
        Columns are states (displacements, any consistent unit); not centred.
    energy : float, in (0, 1]
        Smallest ``n`` with ``sum(s[:n]**2) / sum(s**2) >= energy`` (ignored with ``n_modes``).
    n_modes : int, optional
        Number of modes requested; more than the rank returns the rank (reported).
    inner : (n_dof, n_dof) SPD matrix (sparse or dense), optional
        Inner product W (mass or stiffness); modes are W-orthonormal.
    rtol_rank : float
        Singular values ``<= rtol_rank * s_0`` count as zero (rank).

    Returns
    -------
    PodBasis

    Raises
    ------
    ValueError
        Empty, non-finite or all-zero snapshots; bad ``energy`` / ``n_modes``.
    """
    S = np.asarray(snapshots, dtype=float)
    if S.ndim != 2 or S.size == 0 or not np.all(np.isfinite(S)):
        raise ValueError(f"pod_basis: snapshots must be a non-empty finite (n_dof, n_snap) array (shape {S.shape})")
    if not 0.0 < energy <= 1.0:
        raise ValueError(f"pod_basis: energy must lie in (0, 1], got {energy!r}")
    if n_modes is not None and (int(n_modes) != n_modes or n_modes < 1):
        raise ValueError(f"pod_basis: n_modes must be a positive integer, got {n_modes!r}")
    U, s = _svd_in_inner(S, inner)
    if s.size == 0 or s[0] <= 0.0:
        raise ValueError("pod_basis: every snapshot is zero; no basis can be extracted")
    rank = int(np.sum(s > rtol_rank * s[0]))
    cum = np.cumsum(s**2) / np.sum(s**2)
    if n_modes is None:
        n, deficient = min(int(np.searchsorted(cum, energy * (1 - 1e-14))) + 1, rank), False
        message = f"{n} modes capture {cum[n - 1]:.6g} of the energy (criterion {energy:g}; rank {rank})"
    else:
        n, deficient = min(int(n_modes), rank), int(n_modes) > rank
        message = (f"rank {rank} < requested {int(n_modes)} modes: {rank} returned" if deficient
                   else f"{n} modes requested, capturing {cum[n - 1]:.6g} of the energy (rank {rank})")
    return PodBasis(np.ascontiguousarray(U[:, :n]), s, float(cum[n - 1]), rank, deficient, message)


# ====================================================================== ROMs
class _PodStatic(RomMethod):
    """Options and offline steps shared by the POD statics ROMs (``mu = {"load_factor": lam}``).

    Parameters
    ----------
    n_modes, energy
        Basis size, see :func:`pod_basis` (``n_modes`` wins when both are given).
    inner : {"euclidean", "mass", "stiffness"}
        Inner product of the POD: identity, consistent mass, or the tangent at u = 0 (free dofs).

    The training needs full-dof ``snapshots`` (n_dof, n_snap), a ``backend``, and (for the
    envelope) ``parameters`` with ``load_factor``. The basis lives on the free dofs; the
    prescribed displacements of the problem (scaled values or motions) are placed on the
    fixed dofs at each step's load factor (the lifting), so the snapshots' free part is the
    POD's input as it stands.
    """

    training_kinds = ("path",)

    def __init__(self, n_modes: int | None = None, energy: float = 0.999, inner: str = "euclidean"):
        if inner not in _INNER:
            raise ValueError(f"{self.name}: inner={inner!r}; valid: {list(_INNER)}")
        if n_modes is not None and (isinstance(n_modes, bool) or int(n_modes) != n_modes or n_modes < 1):
            raise ValueError(f"{self.name}: n_modes must be a positive integer, got {n_modes!r}")
        self.n_modes, self.energy, self.inner = n_modes, energy, inner

    def _basis(self, training: Training):
        if training.snapshots is None or training.backend is None:
            raise ValueError(f"{self.name}: training needs snapshots and a backend")
        be, free = training.backend, np.asarray(training.free_dofs)
        if training.snapshots.shape[0] != be.ndof:
            raise ValueError(f"{self.name}: snapshots have {training.snapshots.shape[0]} rows, "
                             f"the backend {be.ndof} dofs")
        W = None
        if self.inner == "mass":
            W = be.mass()[free][:, free]
        elif self.inner == "stiffness":  # the tangent at the origin: the energy norm of the linearised model
            W = be.tangent(np.zeros(be.ndof))[free][:, free]
        return pod_basis(training.snapshots[free], self.energy, self.n_modes, W), free

    @staticmethod
    def _envelope(training: Training) -> dict:
        lams = [p["load_factor"] for p in (training.parameters or []) if "load_factor" in p]
        return {"load_factor": (float(min(lams)), float(max(lams)))} if lams else {}


class _PodOnline(LinearReconstruction, OnlineModel):
    """Reduced state ``q`` on a POD basis of the free dofs; ``u[free] = Phi q``, ``u[fixed] = u_D(lam)``."""

    def __init__(self, name, pod: PodBasis, free, backend, envelope):
        self.name, self.pod, self.free_dofs, self.backend = name, pod, free, backend
        self.basis, self.ndof, self._envelope = pod.modes, backend.ndof, envelope
        self.problem = backend.problem

    @property
    def Phi(self) -> np.ndarray:
        return self.basis

    @property
    def free(self) -> np.ndarray:
        return self.free_dofs

    @property
    def n_reduced(self) -> int:
        return self.basis.shape[1]

    @property
    def envelope(self) -> dict:
        return dict(self._envelope)

    def _status(self, lam) -> tuple[str, str]:
        """(status, message) of load factor ``lam`` against the training envelope."""
        lo, hi = self._envelope.get("load_factor", (-np.inf, np.inf))
        tol = 1e-12 * max(1.0, abs(lo), abs(hi))
        if lo - tol <= lam <= hi + tol:
            return "ok", ""
        return "extrapolation", f"load factor {lam:.6g} outside the training envelope [{lo:.6g}, {hi:.6g}]"

    def _full(self, q, lam) -> np.ndarray:
        return self.reconstruct(StepResult(q, mu={"load_factor": lam}))


@register
class PodLinear(_PodStatic):
    """Linear POD-Galerkin model with the tangent at the origin (paper eq. 13).

    ``Phi^T K_ff Phi q = Phi^T (f(lam) - K_fc u_D(lam))``: the reduced right-hand side of
    the load and of the prescribed values (scaled linearly, or a motion evaluated at
    ``lam`` on the fixed dofs: an O(n_fixed m) product) is solved by a Cholesky factor
    computed offline.
    """

    name = "pod_linear"
    kind = "map"
    applies = Applies(dead_loads=True, linear_model=True)

    def build(self, training: Training) -> OnlineModel:
        basis, free = self._basis(training)
        be = training.backend
        u0 = np.zeros(be.ndof)
        if be.external_tangent(u0, 1.0) is not None:
            raise ValueError("pod_linear: follower loads are not supported (dead loads only)")
        Phi = basis.modes
        K = be.tangent(u0)
        K_r = Phi.T @ (K[free][:, free] @ Phi)
        f_r = Phi.T @ be.external_force(u0, 1.0)[free]
        model = _PodLinearOnline(self.name, basis, free, be, self._envelope(training))
        fixed = be.problem.fixed_dofs
        model._K_rc = np.asarray((K[free][:, fixed].T @ Phi).T) if len(fixed) else None
        # K_r is SPD for a stable reference state; LU is the fallback (e.g. a singular-ish K_r)
        try:
            model._factor, solve = sla.cho_factor(K_r), sla.cho_solve
        except np.linalg.LinAlgError:
            model._factor, solve = sla.lu_factor(K_r), sla.lu_solve
        model._solve = lambda factor, b: solve(factor, b, check_finite=False)
        model.K_r, model.f_r = K_r, f_r
        model._q1 = model._solve(model._factor, f_r)
        model._prepare()
        return model


class _PodLinearOnline(_PodOnline):

    def _prepare(self):
        """Offline: the step as ``q = lam a + b`` when the prescribed values are affine in the
        load factor (:meth:`prescribed_affine`; ``a = K_r^-1 (f_r - K_rc v1)``, ``b = -K_r^-1 K_rc v0``,
        b None when zero), else None (a motion: its share is solved per step)."""
        lo, hi = self._envelope.get("load_factor", (-np.inf, np.inf))
        tol = 1e-12 * max(1.0, abs(lo), abs(hi))
        self._ok = (lo - tol, hi + tol)
        self._affine = None
        aff = self.prescribed_affine() if self._K_rc is not None else (None, None)
        if aff is None:
            return
        a, b = self._q1, None
        if self._K_rc is not None:
            v0, v1 = aff
            if np.any(v1 != 0.0):
                a = a - self._solve(self._factor, self._K_rc @ v1)
            if np.any(v0 != 0.0):
                b = -self._solve(self._factor, self._K_rc @ v0)
        self._affine = (np.ascontiguousarray(a), b)

    def step(self, mu) -> StepResult:
        """``q = lam K_r^{-1} f_r`` (+ the prescribed values' share, solved with the offline factor)."""
        lam = parameter(mu, "load_factor", self.name)
        if self._affine is not None:
            a, b = self._affine
            q = a * lam
            if b is not None:
                q += b
        else:
            q = lam * self._q1
            values = self.prescribed({"load_factor": lam})[1]
            if np.any(values != 0.0):
                q = q - self._solve(self._factor, self._K_rc @ values)
        lo, hi = self._ok
        if lo <= lam <= hi:
            return StepResult(q, "ok", "", {}, mu)
        return StepResult(q, *self._status(lam), mu={"load_factor": lam})

    def floor_ops(self):
        """``q = lam a (+ b)`` and the outputs' product (with the prescribed values' share)."""
        a, b = self._affine if self._affine is not None else (self._q1, None)
        names, _, C_r, fixed_part = getattr(self, "_outputs", ((), None, None, None))
        lam, q = 0.5, np.empty_like(a)
        y = np.empty(0 if C_r is None else C_r.shape[0])
        c0, c1 = fixed_part if type(fixed_part) is tuple else (None, None)

        def floor():
            np.multiply(a, lam, out=q)
            if b is not None:
                q.__iadd__(b)
            if C_r is not None:
                np.dot(C_r, q, out=y)
                if c0 is not None:
                    y.__iadd__(c0 + lam * c1)
        return floor


@register
class PodNewton(_PodStatic):
    """Reduced Newton: ``Phi^T (f_int(u) - f_ext(u, lam))[free] = 0``, ``u = lift(lam) + Phi q``, full assembly.

    Extra options: ``rtol`` (on ``|r_q| / max(|f_ext|, |reaction on the fixed dofs|)``) and
    ``max_iterations``. Each step starts from the last converged ``q`` (``start()``: zero).
    Follower loads enter the reduced tangent through ``external_tangent``.
    """

    name = "pod_newton"
    kind = "path"
    applies = Applies()  # the default, declared: any finite-element scene (the full residual, any load)

    def __init__(self, n_modes=None, energy=0.999, inner="euclidean", rtol: float = 1e-10,
                 max_iterations: int = 25):
        super().__init__(n_modes, energy, inner)
        if not (rtol > 0 and max_iterations >= 1):
            raise ValueError(f"pod_newton: rtol > 0 and max_iterations >= 1 required, got {rtol!r}, {max_iterations!r}")
        self.rtol, self.max_iterations = float(rtol), int(max_iterations)

    def build(self, training: Training) -> OnlineModel:
        basis, free = self._basis(training)
        be = training.backend
        model = _PodNewtonOnline(self.name, basis, free, be, self._envelope(training))
        model.rtol, model.max_iterations = self.rtol, self.max_iterations
        f1 = be.external_force(np.zeros(be.ndof), 1.0)[free]
        # absolute floor of the tolerance, so that lam = 0 (zero load) converges at q = 0, and
        # never below the reduced residual's round-off floor (as the full Newton's,
        # refsolvers.newton): eps x the reduced nodal forces of a unit dilation. A load tiny
        # against the body's stiffness (a path's near-rest point, 1/5120 of its load, on the
        # mean-dilatation cornea) has a residual that stalls there, above rtol x its load
        model._atol = max(1e-14 * max(float(np.linalg.norm(basis.modes.T @ f1)), 1e-300),
                          _round_off_floor(be, basis.modes, free))
        return model


def _round_off_floor(backend, modes, free) -> float:
    """``ROUND_OFF_FACTOR`` x eps x ``||Phi^T (K_0 X)_free||``: the reduced residual of the nodal
    forces of a unit dilation ``X`` about the body's centre (:meth:`refsolvers.newton` 's floor,
    projected on the basis)."""
    K0 = backend.tangent(np.zeros(backend.ndof))
    X = unit_dilation(backend.problem.nodes, backend.ndof)
    return ROUND_OFF_FACTOR * np.finfo(float).eps * scaled_norm(modes.T @ (K0 @ X)[free])


class _PodNewtonOnline(_PodOnline):
    kind = "path"

    def __init__(self, *args):
        super().__init__(*args)
        self.start()

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Forget the warm start (next step starts from q = 0)."""
        self._q, self._lam = np.zeros(self.n_reduced), 0.0

    def _residual_and_tangent(self, q, lam):
        be, free, Phi = self.backend, self.free_dofs, self.basis
        u = self._full(q, lam)
        f_int, K = be.internal_force_and_tangent(u)
        f_ext = be.external_force(u, lam)
        K_ext = be.external_tangent(u, lam)
        if K_ext is not None:  # follower loads: K = K_t - d f_ext / du
            K = K - K_ext
        r = Phi.T @ (f_int - f_ext)[free]
        # the force scale of the residual: the applied load or, for a motion imposed through
        # Dirichlet data (no load at all), the reaction it takes (as the full Newton does)
        scale = max(np.linalg.norm(f_ext), np.linalg.norm(f_int[self.problem.fixed_dofs]))
        return r, Phi.T @ (K[free][:, free] @ Phi), scale

    def floor_ops(self):
        """One Newton iteration: the full internal force and tangent at the last converged state
        (a state the model reached: q = 0 at the envelope's end can be a tangled configuration
        when the load is a prescribed motion, e.g. the cube's 90 degree twist), their projection
        and the reduced solve (a step needs at least one; it takes a few)."""

        def floor():
            r, K_r, _ = self._residual_and_tangent(self._q, self._lam)
            np.linalg.solve(K_r, r)
        return floor

    def step(self, mu) -> StepResult:
        """Newton iterations on ``q`` from the last converged state; ``failed`` if they do not converge."""
        lam = float(check_parameters(mu, ("load_factor",), self.name)["load_factor"])
        q = self._q.copy()
        norms = []
        for it in range(self.max_iterations + 1):
            r, K_r, scale = self._residual_and_tangent(q, lam)
            norms.append(float(np.linalg.norm(r)))
            msg = f"residual {norms[-1]:.3e}"
            if not np.isfinite(norms[-1]):
                break
            if norms[-1] <= self.rtol * scale + self._atol:
                self._q, self._lam = q, lam
                return StepResult(q.copy(), *self._status(lam), info={"iterations": it, "residual_norms": norms},
                                  mu={"load_factor": lam})
            if it == self.max_iterations:
                break
            try:
                q = q - np.linalg.solve(K_r, r)
            except np.linalg.LinAlgError:
                break
        return StepResult(None, "failed", f"{self.name}: no convergence at load factor {lam:g} in "
                          f"{len(norms) - 1} iterations ({msg})",
                          info={"iterations": len(norms) - 1, "residual_norms": norms}, mu={"load_factor": lam})
