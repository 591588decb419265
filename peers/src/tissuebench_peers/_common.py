"""What the adapters share: whether a library is installed, the status of a step against the
training envelope, the snapshot columns a hyper-reduction is fitted on, option checks."""
from __future__ import annotations

import importlib.util

import numpy as np

__all__ = ["missing", "envelope_of", "status_at", "evenly", "positive_int", "positive", "fraction",
           "is_dynamic", "moving_supports", "step_start"]


def missing(*modules: str) -> str:
    """``""`` when every module imports, else what is missing and how to install it."""
    absent = [m for m in modules if importlib.util.find_spec(m) is None]
    if not absent:
        return ""
    return f"needs {', '.join(absent)}, which is not installed (pip install {' '.join(absent)})"


def envelope_of(training) -> dict:
    """``{"load_factor": (lo, hi)}`` of the training's snapshots ({} without parameters)."""
    if not training.parameters:
        return {}
    lam = training.parameter_values("load_factor")
    return {"load_factor": (float(lam.min()), float(lam.max()))}


def status_at(name: str, lam: float, envelope: dict) -> tuple[str, str]:
    """``("ok", "")`` inside the training's load factors (a relative 1e-9 of slack), else flagged."""
    lo, hi = envelope.get("load_factor", (-np.inf, np.inf))
    tol = 1e-9 * max(abs(lo), abs(hi), 1e-300)
    if lo - tol <= lam <= hi + tol:
        return "ok", ""
    return "extrapolation", f"{name}: load factor {lam:.6g} outside the training's [{lo:.6g}, {hi:.6g}]"


def step_start(name: str, t: float, last_t: float | None, dt: float) -> float:
    """The time [s] a trajectory step to ``t`` starts from: the last step's time (``t - dt`` at the
    first step); a ``t`` other than the next step's (a relative 1e-6 of ``dt``) is refused."""
    t0 = t - dt if last_t is None else last_t
    if abs(t - (t0 + dt)) > 1e-6 * dt:
        raise ValueError(f"{name}.step: mu['time'] = {t!r} is not the next step {t0 + dt!r} (dt = {dt!r})")
    return t0


def evenly(n_columns: int, count: int) -> np.ndarray:
    """At most ``count`` snapshot columns evenly through ``n_columns`` (the states ``pod_galerkin``
    fits its hyper-reduction on: the same selection)."""
    return np.unique(np.linspace(0, n_columns - 1, min(count, n_columns)).round().astype(int))


def _number(who, name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or \
            not np.isfinite(value):
        raise ValueError(f"{who} option {name} must be a finite number, got {value!r}")
    return value


def positive_int(who: str, name: str, value, allow_none: bool = False):
    """``value`` as an int >= 1 (or None when allowed); ValueError naming the option and the value."""
    if value is None and allow_none:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer, float)) or value != int(value) or value < 1:
        raise ValueError(f"{who} option {name} must be an integer >= 1{' or None' if allow_none else ''}, "
                         f"got {value!r}")
    return int(value)


def positive(who: str, name: str, value) -> float:
    """``value`` as a float > 0; ValueError naming the option and the value."""
    if not _number(who, name, value) > 0:
        raise ValueError(f"{who} option {name} must be > 0, got {value!r}")
    return float(value)


def fraction(who: str, name: str, value) -> float:
    """``value`` in (0, 1]; ValueError naming the option and the value."""
    if not 0 < _number(who, name, value) <= 1:
        raise ValueError(f"{who} option {name} must lie in (0, 1], got {value!r}")
    return float(value)


def is_dynamic(scene) -> bool:
    return (getattr(scene, "analysis", None) or {}).get("type") == "dynamic"


def moving_supports(scene) -> bool:
    """A ``[[dirichlet]]`` entry prescribes a nonzero displacement or a motion."""
    return any("motion" in d or any(v != 0.0 for v in d.get("value", [])) for d in getattr(scene, "dirichlet", []))
