"""The online WSC model (trajectory kind): start, step, outputs, reconstruction.

``start`` projects the initial state on the subspace (nothing to do from rest) and
factorises the step matrix for ``dt``; ``step({"time", "load_factor"})`` advances one
implicit step (:class:`~.stepper.ReducedStepper`) with the boundary handles at the
prescribed motion of that load factor; the step result holds the full reduced vector
``q`` (``u = U q``, prescribed values included), so outputs cost ``n_out x n_q``.
"""
from __future__ import annotations

import numpy as np

from ..base import OnlineModel, StepResult, check_parameters
from .subspace import MassProjector

__all__ = ["WscModel"]


class WscModel(OnlineModel):
    """Online WSC model (trajectory): see the module docstring."""

    name = "wsc"
    kind = "trajectory"

    def __init__(self, subspace, stepper, problem, info, mass, track_energy=False, dt=None, envelope=None):
        self.sub, self.stepper, self.problem, self.info = subspace, stepper, problem, info
        self._mass, self._projector = mass, None
        self.track_energy = track_energy
        self._dt, self._envelope = dt, dict(envelope or {})
        self._linear_presc = not any(d.motion is not None for d in problem.dirichlet)
        if self._linear_presc:  # g(lam) = lam g1 + g0: q_b affine in lam, precomputed
            g0 = problem.prescribed_values(0.0)
            self._qb0 = subspace.prescribed_q(g0)
            self._qb1 = subspace.prescribed_q(problem.prescribed_values(1.0) - g0)
        self.started = False

    @property
    def n_reduced(self) -> int:
        return self.sub.n_q

    @property
    def envelope(self) -> dict:
        return dict(self._envelope)

    def prescribed_q(self, lam) -> np.ndarray:
        if self._linear_presc:
            return self._qb0 + lam * self._qb1
        return self.sub.prescribed_q(self.problem.prescribed_values(lam))

    # ------------------------------------------------------------------ start
    def project(self, u) -> tuple[np.ndarray, np.ndarray]:
        """(z, q_b) of the mass-orthogonal projection of a full field u (ndof,) on the subspace."""
        if self._projector is None:
            self._projector = MassProjector(self.sub, self._mass)
        return self._projector.project(u)

    def start(self, mu0=None, state0=None, dt=None):
        dt = self._dt if dt is None else dt
        if dt is None or not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"wsc.start: dt must be a time step > 0 (none given and none in the training), got {dt!r}")
        self._dt = float(dt)
        lam0 = float(mu0.get("load_factor", 0.0)) if mu0 else 0.0
        self.t = float(mu0.get("time", 0.0)) if mu0 else 0.0
        nz, nb = self.sub.n_z, 12 * self.sub.n_groups
        at_rest = state0 is None or (not np.any(state0["u"]) and not np.any(state0.get("v", 0.0)))
        if at_rest:  # no projection needed (the harness passes the reference's zero initial state)
            z0, v0, qb0, vb0 = np.zeros(nz), np.zeros(nz), self.prescribed_q(lam0), np.zeros(nb)
        else:
            z0, qb0 = self.project(state0["u"])
            v0, vb0 = self.project(state0.get("v", np.zeros(self.sub.ndof)))
        self.stepper.start(z0, v0, qb0, vb0, lam0, self._dt)
        if self.stepper.H is not None:  # what the measured choice built (linsolve)
            self.info["step_matrix"], self.info["linear_solver"] = self.stepper.H.info, self.stepper.H.kind
        self.reaction_work, self._support0 = 0.0, None
        if self.track_energy:
            self._support0 = self.stepper.support_force()
        self.started = True

    # ------------------------------------------------------------------ step
    def step(self, mu) -> StepResult:
        mu = check_parameters(mu, ("time", "load_factor"), self.name)
        if not self.started:
            self.start()
        lam = float(mu["load_factor"])
        qb_old = self.stepper.qb
        ok, message, info = self.stepper.step(lam, self.prescribed_q(lam))
        if not ok:
            return StepResult(None, "failed", f"t={mu['time']:.6g}: {message}", info, mu)
        self.t = float(mu["time"])
        if self.track_energy:
            support = self.stepper.support_force()
            self.reaction_work += 0.5 * float((self._support0 + support) @ (self.stepper.qb - qb_old))
            self._support0 = support
            info["kinetic_energy"], info["strain_energy"] = self.stepper.energies()
            info["reaction_work"] = self.reaction_work
        status = "ok"
        lo, hi = self._envelope.get("load_factor", (-np.inf, np.inf))
        if not lo - 1e-12 <= lam <= hi + 1e-12:
            status = "extrapolation"
        note = "" if info.get("converged", True) else f"kept unconverged (on_max_iter='accept'): {info['message']}"
        return StepResult(self.stepper.q.copy(), status, note, info, mu)

    def floor_ops(self):
        """The arithmetic an implicit reduced step cannot avoid (wsc paper §2.3): one cubature
        evaluation of the reduced force at the current state and one solve with the step
        matrix the measured choice built; the default floor (:meth:`OnlineModel.floor_ops`)
        before a start or with the Newton solver (no stored step matrix)."""
        st = self.stepper
        if not self.started or st.H is None:
            return super().floor_ops()
        q = st.q.copy()

        def floor():
            return st.H.solve(st.f_z(q)[2])
        return floor

    # ------------------------------------------------------------------ outputs
    def output_map(self):
        return np.arange(self.sub.ndof), self.sub.U

    def reconstruct(self, result: StepResult) -> np.ndarray:
        if result.q is None:
            raise ValueError(f"wsc.reconstruct: the step failed ({result.message}); no state")
        return self.sub.displacement(result.q)
