"""More reference states for a ``path`` training: ``runs = [{ max_load_factor = 3.1, load_steps = 7 }]``.

A path training learns from the states of the scene's reference load path (every ``every``-th
one). ``runs`` adds one state per run: the scene solved again from rest up to another
``max_load_factor`` (with ``load_steps`` increments, default the scene's), its **last converged
state** taken as a snapshot at its load factor. This is how ``tissuebench fit`` adds a
reference where a model errs most (:mod:`.fit`): a load factor between the path's states is a
short path of its own, cached like any reference run (:mod:`tissuebench.reference.cache`), so
that ``tissuebench sweep SPEC`` trains on exactly the states the fit chose.

Only the run's last state is kept, never its intermediate ones: they would land at load factors
the evaluation may measure at (the quarter points of a training interval, near rest), which a
held-out evaluation must never have learnt from. A run that stalls before its
``max_load_factor`` gives its last converged state, at that state's load factor (the snapshot's
parameter is where the state is, not where the run aimed). The keys a run may set are
:data:`PATH_RUN_KEYS` (:func:`~.limits.check_path_runs`): on a path the load factor is the
model's only parameter, so a ``load_scale`` is a ``max_load_factor`` by another name and any
other scene parameter (``nu`` ...) would teach the model a state it cannot tell apart.
"""
from __future__ import annotations

import numpy as np

from ..reference import cached_solve
from .path_states import reference_states

__all__ = ["PATH_RUN_KEYS", "path_run_scenes", "path_run_states", "merge_states"]

#: what a run of a path training may set (module docstring)
PATH_RUN_KEYS = ("max_load_factor", "load_steps")


def path_run_scenes(scene, runs) -> list:
    """The scenes of a path training's ``runs`` (``scene.at(run)`` each; nothing solved)."""
    return [scene.at(dict(run)) for run in runs or []]


def path_run_states(scene, runs, backend: str) -> tuple[np.ndarray, np.ndarray]:
    """``(states (n_dof, k), load factors (k,))``: the last converged state of each run of
    ``runs`` (RuntimeError naming the case when a run converged at no step)."""
    cols, lams = [], []
    for run in path_run_scenes(scene, runs):
        ref, _ = cached_solve(run, backend)
        U, factors = reference_states(ref)
        cols.append(U[:, -1])
        lams.append(float(factors[-1]))
    if not cols:
        return np.zeros((0, 0)), np.zeros(0)
    return np.column_stack(cols), np.asarray(lams, float)


def merge_states(U, lams, extra_U, extra_lams) -> tuple[np.ndarray, np.ndarray]:
    """The columns of ``U`` (load factors ``lams``) and ``extra_U`` (``extra_lams``) in increasing
    load factor (a stable sort: the path's state first where a run lands on one of its load factors)."""
    if not len(extra_lams):
        return U, np.asarray(lams, float)
    lam = np.concatenate([np.asarray(lams, float), np.asarray(extra_lams, float)])
    order = np.argsort(lam, kind="stable")
    return np.hstack([U, extra_U])[:, order], lam[order]
