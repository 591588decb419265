"""Implicit schemes: Newmark family, HHT-alpha, Bathe composite, backward Euler.

All solve for the displacement at the end of each (sub)step with Newton iterations on
the nonlinear residual (:func:`~tissuebench.refsolvers.dynamics.step_newton.newton`); for a
linear system the effective matrix is factorised once and each step is one solve.

References: Hilber, Hughes, Taylor (1977) EESD 5:283; Bathe, Baig (2005) C&S 83:2513;
Bathe (2007) C&S 85:437; backward Euler as in Baraff, Witkin (1998) and the wsc paper.

A prescribed motion of the fixed dofs (see :mod:`.system`) enters each residual through
``M_fc a_c + C_fc v_c``, with ``a_c``, ``v_c`` from the scheme's own kinematics.
"""
from __future__ import annotations

import numpy as np

from .base import Integrator, StepReport
from ..newton import scaled_norm
from .step_newton import REUSE_MIN_DOFS, LinearSolverError, StepSolver, newton, newton_options


def _force_scale(integ, sys) -> float:
    """r_ref of a step [N]: the largest of |f_ext|, |f_int| and |M a| at t_n (scaled norms: a
    1e-200 N load is not 0; all zero at rest, where the predictor's residual is the scale).
    Keeps the run's largest in ``integ._force_peak``: the step Newton refuses a step whose
    forces lie below round-off only while the whole run's have (a load below round-off), not
    once a resolved motion has decayed there."""
    r_ref = max(scaled_norm(integ.f_ext), scaled_norm(integ.f_int), scaled_norm(sys.M_ff @ integ.a))
    integ._force_peak = max(integ._force_peak, r_ref)
    return r_ref


class NewmarkFamily(Integrator):
    """Newmark(beta, gamma) with HHT weighting ``alpha`` of the force terms.

    Residual at t_{n+1} (Hilber's convention, alpha <= 0)::

        M a_{n+1} + (1 + alpha) [C v_{n+1} + f_int(u_{n+1}) - f_ext_{n+1}]
                  - alpha     [C v_n     + f_int(u_n)     - f_ext_n]      = 0
        u_{n+1} = u_n + dt v_n + dt^2 [(1/2 - beta) a_n + beta a_{n+1}]
        v_{n+1} = v_n + dt [(1 - gamma) a_n + gamma a_{n+1}]
    """

    implicit = True

    def __init__(self, alpha=0.0, beta=0.25, gamma=0.5, **newton_opts):
        super().__init__()
        for name, val in (("alpha", alpha), ("beta", beta), ("gamma", gamma)):
            if not np.isfinite(val):
                raise ValueError(f"{name} must be finite, got {val!r}")
        if beta <= 0:
            raise ValueError(f"beta must be > 0 (explicit Newmark is not supported here), got {beta!r}")
        if gamma <= 0:
            raise ValueError(f"gamma must be > 0, got {gamma!r}")
        self.alpha, self.beta, self.gamma = float(alpha), float(beta), float(gamma)
        self.newton_opts = newton_options(type(self).__name__, newton_opts)
        self._lu = StepSolver(self.newton_opts.linear_solver)

    def _setup(self):
        self._lu = StepSolver(self.newton_opts.linear_solver)  # a new system or dt invalidates the factorisation
        self._force_peak = 0.0

    def _kin(self, u1, u0, v0, a0):
        """(v_{n+1}, a_{n+1}) from the candidate u_{n+1} and the state (u0, v0, a0) at t_n."""
        dt, b, g = self.dt, self.beta, self.gamma
        a1 = (u1 - u0 - dt * v0) / (b * dt * dt) - (0.5 / b - 1.0) * a0
        v1 = v0 + dt * ((1.0 - g) * a0 + g * a1)
        return v1, a1

    def _kinematics(self, u1):
        """(v_{n+1}, a_{n+1}) of the free dofs from the candidate u_{n+1}."""
        return self._kin(u1, self.u, self.v, self.a)

    def _jacobian(self, u1, t1, uc1):
        """The step's Newton matrix at the candidate ``u1`` (free dofs)."""
        sys, dt, al = self.system, self.dt, self.alpha
        J = sys.M_ff / (self.beta * dt * dt) + (1.0 + al) * sys.K_t(u1, t1, uc1)
        if sys.C_ff is not None:
            J = J + (1.0 + al) * self.gamma / (self.beta * dt) * sys.C_ff
        return J

    def _predictor(self):
        """The step's first iterate: constant acceleration over the step."""
        dt = self.dt
        return self.u + dt * self.v + 0.5 * dt * dt * self.a

    def prime(self) -> None:
        """Factorise the next step's Newton matrix at its predictor now, the matrix the step would
        form at its first iteration and keep: a linear system's constant one, or modified Newton's
        (``newton_tangent = "reuse"``). The same numbers, and the step costs what the steps after
        it do. A system stepped by full Newton (a matrix per iteration) is left as it is."""
        sys, opts = self.system, self.newton_opts
        if sys.linear:
            key = "linear"
        elif opts.tangent == "reuse" or (opts.tangent == "auto" and len(self.u) >= REUSE_MIN_DOFS):
            key = "newton"
        else:
            return
        t1 = self.t + self.dt
        uc1 = sys.prescribed_values(t1) if sys.has_prescribed else self.uc
        u_pred = self._predictor()
        self._lu.refresh()
        try:
            self._lu.solve_cached(key, lambda: self._jacobian(u_pred, t1, uc1), np.zeros(len(u_pred)))
        except LinearSolverError:  # the step forms it again and reports the singular matrix itself
            self._lu.refresh()

    def _advance(self):
        sys, dt, al = self.system, self.dt, self.alpha
        t1 = self.t + dt
        uc1 = sys.prescribed_values(t1) if sys.has_prescribed else self.uc
        vc1, ac1 = self._constrained_kinematics(uc1, lambda x: self._kin(x, self.uc, self.vc, self.ac))
        old = sys.damping_force(self.v) + sys.damping_coupling(self.vc) + self.f_int - self.f_ext
        inertia_c, damping_c = sys.mass_coupling(ac1), sys.damping_coupling(vc1)
        cache = {}

        def residual(u1):
            v1, a1 = self._kinematics(u1)
            cache["f_ext"], cache["f_int"] = sys.f_ext(t1, u1, uc1), sys.f_int(u1, uc1)
            new = sys.damping_force(v1) + damping_c + cache["f_int"] - cache["f_ext"]
            return sys.M_ff @ a1 + inertia_c + (1.0 + al) * new - al * old

        def jacobian(u1):
            return self._jacobian(u1, t1, uc1)

        u_pred = self._predictor()
        r_ref = _force_scale(self, sys)
        u1, rep = newton(u_pred, residual, jacobian, r_ref, self.newton_opts, sys.linear, self._lu,
                         sys.round_off_floor, self._force_peak)
        if not rep.converged:
            rep.message = f"t={t1:.6g}: {rep.message}"
            return rep
        if sys.linear:  # the residual cache holds the predictor's forces; refresh them
            cache["f_ext"], cache["f_int"] = sys.f_ext(t1, u1, uc1), sys.f_int(u1, uc1)
        v1, a1 = self._kinematics(u1)
        return rep, (t1, u1, v1, a1, cache["f_ext"], cache["f_int"], uc1, vc1, ac1)


class HHT(NewmarkFamily):
    """HHT-alpha: alpha in [-1/3, 0], beta = (1 - alpha)^2 / 4, gamma = 1/2 - alpha.

    Second order, unconditionally stable on linear problems, spectral radius at
    infinity (1 + alpha) / (1 - alpha). ``alpha = 0`` is the trapezoidal rule.
    Newton options: ``newton_rtol``, ``newton_atol``, ``newton_utol``, ``newton_max_iter``.
    """

    name = "hht"

    def __init__(self, alpha=-0.05, **newton_opts):
        alpha = float(alpha)
        if not (-1.0 / 3.0 - 1e-15 <= alpha <= 0.0):
            raise ValueError(f"alpha must lie in [-1/3, 0], got {alpha!r}")
        super().__init__(alpha, (1.0 - alpha) ** 2 / 4.0, 0.5 - alpha, **newton_opts)


class Newmark(NewmarkFamily):
    """Newmark average acceleration (trapezoidal rule, beta = 1/4, gamma = 1/2) by default.

    Energy conserving on linear undamped problems; other (beta, gamma) are accepted.
    """

    name = "newmark"

    def __init__(self, beta=0.25, gamma=0.5, **newton_opts):
        super().__init__(0.0, beta, gamma, **newton_opts)


class Bathe(Integrator):
    """Bathe's composite scheme (gamma = 1/2): trapezoidal rule over [t, t + dt/2],
    then the 3-point backward Euler formula over [t + dt/2, t + dt]::

        v_{n+1} = (u_n - 4 u_{n+1/2} + 3 u_{n+1}) / dt
        a_{n+1} = (v_n - 4 v_{n+1/2} + 3 v_{n+1}) / dt

    Second order, spectral radius 0 at infinity. Newton in each sub-step.
    """

    name = "bathe"
    implicit = True

    def __init__(self, **newton_opts):
        super().__init__()
        self.newton_opts = newton_options("Bathe", newton_opts)
        self._lu1, self._lu2 = (StepSolver(self.newton_opts.linear_solver) for _ in range(2))

    def _setup(self):
        self._lu1, self._lu2 = (StepSolver(self.newton_opts.linear_solver) for _ in range(2))
        self._force_peak = 0.0

    def _solve(self, t1, u_pred, kin, c_m, c_c, lu, r_ref, uc1, kin_c):
        """One sub-step: Newton on M a(u) + C v(u) + f_int(u) - f_ext(t1, u) = 0, the fixed
        dofs at ``uc1`` with velocity and acceleration ``kin_c(uc1)``."""
        sys, cache = self.system, {}
        vc1, ac1 = self._constrained_kinematics(uc1, kin_c)
        coupling = sys.coupling_force(vc1, ac1)

        def residual(u1):
            v1, a1 = kin(u1)
            cache["f_ext"], cache["f_int"] = sys.f_ext(t1, u1, uc1), sys.f_int(u1, uc1)
            return sys.M_ff @ a1 + sys.damping_force(v1) + coupling + cache["f_int"] - cache["f_ext"]

        def jacobian(u1):
            J = c_m * sys.M_ff + sys.K_t(u1, t1, uc1)
            return J if sys.C_ff is None else J + c_c * sys.C_ff

        u1, rep = newton(u_pred, residual, jacobian, r_ref, self.newton_opts, sys.linear, lu, sys.round_off_floor,
                         self._force_peak)
        if rep.converged and sys.linear:
            cache["f_ext"], cache["f_int"] = sys.f_ext(t1, u1, uc1), sys.f_int(u1, uc1)
        v1, a1 = kin(u1)
        return rep, u1, v1, a1, cache.get("f_ext"), cache.get("f_int"), (uc1, vc1, ac1)

    def _advance(self):
        sys, dt, h = self.system, self.dt, 0.5 * self.dt
        r_ref = _force_scale(self, sys)

        def trapezoidal(u0, v0, a0):  # over h
            def kin(u):
                v = 2.0 / h * (u - u0) - v0
                return v, 2.0 / h * (v - v0) - a0
            return kin

        def backward3(u0, v0, uh, vh):  # 3-point backward Euler over [t, t + dt]
            def kin(u):
                v = (u0 - 4.0 * uh + 3.0 * u) / dt
                return v, (v0 - 4.0 * vh + 3.0 * v) / dt
            return kin

        u0, v0, a0 = self.u, self.v, self.a
        uch = sys.prescribed_values(self.t + h) if sys.has_prescribed else self.uc
        rep1, uh, vh, ah, _, _, (_, vch, _) = self._solve(
            self.t + h, u0 + h * v0 + 0.5 * h * h * a0, trapezoidal(u0, v0, a0), 4.0 / (h * h), 2.0 / h,
            self._lu1, r_ref, uch, trapezoidal(self.uc, self.vc, self.ac))
        if not rep1.converged:
            rep1.message = f"t={self.t + h:.6g} (first sub-step): {rep1.message}"
            return rep1
        uc1 = sys.prescribed_values(self.t + dt) if sys.has_prescribed else self.uc
        rep2, u1, v1, a1, fe, fi, c1 = self._solve(
            self.t + dt, uh + h * vh + 0.5 * h * h * ah, backward3(u0, v0, uh, vh), 9.0 / (dt * dt), 3.0 / dt,
            self._lu2, r_ref, uc1, backward3(self.uc, self.vc, uch, vch))
        rep = StepReport(rep2.converged, rep1.iterations + rep2.iterations, rep2.message or rep1.message,
                         rep1.residuals + rep2.residuals, rep1.within_tolerance and rep2.within_tolerance)
        if not rep2.converged:
            rep.message = f"t={self.t + dt:.6g} (second sub-step): {rep2.message}"
            return rep
        return rep, (self.t + dt, u1, v1, a1, fe, fi, *c1)


class BackwardEuler(NewmarkFamily):
    """Backward (implicit) Euler, the integrator of the wsc paper (and of Vega's
    ``ImplicitBackwardEulerSparse``)::

        v_{n+1} = (u_{n+1} - u_n) / dt,   a_{n+1} = (v_{n+1} - v_n) / dt,
        M a_{n+1} + C v_{n+1} + f_int(u_{n+1}) = f_ext_{n+1}

    First order, L-stable (spectral radius 0 at infinity): strongly dissipative, so the
    energy balance shows a negative error that shrinks with dt. Newton per step.
    """

    name = "backward_euler"
    order = 1

    def __init__(self, **newton_opts):
        # beta = 1, gamma = 1 make the Newmark Jacobian M / dt^2 + C / dt + K_t of backward Euler
        super().__init__(0.0, 1.0, 1.0, **newton_opts)

    def _kin(self, u1, u0, v0, a0):
        v1 = (u1 - u0) / self.dt
        return v1, (v1 - v0) / self.dt
