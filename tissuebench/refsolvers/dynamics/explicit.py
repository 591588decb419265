"""Explicit schemes: central difference (lumped mass) and forward Euler.

Central difference is written in the half-step velocity form (Belytschko et al.,
"Nonlinear finite elements", box 6.1)::

    v_{n+1/2} = v_n + dt/2 a_n
    u_{n+1}   = u_n + dt v_{n+1/2}
    a_{n+1}   = M_L^{-1} [f_ext(t_{n+1}) - f_int(u_{n+1}) - C v_{n+1/2}]
    v_{n+1}   = v_{n+1/2} + dt/2 a_{n+1}

identical to ``u_{n+1} - 2 u_n + u_{n-1} = dt^2 a_n`` without damping. The scheme's
damping matrix is C_L = alpha_m M_L + beta_k K0. With mass-proportional damping only
(beta_k = 0) C_L is diagonal and the damping force uses v_{n+1} (a diagonal solve,
second order); with beta_k > 0 it uses the lagged v_{n+1/2} (no solve, first order in
the damping term). Stable for dt <= dt_cr = 2 / omega_max
(undamped), omega_max^2 the largest eigenvalue of (K0, M_L) on the free dofs.

A prescribed motion of the fixed dofs (see :mod:`.system`) needs the lumped mass (no
inertial coupling ``M_fc``); the fixed dofs' velocity is the difference quotient
``(u_c,n+1 - u_c,n) / dt`` (kinetic energy and support work of the energy balance). One
lumped mass and damping (:class:`LumpedOperators`) serve the starting acceleration, the
steps and the energy bookkeeping alike, so the balance's error shrinks with dt (first
order with a moving support: the quotient is a backward difference).
"""
from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .base import Integrator, StepReport
from .system import DENSE_LIMIT


def lumped_mass(M) -> np.ndarray:
    """Row-sum lumped diagonal of M, shape (n,) [kg]; refuses non-positive entries."""
    d = np.asarray(sp.csr_matrix(M).sum(axis=1)).ravel()
    if np.any(d <= 0):
        i = int(np.flatnonzero(d <= 0)[0])
        raise ValueError(f"lumped mass: row sum {i} is {float(d[i])!r} <= 0; the mass cannot be lumped")
    return d


def max_frequency(K, m_diag) -> float:
    """Largest omega [rad/s] of K phi = omega^2 diag(m) phi (K symmetric, (n, n))."""
    s = 1.0 / np.sqrt(m_diag)
    A = sp.diags(s) @ sp.csr_matrix(K) @ sp.diags(s)
    A = 0.5 * (A + A.T)
    if A.shape[0] <= DENSE_LIMIT:
        lam = sla.eigvalsh(A.toarray(), subset_by_index=[A.shape[0] - 1, A.shape[0] - 1])[0]
    else:
        lam = spla.eigsh(A, k=1, which="LA", tol=1e-8, return_eigenvectors=False)[0]
    return float(np.sqrt(max(lam, 0.0)))


def critical_time_step(system) -> float:
    """dt_cr [s] of central difference on ``system`` with its row-sum lumped mass.

    Undamped: 2 / omega_max; with Rayleigh damping the usual estimate
    (2 / omega_max) (sqrt(1 + xi^2) - xi), xi = alpha_m / (2 omega) + beta_k omega / 2.
    The tangent at u = 0 is used: a stiffening nonlinear system lowers the true limit.
    """
    w = max_frequency(system.K0_ff, lumped_mass(system.M_ff))
    if w == 0:
        return float("inf")
    xi = 0.5 * system.alpha_m / w + 0.5 * system.beta_k * w
    return float(2.0 / w * (np.sqrt(1.0 + xi * xi) - xi))


class LumpedOperators:
    """The mass and damping of a lumped scheme on a system, one set for every use.

    ``M_L`` is diagonal: on the free dofs the row sums of ``M_ff`` (the mass the steps
    use, :func:`lumped_mass`), on the fixed dofs the row sums of ``M_cc``; the
    free-fixed blocks ``M_fc`` are dropped, so a prescribed acceleration exerts no
    inertial force on the free dofs. The damping is ``C_L = alpha_m M_L + beta_k K0``, so
    its free-fixed block is ``beta_k K0_fc``. The starting acceleration, the steps, the
    kinetic energy, the dissipation and the support forces of the energy balance all use
    these (a second mass in any of them leaves an energy error that does not shrink with dt).
    """

    def __init__(self, system):
        self.system = system
        self.m = lumped_mass(system.M_ff)
        fixed = system.fixed
        self.m_full = np.zeros(system.n)
        self.m_full[system.free] = self.m
        # the fixed dofs' own block (a massless or negative row is allowed: only the energy uses it)
        self.m_full[fixed] = np.asarray(sp.csr_matrix(system.M)[fixed][:, fixed].sum(axis=1)).ravel()

    @property
    def mass_ff(self) -> sp.dia_matrix:
        return sp.diags(self.m)

    @property
    def mass_full(self) -> sp.dia_matrix:
        return sp.diags(self.m_full)

    @cached_property
    def damping_full(self) -> sp.csr_matrix | None:
        """C_L on all dofs [N s/m], None undamped."""
        sys = self.system
        if not sys.damped:
            return None
        K0 = sp.csr_matrix(sys.tangent(np.zeros(sys.n)))
        return sp.csr_matrix(sys.alpha_m * sp.diags(self.m_full) + sys.beta_k * K0)

    def damping_force(self, v):
        """C_L v [N] on the free dofs."""
        sys = self.system
        if not sys.damped:
            return np.zeros_like(v)
        out = sys.alpha_m * self.m * v
        return out + sys.beta_k * (sys.K0_ff @ v) if sys.beta_k else out

    def coupling_force(self, v_c, a_c):
        """C_L,fc v_c = beta_k K0_fc v_c [N] on the free rows: M_L has no M_fc, so a_c exerts none."""
        sys = self.system
        if not (sys.has_prescribed and sys.beta_k):
            return 0.0
        return sys.beta_k * (sys.K0_fc @ v_c)


class CentralDifference(Integrator):
    """Explicit central difference with the row-sum lumped mass (:class:`LumpedOperators`).

    Parameters
    ----------
    force : bool
        Accept dt > dt_cr (for demonstrating instability); the run then reports
        ``"blow_up"`` when the energy explodes.
    """

    name = "central_difference"

    def __init__(self, force=False):
        super().__init__()
        self.force = bool(force)
        self.dt_critical = None

    @property
    def mass_ff(self):
        return self._lumped.mass_ff

    @property
    def mass_full(self):
        return self._lumped.mass_full

    @property
    def damping_full(self):
        return self._lumped.damping_full

    def _setup(self):
        self._lumped = LumpedOperators(self.system)
        self._m = self._lumped.m
        self.dt_critical = critical_time_step(self.system)
        if self.dt > self.dt_critical and not self.force:
            raise ValueError(f"dt = {self.dt!r} exceeds the critical time step dt_cr = "
                             f"{self.dt_critical!r} of central difference; pass force=True to run anyway")

    def solve_mass(self, rhs):
        return rhs / self._m

    def damping_force(self, v):
        """C_L v [N] with the scheme's damping matrix (lumped mass part)."""
        return self._lumped.damping_force(v)

    def coupling_force(self, v_c, a_c):
        return self._lumped.coupling_force(v_c, a_c)

    def _advance(self):
        sys, dt = self.system, self.dt
        v_half = self.v + 0.5 * dt * self.a
        u1 = self.u + dt * v_half
        t1 = self.t + dt
        if not np.all(np.isfinite(u1)):
            return StepReport(False, 0, f"non-finite displacement at t={t1:.6g}")
        uc1, vc1, ac1 = _prescribed_step(self, t1)
        f_ext, f_int = sys.f_ext(t1, u1, uc1), sys.f_int(u1, uc1)
        if sys.beta_k == 0:
            # diagonal C_L = alpha_m M_L (no coupling to v_c either): (M_L + dt/2 C_L) a1 = f - f_int - C_L v_half
            c = sys.alpha_m * self._m
            a1 = (f_ext - f_int - c * v_half) / (self._m + 0.5 * dt * c)
        else:
            a1 = (f_ext - f_int - self.coupling_force(vc1, ac1) - self.damping_force(v_half)) / self._m
        return StepReport(), (t1, u1, v_half + 0.5 * dt * a1, a1, f_ext, f_int, uc1, vc1, ac1)


def _prescribed_step(integ, t1):
    """(u_c, v_c, a_c) of the fixed dofs at t1 by difference quotients (explicit schemes)."""
    sys = integ.system
    if not sys.has_prescribed:
        return integ.uc, integ.vc, integ.ac
    uc1 = sys.prescribed_values(t1)
    vc1 = (uc1 - integ.uc) / integ.dt
    return uc1, vc1, (vc1 - integ.vc) / integ.dt


class ForwardEuler(Integrator):
    """Forward Euler on the first-order form (u, v)::

        u_{n+1} = u_n + dt v_n,   v_{n+1} = v_n + dt a_n,   M a_n = f_ext_n - f_int(u_n) - C v_n

    First order and unconditionally unstable on an undamped oscillator (amplification
    sqrt(1 + (omega dt)^2) per step): the growth is reported by ``integrate`` through
    ``energy_growth_ratio`` and status ``"energy_growth"`` (default tolerance 1e-3).
    ``lumped=True`` uses the row-sum lumped mass instead of the system's.
    """

    name = "forward_euler"
    order = 1
    growth_tol = 1e-3

    def __init__(self, lumped=False):
        super().__init__()
        self.lumped = bool(lumped)

    def _setup(self):
        self._lumped = LumpedOperators(self.system) if self.lumped else None

    @property
    def mass_ff(self):
        return self._lumped.mass_ff if self.lumped else self.system.M_ff

    @property
    def mass_full(self):
        return self._lumped.mass_full if self.lumped else self.system.M

    @property
    def damping_full(self):
        return self._lumped.damping_full if self.lumped else self.system.C_full

    def damping_force(self, v):
        """C v [N] on the free dofs: the lumped C_L with ``lumped=True``, the system's otherwise."""
        return self._lumped.damping_force(v) if self.lumped else self.system.damping_force(v)

    def coupling_force(self, v_c, a_c):
        return self._lumped.coupling_force(v_c, a_c) if self.lumped else self.system.coupling_force(v_c, a_c)

    def _check_prescribed_support(self):
        if self.system.has_prescribed and not self.lumped:
            raise ValueError("forward_euler: a prescribed motion needs lumped=True (the consistent mass "
                             "couples the free dofs to the prescribed acceleration)")

    def _advance(self):
        sys, dt = self.system, self.dt
        t1 = self.t + dt
        u1 = self.u + dt * self.v
        v1 = self.v + dt * self.a
        if not (np.all(np.isfinite(u1)) and np.all(np.isfinite(v1))):
            return StepReport(False, 0, f"non-finite state at t={t1:.6g}")
        uc1, vc1, ac1 = _prescribed_step(self, t1)
        f_ext, f_int = sys.f_ext(t1, u1, uc1), sys.f_int(u1, uc1)
        a1 = self.solve_mass(f_ext - f_int - self.damping_force(v1) - self.coupling_force(vc1, ac1))
        return StepReport(), (t1, u1, v1, a1, f_ext, f_int, uc1, vc1, ac1)
