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
* ``"pardiso"``: Intel MKL PARDISO (pypardiso), nested-dissection ordering, refactorised on the
  same ordering (:class:`~tissuebench.refsolvers.pardiso.PardisoSolver`); where MKL is installed.
* ``"kept-factor-cg"``: CG preconditioned by the factors (PARDISO's where MKL is installed, else
  NGSolve's LDL^T) of an earlier tangent, factorised again only when CG stalls or costs half a
  factorisation, stopping at Newton's forcing term (:class:`~tissuebench.refsolvers.kept_factors.KeptFactorSolver`).
* ``"auto"`` (the default of the statics): ``"kept-factor-cg"`` from :data:`KEPT_FACTORS_MIN_DOFS`
  unknowns on, ``"cholesky"`` from
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
from .kept_factors import KeptFactorSolver, large_system_solver
from .pardiso import PardisoSolver, why_no_pardiso
from .sparse_direct import NGSOLVE_MIN_DOFS, DirectSolver, NgsolveSparseSolver

__all__ = ["KEPT_FACTORS_MIN_DOFS", "LINEAR_SOLVERS", "AmgCgSolver", "AutoDirectSolver", "DirectSolver",
           "KeptFactorSolver", "LinearSolver", "LinearSolverError", "NgsolveSparseSolver", "PardisoSolver",
           "SparsityPattern", "canonical_csr", "direct_solver_for", "forcing_term", "make_linear_solver",
           "why_no_pardiso", "rigid_body_modes"]


#: from this many unknowns on, ``"auto"`` keeps the factors and solves by CG with them
#: (:class:`KeptFactorSolver`), PARDISO's where MKL is installed: the 5k-node organ at h/2 (107 805
#: dofs) factorised in 13.5 s and solved with the factors in 0.42 s (NGSolve, P1); its 10 load
#: increments took 755 s with a factorisation per Newton iteration
KEPT_FACTORS_MIN_DOFS = 50_000


def direct_solver_for(n: int, ngsolve_from: int = NGSOLVE_MIN_DOFS, **ngsolve_options) -> LinearSolver:
    """The direct solver ``"auto"`` factorises a system of ``n`` unknowns with (the kept factors'
    from :data:`KEPT_FACTORS_MIN_DOFS` on, NGSolve's LDL^T from ``ngsolve_from``, SuperLU below):
    what a memory probe must factorise with."""
    if n >= KEPT_FACTORS_MIN_DOFS:
        return large_system_solver(**ngsolve_options)
    return NgsolveSparseSolver(**ngsolve_options) if n >= ngsolve_from else DirectSolver()


class AutoDirectSolver(LinearSolver):
    """A solver chosen by size on the first system: CG with kept factors (:class:`KeptFactorSolver`;
    PARDISO's where MKL is installed) from :data:`KEPT_FACTORS_MIN_DOFS` unknowns on, NGSolve's sparse
    LDL^T (:class:`NgsolveSparseSolver`) from ``NGSOLVE_MIN_DOFS``, SciPy's SuperLU below. LDL^T
    does not pivot, so a factorised solution whose residual is not small (an indefinite tangent
    near a limit point) is solved again by SuperLU, which then serves for good."""

    name = "auto"
    keeps_factors = True
    RESIDUAL_RTOL = 1e-8

    def __init__(self, ngsolve_from: int = NGSOLVE_MIN_DOFS, **options):
        """``ngsolve_from``: NGSolve's LDL^T from this many unknowns on (0 on the NGSolve backend);
        ``options``: of :class:`NgsolveSparseSolver`."""
        self.ngsolve_from, self.options = int(ngsolve_from), options
        self.reset()

    def reset(self):
        self.chosen = None

    @property
    def iterative(self) -> bool:
        """True once CG with kept factors was chosen (Newton then passes its forcing term)."""
        return isinstance(self.chosen, KeptFactorSolver)

    def _choose(self, n):
        direct = direct_solver_for(n, self.ngsolve_from, **self.options)
        return KeptFactorSolver(direct) if n >= KEPT_FACTORS_MIN_DOFS else direct

    def solve(self, K, b, rtol=None):
        if self.chosen is None:
            self.chosen = self._choose(K.shape[0])
        if isinstance(self.chosen, DirectSolver):
            return self.chosen.solve(K, b, rtol)
        try:
            x, info = self.chosen.solve(K, b, rtol)
            if info.get("solver") == KeptFactorSolver.name:  # CG checked its own residual, to rtol
                return x, info
            r = np.linalg.norm(K @ x - b) if np.ndim(b) == 1 else np.linalg.norm(K @ x - b, axis=0).max()
            if r <= self.RESIDUAL_RTOL * max(np.linalg.norm(b), 1e-300):
                return x, info
            why = f"residual {r:.3g} of LDL^T"
        except LinearSolverError as exc:
            why = str(exc)
        self.chosen = DirectSolver()
        x, info = self.chosen.solve(K, b, rtol)
        return x, {**info, "fallback": why}

    def solve_again(self, b):
        if self.chosen is None:
            raise LinearSolverError("auto solver: no factors yet (solve first)")
        return self.chosen.solve_again(b)


LINEAR_SOLVERS = {"auto": AutoDirectSolver, "direct": DirectSolver, "cholesky": NgsolveSparseSolver,
                  "amg-cg": AmgCgSolver, KeptFactorSolver.name: KeptFactorSolver, PardisoSolver.name: PardisoSolver}


def make_linear_solver(name="auto", **options):
    """Build a linear solver by name (or from a class)."""
    if isinstance(name, type):
        return name(**options)
    if name not in LINEAR_SOLVERS:
        raise ValueError(f"unknown linear solver {name!r}; valid: {sorted(LINEAR_SOLVERS)}")
    return LINEAR_SOLVERS[name](**options)
