"""Online phase of the direct integrator: evaluate the vademecum, project, repeat.

State: the reduced coordinates ``q`` of the scheme's fields (``u`` and ``v``; ``u`` and
``u_prev`` for central difference; ``u``, ``v``, ``u_prev`` (and ``v_prev`` when damped) for
HHT) on mass-orthonormal POD bases (rotated, :mod:`.balance`).
A step evaluates the separated sum at ``(q, lam)`` — its weights ``w_i = prod_d
G_{i,d}(p_d)`` — and maps them to the next coordinates with ``R = Phi^T M F`` (reduced
offline): P x N + n_q x N operations. The full field of the step is ``F_u w``
(:meth:`DirectModel.reconstruct`, timed apart); monitored outputs use ``C F_u`` (n_out x N).
"""
from __future__ import annotations

import math

import numpy as np

from ..base import DeferredStepResult, OnlineModel, StepResult
from ..online import parameter
from .schemes import SCHEMES, StepOperators, VectorAlgebra
from .step_vademecum import Evaluator, StepVademecum

__all__ = ["DirectModel"]


class DirectModel(OnlineModel):
    """Trajectory model: ``start(mu0, state0, dt)`` then ``step({"time": t, "load_factor": lam})``.

    Attributes
    ----------
    vademecum : StepVademecum
    extrapolations : int
        Steps since ``start`` whose input lay outside the parameter intervals.
    info : dict
        Offline record (:attr:`StepVademecum.stats`).
    """

    name = "pgd_direct"
    kind = "trajectory"

    def __init__(self, vademecum: StepVademecum, ops: StepOperators, bases: dict, free_dofs, ndof: int,
                 load_at: str = "end"):
        self.vademecum, self.ops, self.bases = vademecum, ops, bases
        self.free_dofs, self.ndof, self.load_at = np.asarray(free_dofs), int(ndof), load_at
        self.scheme = SCHEMES[vademecum.scheme]
        self.fields = self.scheme.state_fields(ops.C is not None)
        self.info = dict(vademecum.stats)
        self._eval = Evaluator(vademecum)
        sizes = [bases[f].shape[1] for f in self.fields]
        offs = np.concatenate([[0], np.cumsum(sizes)])
        self._slices = {f: slice(offs[i], offs[i + 1]) for i, f in enumerate(self.fields)}
        self._nq = int(offs[-1])
        # next coordinates = R @ weights on the computed fields; shifts copy coordinates
        R = np.zeros((self._nq, vademecum.n_modes))
        for f in self.scheme.outputs:
            R[self._slices[f]] = bases[f].T @ (ops.M @ vademecum.space[f])
        self._R = R
        self._shift = [(self._slices[dst], self._slices[src])
                       for dst, src in self.scheme.state_shifts(ops.C is not None).items()]
        self._p = np.zeros(self._nq + 1)
        self._last_start = (None, None, None)
        self.start()

    # ------------------------------------------------------------------ contract
    @property
    def n_reduced(self) -> int:
        return self._nq

    @property
    def envelope(self) -> dict:
        return self.vademecum.domains

    def start(self, mu0=None, state0=None, dt=None) -> None:
        """Project ``state0`` (full ``u``, ``v`` (n_dof,); default rest) on the bases.

        The other state fields come from the scheme's start (:attr:`Scheme.initial`: the
        Taylor ``u_prev`` of central difference with the equilibrium acceleration at
        ``mu0["load_factor"]``, 0 without ``mu0``; ``u_prev = u0`` for HHT). ``dt`` must be
        the vademecum's (ValueError otherwise).
        """
        vd = self.vademecum
        if dt is not None and not np.isclose(float(dt), vd.dt, rtol=1e-9, atol=0.0):
            raise ValueError(f"pgd_direct.start: dt = {dt!r}, but the vademecum integrates dt = {vd.dt!r}; "
                             "build one for this dt")
        lam0 = 0.0 if not mu0 or "load_factor" not in mu0 else float(mu0["load_factor"])
        x = {}
        for key in ("u", "v"):
            val = None if state0 is None else state0.get(key)
            x[key] = np.zeros(len(self.free_dofs)) if val is None else np.asarray(val, float)[self.free_dofs]
        x = VectorAlgebra(self.ops, lam0).initial_state(self.scheme, x["u"], x["v"], vd.dt)
        self.q = np.concatenate([self.bases[f].T @ (self.ops.M @ x[f]) for f in self.fields])
        self._lam_prev = lam0
        self._last_start = (mu0, state0, dt)
        self.extrapolations, self.n_steps = 0, 0

    def reset(self) -> None:
        """Restart from the last :meth:`start` arguments (the latency protocol repeats runs)."""
        self.start(*self._last_start)

    def step(self, mu) -> StepResult:
        """Advance one step with ``mu["load_factor"]`` (see ``load_at``); reduced work only.

        Status ``"extrapolation"`` when a coordinate of the previous state or the load
        factor lies outside its interval (the value is linearly extrapolated, and counted
        in :attr:`extrapolations`); ``"failed"`` on a non-finite state (kept unchanged).
        """
        lam_new = parameter(mu, "load_factor", self.name)
        p = self._p
        p[:-1] = self.q
        p[-1] = (lam_new if self.load_at == "end" else self._lam_prev if self.load_at == "start"
                 else 0.5 * (lam_new + self._lam_prev))
        self.n_steps += 1
        ev = self._eval
        s = ev.positions(p)
        if not math.isfinite(s.sum()) and not np.all(np.isfinite(p)):  # one reduction on the haptic path
            return StepResult(None, "failed", f"step {self.n_steps}: non-finite input (load factor {lam_new!r} "
                              "or the previous state)", {"step": self.n_steps}, mu)
        inside = ev.inside(s)
        out = None if inside else ev.outside(s)
        w = ev.blend(s)
        with np.errstate(over="ignore", invalid="ignore"):
            q = np.dot(self._R, w)
        for dst, src in self._shift:
            q[dst] = self.q[src]
        if not math.isfinite(q.sum()) and not np.all(np.isfinite(q)):
            return StepResult(None, "failed", f"step {self.n_steps}: non-finite state (extrapolated far outside "
                              "the parameter intervals)", {"step": self.n_steps}, mu)
        self.q, self._lam_prev = q, lam_new
        info = {"weights": w, "step": self.n_steps}
        if out is not None and out.size:
            self.extrapolations += 1
            d = int(out[0])
            n_out, step, value = out.size, self.n_steps, float(p[d])  # p is overwritten by the next step
            name, (lo, hi) = self.vademecum.param_names[d], (self.vademecum.meshes[d].lo, self.vademecum.meshes[d].hi)
            return DeferredStepResult(q, "extrapolation", lambda: (
                f"step {step}: {n_out} parameter(s) outside the vademecum, e.g. {name} = {value:.6g} not in "
                f"[{lo:.6g}, {hi:.6g}]; linearly extrapolated"), info, mu)
        return StepResult(q, "ok", "", info, mu)

    def floor_ops(self):
        """The vademecum's evaluation at the current state (positions, the gather of the P factors'
        elements, the product over parameters), the next coordinates ``R w`` and the output
        product ``C F_u w``."""
        ev, p = self._eval, self._p.copy()
        p[:-1], p[-1] = self.q, 0.0
        R, q = self._R, np.empty(self._R.shape[0])
        C_r = getattr(self, "_outputs", (None, None, None))[2]
        y = np.empty(0 if C_r is None else C_r.shape[0])

        def floor():
            w = ev.blend(ev.positions(p))
            np.dot(R, w, out=q)
            if C_r is not None:
                np.dot(C_r, w, out=y)
        return floor

    # ------------------------------------------------------------------ fields and outputs
    def _weights(self, result: StepResult):
        if result.q is None:
            raise ValueError(f"{self.name}: the step failed ({result.message}); no state")
        return (result.info or {}).get("weights")

    def field(self, result: StepResult, name: str = "u") -> np.ndarray:
        """Full (n_dof,) vector of a field (``u``, ``v``) at the step (zero on the fixed dofs).

        A computed field is the vademecum's ``F w``; a shifted one (``u_prev``) the
        projection of its coordinates. Offline use (energy, plots); ValueError otherwise.
        """
        w = self._weights(result)
        x = np.zeros(self.ndof)
        if w is not None and name in self.vademecum.space:
            x[self.free_dofs] = self.vademecum.space[name] @ w
        elif name in self._slices:  # a state carried without weights: its projection
            x[self.free_dofs] = self.bases[name] @ result.q[self._slices[name]]
        else:
            raise ValueError(f"{self.name}: field {name!r} is not computed by {self.scheme.name}")
        return x

    def reconstruct(self, result: StepResult) -> np.ndarray:
        """Full displacement (n_dof,): the vademecum's ``F_u w`` (homogeneous Dirichlet dofs are zero)."""
        return self.field(result, "u")

    def attach_outputs(self, operators) -> None:
        """Reduce linear outputs ``{name: c (n_dof,)}`` to ``c[free] F_u`` (n_out x N)."""
        names = list(operators)
        C = np.array([np.asarray(operators[n], float) for n in names]).reshape(len(names), -1)
        self._outputs = (names, C, np.ascontiguousarray(C[:, self.free_dofs] @ self.vademecum.space["u"]))

    def outputs(self, result: StepResult) -> dict:
        names, _, C_r = getattr(self, "_outputs", ((), None, None))
        if not names:
            return {}
        if result.q is None:
            return {n: float("nan") for n in names}
        w = (result.info or {}).get("weights")
        y = np.dot(C_r, w) if w is not None else self._outputs[1] @ self.reconstruct(result)
        return dict(zip(names, y.tolist()))
