"""The rule of each round of ``tissuebench fit`` (:mod:`.loop`): met, add, grow or stop, from a
family's learning curve and its lead's measurement alone (no I/O: the rule on its own, for tests).

A reference "helps" when it lowers the family's error by :data:`MIN_GAIN`; after :data:`PATIENCE`
references in a row that did not, training no longer helps and the model grows
(:mod:`.growth`). A rate missed only because the machine was loaded (more runnable tasks than
CPUs when the unit was timed) does not stop the training (:func:`speed_ok`); the requirement
itself is met only by the p99 as timed.
"""
from __future__ import annotations

import math

import numpy as np

from .target import Target

__all__ = ["decide", "speed_ok", "load_factor", "MIN_GAIN", "PATIENCE"]

#: a reference (or a larger model) "helps" when the family's error falls by at least this fraction
MIN_GAIN = 0.10
#: added references in a row that each fail to lower the error by MIN_GAIN before "training no longer helps"
PATIENCE = 2


def load_factor(point: dict) -> float:
    """The machine's load when ``point``'s unit was timed: ``load_average / n_cpus``, at least 1
    (1 where not recorded)."""
    load, cpus = point.get("load_average"), point.get("n_cpus")
    if load is None or not cpus or not math.isfinite(load) or cpus <= 0:
        return 1.0
    return max(1.0, float(load) / float(cpus))


def speed_ok(target: Target, point: dict) -> bool:
    """Whether ``point`` meets the speed clauses as timed, or with its p99 divided by the machine's
    :func:`load_factor` (more runnable tasks than CPUs: the step waited for one; the report's
    "closest" reads latency the same way, :mod:`tissuebench.reports.recommend`). A family whose lead
    misses only by the load goes on training for the error; the requirement itself is met only by
    the p99 as timed."""
    row = _as_row(point)
    if target.meets_speed(row):
        return True
    return target.meets_speed({**row, "haptic_p99_s": row["haptic_p99_s"] / load_factor(point)})


def _stale_adds(curve: list) -> int:
    """How many of the last points of ``curve`` (a family's, oldest first) came from an added
    reference that lowered the error by less than :data:`MIN_GAIN` (counted back to the first
    that helped or was not an added reference)."""
    n = 0
    for prev, p in zip(reversed(curve[:-1]), reversed(curve[1:])):
        if p.get("action") != "add" or _helped(prev["error"], p["error"]):
            break
        n += 1
    return n


def _helped(previous, error) -> bool:
    return previous is None or (error is not None and error <= previous * (1.0 - MIN_GAIN))


def decide(fam_state: dict, point: dict, target: Target, budget_refs: int, can_add: bool, can_grow: bool) -> tuple:
    """``(action, why)`` after ``point`` (the lead's measurement) of a family in ``fam_state``:
    ``"met"``, ``"add"``, ``"grow"`` or ``"stop"`` (module docstring). The rule on its own, for
    tests: ``can_add`` (a candidate is left), ``can_grow`` (a next size exists); the budget of
    references is ``budget_refs``. Training "no longer helps" after :data:`PATIENCE` references in
    a row that each lowered the error by less than :data:`MIN_GAIN` (one may land where the
    indicator misleads: near rest, where a stiff tangent inflates the residual of a small error)."""
    row = _as_row(point)
    if target.meets(row):
        return "met", "meets " + target.text()
    if point["status"] != "ok":
        return "stop", f"its unit failed: {str(point.get('message', ''))[:200]}"
    if not speed_ok(target, point):
        missed = "; ".join(target.missed(row))
        return "stop", (f"misses the speed clauses ({missed}), even with its p99 divided by the machine's load "
                        f"factor ({load_factor(point):.3g}): more training does not make a model faster")
    curve = [p for p in fam_state["curve"] if p is not point and not p.get("dropped")]
    previous = curve[-1]["error"] if curve else None
    last = fam_state.get("last_action", "start")
    budget_left = fam_state["refs_added"] < budget_refs
    if last == "grow" and not _helped(previous, point["error"]):
        return "stop", (f"neither more training nor a larger or refined model lowers the error by {MIN_GAIN:.0%} "
                        f"({_pct(previous)} -> {_pct(point['error'])})")
    stale = _stale_adds(curve + [{**point, "action": last}])
    if last == "add" and stale >= PATIENCE:
        first = curve[-stale]["error"] if len(curve) >= stale else previous
        words = f"training no longer helps ({stale} references: {_pct(first)} -> {_pct(point['error'])})"
        if can_grow:
            return "grow", f"{words}: the model grows"
        return "stop", f"{words} and the model cannot grow"
    if budget_left and can_add:
        return "add", "a reference at the worst candidate"
    if can_grow:
        return "grow", ("the budget of references is spent: the model grows" if not budget_left
                        else "no candidate left: the model grows")
    return "stop", (f"the budget of {budget_refs} references is spent" if not budget_left
                    else "no candidate left and the model cannot grow")


def _pct(x) -> str:
    return "n/a" if x is None else f"{100 * x:.3g} %"


def _as_row(p: dict) -> dict:
    return {"unit_status": p["status"], "seen": p["seen"], "error": p["error"] if p["error"] is not None else np.nan,
            "haptic_p99_s": p["p99_s"] if p["p99_s"] is not None else np.nan}
