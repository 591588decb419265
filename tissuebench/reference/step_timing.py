"""The full model's own step, timed in the process that times a reduced model beside it.

Step 3 of the one timed loop (:mod:`tissuebench.studies.protocol`): one Newton increment from
a converged state of the reference path, one back-substitution for a linear static scene
(and for the 1D models), one time step of the reference integrator from the middle of its
run, each timed ``samples`` times and the median kept, so every row of a sweep has a speed-up
ratio that survives a noisy machine. Measured once per process and scene, and the
semi-discrete system of a dynamic scene built once for the units of that scene (the energy
drift integrates it too): both kept in the layer's :data:`~.memo.MEMO`.
"""
from __future__ import annotations

import time

import numpy as np

from .formulation import scene_backend
from ..refsolvers.dynamics import integrate
from ..refsolvers.line_models import assemble_line_model
from ..refsolvers.linear_solvers import DirectSolver
from ..refsolvers.newton import newton_solve
from .memo import MEMO
from .runner import dynamics_system

__all__ = ["reference_step_seconds", "cached_dynamics_system"]


def reference_step_seconds(ref, scene, backend: str = "skfem", samples: int = 3) -> float:
    """Median wall time [s] of one step of the reference run ``ref`` of ``scene`` (module
    docstring), measured once per process and (scene, backend, samples)."""
    key = (scene.content_hash(), backend, samples)
    return MEMO.get("reference_step", key, lambda: _reference_step(ref, scene, backend, samples))


def _reference_step(ref, scene, backend, samples) -> float:
    if ref.plan.analysis == "dynamic":
        return _dynamic_step(ref, scene, backend, samples)
    if not scene.is_fe:
        system = assemble_line_model(scene.line_model())
        K = system.K[system.free][:, system.free]
        lu = DirectSolver().factorize(K)
        f = system.load_vector(1.0)[system.free]
        return _median_of(lambda: lu.solve(f), samples)
    be = scene_backend(scene, backend, ref.problem)
    if ref.plan.linear:
        free = ref.problem.free_dofs
        lu = DirectSolver().factorize(be.tangent(np.zeros(be.ndof))[free][:, free])
        f = be.external_force(np.zeros(be.ndof), 1.0)[free]
        return _median_of(lambda: lu.solve(f), samples)
    U = ref.displacement.reshape(len(ref.steps), -1)
    ks = _middle_indices(len(ref.steps) - 1, samples)
    times = []
    for k in ks:
        t0 = time.perf_counter()
        newton_solve(be, float(ref.steps[k + 1]), u0=U[k], n_increments=1, min_increment=1.0, store_states=False)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) if times else float("nan")


def cached_dynamics_system(scene, backend: str = "skfem"):
    """:func:`~.runner.dynamics_system` of ``scene``, built once per process for the units of
    a scene (the reference-step timing and the energy drift share it; the last two kept)."""
    return MEMO.get("dynamics_system", (scene.content_hash(), backend), lambda: dynamics_system(scene, backend))


def _dynamic_step(ref, scene, backend, samples):
    system = cached_dynamics_system(scene, backend)
    n = len(ref.steps)
    k = n // 2
    U, V = ref.displacement.reshape(n, -1), ref.velocity.reshape(n, -1)
    dt = float(scene.analysis["dt"])
    t0 = float(ref.steps[k])
    res = integrate(system, U[k], V[k], dt, t0 + samples * dt, method=scene.analysis.get("integrator", "hht"),
                    t0=t0, **scene.analysis.get("integrator_options", {}))
    return float(np.median(res.wall_time[1:])) if len(res.wall_time) > 1 else float("nan")


def _middle_indices(n, k):
    """Up to ``k`` consecutive indices in ``range(n)`` around its middle."""
    if n <= 0:
        return []
    start = max(0, n // 2 - k // 2)
    return list(range(start, min(n, start + k)))


def _median_of(fn, samples):
    times = []
    for _ in range(max(samples, 1)):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
