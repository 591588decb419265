"""Load histories of the scene files: a scalar load factor versus (pseudo-)time.

In dynamics the argument is time; in statics it is the pseudo-time, equal to the
load factor. Types: constant; ramp (t0, t1); step (t0); sine (amplitude, frequency,
phase); ramp_hold_release (t_ramp, t_hold, t_release); tabulated (t, values).

Every load of a scene follows one history (:func:`shared_history`): the reference and every
reduced model drive all loads by one load factor (a static path scales them together, a
trajectory model steps with ``history(t)``), so a scene whose loads differ (gravity held
constant while a probe ramps) is refused when it loads, by every command alike.

A dynamic analysis samples its history at its time steps, so a sine whose period is not
resolved by ``dt`` (:func:`check_history_resolution`: 2 steps a period or fewer, Nyquist) is
refused when the scene loads too: its samples are another, slower sine (aliased), or at 1e12 Hz
noise of the size of the round-off of ``2 pi f t``, which the reference then failed to follow
below round-off rather than the scene saying what it models.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .schema import accepts, c_nonneg, c_num, c_numlist, c_pos, c_str, c_table, check_table, fail

__all__ = ["DEFAULT_HISTORY", "History", "check_history", "check_history_resolution", "check_history_values",
           "shared_history"]

# a load without a history is ramped from 0 at t = 0 to full at t = 1
DEFAULT_HISTORY = {"type": "ramp", "t1": 1.0}

_HISTORY_SCHEMAS = {
    "constant": ({}, ()),
    "ramp": ({"t0": c_num, "t1": c_num}, ("t1",)),
    "step": ({"t0": c_num}, ()),
    "sine": ({"amplitude": c_num, "frequency": c_pos, "phase": c_num}, ("frequency",)),
    "ramp_hold_release": ({"t_ramp": c_pos, "t_hold": c_nonneg, "t_release": c_pos}, ("t_ramp", "t_release")),
    "tabulated": ({"t": c_numlist, "values": c_numlist}, ("t", "values")),
}
# what each history is and what its keys mean (the scene-format reference of the documentation)
HISTORY_DOC = {
    "constant": ("1 at every time", {}),
    "ramp": ("0 until `t0`, linear to 1 at `t1`, then 1", {"t0": "start (default 0)", "t1": "end of the ramp"}),
    "step": ("0 before `t0`, 1 from `t0` on", {"t0": "the time of the step (default 0)"}),
    "sine": ("`amplitude` sin(2 pi `frequency` t + `phase`)",
             {"amplitude": "default 1", "frequency": "[1 / time unit]; in a dynamic analysis below 1 / (2 `dt`): "
                                                  "more than 2 time steps a period (Nyquist)",
              "phase": "[rad] (default 0)"}),
    "ramp_hold_release": ("up to 1 over `t_ramp`, held for `t_hold`, back to 0 over `t_release`",
                          {"t_ramp": "ramp time", "t_hold": "hold time (default 0)", "t_release": "release time"}),
    "tabulated": ("piecewise linear through the points (`t`, `values`)",
                  {"t": "strictly increasing times (at least 2)", "values": "the load factor at each time"}),
}


# the values a history table may leave out: two tables that differ only by them are one history
_DEFAULTS = {"ramp": {"t0": 0.0}, "step": {"t0": 0.0}, "sine": {"amplitude": 1.0, "phase": 0.0},
             "ramp_hold_release": {"t_hold": 0.0}}


def _full(h: dict) -> dict:
    return {**_DEFAULTS.get(h.get("type"), {}), **h}


def shared_history(loads) -> dict:
    """The history table every one of the validated ``loads`` follows (the default ramp without
    loads); ValueError naming the first load whose history differs from ``load[0]``'s."""
    if not loads:
        return dict(DEFAULT_HISTORY)
    first = loads[0]["history"]
    for i, ld in enumerate(loads[1:], start=1):
        if _full(ld["history"]) != _full(first):
            names = [f" ({x['name']!r})" if "name" in x else "" for x in (loads[0], ld)]
            raise ValueError(f"load[{i}].history = {ld['history']}{names[1]}: differs from load[0].history = {first}"
                             f"{names[0]}; loads have different histories, and every load of a scene follows one "
                             "(the reference and the reduced models drive all loads by one load factor): give them "
                             "the same history, or model them in separate scenes")
    return first


@accepts("a history table (see Load histories)")
def check_history(path, h):
    """Validate a history table; returns the checked table."""
    c_table(path, h)
    kind = h.get("type")
    if not isinstance(kind, str) or kind not in _HISTORY_SCHEMAS:
        fail(f"{path}.type", kind, f"unknown history; valid: {sorted(_HISTORY_SCHEMAS)}")
    schema, req = _HISTORY_SCHEMAS[kind]
    out = check_table(path, h, dict(schema, type=c_str), required=req)
    if kind == "ramp" and not out["t1"] > out.get("t0", 0.0):
        fail(f"{path}.t1", out["t1"], "must be > t0")
    if kind == "tabulated":
        t, v = out["t"], out["values"]
        if len(t) != len(v) or len(t) < 2 or np.any(np.diff(t) <= 0):
            fail(f"{path}.t", t, "needs >= 2 strictly increasing times, as many as values")
    return out


#: how many times of an analysis's horizon a history is checked at (its steps, half steps)
_CHECKED_TIMES = 100_001


def check_history_values(path, spec: dict, horizon: float, dt: float | None = None) -> None:
    """Refuse a history that is not a finite number somewhere on ``[0, horizon]`` (the time of a
    dynamic analysis, the load factor of a static one): a parameter whose product overflows
    (``frequency = 1e308``: 2 pi f is inf, and inf x 0 is NaN at t = 0) is named here, by its
    ``path``, rather than by the solver's 'load(t) contains a non-finite value'. Checked at
    every half step of ``dt`` when that is at most :data:`_CHECKED_TIMES` points."""
    n = int(min(np.ceil(2 * horizon / dt), _CHECKED_TIMES - 1)) if dt else _CHECKED_TIMES - 1
    t = np.linspace(0.0, horizon, n + 1)
    with np.errstate(all="ignore"):
        v = np.asarray(History(spec)(t), float)
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        k = int(bad[0])
        fail(path, spec, f"the load factor it gives is {v[k]} at t = {t[k]:g} (not a finite number: a parameter "
             "too large, whose products overflow)")


#: the highest ``frequency x dt`` a sine history may have: below 1/2, more than 2 time steps a period
#: (Nyquist). At 1/2 the steps sample the sine at the same phase every period but one sign (phase 0:
#: zero at every step, no load at all); above it they sample a slower sine than the one written.
MAX_CYCLES_PER_STEP = 0.5


def check_history_resolution(path, spec: dict, dt: float, dt_path: str = "analysis.dt", time_unit: str = "") -> None:
    """Refuse a history that the time step ``dt`` (named ``dt_path``) cannot sample: a sine
    of ``frequency x dt >= 1/2`` (:data:`MAX_CYCLES_PER_STEP`), naming ``<path>.frequency``, its
    value, the step and the highest frequency the step resolves. The other histories are not
    periodic: a ramp or a release shorter than ``dt`` is a step, which the integrators take as such."""
    if spec.get("type") != "sine":
        return
    f = spec["frequency"]
    if f * dt < MAX_CYCLES_PER_STEP:
        return
    unit = f" {time_unit}" if time_unit else ""
    fail(f"{path}.frequency", f, f"its period {1.0 / f:.3g}{unit} is not resolved by the time step {dt_path} = "
         f"{dt:g}{unit} ({f * dt:.3g} periods a step): a dynamic analysis samples the load at its steps, and "
         f"below 2 steps a period (Nyquist) those samples are another, slower sine; expected a frequency below "
         f"1 / (2 dt) = {MAX_CYCLES_PER_STEP / dt:.6g} (or a smaller dt)")


@dataclass(frozen=True)
class History:
    """A scalar load factor as a function of (pseudo-)time: ``h(t)``."""

    spec: dict = field(default_factory=lambda: dict(DEFAULT_HISTORY))

    def __call__(self, t):
        s, t = self.spec, np.asarray(t, float)
        kind = s["type"]
        if kind == "constant":
            out = np.ones_like(t)
        elif kind == "ramp":
            t0 = s.get("t0", 0.0)
            out = np.clip((t - t0) / (s["t1"] - t0), 0.0, 1.0)
        elif kind == "step":
            out = (t >= s.get("t0", 0.0)).astype(float)
        elif kind == "sine":
            out = s.get("amplitude", 1.0) * np.sin(2 * np.pi * s["frequency"] * t + s.get("phase", 0.0))
        elif kind == "ramp_hold_release":
            a, b = s["t_ramp"], s["t_ramp"] + s.get("t_hold", 0.0)
            c = b + s["t_release"]
            out = np.interp(t, [0.0, a, b, c], [0.0, 1.0, 1.0, 0.0], left=0.0, right=0.0)
        else:  # tabulated
            out = np.interp(t, s["t"], s["values"])
        # scalar in, scalar out: callers use h(t) both on one time and on a time grid
        return float(out) if out.ndim == 0 else out
