"""Implicit time stepping in the subspace (the paper's backward Euler; Newmark, HHT).

Free coordinates ``z`` (n_z), boundary-handle prescribed part ``q_b(t)``; ``q = T z + q_b``.
One step solves, for ``z1`` (Hilber's weighting ``alpha``, 0 except for HHT)::

    R(z1) = M_z a1 + M_zb a_b1 + (1 + alpha) (f_z(q1) - f_ext,z1) - alpha (f_z(q0) - f_ext,z0) = 0

with the accelerations from the scheme's kinematics (backward Euler: ``v1 = (z1 - z0)/dt``,
``a1 = (v1 - v0)/dt``; Newmark beta, gamma), the same kinematics giving the prescribed
part's ``v_b1, a_b1`` (as in the full-order dynamics). ``f_z = T^T f_q`` is the cubature
force (:mod:`.reduced`). Without damping and with the loads frozen over the step, ``R``
is the gradient of the incremental potential::

    Phi(z) = c_m/2 |z - z~|^2_Mz + z.(M_zb a_b1 - alpha (f_z0 - f_ext,z0) - (1 + alpha) f_ext,z1)
             + (1 + alpha) E(q(z)),        a1 = c_m (z1 - z~)

Solvers: ``"newton"`` (cubature force and tangent every iteration, dense solve) and
``"lbfgs"`` (default): L-BFGS on Phi with the inverse of the step matrix
``c_m M_z + (1 + alpha) K_z`` at the start state (cubature tangent, factorised in
``start``) as initial Hessian, Armijo backtracking on the cubature energy; each
iteration is one cubature energy + force evaluation and one solve with the stored
factorisation (the tangent is not re-assembled online).
"""
from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .schemes import SCHEMES, Scheme, StepMatrix, make_scheme  # noqa: F401  (re-exported)
from .subspace import regularised

__all__ = ["SCHEMES", "SOLVERS", "Scheme", "ReducedStepper", "make_scheme"]

SOLVERS = ("lbfgs", "newton")


class ReducedStepper:
    """State and step of the reduced dynamics (see the module docstring).

    Parameters
    ----------
    subspace : Subspace
    forces : CubatureForces
    mass_q : sparse (n_q, n_q)
        ``U^T M U``.
    loads : ReducedLoads
    scheme : Scheme
    solver : {"lbfgs", "newton"}
    rtol : float
        Converged when ``|R| <= rtol * r_ref`` (r_ref: the largest force term of the step).
    max_iter : int
    memory : int
        L-BFGS pairs kept.
    linear_solver : {"dense", "sparse"}
    accept_unconverged : bool
        Keep a step that reaches ``max_iter`` (finite state, residual reported) instead of failing.
    """

    def __init__(self, subspace, forces, mass_q, loads, scheme, solver="lbfgs", rtol=1e-6, max_iter=50,
                 memory=8, linear_solver="dense", accept_unconverged=False):
        self.accept_unconverged = bool(accept_unconverged)
        self.sub, self.forces, self.loads, self.scheme = subspace, forces, loads, scheme
        self.solver, self.rtol, self.max_iter, self.memory = solver, rtol, int(max_iter), int(memory)
        self.linear_solver = linear_solver
        T = subspace.T
        nb = 12 * subspace.n_groups
        L = sp.csr_matrix((np.ones(nb), (subspace.bnd, np.arange(nb))), shape=(subspace.n_q, nb))
        self.M_q = sp.csr_matrix(mass_q)
        self.M_z = sp.csr_matrix(T.T @ self.M_q @ T)
        self.M_zb = (T.T @ (self.M_q @ L)).toarray() if nb else np.zeros((subspace.n_z, 0))
        self.M_bb = (L.T @ self.M_q @ L).toarray() if nb else np.zeros((0, 0))
        self._L = L
        self._H = {}

    # ------------------------------------------------------------------ helpers
    def f_z(self, q):
        E, f = self.forces.energy_and_force(q)
        return E, f, self.sub.z_of(f)

    def external_z(self, lam, q):
        """Reduced external force (n_z,) at load factor lam, follower pressure at q."""
        f = self.loads.dead_q if not self.loads.has_follower else self.loads.dead_q + self.loads.follower_q(q)
        return lam * self.sub.z_of(f)

    def step_matrix(self, dt, q):
        """The factorised ``c_m M_z + (1 + alpha) K_z(q)`` (cached per dt)."""
        key = float(dt)
        if key not in self._H:
            _, K = self.forces.force_and_tangent(q)
            T = self.sub.T
            K_z = T.T @ (T.T @ K.T).T
            H = regularised(self.scheme.c_m(dt) * self.M_z.toarray() + (1.0 + self.scheme.alpha) * np.asarray(K_z))
            self._H[key] = StepMatrix(sp.csr_matrix(H) if self.linear_solver == "sparse" else H,
                                       self.linear_solver)
        return self._H[key]

    # ------------------------------------------------------------------ run
    def start(self, z0, v0, qb0, vb0, lam0, dt):
        """Set the state at rest acceleration of the boundary part; factorise for dt."""
        self.dt = float(dt)
        self.z, self.v = np.array(z0, float), np.array(v0, float)
        self.qb, self.vb, self.ab = np.array(qb0, float), np.array(vb0, float), np.zeros(len(qb0))
        q = self.sub.q_of(self.z, self.qb)
        self.E, fq, self.fz = self.f_z(q)
        self.fq_norm = float(np.linalg.norm(fq))
        self.fext = self.external_z(lam0, q)
        rhs = self.fext - self.fz - (self.M_zb @ self.ab if self.M_zb.shape[1] else 0.0)
        self.a = spla.spsolve(sp.csc_matrix(regularised(self.M_z)), rhs) if np.any(rhs) else np.zeros_like(self.z)
        self.H = self.step_matrix(self.dt, q) if self.solver == "lbfgs" else None
        self.q = q

    def step(self, lam1, qb1):
        """Advance one step to load factor ``lam1`` with prescribed boundary dofs ``qb1``.

        Returns ``(ok, message, info)``; on failure the state is unchanged.
        """
        sch, dt = self.scheme, self.dt
        vb1, ab1 = sch.kinematics(dt, qb1, self.qb, self.vb, self.ab)
        fext1 = self.external_z(lam1, self.q)
        al = sch.alpha
        lin = (self.M_zb @ ab1 if self.M_zb.shape[1] else 0.0) - al * (self.fz - self.fext) - (1.0 + al) * fext1
        zt = sch.predicted(dt, self.z, self.v, self.a)
        c_m = sch.c_m(dt)
        z = self.z + dt * self.v + 0.5 * dt * dt * self.a
        # the force scale of the step; |f_q| includes the support reaction on the prescribed
        # boundary dofs, which keeps the scale when the free forces balance (a held stretch)
        r_ref = max(np.linalg.norm(self.fz), self.fq_norm, np.linalg.norm(fext1), np.linalg.norm(self.M_z @ self.a),
                    1e-300)
        run = self._lbfgs if self.solver == "lbfgs" else self._newton
        ok, z, E, fz, info = run(z, zt, c_m, lin, qb1, r_ref)
        if not ok:
            return False, info["message"], info
        v1, a1 = sch.kinematics(dt, z, self.z, self.v, self.a)
        self.z, self.v, self.a, self.E, self.fz, self.fext = z, v1, a1, E, fz, fext1
        self.fq_norm = info.pop("fq_norm", self.fq_norm)
        self.qb, self.vb, self.ab = qb1, vb1, ab1
        self.q = self.sub.q_of(z, qb1)
        return True, "", info

    # ------------------------------------------------------------------ solvers
    def _phi(self, z, zt, c_m, lin, qb1):
        """(Phi, gradient, E, f_z) at z."""
        al = self.scheme.alpha
        E, fq, fz = self.f_z(self.sub.q_of(z, qb1))
        self._last_fq_norm = float(np.linalg.norm(fq))
        dz = z - zt
        Mdz = self.M_z @ dz
        phi = 0.5 * c_m * dz @ Mdz + lin @ z + (1.0 + al) * E
        return phi, c_m * Mdz + lin + (1.0 + al) * fz, E, fz

    def _lbfgs(self, z, zt, c_m, lin, qb1, r_ref):
        tic = time.perf_counter()
        # a predictor that inverts an element (non-finite energy) falls back to the last state
        for start in (z, self.z + self.dt * self.v, self.z):
            phi, g, E, fz = self._phi(start, zt, c_m, lin, qb1)
            if np.isfinite(phi):
                z = start
                break
        fq_norm = self._last_fq_norm
        tol = self.rtol * max(r_ref, np.linalg.norm(g))
        S, Y, evals = [], [], 1
        for it in range(self.max_iter + 1):
            gn = float(np.linalg.norm(g))
            if not np.isfinite(phi) or not np.isfinite(gn):
                return False, z, E, fz, {"message": f"non-finite energy or force (an inverted element?) at "
                                                    f"iteration {it}", "iterations": it, "evaluations": evals}
            if gn <= tol:
                return True, z, E, fz, {"iterations": it, "evaluations": evals, "residual": gn, "converged": True,
                                        "solve_s": time.perf_counter() - tic, "fq_norm": fq_norm}
            if it == self.max_iter:
                break
            d = -self._two_loop(g, S, Y)
            slope = g @ d
            if slope >= 0:  # not a descent direction: restart from the step matrix
                S, Y = [], []
                d = -self.H.solve(g)
                slope = g @ d
            s = 1.0
            for _ in range(12):
                z1 = z + s * d
                phi1, g1, E1, fz1 = self._phi(z1, zt, c_m, lin, qb1)
                evals += 1
                # Armijo, with a slack at the round-off of Phi: near convergence the true
                # decrease falls below the rounding of the summed element energies
                slack = 1e-12 * max(abs(phi), abs(phi1)) if np.isfinite(phi1) else 0.0
                if np.isfinite(phi1) and phi1 <= phi + 1e-4 * s * slope + slack:
                    break
                s *= 0.5
            else:
                return False, z, E, fz, {"message": f"line search failed at iteration {it} "
                                                    f"(|R| = {gn:.3e}, tolerance {tol:.3e})",
                                         "iterations": it, "evaluations": evals}
            sk, yk = z1 - z, g1 - g
            if yk @ sk > 1e-12 * np.linalg.norm(yk) * np.linalg.norm(sk):
                S.append(sk)
                Y.append(yk)
                if len(S) > self.memory:
                    S.pop(0)
                    Y.pop(0)
            z, phi, g, E, fz, fq_norm = z1, phi1, g1, E1, fz1, self._last_fq_norm
        info = {"message": f"L-BFGS did not converge in {self.max_iter} iterations (|R| = {gn:.3e}, tolerance "
                           f"{tol:.3e})", "iterations": self.max_iter, "evaluations": evals, "residual": gn,
                "converged": False, "solve_s": time.perf_counter() - tic}
        return self.accept_unconverged, z, E, fz, info

    def _two_loop(self, g, S, Y):
        q = g.copy()
        alphas = []
        for s, y in zip(reversed(S), reversed(Y)):
            rho = 1.0 / (y @ s)
            a = rho * (s @ q)
            q -= a * y
            alphas.append((rho, a))
        r = self.H.solve(q)
        for (s, y), (rho, a) in zip(zip(S, Y), reversed(alphas)):
            r += s * (a - rho * (y @ r))
        return r

    def _newton(self, z, zt, c_m, lin, qb1, r_ref):
        tic = time.perf_counter()
        al, T = self.scheme.alpha, self.sub.T
        Mz = self.M_z.toarray()
        small_step = False
        for it in range(self.max_iter + 1):
            q = self.sub.q_of(z, qb1)
            fq, K = self.forces.force_and_tangent(q)
            fz = self.sub.z_of(fq)
            g = c_m * (self.M_z @ (z - zt)) + lin + (1.0 + al) * fz
            gn = float(np.linalg.norm(g))
            if it == 0:
                tol = self.rtol * max(r_ref, gn)
            if not np.isfinite(gn):
                return False, z, np.nan, fz, {"message": f"non-finite residual at iteration {it}", "iterations": it}
            if gn <= tol or small_step:  # the step-size test of the full-order Newton (utol = 1e-12)
                E = self.forces.energy_and_force(q)[0]
                return True, z, E, fz, {"iterations": it, "evaluations": it + 1, "residual": gn, "converged": True,
                                        "solve_s": time.perf_counter() - tic, "fq_norm": float(np.linalg.norm(fq))}
            if it == self.max_iter:
                break
            K_z = (T.T @ (T.T @ K.T).T)
            J = regularised(c_m * Mz + (1.0 + al) * np.asarray(K_z))
            try:
                dz = sla.solve(J, g, assume_a="sym", check_finite=False)
                z = z - dz
                small_step = np.linalg.norm(dz) <= 1e-12 * max(np.linalg.norm(z), 1e-300)
            except (np.linalg.LinAlgError, ValueError) as exc:
                return False, z, np.nan, fz, {"message": f"singular Newton matrix: {exc}", "iterations": it}
        info = {"message": f"Newton did not converge in {self.max_iter} iterations (|R| = {gn:.3e}, tolerance "
                           f"{tol:.3e})", "iterations": self.max_iter, "residual": gn, "converged": False}
        if self.accept_unconverged:  # the last iterate's energy and force (not checked further)
            E, fq = self.forces.energy_and_force(self.sub.q_of(z, qb1))
            return True, z, E, self.sub.z_of(fq), info
        return False, z, np.nan, fz, info

    # ------------------------------------------------------------------ energy
    def energies(self):
        """(kinetic, strain) energy of the current state [energy unit]."""
        vq = self.sub.q_of(self.v, self.vb)
        return 0.5 * float(vq @ (self.M_q @ vq)), float(self.E)

    def support_force(self):
        """Force on the prescribed boundary dofs, ``L^T (M_q a_q + f_q(q))`` (12 n_groups,)."""
        aq = self.sub.q_of(self.a, self.ab)
        fq = self.forces.force(self.q)
        return self._L.T @ (self.M_q @ aq + fq)
