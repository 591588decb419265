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

Which to pick (cube bar, P1, Mooney-Rivlin; ``tests/benchmarks/test_bench_newton_solvers.py``):
``amg-cg`` from a few thousand dofs on, ``cholesky`` or ``direct`` for small systems and
whenever an exact solve per iteration is wanted (the linear dynamics, condition studies).
"""
from __future__ import annotations

from .amg import AmgCgSolver, rigid_body_modes
from .solver_base import (
    LinearSolver,
    LinearSolverError,
    SparsityPattern,
    canonical_csr,
    forcing_term,
)
from .sparse_direct import DirectSolver, NgsolveSparseSolver

__all__ = ["LINEAR_SOLVERS", "AmgCgSolver", "DirectSolver", "LinearSolver", "LinearSolverError",
           "NgsolveSparseSolver", "SparsityPattern", "canonical_csr", "forcing_term", "make_linear_solver",
           "rigid_body_modes"]

LINEAR_SOLVERS = {"direct": DirectSolver, "cholesky": NgsolveSparseSolver, "amg-cg": AmgCgSolver}


def make_linear_solver(name="direct", **options):
    """Build a linear solver by name (or from a class)."""
    if isinstance(name, type):
        return name(**options)
    if name not in LINEAR_SOLVERS:
        raise ValueError(f"unknown linear solver {name!r}; valid: {sorted(LINEAR_SOLVERS)}")
    return LINEAR_SOLVERS[name](**options)
