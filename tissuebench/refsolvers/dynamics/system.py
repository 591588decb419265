"""The semi-discrete system ``M a + C v + f_int(u) = f_ext(t, u)`` the integrators march.

A :class:`SecondOrderSystem` is all an integrator sees: it never imports a backend.
Operators act on the full dof vector (length ``n``); dofs outside ``free`` (the
``fixed`` dofs) are held at zero, or follow a prescribed motion ``prescribed(t)``
(non-homogeneous Dirichlet conditions). The ``*_ff`` helpers restrict everything to
the free dofs, which is where the integrators work; ``*_fc`` blocks couple the free
rows to the prescribed motion (inertia ``M_fc a_c`` and damping ``C_fc v_c``).

Prescribed motion: the integrators impose ``u_c = prescribed(t_{n+1})`` and derive the
velocity and acceleration of the fixed dofs with their own kinematic relations (as if
the scheme ran on all dofs with the fixed rows replaced by ``u_c = g(t)``), so a velocity
jump at t0 acts as the impulse ``M_fc (v_c1 - v_c0)`` it is. The energy balance then
counts the work of the support forces ``R_c = [M a + C v + f_int]_c`` on the prescribed
displacements (``DynamicsResult.reaction_work``).

Units are whatever the caller uses consistently (SI in the cases: m, kg, s, N).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Callable

import numpy as np
import scipy.sparse as sp

from ..newton import ROUND_OFF_FACTOR, scaled_norm, unit_dilation
from .checks import DENSE_LIMIT, check_spd_mass, check_vector  # noqa: F401  (re-exported)


def _constant_load(f):
    f = np.asarray(f, dtype=float).copy()
    return lambda t: f


@dataclass
class SecondOrderSystem:
    """``M a + C v + f_int(u) = f_ext(t, u)`` with ``C = alpha_m M + beta_k K0``.

    Parameters
    ----------
    M : scipy.sparse matrix, (n, n)
        Mass matrix [kg]; symmetric positive definite on the free dofs.
    internal_force : callable ``u -> (n,)``
        Internal force [N] at displacement ``u`` [m], shape (n,).
    tangent : callable ``u -> sparse (n, n)``
        d internal_force / du [N/m].
    load : callable
        ``load(t) -> (n,)`` external force [N] at time ``t`` [s]; with
        ``load_depends_on_u=True`` it is called as ``load(t, u)`` (follower loads).
    free : int array, optional
        Free dof indices; the others are held at zero. Default: all dofs.
    alpha_m, beta_k : float
        Rayleigh coefficients [1/s] and [s]; K0 is the tangent at ``u = 0``.
    linear : bool
        True when ``f_int = K u`` with constant K: effective matrices are factorised
        once and each step is one linear solve.
    strain_energy : callable ``u -> float``, optional
        Stored energy [J]; for linear systems 0.5 u^T K u is used when omitted, for
        nonlinear ones the internal work is accumulated by the trapezoidal rule.
    load_tangent : callable ``(t, u) -> sparse (n, n) | None``, optional
        d load / du for follower loads.
    prescribed : callable ``t -> (n_fixed,)``, optional
        Displacements [m] of the fixed dofs (in the order of :attr:`fixed`) at time ``t``
        [s]; None holds them at zero.
    unit_strain : (n,) array, optional
        The displacement [m] of a unit dilation (the nodes' coordinates about their centre);
        it sets the :attr:`round_off_floor` of a nonlinear system's residual.
    """

    M: sp.spmatrix
    internal_force: Callable
    tangent: Callable
    load: Callable
    free: np.ndarray | None = None
    alpha_m: float = 0.0
    beta_k: float = 0.0
    linear: bool = False
    strain_energy: Callable | None = None
    load_depends_on_u: bool = False
    load_tangent: Callable | None = None
    prescribed: Callable | None = None
    unit_strain: np.ndarray | None = None

    def __post_init__(self):
        if not sp.issparse(self.M):
            self.M = sp.csr_matrix(np.atleast_2d(np.asarray(self.M, dtype=float)))
        self.M = sp.csr_matrix(self.M, dtype=float)
        if self.M.ndim != 2 or self.M.shape[0] != self.M.shape[1]:
            raise ValueError(f"M must be square, got shape {self.M.shape}")
        n = self.M.shape[0]
        free = np.arange(n) if self.free is None else np.unique(np.asarray(self.free, dtype=np.int64))
        if free.size and (free.min() < 0 or free.max() >= n):
            raise ValueError(f"free: dof index out of range 0..{n - 1}")
        self.free = free
        for name in ("alpha_m", "beta_k"):
            val = float(getattr(self, name))
            setattr(self, name, val)
            if not np.isfinite(val) or val < 0:
                raise ValueError(f"{name} must be finite and >= 0, got {val!r}")
        if not callable(self.load):
            self.load = _constant_load(check_vector("load", self.load, n))
        if self.prescribed is not None and not callable(self.prescribed):
            raise TypeError(f"prescribed must be a callable t -> (n_fixed,), got {type(self.prescribed).__name__}")
        if self.unit_strain is not None:
            self.unit_strain = check_vector("unit_strain", self.unit_strain, n).copy()
        check_spd_mass(self.M_ff)

    # ---------------------------------------------------------------- constructors
    @classmethod
    def linear_system(cls, M, K, load, free=None, alpha_m=0.0, beta_k=0.0, **fields):
        """``M a + C v + K u = load(t)``; ``load`` is a callable of t or a constant (n,) vector;
        ``fields``: the other fields of the system (``load_depends_on_u``, ``prescribed`` ...)."""
        K = sp.csr_matrix(K, dtype=float)
        n = sp.csr_matrix(M).shape[0]
        if K.shape != (n, n):
            raise ValueError(f"K must have shape ({n}, {n}) like M, got {K.shape}")
        return cls(M=M, internal_force=lambda u: K @ u, tangent=lambda u: K, load=load, free=free,
                   alpha_m=alpha_m, beta_k=beta_k, linear=True,
                   strain_energy=lambda u: 0.5 * float(u @ (K @ u)), **fields)

    @classmethod
    def from_backend(cls, backend, load_history: Callable[[float], float], lumped=False,
                     alpha_m=0.0, beta_k=0.0, linear=False):
        """A system from a finite-element backend (any object with the Backend interface).

        With ``linear=True`` the internal force is ``K u`` with ``K`` the backend's tangent at
        ``u = 0`` assembled once (a linear material's force is exactly that).
        The force at time t is ``backend.external_force(u, load_history(t))`` (follower
        loads allowed); ``problem.fixed_dofs`` follow ``problem.prescribed_values(
        load_history(t))`` (prescribed translations and rotations of the Dirichlet sets),
        or are held at zero when every Dirichlet set is homogeneous.
        """
        problem = backend.problem
        lam0 = float(load_history(0.0))
        prescribed = _prescribed_motion(problem, load_history)

        if linear and backend.external_tangent(np.zeros(problem.ndof), lam0) is not None:
            raise ValueError("from_backend: linear=True needs dead loads (external_tangent is not None, "
                             "the effective matrix would not be constant)")

        def ext_tangent(t, u):
            return backend.external_tangent(u, float(load_history(t)))

        M = backend.mass(lumped=lumped)

        def load(t, u):
            return backend.external_force(u, float(load_history(t)))
        coupling = dict(load_depends_on_u=True, load_tangent=ext_tangent, prescribed=prescribed)
        if linear:  # f_int = K u with K assembled once: a product per call instead of an element loop
            K = backend.tangent(np.zeros(problem.ndof))
            return cls.linear_system(M, K, load, free=problem.free_dofs, alpha_m=alpha_m, beta_k=beta_k, **coupling)
        return cls(M=M, internal_force=backend.internal_force, tangent=backend.tangent, load=load,
                   free=problem.free_dofs, alpha_m=alpha_m, beta_k=beta_k, strain_energy=backend.strain_energy,
                   unit_strain=_unit_strain(problem), **coupling)

    # ---------------------------------------------------------------- free-dof operators
    @property
    def n(self) -> int:
        """Number of dofs of the full vector."""
        return self.M.shape[0]

    @cached_property
    def fixed(self) -> np.ndarray:
        """The constrained dofs (sorted): held at zero or following :attr:`prescribed`."""
        return np.setdiff1d(np.arange(self.n), self.free)

    @property
    def has_prescribed(self) -> bool:
        return self.prescribed is not None and len(self.fixed) > 0

    def prescribed_values(self, t: float) -> np.ndarray:
        """Displacements of the fixed dofs at ``t`` (zeros without a prescribed motion)."""
        if not self.has_prescribed:
            return np.zeros(len(self.fixed))
        return check_vector(f"prescribed(t) at t={t!r}", self.prescribed(float(t)), len(self.fixed))

    def _fc(self, A) -> sp.csr_matrix:
        return sp.csr_matrix(A)[self.free][:, self.fixed]

    @cached_property
    def round_off_floor(self) -> float:
        """The residual norm [N] below which round-off hides the equilibrium of a nonlinear
        system, as in statics (:meth:`tissuebench.refsolvers.newton._Equilibrium.round_off_floor`):
        ``ROUND_OFF_FACTOR`` x eps x ``||K0_f X||``, the free rows of the tangent at rest times
        :attr:`unit_strain` (the nodal forces of a strain of 1). Its stresses are sums of terms
        of that size that cancel near the reference state, so their round-off does not shrink
        with the load. 0.0 for a linear system (``K u`` shrinks with u) or without ``unit_strain``."""
        if self.linear or self.unit_strain is None:
            return 0.0
        K_f = sp.csr_matrix(self.tangent(np.zeros(self.n)))[self.free]
        return ROUND_OFF_FACTOR * float(np.finfo(float).eps) * scaled_norm(K_f @ self.unit_strain)

    @cached_property
    def M_fc(self) -> sp.csr_matrix:
        return self._fc(self.M)

    @cached_property
    def K0_fc(self) -> sp.csr_matrix:
        """Tangent at u = 0, free rows and fixed columns (Rayleigh damping coupling)."""
        return self._fc(self.tangent(np.zeros(self.n)))

    @cached_property
    def C_fc(self) -> sp.csr_matrix | None:
        if not self.damped:
            return None
        return sp.csr_matrix(self.alpha_m * self.M_fc + self.beta_k * self.K0_fc)

    @cached_property
    def C_full(self) -> sp.csr_matrix | None:
        if not self.damped:
            return None
        return sp.csr_matrix(self.alpha_m * self.M + self.beta_k * sp.csr_matrix(self.tangent(np.zeros(self.n))))

    def mass_coupling(self, a_c) -> np.ndarray | float:
        """``M_fc a_c`` on the free rows [N] (0.0 without a prescribed motion)."""
        return self.M_fc @ a_c if self.has_prescribed else 0.0

    def damping_coupling(self, v_c) -> np.ndarray | float:
        """``C_fc v_c`` on the free rows [N] (0.0 without a prescribed motion or damping)."""
        return self.C_fc @ v_c if self.has_prescribed and self.C_fc is not None else 0.0

    def coupling_force(self, v_c, a_c) -> np.ndarray | float:
        """``M_fc a_c + C_fc v_c`` on the free rows [N] (0.0 without a prescribed motion)."""
        return self.mass_coupling(a_c) + self.damping_coupling(v_c)

    def support_force(self, u_f, u_c, v_full, a_full, mass=None, damping=None) -> np.ndarray:
        """Force the supports and loads apply on the fixed dofs, ``[M a + C v + f_int]_c`` [N].

        ``mass`` and ``damping`` are the full mass and damping matrices the scheme uses
        (default :attr:`M` and :attr:`C_full`; a lumped scheme passes its own, so the
        reaction is the one its steps balance); ``v_full``, ``a_full`` are full vectors (n,).
        """
        M = self.M if mass is None else mass
        C = self.C_full if damping is None else damping
        r = M @ a_full + np.asarray(self.internal_force(self.expand(u_f, u_c)), dtype=float)
        if C is not None:
            r = r + C @ v_full
        return r[self.fixed]

    def reactions(self, t, u, v, a, mass=None, damping=None) -> np.ndarray:
        """The forces the supports exert on the body at time ``t`` [s], shape (n,) [N]:
        ``[M a + C v + f_int(u) - f_ext(t, u)]`` on the fixed dofs, zero on the free ones.

        ``u``, ``v``, ``a`` are full vectors (n,) of a dynamic state. The load lumped onto a
        supported dof is the support's to carry, as in statics
        (:meth:`~tissuebench.refsolvers.problem.Problem.support_reactions`, ``f_int - f_ext``
        there, which this is at rest); in motion the supports also carry the inertia and
        damping forces of their rows (``M_cf a_f`` of a consistent mass, ``M_cc a_c`` of a
        moving support). ``mass``, ``damping``: as in :meth:`support_force`.
        """
        u = check_vector("u", u, self.n)
        v, a = check_vector("v", v, self.n), check_vector("a", a, self.n)
        t = float(t)
        f = self.load(t, u) if self.load_depends_on_u else self.load(t)
        f = check_vector(f"load(t) at t={t!r}", f, self.n)
        r = np.zeros(self.n)
        fixed = self.fixed
        r[fixed] = self.support_force(u[self.free], u[fixed], v, a, mass, damping) - f[fixed]
        return r

    @property
    def damped(self) -> bool:
        return self.alpha_m != 0.0 or self.beta_k != 0.0

    def _ff(self, A) -> sp.csr_matrix:
        return sp.csr_matrix(A)[self.free][:, self.free]

    @cached_property
    def M_ff(self) -> sp.csr_matrix:
        return self._ff(self.M)

    @cached_property
    def K0_ff(self) -> sp.csr_matrix:
        """Tangent at u = 0 on the free dofs (Rayleigh damping, critical step)."""
        return self._ff(self.tangent(np.zeros(self.n)))

    @cached_property
    def C_ff(self) -> sp.csr_matrix | None:
        if not self.damped:
            return None
        return sp.csr_matrix(self.alpha_m * self.M_ff + self.beta_k * self.K0_ff)

    def expand(self, x_f: np.ndarray, x_c=None) -> np.ndarray:
        """Full vector (n,) with ``x_f`` on the free dofs and ``x_c`` (default zero) on the fixed ones."""
        x = np.zeros(self.n)
        x[self.free] = x_f
        if x_c is not None and len(self.fixed):
            x[self.fixed] = x_c
        return x

    def f_int(self, u_f, u_c=None):
        """Internal force on the free dofs at ``u_f`` with the fixed dofs at ``u_c`` (default zero)."""
        return np.asarray(self.internal_force(self.expand(u_f, u_c)), dtype=float)[self.free]

    def K_t(self, u_f, t=None, u_c=None) -> sp.csr_matrix:
        """Tangent of ``f_int - f_ext`` on the free dofs (includes follower loads at ``t``)."""
        u = self.expand(u_f, u_c)
        K = self._ff(self.tangent(u))
        if self.load_tangent is not None and t is not None:
            Ke = self.load_tangent(t, u)
            if Ke is not None:
                K = sp.csr_matrix(K - self._ff(Ke))
        return K

    def f_ext(self, t: float, u_f, u_c=None) -> np.ndarray:
        """External force on the free dofs; raises ValueError on a wrong shape or non-finite value."""
        f = self.load(t, self.expand(u_f, u_c)) if self.load_depends_on_u else self.load(t)
        return check_vector(f"load(t) at t={t!r}", f, self.n)[self.free]

    def damping_force(self, v_f):
        return np.zeros_like(v_f) if self.C_ff is None else self.C_ff @ v_f

    def energy(self, u_f, u_c=None) -> float | None:
        """Stored energy [J], or None when the system cannot supply it."""
        if self.strain_energy is None:
            return None
        return float(self.strain_energy(self.expand(u_f, u_c)))


def _unit_strain(problem) -> np.ndarray | None:
    """The displacement of a unit dilation of ``problem``'s nodes about their centre (zero on
    any dof beyond the nodes'), or None for a problem without nodes."""
    nodes = getattr(problem, "nodes", None)
    return None if nodes is None else unit_dilation(nodes, problem.ndof)


def _prescribed_motion(problem, load_history):
    """``t -> values of the fixed dofs (sorted)`` of ``problem`` driven by ``load_history``,
    or None when every Dirichlet set holds its dofs at zero."""
    motions = any(getattr(d, "motion", None) is not None for d in getattr(problem, "dirichlet", ()))
    # without motions the values are affine in the load factor (scaled or constant): zero at 1 is zero always
    if not motions and not np.any(np.asarray(problem.prescribed_values(1.0), dtype=float) != 0):
        return None
    order = np.argsort(problem.fixed_dofs)

    def prescribed(t):
        return np.asarray(problem.prescribed_values(float(load_history(t))), dtype=float)[order]
    return prescribed


class _LinearFlagOrCtor:
    """``SecondOrderSystem.linear(M, K, load, ...)`` on the class builds a linear system
    (alias of :meth:`SecondOrderSystem.linear_system`); ``system.linear`` on an instance
    is the bool field. A data descriptor installed after the dataclass has read the
    field's default, so both spellings of the contract hold."""

    def __get__(self, obj, owner):
        if obj is None:
            return owner.linear_system
        return obj.__dict__.get("linear", False)

    def __set__(self, obj, value):
        obj.__dict__["linear"] = bool(value)


SecondOrderSystem.linear = _LinearFlagOrCtor()
