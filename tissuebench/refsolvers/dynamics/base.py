"""Contract of a time integrator for ``M a + C v + f_int(u) = f_ext(t, u)``.

An integrator is configured with its options (``HHT(alpha=-0.1)``), bound to a
:class:`~tissuebench.refsolvers.dynamics.system.SecondOrderSystem` and an initial
state with :meth:`Integrator.start`, then advanced by :meth:`Integrator.step`, one
fixed step ``dt`` at a time (like SciPy's ``integrate._ivp.base.OdeSolver``).

State after ``start`` / each successful ``step`` (free dofs only, shape (n_free,)):
``t`` [s], ``u`` [m], ``v`` [m/s], ``a`` [m/s^2], plus ``f_ext`` and ``f_int`` [N]
at that state; the fixed dofs carry ``uc``, ``vc``, ``ac`` (shape (n_fixed,)), zero
unless the system prescribes a motion (see :mod:`.system`). A step that fails (Newton
divergence, non-finite values) leaves the state unchanged and says so in its
:class:`StepReport`; it never raises. Bad input (dt <= 0, options out of range, wrong
shapes, a non-finite load) raises ValueError.
"""
from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np
import scipy.sparse as sp

from .report import StepReport
from .step_newton import StepSolver
from .system import SecondOrderSystem, check_vector

__all__ = ["Integrator", "StepReport", "SecondOrderSystem", "check_dt"]


def check_dt(dt) -> float:
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise ValueError(f"dt must be a finite time step > 0, got {dt!r}")
    return dt


class Integrator(ABC):
    """Base class: subclasses implement :meth:`_advance` and may override :meth:`_setup`.

    Class attributes
    ----------------
    name : str
        Registry name.
    implicit : bool
        Whether steps solve (non)linear systems.
    order : int
        Nominal global order of accuracy.
    growth_tol : float or None
        Default tolerance on ``energy_growth_ratio - 1`` above which
        :func:`~tissuebench.refsolvers.dynamics.integrate` reports ``"energy_growth"``
        (None: not checked).
    """

    name = ""
    implicit = False
    order = 2
    growth_tol: float | None = None

    def __init__(self):
        self.system = None

    # ------------------------------------------------------------------ binding
    def start(self, system: SecondOrderSystem, u0=None, v0=None, dt=None, t0=0.0):
        """Bind to ``system`` with full-vector initial state u0, v0 (n,) at time t0 [s].

        Without a prescribed motion the values of u0, v0 on constrained dofs must be zero.
        With one, u0 there must equal ``prescribed(t0)`` (None: it is filled in) and v0
        there is the initial velocity of the prescribed dofs (None: at rest); their
        initial acceleration is zero. The free acceleration comes from the equation of
        motion: M_ff a0 = f_ext(t0) - f_int(u0) - C v0 - M_fc a_c0.
        """
        if not isinstance(system, SecondOrderSystem):
            raise TypeError(f"system must be a SecondOrderSystem, got {type(system).__name__}")
        self.system = system
        self.dt = check_dt(dt)
        t0 = float(t0)
        if not np.isfinite(t0):
            raise ValueError(f"t0 must be finite, got {t0!r}")
        self._check_prescribed_support()
        uc0 = system.prescribed_values(t0)
        u_full = self._initial("u0", u0, uc0)
        v_full = self._initial("v0", v0, None)
        self._setup()
        fixed = system.fixed
        u, v = u_full[system.free], v_full[system.free]
        self.set_state(t0, u, v, None, u_full[fixed], v_full[fixed], np.zeros(len(fixed)))
        return self

    def _check_prescribed_support(self):
        """Hook: refuse a prescribed motion the scheme cannot take (ValueError)."""

    def _initial(self, name, x, expected):
        """Full initial vector; on the fixed dofs ``expected`` (prescribed displacement),
        free (prescribed velocity, ``expected`` None) or zero (no prescribed motion)."""
        sys = self.system
        n, fixed = sys.n, sys.fixed
        if x is None:
            x = np.zeros(n)
            if expected is not None and fixed.size:
                x[fixed] = expected
            return x
        x = check_vector(name, x, n)
        if not fixed.size:
            return x
        if not sys.has_prescribed:
            if np.any(x[fixed] != 0):
                raise ValueError(f"{name} must be zero on the constrained dofs (the system prescribes no "
                                 f"motion), max |{name}| there = {np.abs(x[fixed]).max():.3e}")
        elif expected is not None:
            gap = np.abs(x[fixed] - expected).max()
            if gap > 1e-12 * max(1.0, np.abs(expected).max()):
                raise ValueError(f"{name} on the constrained dofs differs from the prescribed displacement at t0 "
                                 f"by {gap:.3e}")
        return x

    def full(self, x_f, x_c) -> np.ndarray:
        """Full vector (n,) from free and fixed parts."""
        return self.system.expand(x_f, x_c)

    def full_u(self) -> np.ndarray:
        """Current displacement on all dofs (prescribed values included)."""
        return self.system.expand(self.u, self.uc)

    @property
    def mass_full(self) -> sp.csr_matrix:
        """The mass the scheme uses on all dofs (kinetic energy with a prescribed motion)."""
        return self.system.M

    @property
    def damping_full(self) -> sp.csr_matrix | None:
        """The damping matrix the scheme uses on all dofs (None undamped): the dissipation
        and the support forces of the energy balance with a prescribed motion."""
        return self.system.C_full

    def coupling_force(self, v_c, a_c):
        """``M_fc a_c + C_fc v_c`` [N] on the free rows with the scheme's mass and damping
        (0.0 without a prescribed motion)."""
        return self.system.coupling_force(v_c, a_c)

    def _constrained_kinematics(self, uc1, kin):
        """(v_c1, a_c1) of the fixed dofs at ``uc1`` by the scheme's kinematics ``kin``
        (zero when nothing is prescribed)."""
        if not self.system.has_prescribed:
            return self.vc, self.ac
        return kin(uc1)
    @property
    def mass_ff(self) -> sp.csr_matrix:
        """The mass matrix the scheme uses on the free dofs (lumped for explicit schemes)."""
        return self.system.M_ff

    def damping_force(self, v):
        """C v [N] with the damping matrix the scheme uses (free dofs)."""
        return self.system.damping_force(v)

    def _setup(self):
        """Hook: factorisations and step-size checks once ``system`` and ``dt`` are known."""

    def prime(self) -> None:
        """Hook: do now the work the next step would do first and that does not change its
        numbers (an implicit scheme's first Newton matrix), so that the step costs what the
        steps after it do. Called by a caller that times steps, after :meth:`start`; nothing here."""

    def solve_mass(self, rhs):
        """M_ff^{-1} rhs with a factorisation computed once per system."""
        if getattr(self, "_mass_lu", None) is None or self._mass_lu[0] is not self.system:
            self._mass_lu = (self.system, StepSolver("auto"))
        return self._mass_lu[1].solve_cached("mass", lambda: self.mass_ff, rhs)

    def set_state(self, t, u, v, a=None, uc=None, vc=None, ac=None):
        """Set the free-dof state; ``a=None`` computes it from the equation of motion.

        ``uc``, ``vc``, ``ac``: state of the fixed dofs (default: ``prescribed(t)``, rest).
        """
        sys = self.system
        nf, nc = len(sys.free), len(sys.fixed)
        self.t = float(t)
        self.u = check_vector("u", u, nf).copy()
        self.v = check_vector("v", v, nf).copy()
        self.uc = sys.prescribed_values(self.t) if uc is None else check_vector("uc", uc, nc).copy()
        self.vc = np.zeros(nc) if vc is None else check_vector("vc", vc, nc).copy()
        self.ac = np.zeros(nc) if ac is None else check_vector("ac", ac, nc).copy()
        self.f_ext = sys.f_ext(self.t, self.u, self.uc)
        self.f_int = sys.f_int(self.u, self.uc)
        if a is None:
            a = self.solve_mass(self.f_ext - self.f_int - self.damping_force(self.v)
                                - self.coupling_force(self.vc, self.ac))
        self.a = check_vector("a", a, nf).copy()

    # ------------------------------------------------------------------ stepping
    def step(self) -> StepReport:
        """Advance one step of size ``dt``; on failure the state is left unchanged."""
        if self.system is None:
            raise RuntimeError("call start(system, u0, v0, dt) before step()")
        with np.errstate(over="ignore", invalid="ignore"):
            out = self._advance()
        report, new = out if isinstance(out, tuple) else (out, None)
        if not report.converged:
            return report
        t, u, v, a, f_ext, f_int = new[:6]
        if not (np.all(np.isfinite(u)) and np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
            report.converged = False
            report.message = f"non-finite state at t={t:.6g}"
            return report
        self.t, self.u, self.v, self.a, self.f_ext, self.f_int = t, u, v, a, f_ext, f_int
        if len(new) > 6:  # the fixed dofs' state (prescribed motion)
            self.uc, self.vc, self.ac = new[6:]
        return report

    @abstractmethod
    def _advance(self):
        """Compute one step from the current state.

        Returns ``(StepReport, (t, u, v, a, f_ext, f_int[, uc, vc, ac]))`` on success or a
        ``StepReport`` with ``converged=False`` on failure (state untouched).
        """
