"""Full-FE references of the cutting model: the same cut mesh (node duplication,
:mod:`tissuebench.cases.cutting`) with the contact force on the scalpel node.

A strip is anything with the incision strip's interface (``max_cut_length``,
``check_length(c)``, ``tip(c)``, ``incision(c)``, ``depth_fraction``: the PGD cutting
model's :class:`~tissuebench.rom.pgd.strip.IncisionStrip`); this module imports no ROM.

* :func:`cut_problem` — the Problem of the scene cut to length ``c`` of a strip, loaded by
  ``force`` on the strip's tip node (the crack-front node: same id in the cut mesh).
* :func:`linear_reference` — ``K u = f`` with the stiffness at u = 0 (the linear system
  the cutting model (28) reduces), factorisation and solve timed separately: the "full
  FE step of the same cut" the speed-up is measured against (a cut changes the mesh, so
  a full simulator refactorises at every new cut length). Factorised as a peer FE code
  would (NGSolve's sparse LDL^T from 1000 dofs, :func:`~tissuebench.refsolvers.sparse_direct.factorized`):
  SuperLU's minimum-degree ordering took 3.4 s of the paper cornea's 8.9 s step.
* :func:`cut_references` — the linear FE of every cut length of a strip and the seconds of
  each (the ``cut_lengths`` evaluation's references and its full step), solved once per
  process: every unit of a sweep on that strip compares with the same fields (a unit took
  25 s of its 50 s re-solving them at paper resolution); the last strip's kept in
  :data:`~.memo.MEMO` (the units of a sweep come case by case).
* :func:`l2_error` — relative L2 error ``|u - u_ref|_M / |u_ref|_M`` with the mass
  matrix of the cut mesh (unit density; the paper's "L2-error norm").
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np
import scipy.sparse as sp

from ..refsolvers import PointLoad
from ..refsolvers.sparse_direct import factorized
from .formulation import scene_backend
from .memo import MEMO

__all__ = ["cut_problem", "linear_reference", "cut_references", "l2_error"]


def cut_problem(scene, strip, c: int, force, node: int | None = None):
    """Problem of ``scene`` cut to length ``c`` along ``strip``, point load ``force`` (3,)
    on ``node`` (default: the scalpel tip of length c)."""

    c = strip.check_length(c)
    if c == 0:
        s = dataclasses.replace(scene, cut=None)
    else:
        s = dataclasses.replace(scene, cut={"incisions": [strip.incision(c)], "depth_fraction": strip.depth_fraction})
    node = strip.tip(c) if node is None else int(node)
    return dataclasses.replace(s.to_problem(), loads=(PointLoad(np.array([node]), np.asarray(force, float)),))


def linear_reference(backend) -> tuple[np.ndarray, dict]:
    """Linear solve of ``backend``'s problem at load factor 1 (homogeneous Dirichlet).

    Returns
    -------
    u : (ndof,) displacement
    times : dict, ``assemble_s`` (stiffness at 0 and load), ``factor_s``, ``solve_s``
    """
    t0 = time.perf_counter()
    z = np.zeros(backend.ndof)
    K, f = backend.tangent(z), backend.external_force(z, 1.0)
    free = np.asarray(backend.problem.free_dofs)
    Kff = sp.csr_matrix(K[free][:, free])
    t1 = time.perf_counter()
    solve = factorized(Kff)
    t2 = time.perf_counter()
    u = np.zeros(backend.ndof)
    u[free] = solve(f[free])
    t3 = time.perf_counter()
    return u, {"assemble_s": t1 - t0, "factor_s": t2 - t1, "solve_s": t3 - t2}


def cut_references(scene, backend: str, strip, force) -> list:
    """``[(u, seconds)]`` per cut length ``c = 0 .. strip.max_cut_length``: the linear FE
    (:func:`linear_reference`) of ``scene`` cut to length ``c``, loaded by ``force`` (3,) on the
    scalpel tip, and the wall time of that full step (assembly, factorisation, solve) [s]."""
    lengths = range(strip.max_cut_length + 1)
    key = (scene.content_hash(), backend, strip.depth_fraction, np.asarray(force, float).tobytes(),
           repr(strip.incision(strip.max_cut_length)), tuple(int(strip.tip(c)) for c in lengths))

    def solve_all():
        solved = []
        for c in lengths:
            t0 = time.perf_counter()
            be = scene_backend(scene, backend, cut_problem(scene, strip, c, force))  # the reference's formulation
            u, _ = linear_reference(be)
            solved.append((u, time.perf_counter() - t0))
        return solved
    return MEMO.get("cut_references", key, solve_all)


def l2_error(u, u_ref, mass) -> float:
    """``|u - u_ref|_M / |u_ref|_M`` (mass-matrix L2 norm of the displacement fields)."""
    e = np.asarray(u) - np.asarray(u_ref)
    den = float(u_ref @ (mass @ u_ref))
    if not den > 0:
        raise ValueError("l2_error: the reference field is zero")
    return float(np.sqrt(max(float(e @ (mass @ e)), 0.0) / den))
