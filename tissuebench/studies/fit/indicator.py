"""The cheap error indicator of a fit: the full model's residual at the reduced state.

A reduced model's state ``u_rom`` (its reconstructed full field, supports' values included) is
put into the **full** model's equations, where the reference state makes them vanish; what is
left measures how far ``u_rom`` is from being the answer, for one assembly of the internal
force and no solve:

* **a static path** at load factor ``lam``: ``r = f_int(u_rom) - f_ext(u_rom, lam)`` on the free
  dofs (:func:`static_residual`). For a linear problem ``r = K (u_rom - u_ref)``: the residual
  is the error seen through the stiffness (a lower and an upper bound on ``||u_rom - u_ref||``
  by the extreme eigenvalues of ``K``), which is why ranking parameters by it ranks them by their
  error without computing one reference.
* **a motion** stepped with the Newmark family (HHT-alpha, Newmark): the scheme's own residual
  at every step ``n -> n+1`` (:func:`newmark_residuals`)::

      M a_{n+1} + (1 + alpha) [C v_{n+1} + f_int(u_{n+1}) - f_ext_{n+1}]
                - alpha     [C v_n     + f_int(u_n)     - f_ext_n]

  with ``v``, ``a`` carried by the scheme's update formulas from the reduced displacements, from
  the same initial state as the reference (its ``a_0`` from the equation of motion). The
  reference trajectory makes it vanish at every step (to its Newton tolerance); a reduced one
  leaves the part of the full dynamics its basis or its hyper-reduction misses. Other schemes
  (central difference, Bathe): the equation of motion with central differences of the
  displacements (exact for the central-difference scheme; an estimate for Bathe, said as
  ``exact = False``).

The indicator of a point is its residual norm divided by the **largest** force of the range the
family claims (a path: the internal force of its top reference state over every dof, the loads and
the supports' reactions, so that a scene pulled by a prescribed displacement has one too; a motion:
its peak external force norm): peak-normalised like the
headline error (:mod:`~tissuebench.studies.metrics`, issue 52), so that near rest, where every
force is small, a model is not found "worst" by a ratio of two small numbers. Its ranking is
checked against the true errors where references exist (:func:`rank_correlation`, Spearman's).
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.stats import spearmanr

from ..evaluation import Evaluation, EvaluationPoint
from ..protocol import drive

__all__ = ["static_residual", "path_fields", "path_residuals", "newmark_parameters", "newmark_residuals",
           "central_residuals", "trajectory_fields", "trajectory_residuals", "rank_correlation"]


def static_residual(backend, u, load_factor: float, free) -> np.ndarray:
    """``f_int(u) - f_ext(u, load_factor)`` on the ``free`` dofs [force unit] (module docstring)."""
    u = np.asarray(u, float)
    return (np.asarray(backend.internal_force(u), float) - np.asarray(backend.external_force(u, float(load_factor)),
                                                                      float))[np.asarray(free)]


def path_fields(model, load_factors) -> list:
    """The full fields of a path (or map) model stepped at ``load_factors`` in increasing order
    (:func:`~tissuebench.studies.protocol.drive`: start, step, reconstruct; a failed or non-finite
    step gives None), in the order of ``load_factors``."""
    lams = np.asarray(load_factors, float)
    order = np.argsort(lams, kind="stable")
    points = [EvaluationPoint({"load_factor": float(lams[k])}, None, {}, float(lams[k])) for k in order]
    driven = drive(model, Evaluation("path", "load_factor", points))
    fields = [None] * len(lams)
    for k, u in zip(order, driven.fields):
        fields[k] = u
    return fields


def path_residuals(backend, fields, load_factors, free) -> tuple[np.ndarray, np.ndarray]:
    """``(||r||, ||f_ext||)`` per field of a path (``inf`` residual where the field is None)."""
    res, ext = [], []
    for u, lam in zip(fields, load_factors):
        f = np.asarray(backend.external_force(np.zeros(backend.ndof) if u is None else u, float(lam)), float)
        ext.append(float(np.linalg.norm(f[np.asarray(free)])))
        res.append(np.inf if u is None else float(np.linalg.norm(static_residual(backend, u, lam, free))))
    return np.asarray(res), np.asarray(ext)


def newmark_parameters(integrator: str, options: dict | None = None) -> tuple[float, float, float] | None:
    """``(alpha, beta, gamma)`` of a Newmark-family scheme (``hht``, ``newmark``) with its
    ``integrator_options``; None for any other scheme."""
    options = options or {}
    if integrator == "hht":
        alpha = float(options.get("alpha", -0.05))
        return alpha, (1.0 - alpha) ** 2 / 4.0, 0.5 - alpha
    if integrator == "newmark":
        return 0.0, float(options.get("beta", 0.25)), float(options.get("gamma", 0.5))
    return None


def _forces(system, U, times, scale):
    """``(f_int, f_ext)`` on the free dofs at each row of ``U`` (free dofs), loads times ``scale``."""
    f_int = [np.asarray(system.f_int(u), float) for u in U]
    f_ext = [scale * np.asarray(system.f_ext(float(t), u), float) for t, u in zip(times, U)]
    return f_int, f_ext


def newmark_residuals(system, U, times, v0, params, scale: float = 1.0, a0=None) -> tuple[np.ndarray, np.ndarray]:
    """``(||r_{n+1}||, ||f_ext_{n+1}||)`` for n = 0 .. N-1 (module docstring) of the trajectory
    ``U`` (N+1, n_free) at ``times`` (N+1,) spaced by the step, from velocity ``v0`` (n_free,);
    ``params`` = ``(alpha, beta, gamma)``; loads times ``scale``; ``a0`` from the equation of motion
    when None. A row that is not finite ends the measured part: its residual and the later ones
    are ``inf``."""
    alpha, beta, gamma = params
    U = np.asarray(U, float)
    n = len(U) - 1
    res, ext = np.full(n, np.inf), np.zeros(n)
    if n < 1:
        return res, ext
    dt = float(times[1] - times[0])
    C = system.C_ff
    cv = (lambda v: C @ v) if C is not None else (lambda v: 0.0)
    u0, v0 = U[0], np.asarray(v0, float)
    fi0, fe0 = np.asarray(system.f_int(u0), float), scale * np.asarray(system.f_ext(float(times[0]), u0), float)
    if a0 is None:
        a0 = spla.spsolve(sp.csc_matrix(system.M_ff), fe0 - fi0 - cv(v0))
    old = cv(v0) + fi0 - fe0
    M = system.M_ff
    for k in range(n):
        u1 = U[k + 1]
        if not np.all(np.isfinite(u1)):
            break
        a1 = (u1 - u0 - dt * v0) / (beta * dt * dt) - (0.5 / beta - 1.0) * a0
        v1 = v0 + dt * ((1.0 - gamma) * a0 + gamma * a1)
        fi1 = np.asarray(system.f_int(u1), float)
        fe1 = scale * np.asarray(system.f_ext(float(times[k + 1]), u1), float)
        new = cv(v1) + fi1 - fe1
        r = M @ a1 + (1.0 + alpha) * new - alpha * old
        res[k], ext[k] = float(np.linalg.norm(r)), float(np.linalg.norm(fe1))
        u0, v0, a0, old = u1, v1, a1, new
    return res, ext


def central_residuals(system, U, times, scale: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``(||r_n||, ||f_ext_n||)`` for n = 1 .. N-1: the equation of motion with central
    differences of the displacements (module docstring); ``inf`` from a non-finite row on."""
    U = np.asarray(U, float)
    n = len(U) - 2
    res, ext = np.full(max(n, 0), np.inf), np.zeros(max(n, 0))
    if n < 1:
        return res, ext
    dt = float(times[1] - times[0])
    C = system.C_ff
    for k in range(1, n + 1):
        if not np.all(np.isfinite(U[k - 1:k + 2])):
            break
        a = (U[k + 1] - 2 * U[k] + U[k - 1]) / (dt * dt)
        v = (U[k + 1] - U[k - 1]) / (2 * dt)
        fe = scale * np.asarray(system.f_ext(float(times[k]), U[k]), float)
        r = system.M_ff @ a + (C @ v if C is not None else 0.0) + np.asarray(system.f_int(U[k]), float) - fe
        res[k - 1], ext[k - 1] = float(np.linalg.norm(r)), float(np.linalg.norm(fe))
    return res, ext


def trajectory_fields(model, history, dt: float, t_end: float, state0: dict, scale: float = 1.0) -> tuple:
    """``(times (N+1,), fields (N+1, n_dof))`` of a trajectory model stepped from ``state0``
    (``{"u", "v"}`` full vectors) at every step of ``dt`` to ``t_end`` with the load factor
    ``scale * history(t)`` (:func:`~tissuebench.studies.protocol.drive`); rows after a failed
    step are NaN."""
    n = int(math.ceil(t_end / dt - 1e-9))
    times = np.arange(n + 1) * dt
    hist = (lambda t: scale * history(t)) if scale != 1.0 else history
    points = [EvaluationPoint({"time": float(t), "load_factor": float(hist(t))}, None, {}, float(t)) for t in times]
    ev = Evaluation("trajectory", "time", points, dt=dt, state0=state0, info={"t_end": float(times[-1])}, history=hist)
    driven = drive(model, ev, hist)
    size = len(state0["u"])
    fields = np.vstack([np.full(size, np.nan) if u is None else np.asarray(u, float) for u in driven.fields])
    return times, fields


def trajectory_residuals(system, times, fields, v0, integrator: str, options=None,
                         scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """``(times of the residuals, ||r||, ||f_ext||, exact)`` of a trajectory's full fields (free
    dofs taken here): the scheme's own residual for the Newmark family (``exact = True``), else
    the central-difference one (module docstring)."""
    free = np.asarray(system.free)
    U = np.asarray(fields, float)[:, free]
    params = newmark_parameters(integrator, options)
    if params is not None:
        res, ext = newmark_residuals(system, U, times, np.asarray(v0, float)[free], params, scale)
        return np.asarray(times[1:]), res, ext, True
    res, ext = central_residuals(system, U, times, scale)
    return np.asarray(times[1:-1]), res, ext, integrator == "central_difference"


def rank_correlation(indicator, error) -> tuple[float, int]:
    """``(Spearman's rank correlation, pairs)`` of ``indicator`` and ``error`` over the pairs where
    both are numbers (``inf`` ranks last: a failed step); NaN with fewer than 3 pairs or a constant
    side."""
    a, b = np.asarray(indicator, float), np.asarray(error, float)
    keep = ~np.isnan(a) & ~np.isnan(b)
    a, b = a[keep], b[keep]
    if len(a) < 3 or np.unique(a).size < 2 or np.unique(b).size < 2:
        return float("nan"), int(len(a))
    big = np.finfo(float).max
    rho = spearmanr(np.where(np.isinf(a), big, a), np.where(np.isinf(b), big, b)).statistic
    return float(rho), int(len(a))
