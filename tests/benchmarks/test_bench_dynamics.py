"""Per-step cost of the full-order implicit integrators (HHT, Bathe) on the liver and the bar.

Each benchmark times ONE ``step()`` of an integrator already started on its system and
advanced by a few warm-up steps (the first steps factorise the effective matrix of a
linear system, and bring a nonlinear one away from the trivial state); every round is
the next step of the same trajectory. Run::

    .venv/bin/pytest tests/benchmarks/test_bench_dynamics.py --benchmark-only
    .venv/bin/pytest tests/benchmarks/test_bench_dynamics.py --benchmark-disable   # once each, as tests

Scenes
------
liver (``liver_dynamic``): ``<shared data>/liver/liver_tet.vtu`` (2866 nodes, 10995 P1
    tets), units **mm, N, t (tonne), s, MPa** -- consistent: 1 N = 1 t mm / s^2 and
    1 MPa = 1 N/mm^2. E = 0.17 MPa, nu = 0.48, density 1.0e-9 t/mm^3 (= 1000 kg/m^3).
    Clamped: all components of the 10 % of nodes with the smallest y (the posterior
    side; the vena cava region). Load: 5 N along -y at the node of largest y (anterior
    point), ramped to 5 N over 0.25 s and released over the next 0.25 s. dt = 1e-3 s
    (HHT alpha = -0.05). Skipped when the shared data folder is missing.
bar (``cube_tension_twist``): 2 x 2 x 8 cm (x, y, 0..8 cm along z), netgen tets; SI
    units. maxh = 4 mm (~760 vertices) by default; with ``TISSUEBENCH_BENCH_FULL=1``
    maxh = 1.5 mm (7147 vertices / 31501 tets, the paper's 7273 / 37592 size).
    The materials are linear elastic and SVK with the paper's shear modulus
    mu = mu1 + mu2 = 1.1 kPa and nu = 0.45 (E = 3.19 kPa), rho = 500 kg/m^3. End z = 0
    clamped, a dead traction (0, 0, 100) Pa on the end z = 8 cm ramped over 0.5 s.
    dt = 1e-2 s.

Backends: scikit-fem and NGSolve (``threads=1``: NGSolve's default enters its
TaskManager on every operator call, ~0.2 s each, which would swamp these timings).
Set ``TISSUEBENCH_BENCH_ROUNDS`` to change the number of timed steps (default 5).
"""
from __future__ import annotations

import importlib
import os
from functools import lru_cache

import numpy as np
import pytest

from tissuebench.cases.io import liver_mesh_path, read_mesh
from tissuebench.cases.meshes import netgen_box_mesh
from tissuebench.refsolvers import (BACKENDS, Dirichlet, LinearElastic, PointLoad, Problem,
                                    SaintVenantKirchhoff, SurfaceTraction)
from tissuebench.refsolvers.dynamics import SecondOrderSystem, make_integrator

pytestmark = pytest.mark.benchmark

FULL = os.environ.get("TISSUEBENCH_BENCH_FULL", "") == "1"
ROUNDS = int(os.environ.get("TISSUEBENCH_BENCH_ROUNDS", "5"))
WARMUP_STEPS = 3
HHT_ALPHA = -0.05

# ------------------------------------------------------------------ liver (mm, N, t, s)
LIVER_E = 0.17          # MPa = N/mm^2
LIVER_NU = 0.48
LIVER_RHO = 1.0e-9      # t/mm^3 (1000 kg/m^3)
LIVER_FORCE = 5.0       # N
LIVER_CLAMP_FRACTION = 0.10
LIVER_DT = 1e-3         # s

# ------------------------------------------------------------------ bar (SI)
BAR_LENGTHS = (0.02, 0.02, 0.08)             # m
BAR_MAXH = 0.0015 if FULL else 0.004         # m
BAR_MU = 1.1e3                               # Pa (mu1 + mu2 of the wsc paper)
BAR_NU = 0.45
BAR_RHO = 500.0                              # kg/m^3
BAR_TRACTION = 100.0                         # Pa
BAR_DT = 1e-2                                # s


def ramp_release(t, t_up=0.25, t_down=0.25):
    """0 -> 1 over [0, t_up], 1 -> 0 over [t_up, t_up + t_down], then 0."""
    if t <= 0:
        return 0.0
    if t <= t_up:
        return t / t_up
    return max(0.0, 1.0 - (t - t_up) / t_down)


def ramp(t, t_up=0.5):
    return min(max(t / t_up, 0.0), 1.0)


def _material(kind, E, nu):
    return LinearElastic(E, nu) if kind == "linear" else SaintVenantKirchhoff(E, nu)


@lru_cache(maxsize=None)
def liver_mesh():
    path = liver_mesh_path()
    if not path.is_file():
        return None
    return read_mesh(path)


def liver_problem(material):
    mesh = liver_mesh()
    if mesh is None:
        pytest.skip(f"shared liver mesh not found at {liver_mesh_path()} (set TISSUEBENCH_DATA)")
    y = mesh.points[:, 1]
    clamped = np.argsort(y, kind="stable")[: int(np.ceil(LIVER_CLAMP_FRACTION * mesh.n_vertices))]
    loaded = int(np.argmax(y))
    return Problem(mesh, _material(material, LIVER_E, LIVER_NU), element="P1",
                   dirichlet=[Dirichlet(clamped)],
                   loads=[PointLoad([loaded], np.array([0.0, -LIVER_FORCE, 0.0]))], density=LIVER_RHO), \
        ramp_release, LIVER_DT


@lru_cache(maxsize=None)
def bar_mesh():
    return netgen_box_mesh(BAR_LENGTHS, BAR_MAXH)


def bar_problem(material):
    mesh = bar_mesh()
    Lz = BAR_LENGTHS[2]
    tol = 1e-9 * Lz
    E = 2 * BAR_MU * (1 + BAR_NU)
    return Problem(mesh, _material(material, E, BAR_NU), element="P1",
                   dirichlet=[Dirichlet(lambda x: np.abs(x[:, 2]) < tol)],
                   loads=[SurfaceTraction(lambda x: np.abs(x[:, 2] - Lz) < tol,
                                          np.array([0.0, 0.0, BAR_TRACTION]))], density=BAR_RHO), \
        ramp, BAR_DT


SCENES = {"liver": liver_problem, "bar": bar_problem}


def make_backend(name, problem):
    module, cls = BACKENDS[name].split(":")
    opts = {"threads": 1} if name == "ngsolve" else {}
    return getattr(importlib.import_module(module), cls)(problem, **opts)


def started_integrator(scene, material, backend, method):
    """An integrator started from rest on the scene and advanced WARMUP_STEPS steps."""
    problem, history, dt = SCENES[scene](material)
    be = make_backend(backend, problem)
    system = SecondOrderSystem.from_backend(be, history, linear=(material == "linear"))
    integ = make_integrator(method, **({"alpha": HHT_ALPHA} if method == "hht" else {}))
    integ.start(system, None, None, dt)
    for _ in range(WARMUP_STEPS):
        rep = integ.step()
        assert rep.converged, rep.message
    return integ, problem


@pytest.mark.parametrize("method", ["hht", "bathe"])
@pytest.mark.parametrize("backend", ["skfem", "ngsolve"])
@pytest.mark.parametrize("material", ["linear", "svk"])
@pytest.mark.parametrize("scene", ["liver", "bar"])
def test_step_time(benchmark, scene, material, backend, method):
    integ, problem = started_integrator(scene, material, backend, method)
    reports = []

    def step():
        reports.append(integ.step())

    benchmark.extra_info.update({
        "scene": scene, "material": material, "backend": backend, "method": method,
        "n_vertices": problem.mesh.n_vertices, "n_cells": problem.mesh.n_cells,
        "n_free_dofs": len(problem.free_dofs), "dt": integ.dt, "warmup_steps": WARMUP_STEPS,
        "full_size": FULL,
    })
    benchmark.pedantic(step, rounds=ROUNDS, iterations=1, warmup_rounds=0)
    assert reports and all(r.converged for r in reports), [r.message for r in reports]
    benchmark.extra_info["newton_iterations"] = [r.iterations for r in reports]
    assert np.all(np.isfinite(integ.u)) and np.max(np.abs(integ.u)) > 0
