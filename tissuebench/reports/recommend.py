"""Requirements ("rate>=500Hz, error<=2%") and the units of a sweep that meet them, ranked.

A requirement is a comma-separated list of clauses ``<quantity><op><number><unit>``:

``rate``     haptic rate, ``>=`` or ``>``, unit ``Hz`` (default) or ``kHz``. It applies to the
             **99th percentile** of the haptic step (``haptic_p99_s``): a haptic loop misses
             its deadline on its slow steps, so a rate met only by the median is not met.
``latency``  haptic step time, ``<=`` or ``<``, unit ``s``, ``ms``, ``us`` (or ``µs``); also the p99.
``error``    the sweep's error metric (``error_metric`` of ``_sweep.json``, e.g. ``max_rel_l2``),
             ``<=`` or ``<``, unit ``%`` or none (a fraction below 1).

The margin of a unit is the smallest headroom over the clauses, each a ratio that is > 1
when the clause holds with room to spare: ``achieved rate / required rate``, ``allowed
latency / p99``, ``allowed error / error``. Units that meet every clause are ranked by it
(largest first), on the latency as measured. When none does, what each misses by is each failed
clause's ratio, and:

* **the closest** is the unit with the largest ``closeness``: its margin with the headroom of
  each latency clause (rate, latency) multiplied by the load factor of the machine when it was
  timed where that exceeds 1 (``load_average / n_cpus``: more runnable tasks than CPUs, the
  step waits for one; issue 52). A latency miss that the machine's load accounts for therefore
  never ranks a unit below one whose error misses the requirement: a look-up table 3.8x over
  the error was named closest over a POD-Galerkin that missed 1 kHz only on a loaded machine.
  On an idle machine (or where the load was not recorded) it is the margin.
* **per clause**, the best unit that meets the others (:func:`best_per_clause`): the most
  accurate unit that meets the rate, the fastest that meets the error, and by how much each
  misses its own clause.

The p99 comes with the samples behind it: ``p99_n`` timed steps, ``p99_tail`` of them beyond it
(:func:`tissuebench.studies.timing.p99_tail`); a verdict on the rate or the latency that rests
on fewer than :data:`~tissuebench.studies.timing.TAIL_SAMPLES` says so (:func:`tail_note`).

A unit evaluated only where it was trained (``seen``: every evaluation point's reference is one
of its training snapshots, :func:`tissuebench.studies.metrics.seen_points`) is never
recommended, nor the closest: its error says what it stored, not what it predicts (a nearest
snapshot replaying its trajectory "met" 500 Hz / 2 % with 0 % error, issue 27). It is ranked
last with the reason; a unit with some points seen carries their count.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ..studies.timing import TAIL_SAMPLES, p99_tail
from .format import hz as _hz, percent as _percent, seconds as _seconds, times as _times
from .wording import metric_words

__all__ = ["DEFAULT_REQUIREMENT", "Clause", "Requirement", "parse_requirement", "rank_units", "LATENCY_STATISTIC",
           "SEEN_REASON", "tail_note", "best_per_clause", "LATENCY_QUANTITIES"]

SEEN_REASON = ("not recommended: evaluated only on its training data (every evaluation point is a training snapshot: "
               "seen); give its case a held-out evaluation")

DEFAULT_REQUIREMENT = "rate>=1kHz, error<=1%"
LATENCY_STATISTIC = "haptic_p99_s"
_CLAUSE = re.compile(r"^\s*([A-Za-z_]+)\s*(>=|<=|>|<|==|=)?\s*(.*?)\s*$")
_NUMBER = re.compile(r"^([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*(\S*)$")
_UNITS = {"rate": {"": 1.0, "hz": 1.0, "khz": 1e3},
          "latency": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6},
          "error": {"": 1.0, "%": 1e-2}}
_DIRECTIONS = {"rate": (">=", ">"), "latency": ("<=", "<"), "error": ("<=", "<")}
#: the clauses measured on the machine's clock (the p99), which its load slows
LATENCY_QUANTITIES = ("rate", "latency")


@dataclass(frozen=True)
class Clause:
    """One clause: ``quantity`` (rate | latency | error), ``op``, ``value`` in SI (Hz, s, fraction)
    and the clause as the user wrote it."""

    quantity: str
    op: str
    value: float
    text: str

    def describe(self, error_metric: str) -> str:
        if self.quantity == "rate":
            return f"haptic rate {self.op} {_hz(self.value)} on the p99 step (p99 {self.op.replace('>', '<')} " \
                   f"{_seconds(1.0 / self.value)})"
        if self.quantity == "latency":
            return f"haptic step p99 {self.op} {_seconds(self.value)}"
        return f"error ({metric_words(error_metric)}, {error_metric}) {self.op} {_percent(self.value)}"


@dataclass(frozen=True)
class Requirement:
    clauses: tuple
    text: str

    def describe(self, error_metric: str) -> str:
        return " and ".join(c.describe(error_metric) for c in self.clauses)


def _bad(text, clause, why):
    raise ValueError(f"require = {text!r}: clause {clause!r}: {why}")


def parse_requirement(text: str | None) -> Requirement:
    """Parse a requirement string (module docstring); ``None`` gives :data:`DEFAULT_REQUIREMENT`.

    Raises ValueError naming the clause that is wrong and why (unknown quantity or unit,
    missing or wrong-way comparison, not a positive finite number, a quantity given twice)."""
    if text is None:
        text = DEFAULT_REQUIREMENT
    if not isinstance(text, str):
        raise TypeError(f"require = {text!r}: expected a string like {DEFAULT_REQUIREMENT!r}")
    parts = [p for p in text.split(",")]
    if not text.strip() or any(not p.strip() for p in parts):
        raise ValueError(f"require = {text!r}: empty clause; expected clauses like {DEFAULT_REQUIREMENT!r}")
    clauses, seen = [], set()
    for part in parts:
        m = _CLAUSE.match(part)
        name = m.group(1).lower() if m else ""
        if not m or name not in _UNITS:
            _bad(text, part.strip(), f"unknown quantity {name or part.strip()!r}; valid: {sorted(_UNITS)}")
        op = m.group(2)
        if op not in _DIRECTIONS[name]:
            _bad(text, part.strip(), f"{name} needs {' or '.join(_DIRECTIONS[name])}" + (f", not {op}" if op else ""))
        num = _NUMBER.match(m.group(3))
        if not num:
            _bad(text, part.strip(), f"{m.group(3)!r} is not a number with a unit")
        unit = num.group(2).lower()
        if unit not in _UNITS[name]:
            _bad(text, part.strip(), f"unknown unit {num.group(2)!r} for {name}; valid: "
                                     f"{[u for u in _UNITS[name] if u] + (['none'] if '' in _UNITS[name] else [])}")
        value = float(num.group(1)) * _UNITS[name][unit]
        if not math.isfinite(value) or value <= 0:
            _bad(text, part.strip(), f"{num.group(1)} must be a positive finite number")
        if name == "error" and unit == "" and value >= 1:
            _bad(text, part.strip(), f"error {value:g} without a unit is a fraction and must be < 1 (for percent "
                                     f"write {value:g}%)")
        if name in seen:
            _bad(text, part.strip(), f"{name} is given twice")
        seen.add(name)
        clauses.append(Clause(name, op, value, part.strip()))
    return Requirement(tuple(clauses), text)


def _headroom(clause: Clause, p99: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Per unit, the clause's ratio (> 1: met with room to spare; NaN: not measurable)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        if clause.quantity == "rate":
            return (1.0 / p99) / clause.value
        if clause.quantity == "latency":
            return clause.value / p99
        return np.where(error == 0, np.inf, clause.value / error)


def _holds(clause: Clause, ratio: np.ndarray) -> np.ndarray:
    strict = clause.op in (">", "<")
    with np.errstate(invalid="ignore"):
        return (ratio > 1.0) if strict else (ratio >= 1.0)


def rank_units(units: pd.DataFrame, requirement: Requirement, error_metric: str) -> pd.DataFrame:
    """``units`` with ``error``, ``p99_s``, ``rate_hz``, ``p99_n`` / ``p99_tail`` (the timed steps and
    those beyond the p99), one ``headroom_<quantity>`` column per clause,
    ``margin`` (the smallest headroom), ``meets`` (bool), ``measurable`` (ok unit, finite
    error and p99) and ``misses`` (text: the failed clauses and by how much), ``load_factor`` and
    ``closeness`` (:func:`_closest_first`), sorted: units that meet first, by margin, largest
    first; then the others by closeness, largest first."""
    if error_metric not in units:
        raise ValueError(f"error_metric = {error_metric!r}: not a column of the results")
    out = units.copy()
    out["error"] = out[error_metric].astype(float)
    out["p99_s"] = out[LATENCY_STATISTIC].astype(float)
    n = out["haptic_n"].astype(float) if "haptic_n" in out else pd.Series(np.nan, index=out.index)
    out["p99_n"] = n.where(n > 0)  # -1: the schema's missing value (a failed unit)
    out["p99_tail"] = [p99_tail(k) if np.isfinite(k) else np.nan for k in out["p99_n"]]
    with np.errstate(divide="ignore"):
        out["rate_hz"] = 1.0 / out["p99_s"]
    ok = (out["unit_status"] == "ok") & np.isfinite(out["p99_s"]) & (out["p99_s"] > 0) & ~out["error"].isna()
    seen = out["seen"].fillna(False).astype(bool) if "seen" in out else pd.Series(False, index=out.index)
    out["seen"] = seen
    ok = ok & ~seen  # a unit evaluated on its training data is not a candidate (module docstring)
    out["measurable"] = ok
    meets = ok.to_numpy().copy()
    ratios = []
    for c in requirement.clauses:
        r = _headroom(c, out["p99_s"].to_numpy(float), out["error"].to_numpy(float))
        out[f"headroom_{c.quantity}"] = r
        ratios.append(r)
        meets &= _holds(c, r)
    margin = np.min(np.vstack(ratios), axis=0) if ratios else np.full(len(out), np.inf)
    out["margin"] = np.where(ok, np.nan_to_num(margin, nan=0.0), np.nan)
    out["meets"] = meets
    out["misses"] = [("" if good else _misses(requirement, row)) if m else _unmeasurable(row)
                     for (_, row), m, good in zip(out.iterrows(), ok, meets)]
    return _closest_first(out, requirement)


def _closest_first(out: pd.DataFrame, requirement: Requirement) -> pd.DataFrame:
    """``out`` (:func:`rank_units`) with ``load_factor`` (``load_average / n_cpus`` when the unit
    was timed: :func:`load_factor`) and ``closeness`` (its margin with each latency clause's
    headroom multiplied by a load factor above 1: module docstring; NaN where not measurable),
    sorted: the units that meet by margin, the others by closeness, largest first. A latency miss
    the machine's load accounts for is not held against a unit when naming the closest."""
    out["load_factor"] = load_factor(out)
    busy = np.fmax(out["load_factor"].to_numpy(float), 1.0)
    idle = [out[f"headroom_{c.quantity}"].to_numpy(float) * (busy if c.quantity in LATENCY_QUANTITIES else 1.0)
            for c in requirement.clauses]
    closeness = np.min(np.vstack(idle), axis=0) if idle else np.full(len(out), np.inf)
    out["closeness"] = np.where(out["measurable"], closeness, np.nan)  # finite or inf where measurable
    order = out["margin"].where(out["meets"], out["closeness"])
    return (out.assign(_order=order).sort_values(["meets", "_order"], ascending=[False, False], na_position="last",
                                                  kind="stable").drop(columns="_order"))


def load_factor(units: pd.DataFrame) -> pd.Series:
    """Per unit, the machine's ``load_average / n_cpus`` when it was timed; NaN where either is
    not recorded (a store written before issue 52, a system without a load average) or the CPU
    count is not positive."""
    if "load_average" not in units or "n_cpus" not in units:
        return pd.Series(np.nan, index=units.index)
    load, cpus = units["load_average"].astype(float), units["n_cpus"].astype(float)
    return (load / cpus).where(cpus > 0)


def best_per_clause(ranked: pd.DataFrame, requirement: Requirement) -> list[tuple]:
    """``[(clause, others, row or None)]``, one per clause of a requirement of two clauses or
    more: among the measurable units of ``ranked`` (:func:`rank_units`) that meet every other
    clause, the one with the largest headroom on this one (the most accurate that meets the rate,
    the fastest that meets the error; the first in ``ranked``'s order on a tie), or None when no
    unit meets the others. ``[]`` for a requirement of one clause (its best is the closest)."""
    if len(requirement.clauses) < 2:
        return []
    out = []
    for c in requirement.clauses:
        others = tuple(d for d in requirement.clauses if d is not c)
        pool = ranked["measurable"].to_numpy(bool).copy()
        for d in others:
            pool &= _holds(d, ranked[f"headroom_{d.quantity}"].to_numpy(float))
        candidates = ranked[pool]
        best = None if candidates.empty else candidates.iloc[int(np.argmax(
            candidates[f"headroom_{c.quantity}"].to_numpy(float)))]
        out.append((c, others, best))
    return out


def _unmeasurable(row) -> str:
    if row["unit_status"] != "ok":
        return f"unit failed: {row.get('message', '')}"
    if row["seen"]:
        return SEEN_REASON
    return "no error (no evaluation point with a reference)" if pd.isna(row["error"]) else "no latency measured"


def _misses(requirement: Requirement, row) -> str:
    parts = []
    for c in requirement.clauses:
        r = row[f"headroom_{c.quantity}"]
        if _holds(c, np.array([r]))[0]:
            continue
        if c.quantity == "rate":
            parts.append(f"rate {_hz(row['rate_hz'])} (p99 {_seconds(row['p99_s'])}{tail_note(row)}) is {_times(r)} "
                         f"short of {_hz(c.value)}")
        elif c.quantity == "latency":
            parts.append(f"p99 {_seconds(row['p99_s'])}{tail_note(row)} is {_times(r)} over {_seconds(c.value)}")
        else:
            parts.append(f"error {_percent(row['error'])} is {_times(r)} over {_percent(c.value)}")
    return "; ".join(parts)


def tail_note(row) -> str:
    """``", decided by 2 samples of 200 (fewer than 20)"`` where the p99 of ``row`` (a row of
    :func:`rank_units`) rests on fewer than :data:`TAIL_SAMPLES` samples, else ``""``."""
    n, tail = row.get("p99_n", np.nan), row.get("p99_tail", np.nan)
    if not (isinstance(n, (int, float)) and np.isfinite(n)) or tail >= TAIL_SAMPLES:
        return ""
    return f", decided by {int(tail)} sample{'s' if tail != 1 else ''} of {int(n)} (fewer than {TAIL_SAMPLES})"
