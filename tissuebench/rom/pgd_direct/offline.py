"""Offline PGD solution of one time step, parametrised by the previous state and the load.

The parametric problem (paper §3-4): for every previous state ``x_n = sum_j phi_j q_j``
(reduced coordinates on the POD bases of the state fields) and load factor ``lam`` in
their intervals, the state at ``t + dt`` given by the inner integrator. In weak form over
the parameter domain, each linear solve of the scheme (``c_m M + w(c_c C + K)`` for an
implicit sub-step, ``M`` for the explicit update) becomes

    (A ⊗ W_1 ⊗ ... ⊗ W_P) y = sum_t r_t ⊗ W_1 g_1t ⊗ ... ⊗ W_P g_Pt,

with ``W_d`` the P1 mass matrix of parameter ``d`` (divided by its interval length) and
the right-hand side a :class:`~.fields.SepField` built from the inputs (``u_n = sum_j phi_j ⊗ q_j``, ``lam f``)
and earlier sub-steps. Each is solved by greedy PGD with alternating directions
(:func:`tissuebench.rom.separated_solver.pgd_solve`) over space x each reduced coordinate x
load: the explicit update ``M z = r`` of the paper's explicit schemes, the sub-steps of
an implicit one (and HHT's acceleration). The fields at ``t + dt`` are then exact linear
combinations of the inputs and of those PGD modes; the vademecum is that separated sum
(terms with the same parametric factors merged). A last PGD compression of the stacked
fields was tried and dropped: its greedy enrichment stalls on fields of different units
(clamped_beam, Bathe: 150 modes for a 1e-3 error where the sub-steps need 10 each).
Every solve is recorded (modes, fixed-point iterations, stop reason, residuals, time).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from ..separated import SeparatedOperator, SeparatedVector
from ..separated_solver import pgd_solve
from .fields import SepField, coordinate_field, parameter_field, stack_fields
from .schemes import Scheme, StepOperators, scheme_step
from .step_vademecum import StepVademecum

__all__ = ["PgdSettings", "SeparatedAlgebra", "build_vademecum"]


@dataclass(frozen=True)
class PgdSettings:
    """Options of every PGD solve of the build.

    Attributes
    ----------
    max_modes : int
        Largest number of modes of every PGD solve.
    tol : float
        Amplitude stop (mode amplitude / first mode's): the main criterion, reliable to
        round-off (a linear step map has an exact separated rank, the next mode's
        amplitude then drops to ~1e-15).
    residual_tol : float, optional
        Stop on the relative residual of the weak equations (its separated evaluation
        is reliable only down to ~1e-7; None: not used).
    max_fixed_point, fixed_point_tol : int, float
        Alternating-direction sweeps per mode and their convergence tolerance.
    seed : int
        Seed of the random initial factors.
    """

    max_modes: int = 200
    tol: float = 1e-12
    residual_tol: float | None = None
    max_fixed_point: int = 50
    fixed_point_tol: float = 1e-8
    seed: int = 0
    update_last: bool = False


def _record(name, sol, t0, n_terms):
    return {"solve": name, "modes": sol.n_modes, "fixed_point_iterations": list(sol.fixed_point_iterations),
            "fixed_point_converged": [bool(c) for c in sol.converged], "stop_reason": sol.stop_reason,
            "residual": float(sol.residuals[-1]) if sol.residuals else float("nan"),
            "rhs_terms": n_terms, "wall_s": time.perf_counter() - t0}


class SeparatedAlgebra:
    """The scheme formulas on separated fields; implicit solves by PGD (see the module docstring).

    Parameters
    ----------
    ops : StepOperators
    meshes : list of ParameterMesh
        The P parameter meshes (reduced coordinates, then the load factor).
    inputs : dict
        State field -> SepField of the previous state.
    internal_force_field : SepField, optional
        ``f_int(u_n)`` of a nonlinear system (polynomial in the coordinates, :mod:`.nonlinear`).
    settings : PgdSettings
    """

    def __init__(self, ops: StepOperators, meshes, inputs: dict, settings: PgdSettings,
                 internal_force_field: SepField | None = None):
        self.ops, self.meshes, self.inputs, self.settings = ops, list(meshes), inputs, settings
        # the L2 inner product of each parameter normalised by its interval length: the
        # Galerkin solution is unchanged (every W_d scales both sides), but the products of
        # P parameter norms in the alternating directions stay O(1) (with 61 parameters of
        # width ~1e-4 they underflowed and the first mode broke down on liver_dynamic)
        self.W = [m.mass() / (m.hi - m.lo) for m in self.meshes]
        self._load = parameter_field(ops.f, len(self.meshes) - 1, self.meshes)
        self._fint = internal_force_field
        self.rng = np.random.default_rng(settings.seed)
        self.records = []
        if not ops.linear and internal_force_field is None:
            raise ValueError("SeparatedAlgebra: a nonlinear system needs the separated internal force of u_n")

    # --------------------------------------------------------------- the algebra
    def load(self):
        return self._load

    def internal_force(self, u: SepField) -> SepField:
        if self._fint is not None and u is self.inputs.get("u"):
            return self._fint
        if self.ops.linear:
            return u.apply(self.ops.K)
        raise ValueError("the separated internal force is only known for the previous displacement u_n "
                         "(implicit schemes need a linear system)")

    def K(self, x):
        return x.apply(self.ops.K)

    def M(self, x):
        return x.apply(self.ops.M)

    def damp(self, x):
        return SepField.zeros(x.n_space, self.meshes) if self.ops.C is None else x.apply(self.ops.C)

    def pgd(self, name, A, rhs: SepField, max_modes: int):
        """PGD solution of ``(A ⊗ W_1 ⊗ ... ⊗ W_P) y = rhs`` (rhs in nodal form)."""
        t0 = time.perf_counter()
        rhs = rhs.combined()
        if rhs.n_terms == 0:
            raise ValueError(f"{name}: the right-hand side is zero")
        s = self.settings
        sol = pgd_solve(SeparatedOperator([(A, *self.W)]), SeparatedVector(rhs.weak_terms(None, self.W)),
                        max_modes=max_modes, tol=s.tol, residual_tol=s.residual_tol,
                        max_fixed_point=s.max_fixed_point, fixed_point_tol=s.fixed_point_tol, rng=self.rng,
                        update_last=s.update_last)
        self.records.append(_record(name, sol, t0, rhs.n_terms))
        if not sol.modes:
            raise RuntimeError(f"{name}: the PGD returned no mode ({sol.message})")
        return SepField.from_modes(sol.modes), sol

    def mass_solve(self, rhs, name: str = "mass", max_modes: int | None = None):
        """``M y = rhs`` in separated form (an acceleration, or the explicit update of a field)."""
        y, _ = self.pgd(name, self.ops.M, rhs, max_modes or self.settings.max_modes)
        return y

    def solve(self, name, c_m, c_c, w, rhs):
        """Implicit sub-step ``(c_m M + w (c_c C + K)) y = rhs`` in separated form."""
        y, _ = self.pgd(name, self.ops.effective(c_m, c_c, w), rhs, self.settings.max_modes)
        return y


def build_vademecum(ops: StepOperators, scheme: Scheme, bases: dict, meshes, dt: float, settings: PgdSettings,
                    internal_force_field=None, **options) -> StepVademecum:
    """PGD vademecum of one step of ``scheme``.

    Parameters
    ----------
    ops : StepOperators
    scheme : Scheme
    bases : dict
        State field (``scheme.state_fields(damped)``) -> (n_free, m_k) basis of its coordinates.
    meshes : list of ParameterMesh
        ``sum m_k`` coordinate meshes in field order, then the load-factor mesh.
    dt : float
        Time step [s].
    settings : PgdSettings
    internal_force_field : SepField, optional
        Separated ``f_int(u_n)`` (nonlinear systems).
    **options
        Scheme options (HHT: alpha).
    """
    t0 = time.perf_counter()
    options = {k: v for k, v in options.items() if k in scheme.options}
    fields = scheme.state_fields(ops.C is not None)
    dims, start, names = {}, 0, []
    for f in fields:
        m = bases[f].shape[1]
        dims[f] = list(range(start, start + m))
        names += [f"{f}:{j}" for j in range(m)]
        start += m
    if len(meshes) != start + 1:
        raise ValueError(f"build_vademecum: {len(meshes)} meshes for {start} coordinates + the load")
    inputs = {f: coordinate_field(bases[f], dims[f], meshes) for f in fields}
    alg = SeparatedAlgebra(ops, meshes, inputs, settings, internal_force_field)
    out = scheme_step(scheme, alg, inputs, dt, **options)
    fields_out = []
    for k in scheme.outputs:
        kind, x = out[k]
        if kind == "mass":  # the explicit update M z = r: the PGD solve of the paper's explicit schemes
            x = alg.mass_solve(x, name=f"update {k}", max_modes=settings.max_modes)
        fields_out.append(x)
    # the step = exact combinations of the inputs and of the PGD modes of every solve;
    # terms with the same parametric factors (an input entering several fields) merged
    Z = stack_fields(fields_out).combined()
    n = ops.n
    space = {k: np.ascontiguousarray(Z.space[i * n:(i + 1) * n]) for i, k in enumerate(scheme.outputs)}
    stats = {"solves": alg.records, "separated_terms": Z.n_terms, "offline_s": time.perf_counter() - t0,
             "pgd_modes": {r["solve"]: r["modes"] for r in alg.records},
             "fixed_point_iterations": {r["solve"]: r["fixed_point_iterations"] for r in alg.records}}
    return StepVademecum(scheme.name, float(dt), dict(options), names + ["load_factor"], list(meshes), space,
                     np.stack(Z.factors), stats)
