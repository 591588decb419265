"""The large systems' direct solvers side by side: MKL PARDISO against NGSolve's LDL^T on the same
nearly incompressible tangent (average nodal pressure tetrahedra, nu = 0.499, a jittered block of
12 000 free unknowns, each vertex coupled to its neighbours' neighbours as on an organ's h/2 mesh).

Timed with pytest-benchmark in one run, so the ratio is measured side by side
(``pytest -n 0 -m slow tests/benchmarks/test_bench_factorisations.py --benchmark-enable``); the slow
test run executes each once, untimed, and checks both solve the system. On the 5k-node organ at
h/2 (102 318 unknowns) PARDISO factorised in 38-45 s against NGSolve's 147 s
(docs/explanation/nearly-incompressible.md); the gap grows with the mesh (nested dissection
against minimum degree).
"""
from __future__ import annotations

import numpy as np
import pytest
from _fe_helpers import element_mesh

from tissuebench.refsolvers import Dirichlet, NeoHookean, Problem
from tissuebench.refsolvers.anp import AnpBackend
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.pardiso import PardisoSolver, why_no_pardiso
from tissuebench.refsolvers.sparse_direct import NgsolveSparseSolver

pytestmark = [pytest.mark.benchmark, pytest.mark.ngsolve]

SOLVERS = {"ngsolve-ldlt": lambda: NgsolveSparseSolver(),
           "pardiso": pytest.param(PardisoSolver, marks=pytest.mark.skipif(bool(why_no_pardiso()),
                                                                           reason=why_no_pardiso() or "-"))}


@pytest.fixture(scope="module")
def anp_tangent():
    mesh = element_mesh("P1", (2.0, 1.0, 1.0), (24, 12, 12), jitter=0.15, seed=3)
    pb = Problem(mesh, NeoHookean(E=3.0, nu=0.499), "P1", dirichlet=[Dirichlet(lambda x: x[:, 0] <= 1e-9)])
    be = AnpBackend(pb, make_backend("ngsolve", pb))
    free = pb.free_dofs
    K = be.tangent(np.zeros(pb.ndof))[free][:, free].tocsr()
    return K, np.random.default_rng(0).standard_normal(K.shape[0])


@pytest.mark.parametrize("make", [SOLVERS["ngsolve-ldlt"], SOLVERS["pardiso"]], ids=list(SOLVERS))
def test_factorise_and_solve_the_anp_tangent(benchmark, anp_tangent, make):
    K, b = anp_tangent
    solver = make()
    x, _ = benchmark.pedantic(solver.solve, args=(K, b), rounds=3, iterations=1)
    assert np.linalg.norm(K @ x - b) <= 1e-8 * np.linalg.norm(b)
