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
``H = c_m M_z + (1 + alpha) K_z`` at the start state (cubature tangent, factorised in
``start``, :mod:`.linsolve`) as initial Hessian, Armijo backtracking on the cubature
energy; each iteration is one cubature energy + force evaluation and one solve with the
stored operator (the tangent is not re-assembled online).

Where the iteration starts (``predictor``): ``"explicit"`` (default), ``z_n + dt v_n + dt^2/2
a_n``; ``"linearised"``, one step of the start-state Newton from ``z_n`` with the force
linearised about the last converged state (no evaluation; one solve), ``z_n - B^-1 [c_m M_z
(z_n - z~) + lin + (1 + alpha)(f_z,n + K_zb (q_b1 - q_b,n))]``, ``K_zb`` the start-state
coupling to the prescribed boundary dofs. The L-BFGS pairs (``history``) are kept within a
step (``"step"``) or carried from step to step (``"run"``, default): the curvature of the
stretched state then corrects the rest-state step matrix, the full step is accepted
without backtracking and fewer iterations are needed. Measured on the paper cube (364
handles, 2820 BGBC elements, 200 steps, rtol 1e-3; cubature evaluations / iterations per
step): explicit + step 2.65 / 1.28, explicit + run 2.12 / 1.10, linearised + step 2.69 /
1.57, linearised + run 2.50 / 1.36 (the trajectories agree to 2e-4; with states converged
to rtol only, no predictor meets the tolerance by itself: about two evaluations a step).
The products of ``M_z`` with z, v, a are carried along with the state (the kinematics are
linear) and :mod:`.lbfgs` carries ``M_z (z - z~)``: one ``M_z`` product per iteration.
"""
from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .lbfgs import lbfgs, two_loop
from .linsolve import StepMatrix
from .kinematics import SCHEMES, Scheme, make_scheme  # noqa: F401  (re-exported)
from .subspace import regularised

__all__ = ["SCHEMES", "SOLVERS", "PREDICTORS", "HISTORIES", "Scheme", "ReducedStepper", "IndefiniteStepMatrix",
           "make_scheme"]

SOLVERS = ("lbfgs", "newton")
PREDICTORS = ("explicit", "linearised")
HISTORIES = ("step", "run")


class IndefiniteStepMatrix(ValueError):
    """The step matrix at the start state is not positive definite (the cubature's reduced
    stiffness is indefinite there): the model cannot step; the message says why and what to change."""


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
    linear_solver : {"auto", "dense", "cholesky", "sparse"}
        Kind of the step-matrix operator (:class:`~.linsolve.StepMatrix`).
    precision : {"single", "double"}
        Of the step-matrix operator.
    predictor : {"explicit", "linearised"}
        Start of the iteration (module docstring; Newton always starts from the explicit one).
    history : {"step", "run"}
        L-BFGS pairs kept within a step, or from one step to the next.
    accept_unconverged : bool
        Keep a step that reaches ``max_iter`` (finite state, residual reported) instead of failing.
    """

    def __init__(self, subspace, forces, mass_q, loads, scheme, solver="lbfgs", rtol=1e-6, max_iter=50,
                 memory=8, linear_solver="auto", accept_unconverged=False, precision="single",
                 predictor="explicit", history="run"):
        self.accept_unconverged = bool(accept_unconverged)
        self.sub, self.forces, self.loads, self.scheme = subspace, forces, loads, scheme
        self.solver, self.rtol, self.max_iter, self.memory = solver, rtol, int(max_iter), int(memory)
        self.linear_solver, self.precision = linear_solver, precision
        self.predictor, self.history = (predictor, history) if solver == "lbfgs" else ("explicit", "step")
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
        """(``c_m M_z + (1 + alpha) K_z(q)`` as a :class:`StepMatrix`, ``(1 + alpha) K_zb(q)``
        dense (n_z, 12 n_groups)), cached per dt."""
        key = float(dt)
        if key not in self._H:
            _, K = self.forces.force_and_tangent(q)
            T, w = self.sub.T, 1.0 + self.scheme.alpha
            K_z = T.T @ (T.T @ K.T).T
            H = regularised(self.scheme.c_m(dt) * self.M_z.toarray() + w * np.asarray(K_z))
            K_zb = w * np.asarray(T.T @ K[:, self.sub.bnd]) if len(self.sub.bnd) else np.zeros((self.sub.n_z, 0))
            try:
                op = StepMatrix(H, self.linear_solver, self.precision)
            except np.linalg.LinAlgError as exc:
                raise IndefiniteStepMatrix(self._indefinite(dt, exc)) from exc
            self._H[key] = (op, K_zb)
        return self._H[key]

    def _indefinite(self, dt, exc) -> str:
        """Why the step matrix has no Cholesky factor, and what to change."""
        cub = self.forces.cubature
        negative = int(np.sum(np.asarray(cub.weights) < 0))
        cause = (f"the {cub.scheme} cubature's {negative} negative weights (of {len(cub.weights)}) make the reduced "
                 f"stiffness indefinite" if negative else
                 f"the {cub.scheme} cubature's reduced stiffness is indefinite")
        return (f"wsc: the step matrix c_m M_z + (1 + alpha) K_z at dt = {dt:g} s is not positive definite "
                f"({exc}): {cause}, so the reduced dynamics are unstable at this state and its L-BFGS has no "
                f"initial Hessian; take more cubature elements (cubature_elements), fewer handles (n_z = "
                f"{self.sub.n_z}), or a rule with positive weights (cubature = 'rbf' or 'nnls')")

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
        self.Mz, self.Mv, self.Ma = (self.M_z @ x for x in (self.z, self.v, self.a))  # carried along (docstring)
        self._pairs = ([], [])  # L-BFGS (s, y) pairs, kept from step to step with history = "run"
        self.H, self.K_zb = self.step_matrix(self.dt, q) if self.solver == "lbfgs" else (None, None)
        self.q = q

    def step(self, lam1, qb1):
        """Advance one step to load factor ``lam1`` with prescribed boundary dofs ``qb1``.

        Returns ``(ok, message, info)``; on failure the state is unchanged.
        """
        sch, dt, al = self.scheme, self.dt, self.scheme.alpha
        vb1, ab1 = sch.kinematics(dt, qb1, self.qb, self.vb, self.ab)
        fext1 = self.external_z(lam1, self.q)
        lin = (self.M_zb @ ab1 if self.M_zb.shape[1] else 0.0) - al * (self.fz - self.fext) - (1.0 + al) * fext1
        zt = sch.predicted(dt, self.z, self.v, self.a)
        Mzt = sch.predicted(dt, self.Mz, self.Mv, self.Ma)
        c_m = sch.c_m(dt)
        # the force scale of the step; |f_q| includes the support reaction on the prescribed
        # boundary dofs, which keeps the scale when the free forces balance (a held stretch)
        r_ref = max(np.linalg.norm(self.fz), self.fq_norm, np.linalg.norm(fext1), np.linalg.norm(self.Ma), 1e-300)
        pairs = tuple(list(p) for p in self._pairs)
        if self.solver == "lbfgs":
            ok, z, Mdz, extra, info = self._lbfgs(zt, Mzt, c_m, lin, qb1, r_ref)
        else:
            ok, z, extra, info = self._newton(self.z + dt * self.v + 0.5 * dt * dt * self.a, zt, c_m, lin, qb1,
                                              r_ref)
            Mdz = self.M_z @ (z - zt)
        if not ok:
            self._pairs = pairs
            return False, info["message"], info
        E, fz, self.fq_norm = extra
        v1, a1 = sch.kinematics(dt, z, self.z, self.v, self.a)
        Mz1 = Mzt + Mdz
        self.Mv, self.Ma = sch.kinematics(dt, Mz1, self.Mz, self.Mv, self.Ma)
        self.Mz = Mz1
        self.z, self.v, self.a, self.E, self.fz, self.fext = z, v1, a1, E, fz, fext1
        self.qb, self.vb, self.ab = qb1, vb1, ab1
        self.q = self.sub.q_of(z, qb1)
        return True, "", info

    # ------------------------------------------------------------------ solvers
    def _lbfgs(self, zt, Mzt, c_m, lin, qb1, r_ref):
        al, dt = self.scheme.alpha, self.dt
        starts = []
        if self.predictor == "linearised":
            g_n = c_m * (self.Mz - Mzt) + lin + (1.0 + al) * self.fz + self.K_zb @ (qb1 - self.qb)
            dz = two_loop(g_n, *self._pairs, self.H.solve)
            starts.append((self.z - dz, self.Mz - Mzt - self.M_z @ dz))
        # the explicit predictor; after one that inverts an element, the last state moved with its
        # velocity, the last state (their M_z products from the state's: no product computed)
        h = 0.5 * dt * dt
        for z, Mz in ((self.z + dt * self.v + h * self.a, self.Mz + dt * self.Mv + h * self.Ma),
                      (self.z + dt * self.v, self.Mz + dt * self.Mv), (self.z, self.Mz)):
            starts.append((z, Mz - Mzt))

        def evaluate(z, Mdz):
            """(Phi, gradient, (E, f_z, |f_q|)) at z, from Mdz = M_z (z - z~)."""
            E, fq, fz = self.f_z(self.sub.q_of(z, qb1))
            phi = 0.5 * c_m * (z - zt) @ Mdz + lin @ z + (1.0 + al) * E
            return phi, c_m * Mdz + lin + (1.0 + al) * fz, (E, fz, float(np.linalg.norm(fq)))

        S, Y = self._pairs if self.history == "run" else ([], [])
        ok, z, Mdz, extra, info = lbfgs(evaluate, starts, self.H.solve, self.M_z.dot,
                                        lambda g0: self.rtol * max(r_ref, g0), self.max_iter, S, Y, self.memory)
        if not ok and info.get("converged") is False and self.accept_unconverged:
            ok = True  # the paper's capped iteration: kept, its residual reported
        return ok, z, Mdz, extra, info

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
                return False, z, None, {"message": f"non-finite residual at iteration {it}", "iterations": it}
            if gn <= tol or small_step:  # the step-size test of the full-order Newton (utol = 1e-12)
                E = self.forces.energy_and_force(q)[0]
                return True, z, (E, fz, float(np.linalg.norm(fq))), {
                    "iterations": it, "evaluations": it + 1, "residual": gn, "converged": True,
                    "solve_s": time.perf_counter() - tic}
            if it == self.max_iter:
                break
            K_z = (T.T @ (T.T @ K.T).T)
            J = regularised(c_m * Mz + (1.0 + al) * np.asarray(K_z))
            try:
                dz = sla.solve(J, g, assume_a="sym", check_finite=False)
                z = z - dz
                small_step = np.linalg.norm(dz) <= 1e-12 * max(np.linalg.norm(z), 1e-300)
            except (np.linalg.LinAlgError, ValueError) as exc:
                return False, z, None, {"message": f"singular Newton matrix: {exc}", "iterations": it}
        info = {"message": f"Newton did not converge in {self.max_iter} iterations (|R| = {gn:.3e}, tolerance "
                           f"{tol:.3e})", "iterations": self.max_iter, "residual": gn, "converged": False}
        if self.accept_unconverged:  # the last iterate's energy and force (not checked further)
            E, fq = self.forces.energy_and_force(self.sub.q_of(z, qb1))
            return True, z, (E, self.sub.z_of(fq), float(np.linalg.norm(fq))), info
        return False, z, None, info

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
