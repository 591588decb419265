"""The time integrators inside one step, written once for vectors and for separated fields.

Each scheme maps the state at ``t_n`` and the load factor ``lam`` of the step (held
constant over ``[t_n, t_n + dt]``, the paper's assumption, §4.1) to the state at
``t_n + dt`` for ``M a + C v + f_int(u) = lam f``. The formulas only add, scale, apply
``M``, ``K``, ``C`` and solve with ``c_m M + w (c_c C + K)``, through an *algebra*:

* :class:`VectorAlgebra` runs them on free-dof vectors (the explicit update formula of
  the inner integrator, used as the reference of one step);
* :class:`~tissuebench.rom.pgd_direct.offline.SeparatedAlgebra` runs them on
  :class:`~tissuebench.rom.pgd_direct.fields.SepField` inputs, each implicit solve being a
  PGD solve of the parametric problem (the vademecum).

A scheme returns, per computed field, ``("value", x)`` (the field itself) or
``("mass", r)`` (the field is ``M^{-1} r``: the explicit update of the paper, solved as
``M z = r`` in separated form).

Schemes (state fields in brackets)
----------------------------------
``forward_euler`` [u, v]
    ``u1 = u0 + dt v0``, ``M v1 = M v0 + dt (lam f - f_int(u0) - C v0)``; first order,
    unconditionally unstable on an undamped oscillator (as ``refsolvers`` ForwardEuler).
``central_difference`` [u, u_prev]
    The paper's explicit scheme on ``u^n, u^{n-1}`` (its "forward Euler", Fig. 7):
    ``M (u1 - 2 u0 + u_prev) = dt^2 (lam f - f_int(u0) - C (u0 - u_prev) / dt)``; the next
    ``u_prev`` is ``u0`` (a shift of reduced coordinates, not a vademecum output).
``bathe`` [u, v]
    Bathe's composite scheme (trapezoidal half step, then 3-point backward Euler), as
    ``refsolvers`` Bathe; the acceleration at ``t_n`` comes from equilibrium at ``lam``.
``hht`` [u, v, u_prev (, v_prev when damped)]
    HHT-alpha (beta = (1 - alpha)^2 / 4, gamma = 1/2 - alpha). HHT's acceleration is not
    in equilibrium; it follows from the previous step's HHT equation, so the previous
    displacement (and velocity) are state fields (better captured by the POD of
    displacements than accelerations are: 77 % of the energy in 8 modes on wave_block).
Implicit schemes need a linear system (the separated nonlinear solve is not implemented).
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["SCHEMES", "Scheme", "StepOperators", "VectorAlgebra", "scheme_step"]


@dataclass
class StepOperators:
    """The semi-discrete system on the free dofs: ``M a + C v + f_int(u) = lam f``.

    Attributes
    ----------
    M, K : sparse (n, n)
        Mass [kg] and stiffness (tangent at u = 0) [N/m].
    f : (n,) array
        External force at load factor 1 [N].
    C : sparse (n, n) or None
        Damping [N s/m].
    internal_force : callable ``(n,) -> (n,)``, optional
        Nonlinear internal force [N] on the free dofs; None for ``f_int = K u``.
    """

    M: sp.spmatrix
    K: sp.spmatrix
    f: np.ndarray
    C: sp.spmatrix | None = None
    internal_force: Callable | None = None

    @property
    def n(self) -> int:
        return self.M.shape[0]

    @property
    def linear(self) -> bool:
        return self.internal_force is None

    def effective(self, c_m: float, c_c: float, w: float) -> sp.csc_matrix:
        """``c_m M + w (c_c C + K)``, the matrix of an implicit (sub)step."""
        A = c_m * self.M + w * self.K
        if self.C is not None:
            A = A + (w * c_c) * self.C
        return sp.csc_matrix(A)


def _forward_euler(alg, x, dt):
    u, v = x["u"], x["v"]
    r = alg.load() - alg.internal_force(u) - alg.damp(v)
    return {"u": ("value", u + dt * v), "v": ("mass", alg.M(v) + dt * r)}


def _central_difference(alg, x, dt):
    u, up = x["u"], x["u_prev"]
    # damping with the lagged half-step velocity (u^n - u^{n-1}) / dt, as refsolvers with beta_k > 0
    r = alg.load() - alg.internal_force(u) - alg.damp((u - up) / dt)
    return {"u": ("mass", alg.M(2.0 * u - up) + (dt * dt) * r)}


def _bathe(alg, x, dt):
    u0, v0 = x["u"], x["v"]
    h = 0.5 * dt
    f = alg.load()
    Ma0 = f - alg.K(u0) - alg.damp(v0)                 # M a0: equilibrium at the step's load
    # sub-step 1 (trapezoidal over h): v = 2/h (u - u0) - v0, a = 4/h^2 (u - u0) - 4/h v0 - a0
    v_hat = -(2.0 / h) * u0 - v0
    Ma_hat = -alg.M((4.0 / h**2) * u0 + (4.0 / h) * v0) - Ma0
    uh = alg.solve("bathe_1", 4.0 / h**2, 2.0 / h, 1.0, f - Ma_hat - alg.damp(v_hat))
    vh = (2.0 / h) * (uh - u0) - v0
    # sub-step 2 (3-point backward Euler): v = (u0 - 4 uh + 3 u)/dt, a = (v0 - 4 vh + 3 v)/dt
    v_hat2 = (u0 - 4.0 * uh) / dt
    a_hat2 = (v0 - 4.0 * vh) / dt + (3.0 / dt) * v_hat2
    u1 = alg.solve("bathe_2", 9.0 / dt**2, 3.0 / dt, 1.0, f - alg.M(a_hat2) - alg.damp(v_hat2))
    return {"u": ("value", u1), "v": ("value", (3.0 / dt) * u1 + v_hat2)}


def _hht(alg, x, dt, alpha=-0.05):
    beta, gamma = (1.0 - alpha) ** 2 / 4.0, 0.5 - alpha
    u0, v0, up = x["u"], x["v"], x["u_prev"]
    vp = x.get("v_prev")
    w = 1.0 + alpha
    f = alg.load()
    # HHT's a0 from the equation of the previous step, with the load factor of this step
    # (a piecewise-constant load: the acceleration jumps with the load at t_n)
    Ma0 = f - w * (alg.K(u0) + alg.damp(v0)) + alpha * alg.K(up)
    if vp is not None:
        Ma0 = Ma0 + alpha * alg.damp(vp)
    a0 = alg.mass_solve(Ma0)
    # Newmark kinematics: a = c_m u + a_hat, v = c_c u + v_hat
    c_m, c_c = 1.0 / (beta * dt * dt), gamma / (beta * dt)
    Ma_hat = -c_m * alg.M(u0 + dt * v0) - (0.5 / beta - 1.0) * Ma0
    v_hat = v0 - (c_c * dt) * v0 - c_c * u0 + (dt * (1.0 - gamma / (2.0 * beta))) * a0
    # M a1 + (1 + alpha)(C v1 + K u1 - f) - alpha (C v0 + K u0 - f) = 0, f held over the step
    rhs = f + alpha * (alg.damp(v0) + alg.K(u0)) - Ma_hat - w * alg.damp(v_hat)
    u1 = alg.solve("hht", c_m, c_c, w, rhs)
    return {"u": ("value", u1), "v": ("value", c_c * u1 + v_hat)}


def _cd_initial(alg, x, dt):
    """u^{-1} of the Taylor start: u0 - dt v0 + dt^2/2 a0 (a0 from equilibrium)."""
    a0 = alg.mass_solve(alg.load() - alg.internal_force(x["u"]) - alg.damp(x["v"]))
    return {"u_prev": x["u"] - dt * x["v"] + (0.5 * dt * dt) * a0}


def _hht_initial(alg, x, dt):
    """u_prev = u0, v_prev = v0: HHT's a0 is then the equilibrium acceleration (its start)."""
    return {"u_prev": x["u"], "v_prev": x["v"]}


def _no_initial(alg, x, dt):
    return {}


@dataclass(frozen=True)
class Scheme:
    """A one-step scheme: its state fields, what the vademecum computes, what is shifted.

    Attributes
    ----------
    name : str
    fields : tuple of str
        State fields, in the order of the reduced coordinates.
    outputs : tuple of str
        Fields computed by the step (vademecum outputs).
    shifts : dict
        ``next field -> current field`` copied exactly (central difference: u_prev <- u).
    basis : dict
        Field -> POD basis it is projected on ("u" or "v").
    implicit : bool
    options : tuple of str
        Scheme options (HHT: alpha).
    damped_fields : tuple of str
        Extra state fields when the system is damped (HHT: v_prev).
    initial : callable ``(alg, {"u", "v"}, dt) -> dict``
        The other state fields of a start from displacement and velocity.
    """

    name: str
    fields: tuple
    outputs: tuple
    implicit: bool
    run: Callable
    shifts: dict = field(default_factory=dict)
    basis: dict = field(default_factory=dict)
    options: tuple = ()
    damped_fields: tuple = ()
    initial: Callable = _no_initial

    def state_fields(self, damped: bool) -> tuple:
        """The state fields for a damped or undamped system."""
        return self.fields + (self.damped_fields if damped else ())

    def state_shifts(self, damped: bool) -> dict:
        return {k: v for k, v in self.shifts.items() if k in self.state_fields(damped)}


SCHEMES = {
    "forward_euler": Scheme("forward_euler", ("u", "v"), ("u", "v"), False, _forward_euler,
                            basis={"u": "u", "v": "v"}),
    "central_difference": Scheme("central_difference", ("u", "u_prev"), ("u",), False, _central_difference,
                                 shifts={"u_prev": "u"}, basis={"u": "u", "u_prev": "u"}, initial=_cd_initial),
    "bathe": Scheme("bathe", ("u", "v"), ("u", "v"), True, _bathe, basis={"u": "u", "v": "v"}),
    "hht": Scheme("hht", ("u", "v", "u_prev"), ("u", "v"), True, _hht,
                  shifts={"u_prev": "u", "v_prev": "v"}, basis={"u": "u", "v": "v", "u_prev": "u", "v_prev": "v"},
                  options=("alpha",), damped_fields=("v_prev",), initial=_hht_initial),
}


def scheme_step(scheme: Scheme, alg, state: dict, dt: float, **options) -> dict:
    """Run ``scheme`` on ``state`` ({field: value}) with the algebra ``alg``; returns its outputs."""
    return scheme.run(alg, state, dt, **{k: v for k, v in options.items() if k in scheme.options})


class VectorAlgebra:
    """The scheme formulas on free-dof vectors at load factor ``lam`` (one full-size step).

    Implicit solves use a sparse LU cached per matrix, so a loop of steps costs one
    factorisation per sub-step matrix.
    """

    def __init__(self, ops: StepOperators, lam: float = 0.0):
        self.ops, self.lam = ops, float(lam)
        self._lu = {}

    def load(self):
        return self.lam * self.ops.f

    def internal_force(self, u):
        return self.ops.K @ u if self.ops.linear else np.asarray(self.ops.internal_force(u), dtype=float)

    def K(self, x):
        return self.ops.K @ x

    def M(self, x):
        return self.ops.M @ x

    def damp(self, x):
        return np.zeros_like(x) if self.ops.C is None else self.ops.C @ x

    def solve(self, name, c_m, c_c, w, rhs):
        key = (name, c_m, c_c, w)
        if key not in self._lu:
            self._lu[key] = spla.splu(self.ops.effective(c_m, c_c, w))
        return self._lu[key].solve(rhs)

    def mass_solve(self, rhs):
        if "mass" not in self._lu:
            self._lu["mass"] = spla.splu(sp.csc_matrix(self.ops.M))
        return self._lu["mass"].solve(rhs)

    def initial_state(self, scheme: Scheme, u, v, dt: float, lam: float | None = None) -> dict:
        """The full state of ``scheme`` starting from displacement ``u`` and velocity ``v`` at ``lam``."""
        if lam is not None:
            self.lam = float(lam)
        x = {"u": np.asarray(u, dtype=float), "v": np.asarray(v, dtype=float)}
        x.update(scheme.initial(self, x, dt))
        return {k: x[k] for k in scheme.state_fields(self.ops.C is not None)}

    def step(self, scheme: Scheme, state: dict, dt: float, lam: float | None = None, **options) -> dict:
        """Next state ``{field: (n,) array}`` (shifts included) from ``state`` at load factor ``lam``."""
        if lam is not None:
            self.lam = float(lam)
        out = scheme_step(scheme, self, state, dt, **options)
        nxt = {k: (x if kind == "value" else self.mass_solve(x)) for k, (kind, x) in out.items()}
        nxt.update({k: state[src] for k, src in scheme.shifts.items() if k in state})
        return nxt
