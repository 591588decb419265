"""The reference runs a ``path`` evaluation reads besides the path itself: its range, and past it.

The error of a unit is its worst over the range it claims (the training path, from rest to its
top), so a path evaluation is measured at more load factors than the path's own states:

* **between** the training states: the path solved again with a finer increment, so that the
  middle and the quarter points of every training interval are references the training never
  saw (``refine = r``: the training interval cut into ``r``; ``r = 4`` by default: the
  quarter points and the middle). With ``training.every = k`` the interval is ``k`` path
  increments; the finer path has ``r / gcd(r, k)`` times the path's increments (none when the
  path's own states already are those points, e.g. ``k = 4``).
* **near rest**, where a model interpolating between rest and its first training state is
  furthest from the tangent it never learnt: the load factors ``L / (2 r)`` and ``L / (4 r)``
  (``L``: the first training state's; 1/8 and 1/16 of it by default), a short path of
  :data:`NEAR_REST_STEPS` increments from rest, and ``L / 64``, ``L / 1024``
  (:data:`REST_FRACTIONS`), one increment from rest each: the error there is the limit at
  rest (on a kidney of 2013 nodes, RBF-interpolated POD coefficients: 18.9 % at L / 16, 21.6 %
  at L / 80, against 6.0 % at the first held-out state L / 2; the limit is what a dense check
  finds, so it is what the unit reports).

Both are ordinary reference runs of the scene at other ``load_steps`` / ``max_load_factor``
(cached under their own keys, :mod:`tissuebench.reference.cache`), declared from the case entry
alone (:func:`range_scenes`), so the dask executor solves them as tasks. The model steps cost
microseconds; what limits the points is the reference, solved once per scene and shared by
every unit of it: a method that is cheap to evaluate gets the same dense set for free, and a
spec may ask for more (``refine = 8``). ``refine = 1`` keeps the path's states only (the
evaluation of tissuebench before issue 44).

**Past** the path (``beyond``): :func:`beyond_scene`, the path continued with its own increment.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..reference import cached_solve
from .path_states import reference_states, training_indices

__all__ = ["DEFAULT_REFINE", "NEAR_REST_STEPS", "REST_FRACTIONS", "BEYOND_MAX_INCREMENTS", "BEYOND_MAX_CUTS",
           "range_scenes", "range_states", "beyond_scene", "interval_every"]

#: the training interval is cut into this many parts by default (quarter points and the middle)
DEFAULT_REFINE = 4
#: increments of the path from rest to L / (2 refine): its states are L / (4 refine) and L / (2 refine)
NEAR_REST_STEPS = 2
#: one increment from rest to each of these fractions of the first training state's load factor L
REST_FRACTIONS = (2.0 ** -6, 2.0 ** -10)
#: the continuation of a path past its top takes at most this many times the path's increments,
#: each halved at most BEYOND_MAX_CUTS times where Newton does not converge
BEYOND_MAX_INCREMENTS, BEYOND_MAX_CUTS = 4, 2


def _capped(scene, mu: dict):
    """``scene.at(mu)`` whose Newton halves an increment at most :data:`BEYOND_MAX_CUTS` times
    before it stalls (where the path itself stops, without crawling towards it in ever smaller
    steps: a kidney took > 4 min there with the default 1/4096), on the same mesh."""
    ext = scene.at(mu)
    new = dataclasses.replace(ext, analysis={**ext.analysis, "max_cuts": BEYOND_MAX_CUTS})
    if "built" in scene.__dict__:  # the same mesh: not built again
        new.__dict__["built"] = scene.__dict__["built"]
    return new


def beyond_scene(scene, load_factor: float):
    """``scene`` run past its path's top to ``load_factor`` with the path's own increment (at
    most :data:`BEYOND_MAX_INCREMENTS` x its increments past the top), an increment Newton does
    not converge halved at most :data:`BEYOND_MAX_CUTS` times, until it stalls: its last converged
    load factor is where the reference stops (``status = "stalled"``, the message says at which)."""
    a = scene.analysis
    n, top = int(a.get("load_steps", 1)), float(a.get("max_load_factor", 1.0))
    h = top / n
    steps = min(int(np.ceil(load_factor / h - 1e-9)), n * (1 + BEYOND_MAX_INCREMENTS))
    return _capped(scene, {"max_load_factor": steps * h, "load_steps": steps})


def interval_every(case) -> int:
    """The path increments in one training interval of ``case``: its path training's ``every``
    (1 for any other training: the path's own increments are the intervals)."""
    return int(case.training.get("every", 1)) if case.training_kind == "path" else 1


def range_scenes(scene, every: int, refine: int = DEFAULT_REFINE) -> list[tuple[str, object]]:
    """``[(role, scene)]``: the reference runs between the training states (``"between"``) and
    near rest (``"near_rest"``, ``"rest_64"``, ``"rest_1024"``) of a static ``scene`` whose training
    keeps every ``every``-th state (module docstring); nothing solved, ``[]`` for ``refine = 1`` or
    a dynamic scene."""
    a = scene.analysis
    if int(refine) <= 1 or a.get("type") != "static":
        return []
    n, top = int(a.get("load_steps", 1)), float(a.get("max_load_factor", 1.0))
    runs = []
    finer = int(refine) // math.gcd(int(refine), int(every))
    if finer > 1:
        runs.append(("between", _capped(scene, {"load_steps": n * finer})))
    trained = training_indices(n + 1, every)
    first = float(trained[trained > 0].min()) * top / n  # the last state is always trained
    runs.append(("near_rest", _capped(scene, {"max_load_factor": first / (2 * int(refine)),
                                              "load_steps": NEAR_REST_STEPS})))
    runs += [(f"rest_{round(1 / f)}", _capped(scene, {"max_load_factor": first * f, "load_steps": 1}))
             for f in REST_FRACTIONS]
    return runs


def range_states(scene, backend: str, every: int, refine: int, path_factors) -> tuple[list, dict]:
    """``([(load factor, state (n_dof,), monitors)], info)``: the states of :func:`range_scenes`'
    runs at load factors the path has no state at (``path_factors``: its converged load factors,
    rest excluded), up to the path's last one (the range the training claims), in increasing order.
    ``info`` holds each run's status (``reference_<role>_status``) and message where it did not
    succeed (a finer path stalling leaves fewer points, said, never hidden)."""
    lams = np.asarray(path_factors, float)
    if not lams.size:
        return [], {}
    top = float(lams[-1])
    tol = 1e-9 * max(abs(top), 1e-300)
    out, info = [], {}
    for role, run in range_scenes(scene, every, refine):
        ref, _ = cached_solve(run, backend)
        info[f"reference_{role}_status"] = ref.status
        if ref.status != "success":
            info[f"reference_{role}_message"] = ref.message[:300]
        if len(ref.steps) < 2:
            continue
        U, factors = reference_states(ref)
        for k, lam in enumerate(factors):
            taken = np.min(np.abs(lams - lam)) <= tol or any(abs(lam - o[0]) <= tol for o in out)
            if 0 < lam <= top + tol and not taken:
                out.append((float(lam), U[:, k], ref.monitors_at("load_factor", lam)))
    out.sort(key=lambda s: s[0])
    info["range_points"] = len(out)
    return out, info
