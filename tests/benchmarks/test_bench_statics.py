"""Statics benchmarks on the cube bar at paper resolution (2x2x8 cm, 7744 vertices, 37800 P1 tets).

Timed with pytest-benchmark (``pytest -n 0 tests/benchmarks --benchmark-enable --benchmark-only``);
under the plain test run they execute once, untimed. Peak memory of each timed call is
recorded in ``extra_info``: ``tracemalloc_peak_MiB`` (Python/NumPy allocations) and
``rss_peak_MiB`` (process high-water mark, includes NGSolve's C++ allocations).
The issue's target: NGSolve tangent assembly + factorisation < 2 s per Newton iteration,
scikit-fem within 3x of NGSolve (``test_tangent_plus_factorisation``).
"""
import resource
import tracemalloc

import numpy as np
import pytest

from tissuebench.cases.bar import bar_tension
from tissuebench.refsolvers import make_backend
from tissuebench.refsolvers.newton import newton_solve

pytestmark = pytest.mark.benchmark
BACKENDS = ["skfem", pytest.param("ngsolve", marks=pytest.mark.ngsolve)]


@pytest.fixture(scope="module")
def bar():
    return bar_tension("paper")


@pytest.fixture(scope="module")
def stretched(bar):
    """A state near 15 % stretch, where the tangent is genuinely nonlinear."""
    res = newton_solve(make_backend("skfem", bar.problem), 0.5, n_increments=1)
    assert res.success
    return res.u


def _rss_peak_mib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _with_memory(benchmark, fn, *args):
    """Benchmark ``fn(*args)``; its peak traced memory is taken in one extra, untimed call
    (tracemalloc slows allocation-heavy code, so it stays off while timing)."""
    tracemalloc.start()
    fn(*args)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    out = benchmark(fn, *args)
    benchmark.extra_info["tracemalloc_peak_MiB"] = peak / 2**20
    benchmark.extra_info["rss_peak_MiB"] = _rss_peak_mib()
    return out


@pytest.mark.parametrize("backend", BACKENDS)
def test_internal_force_assembly(benchmark, bar, stretched, backend):
    be = make_backend(backend, bar.problem)
    be.internal_force(stretched)  # warm-up (pattern, compiled forms)
    f = _with_memory(benchmark, be.internal_force, stretched)
    assert f.shape == (bar.problem.ndof,) and np.all(np.isfinite(f))


@pytest.mark.parametrize("backend", BACKENDS)
def test_tangent_assembly(benchmark, bar, stretched, backend):
    be = make_backend(backend, bar.problem)
    be.tangent(stretched)
    K = _with_memory(benchmark, be.tangent, stretched)
    assert K.shape == (bar.problem.ndof,) * 2 and abs(K - K.T).max() <= 1e-10 * abs(K).max()


@pytest.mark.parametrize("backend", BACKENDS)
def test_tangent_plus_factorisation(benchmark, bar, stretched, backend):
    """What one Newton iteration costs: assemble K_t, restrict to free dofs, factorise and solve."""
    pb = bar.problem
    be = make_backend(backend, pb)
    solver = be.make_linear_solver("direct")
    free = pb.free_dofs
    rhs = np.ones(len(free))
    be.tangent(stretched)

    def iteration():
        K = be.tangent(stretched)
        return solver.solve(K[free][:, free], rhs)

    x, info = _with_memory(benchmark, iteration)
    benchmark.extra_info["solver"] = info["solver"]
    assert np.all(np.isfinite(x))


@pytest.mark.parametrize("backend", BACKENDS)
def test_full_newton_solve(benchmark, bar, backend):
    be = make_backend(backend, bar.problem)
    res = benchmark.pedantic(newton_solve, args=(be, 1.0), kwargs={"n_increments": 1}, rounds=1, iterations=1)
    benchmark.extra_info.update(newton_iterations=sum(i.iterations for i in res.increments),
                                rss_peak_MiB=_rss_peak_mib())
    assert res.success
    m = bar.monitors(res.u, be.internal_force(res.u))
    benchmark.extra_info.update(m)
    assert m["volume_ratio"] > 1.0
