"""Linear solvers for the tangent systems of Newton and the implicit integrators.

The interface (``solve(K, b, rtol=None) -> (x, info)``, ``reset()``) is described in
:mod:`~tissuebench.refsolvers.solver_base`. Every solver keeps what it can between calls
while the sparsity pattern stays the same (checked exactly):

* ``"direct"``: SciPy SuperLU, LU with a minimum-degree ordering of K + K^T computed once
  per pattern (:class:`~tissuebench.refsolvers.sparse_direct.DirectSolver`). Backends may
  override it (NGSolve uses its own sparse Cholesky).
* ``"cholesky"``: NGSolve's sparse LDL^T (UMFPACK if K is not symmetric), refactorised in
  place on the same ordering (:class:`~tissuebench.refsolvers.sparse_direct.NgsolveSparseSolver`).
* ``"amg-cg"``: CG preconditioned by pyamg smoothed aggregation with the rigid-body modes,
  the hierarchy reused across Newton iterations and load increments, stopping at
  Newton's forcing term (:class:`~tissuebench.refsolvers.amg.AmgCgSolver`).
* ``"auto"`` (the default of the statics): ``"cholesky"`` from
  :data:`~tissuebench.refsolvers.sparse_direct.NGSOLVE_MIN_DOFS` unknowns on, ``"direct"``
  below (:class:`AutoDirectSolver`). SuperLU's minimum-degree ordering on a large 3D mesh is
  what made a user's 13k-dof kidney take 12 min 46 s for 10 load steps, against 1 min 10 s
  with NGSolve's LDL^T.

Which to pick (cube bar, P1, Mooney-Rivlin; ``tests/benchmarks/test_bench_newton_solvers.py``):
``amg-cg`` from a few thousand dofs on, ``cholesky`` or ``direct`` for small systems and
whenever an exact solve per iteration is wanted (the linear dynamics, condition studies).
"""
from __future__ import annotations

import numpy as np

from .amg import AmgCgSolver, rigid_body_modes
from .solver_base import (
    LinearSolver,
    LinearSolverError,
    SparsityPattern,
    canonical_csr,
    forcing_term,
)
from .sparse_direct import NGSOLVE_MIN_DOFS, DirectSolver, NgsolveSparseSolver

__all__ = ["LINEAR_SOLVERS", "AmgCgSolver", "AutoDirectSolver", "DirectSolver", "LinearSolver", "LinearSolverError",
           "NgsolveSparseSolver", "SparsityPattern", "canonical_csr", "forcing_term", "make_linear_solver",
           "rigid_body_modes"]



class AutoDirectSolver(LinearSolver):
    """A direct solver chosen by size on the first system: NGSolve's sparse LDL^T
    (:class:`NgsolveSparseSolver`) from ``NGSOLVE_MIN_DOFS`` unknowns on, SciPy's SuperLU
    below. LDL^T does not pivot, so a solution whose residual is not small (an indefinite
    tangent near a limit point) is solved again by SuperLU, which then serves for good."""

    name = "auto"
    RESIDUAL_RTOL = 1e-8

    def __init__(self, **options):
        self.options = options
        self.reset()

    def reset(self):
        self.chosen = None

    def solve(self, K, b, rtol=None):
        if self.chosen is None:
            self.chosen = NgsolveSparseSolver(**self.options) if K.shape[0] >= NGSOLVE_MIN_DOFS else DirectSolver()
        if isinstance(self.chosen, DirectSolver):
            return self.chosen.solve(K, b, rtol)
        try:
            x, info = self.chosen.solve(K, b, rtol)
            r = np.linalg.norm(K @ x - b) if np.ndim(b) == 1 else np.linalg.norm(K @ x - b, axis=0).max()
            if r <= self.RESIDUAL_RTOL * max(np.linalg.norm(b), 1e-300):
                return x, info
            why = f"residual {r:.3g} of LDL^T"
        except LinearSolverError as exc:
            why = str(exc)
        self.chosen = DirectSolver()
        x, info = self.chosen.solve(K, b, rtol)
        return x, {**info, "fallback": why}


LINEAR_SOLVERS = {"auto": AutoDirectSolver, "direct": DirectSolver, "cholesky": NgsolveSparseSolver,
                  "amg-cg": AmgCgSolver}


def make_linear_solver(name="auto", **options):
    """Build a linear solver by name (or from a class)."""
    if isinstance(name, type):
        return name(**options)
    if name not in LINEAR_SOLVERS:
        raise ValueError(f"unknown linear solver {name!r}; valid: {sorted(LINEAR_SOLVERS)}")
    return LINEAR_SOLVERS[name](**options)
