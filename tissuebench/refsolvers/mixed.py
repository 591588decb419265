"""Incompressible solids: the mixed u-p formulation with Taylor-Hood P2-P1 elements.

A displacement-only model of a nearly incompressible solid with a penalty kappa/2 (J - 1)^2
locks: P1 through a 3 mm ventricle wall, and even P2 on Land et al.'s beam stays below the
codes that impose J = 1. Here the volumetric part U(J) of the material
(:meth:`~tissuebench.refsolvers.materials.Material.volumetric`) is replaced by a pressure-like
Lagrange multiplier p, continuous and piecewise linear (Taylor-Hood, inf-sup stable):

    L(u, p) = int [W(F) - U(J) + p (J - 1) - p^2 / (2 kappa)] dV - external work,

the last term only with a finite ``bulk_modulus`` (perturbed Lagrangian; the default None
imposes J = 1); ``penalty_weight`` w keeps w U(J) as well, a stabilisation that leaves the
constraint, and so the converged limit, unchanged. With W = C/2 (exp Q - 1) + kappa/2 (J - 1)^2 (Guccione) this is the
incompressible Guccione law of Land et al. 2015; p is the mean (Kirchhoff) stress.

:class:`MixedBackend` presents the mixed system as a :class:`~.backends.base.Backend` whose
unknowns are ``z = [u (3 n_nodes), p (n_vertices)]``, so the load-stepped Newton of
:mod:`.newton` (increment cutting, inverted-element guard) solves it unchanged; follower
pressure and dead loads come from the displacement backend. Both backends implement the
forms (:mod:`.backends.mixed_ngsolve` symbolically, :mod:`.backends.mixed_skfem` by hand)
and agree to round-off on the same mesh. Static analysis only.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .backends.base import Backend, make_backend
from .newton import StaticResult, newton_solve

__all__ = ["MixedBackend", "MixedResult", "solve_mixed"]


class MixedLayout:
    """Dofs of ``z = [u, p]`` with the Dirichlet data of the displacement ``problem``.

    The pressure dofs (one per mesh vertex, after the 3 n_nodes displacement dofs) are
    all free; the fixed dofs are the problem's.
    """

    def __init__(self, problem):
        self.problem = problem
        self.n_u, self.n_p = problem.ndof, problem.mesh.n_vertices
        self.ndof = self.n_u + self.n_p
        self.fixed_dofs = problem.fixed_dofs
        self.free_dofs = np.concatenate([problem.free_dofs, self.n_u + np.arange(self.n_p)])
        self.nodes = problem.nodes
        self.material = problem.material

    def prescribed_values(self, load_factor: float) -> np.ndarray:
        return self.problem.prescribed_values(load_factor)


class MixedBackend(Backend):
    """Operators of the mixed u-p (P2-P1) formulation of a P2 ``problem``.

    Parameters
    ----------
    problem : Problem
        ``element="P2"``; a material with a volumetric part (neo-Hookean, decoupled
        neo-Hookean, Mooney-Rivlin, Guccione).
    backend : {"ngsolve", "skfem"} or Backend (a displacement backend of ``problem``, reused)
    bulk_modulus : float or None
        None: incompressible (J = 1); a number > 0: perturbed Lagrangian with that modulus.
    penalty_weight : float
        Fraction w in [0, 1] of the material's volumetric penalty U(J) kept beside the
        constraint (in the spirit of Land et al. 2014, IEEE TBME 62, "Improving the stability
        of cardiac mechanical simulations"). The constraint still holds (the L2 projection of
        J - 1 on the pressure space is zero), so the limit is the incompressible one; w U only
        damps the part of J - 1 the P1 pressure cannot see, which with w = 0 lets det F
        collapse inside a cell under large inflation (the ventricle stalls at 7.3 kPa of 10,
        min det F = 0.09 at 7 kPa). w = 1 locks again on coarse meshes (beam (10, 2, 2):
        3.887 mm against 4.116 with w = 0).
    """

    name = "mixed"

    def __init__(self, problem, backend="ngsolve", bulk_modulus=None, penalty_weight=0.0):
        if problem.element != "P2":
            raise ValueError(f"element={problem.element!r}: the mixed formulation is Taylor-Hood P2-P1, use 'P2'")
        problem.material.volumetric(np.ones(1))  # TypeError for materials without a volumetric part
        if bulk_modulus is not None and not (math.isfinite(bulk_modulus) and bulk_modulus > 0):
            raise ValueError(f"bulk_modulus must be None or a finite number > 0, got {bulk_modulus!r}")
        if not (isinstance(penalty_weight, (int, float)) and 0.0 <= penalty_weight <= 1.0):
            raise ValueError(f"penalty_weight must be a number in [0, 1], got {penalty_weight!r}")
        # a displacement backend of the same problem may be handed in (the scene runner's): not built twice
        self.displacement_backend = backend if isinstance(backend, Backend) and backend.problem is problem \
            else make_backend(backend, problem)
        super().__init__(MixedLayout(problem))
        if self.displacement_backend.name == "ngsolve":
            from .backends.mixed_ngsolve import NgsolveMixedForms as Forms
        elif self.displacement_backend.name == "skfem":
            from .backends.mixed_skfem import SkfemMixedForms as Forms
        else:
            raise ValueError(f"backend={backend!r}: the mixed formulation runs on 'ngsolve' or 'skfem'")
        self.forms = Forms(self.displacement_backend, bulk_modulus, penalty_weight)
        self.n_u, self.n_p = self.problem.n_u, self.problem.n_p

    def split(self, z):
        """(u (3 n_nodes,), p (n_vertices,)) of a mixed state."""
        z = self._check_u(z)
        return z[:self.n_u], z[self.n_u:]

    # ------------------------------------------------------------------ operators
    def internal_force(self, z):
        return self.forms.force(self._check_u(z))

    def tangent(self, z):
        return self.forms.tangent(self._check_u(z))

    def internal_force_and_tangent(self, z):
        return self.forms.force_and_tangent(self._check_u(z))

    def external_force(self, z, load_factor):
        u, _ = self.split(z)
        return np.concatenate([self.displacement_backend.external_force(u, load_factor), np.zeros(self.n_p)])

    def external_tangent(self, z, load_factor):
        u, _ = self.split(z)
        K = self.displacement_backend.external_tangent(u, load_factor)
        return None if K is None else sp.block_diag((K, sp.csr_matrix((self.n_p, self.n_p))), format="csr")

    def strain_energy(self, z):
        """Integral of the Lagrangian density W - U + p (J - 1) (- p^2 / 2 kappa)."""
        return self.forms.lagrangian(self._check_u(z))

    def min_jacobian(self, z):
        return self.displacement_backend.min_jacobian(self.split(z)[0])

    def mass(self, lumped=False):
        raise NotImplementedError("the mixed formulation is static only (no mass)")

    def element_strain_energies(self, z):
        raise NotImplementedError("element quantities are not defined for the mixed formulation")

    def element_internal_forces(self, z):
        raise NotImplementedError("element quantities are not defined for the mixed formulation")

    def make_linear_solver(self, name="auto", **options):
        """:class:`~.saddle_solver.SaddlePointSolver` (the tangent is indefinite): LDL^T of the
        regularised symmetric part + GMRES, falling back to SuperLU (COLAMD); for ``"auto"``
        and ``"direct"`` alike."""
        if name not in ("auto", "direct"):
            raise ValueError(f"linear_solver={name!r}: the mixed formulation needs 'auto' or 'direct' "
                             "(indefinite tangent)")
        from .saddle_solver import SaddlePointSolver

        return SaddlePointSolver(self.n_p, **options)


@dataclass
class MixedResult:
    """Outcome of :func:`solve_mixed`: final ``u`` (3 n_nodes,) and ``p`` (n_vertices,),
    the Newton record ``newton`` (states are mixed vectors ``[u, p]``)."""

    status: str
    message: str
    u: np.ndarray
    p: np.ndarray
    load_factor: float
    newton: StaticResult

    @property
    def success(self) -> bool:
        return self.status == "success"


def solve_mixed(problem, backend="ngsolve", load_factor=1.0, bulk_modulus=None, penalty_weight=0.0,
                **newton_options) -> MixedResult:
    """Load-stepped Newton on the mixed u-p system of ``problem`` (see :class:`MixedBackend`).

    ``newton_options`` are :class:`~.newton.NewtonOptions` fields (``n_increments``,
    ``rtol``, ``strict`` ...). A stall is a status of the result, as for :func:`newton_solve`.
    """
    mb = MixedBackend(problem, backend, bulk_modulus, penalty_weight)
    res = newton_solve(mb, load_factor, **newton_options)
    u, p = mb.split(res.u)
    return MixedResult(res.status, res.message, u.copy(), p.copy(), res.load_factor, res)


def static_run(problem, backend, n_steps, target, monitors, needs_force=False, progress=None,
               bulk_modulus=None, penalty_weight=0.0) -> dict:
    """A static reference run of ``problem`` with the mixed formulation, in the shape of the
    scene runner's output (:mod:`.reference`): table, stored states, fields.

    Parameters
    ----------
    problem : Problem
    backend : {"ngsolve", "skfem"} or Backend
        A backend name, or a displacement backend of ``problem`` to reuse.
    n_steps : int
        Load increments (the step is never larger; it is cut when Newton fails).
    target : float
        Final load factor.
    monitors : callable
        ``monitors(u, reactions) -> dict`` of monitored scalars; ``reactions`` (None unless
        ``needs_force``) are the forces of the supports, ``f_int - f_ext`` of the displacement
        dofs on the fixed ones (:meth:`~.problem.Problem.support_reactions`), e.g.
        ``lambda u, r: scene.evaluate_monitors(problem, u, r)``.
    progress : callable, optional
        ``progress(load_factor, target)``.

    Returns
    -------
    dict
        status, message, table (one row per attempted increment), steps (load factors of
        the stored states), displacement (n_states, n_nodes, 3), points, cells, cell_type,
        components, info (formulation, pressure range of the final state).
    """
    import pandas as pd

    mb = MixedBackend(problem, backend, bulk_modulus, penalty_weight)
    res = newton_solve(mb, target, n_increments=n_steps, max_increment=1.0 / n_steps, progress=progress)

    def on_converged(z, load_factor):
        u = z[:mb.n_u].copy()
        if not needs_force:
            return u, monitors(u, None)
        f_ext = mb.displacement_backend.external_force(u, load_factor)
        return u, monitors(u, problem.support_reactions(mb.internal_force(z)[:mb.n_u], f_ext))
    stored, rows = res.increment_rows(on_converged)
    states = [np.zeros(mb.n_u)] + stored
    nodes, cell_nodes = problem.layout
    p = res.u[mb.n_u:]
    info = {"formulation": "mixed u-p, Taylor-Hood P2-P1", "bulk_modulus": bulk_modulus,
            "penalty_weight": penalty_weight,
            "pressure_min": float(p.min()), "pressure_max": float(p.max())}
    return {"status": res.status, "message": res.message, "table": pd.DataFrame(rows),
            "steps": np.array([0.0] + [r["load_factor"] for r in rows if r["converged"]]),
            "displacement": np.array(states).reshape(len(states), -1, 3), "points": nodes, "cells": cell_nodes,
            "cell_type": problem.mesh.cell_type, "components": ("x", "y", "z"), "info": info}
