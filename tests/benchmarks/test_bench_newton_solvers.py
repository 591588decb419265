"""The same Newton solve per backend and linear solver, timed per phase and per iteration.

The cube bar (Mooney-Rivlin, pulled to 30 % in 10 load increments): a coarse bar by
default, so that CI runs this in seconds (untimed, ``--benchmark-disable``); the paper
bar (7744 vertices, 37800 P1 tets, 22506 free dofs) with ``TISSUEBENCH_BENCH_FULL=1``.
``TISSUEBENCH_BENCH_REPEATS=n`` repeats each solve n times (medians reported).

Each test prints one row of the per-iteration table (``pytest -s``), wall and process
CPU time in seconds per Newton iteration:

* ``assembly``: residual and tangent at the iterate (``internal_force_and_tangent``,
  ``tangent``, ``external_tangent``), including the matrix transfer;
* ``setup``: factorisation (direct) or AMG hierarchy setup (zero while reused);
* ``solve``: triangular solves or Krylov iterations;
* ``residual``: f_int and det F at each trial state (``internal_force``, ``min_jacobian``);
* ``other``: the rest of Newton's bookkeeping (free-dof slicing, norms);
* ``total``: the whole solve divided by the number of Newton iterations.

Example (the figures of issue 11, on a loaded 2-core machine: read the CPU columns)::

    TISSUEBENCH_BENCH_FULL=1 TISSUEBENCH_BENCH_REPEATS=3 OPENBLAS_NUM_THREADS=1 \\
        python -m pytest tests/benchmarks/test_bench_newton_solvers.py -s -p no:cacheprovider
"""
import os
import statistics
import time
from collections import defaultdict

import numpy as np
import pytest

from tissuebench.cases.bar import bar_tension
from tissuebench.refsolvers import make_backend
from tissuebench.refsolvers.newton import NewtonOptions, newton_solve

pytestmark = pytest.mark.benchmark
FULL = os.environ.get("TISSUEBENCH_BENCH_FULL") == "1"
REPEATS = max(1, int(os.environ.get("TISSUEBENCH_BENCH_REPEATS", "1")))
RESOLUTION = "paper" if FULL else "ci"
PHASES = ("assembly", "setup", "solve", "residual", "other", "total")
_ASSEMBLY = ("internal_force_and_tangent", "tangent", "external_tangent")
_RESIDUAL = ("internal_force", "min_jacobian", "external_force")
CASES = [("skfem", "direct", {}), ("skfem", "cholesky", {}), ("skfem", "amg-cg", {}),
         ("ngsolve", "direct", {}), ("ngsolve", "amg-cg", {}), ("ngsolve", "amg-cg", {"threads": 1})]


class _Clock:
    """Wall and CPU seconds per phase."""

    def __init__(self):
        self.wall, self.cpu = defaultdict(float), defaultdict(float)

    def timed(self, phase, fn):
        def wrapper(*args, **kwargs):
            t, c = time.perf_counter(), time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.wall[phase] += time.perf_counter() - t
                self.cpu[phase] += time.process_time() - c
        return wrapper


class _TimedSolver:
    def __init__(self, solver, clock):
        self._solver, self._clock, self.iterative = solver, clock, getattr(solver, "iterative", False)

    def solve(self, K, b, rtol=None):
        t, c = time.perf_counter(), time.process_time()
        x, info = self._solver.solve(K, b, rtol=rtol) if self.iterative else self._solver.solve(K, b)
        wall, cpu = time.perf_counter() - t, time.process_time() - c
        setup_wall, setup_cpu = info.get("factor_s", 0.0), info.get("factor_cpu_s", 0.0)
        for clock, total, setup in ((self._clock.wall, wall, setup_wall), (self._clock.cpu, cpu, setup_cpu)):
            clock["setup"] += setup
            clock["solve"] += total - setup
        return x, info


class _TimedBackend:
    """The backend with its operator calls timed; everything else passed through."""

    def __init__(self, backend, clock):
        self._backend, self._clock = backend, clock
        for name in _ASSEMBLY + _RESIDUAL:
            setattr(self, name, clock.timed("assembly" if name in _ASSEMBLY else "residual",
                                            getattr(backend, name)))

    def __getattr__(self, name):
        return getattr(self._backend, name)

    def make_linear_solver(self, name, **options):
        return _TimedSolver(self._backend.make_linear_solver(name, **options), self._clock)


def timed_newton(backend, linear_solver):
    """One load-stepped Newton solve; (result, {phase: (wall, cpu) per iteration})."""
    clock = _Clock()
    opts = NewtonOptions(n_increments=10, max_increment=0.1, linear_solver=linear_solver)
    t, c = time.perf_counter(), time.process_time()
    res = newton_solve(_TimedBackend(backend, clock), 1.0, opts)
    clock.wall["total"], clock.cpu["total"] = time.perf_counter() - t, time.process_time() - c
    for d in (clock.wall, clock.cpu):
        d["other"] = d["total"] - sum(d[p] for p in PHASES if p not in ("other", "total"))
    its = sum(i.iterations for i in res.increments)
    return res, {p: (clock.wall[p] / its, clock.cpu[p] / its) for p in PHASES}


def _row(label, its, lin_its, phases):
    cells = " ".join(f"{phases[p][0]:6.3f} {phases[p][1]:6.3f}" for p in PHASES)
    return f"{label:28s} {its:4d} {lin_its:6d} {cells}"


def _header():
    names = " ".join(f"{p:>13s}" for p in PHASES)
    return f"{'backend / solver':28s} {'its':>4s} {'lin':>6s} {names}\n{'':40s}" + " wall    cpu " * len(PHASES)


_FIRST = {}  # monitors of the first run, against which the others are compared


@pytest.mark.parametrize("backend,solver,options", [
    pytest.param(*c, marks=pytest.mark.ngsolve, id=f"{c[0]}-{c[1]}" + ("-serial" if c[2] else ""))
    if c[0] == "ngsolve" else pytest.param(*c, id=f"{c[0]}-{c[1]}") for c in CASES])
def test_newton_per_iteration(benchmark, capsys, backend, solver, options):
    case = bar_tension(RESOLUTION)
    if backend == "ngsolve":
        from tissuebench.refsolvers.backends.ngsolve_backend import NgsolveBackend

        be = NgsolveBackend(case.problem, **options)  # realcompile (paper size) happens here
    else:
        be = make_backend(backend, case.problem)
    try:
        be.make_linear_solver(solver)
    except ValueError as exc:  # an older tissuebench without this solver (baseline runs)
        pytest.skip(str(exc))
    runs = []
    benchmark.pedantic(lambda: runs.append(timed_newton(be, solver)), rounds=REPEATS, iterations=1)
    res = runs[-1][0]
    assert res.success
    its = sum(i.iterations for i in res.increments)
    lin_its = sum(i.linear_iterations for i in res.increments)
    phases = {p: tuple(statistics.median(r[1][p][k] for r in runs) for k in (0, 1)) for p in PHASES}
    label = f"{backend}{'-serial' if options else ''} / {solver}"
    benchmark.extra_info.update(resolution=RESOLUTION, newton_iterations=its, linear_iterations=lin_its,
                                compiled=bool(getattr(be, "compiled", False)),
                                **{f"{p}_{k}_per_iteration": phases[p][i] for p in PHASES
                                   for i, k in enumerate(("wall", "cpu"))})
    with capsys.disabled():
        if not _FIRST:
            print(f"\nNewton per iteration on the {RESOLUTION} bar (s), median of {REPEATS}\n{_header()}")
        print(_row(label, its, lin_its, phases))
    m = case.monitors(res.u, be.internal_force(res.u))
    ref = _FIRST.setdefault("monitors", m)
    for key, value in m.items():  # every backend and solver: the same converged state
        assert value == pytest.approx(ref[key], rel=1e-8)
    assert np.all(np.isfinite(res.u))
