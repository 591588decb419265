"""The requirement a fit trains to, as numbers, and the stopping rule.

``tissuebench fit --require "rate>=1kHz, error<=2%"`` parses the text with the report's grammar
(:func:`tissuebench.reports.recommend.parse_requirement`, in the command line: studies never
imports reports) and hands the clauses here as ``(quantity, op, value)`` in SI units. A unit
**meets** the target when it ran (``unit_status = "ok"``), was measured on points it never
learnt from (not ``seen``), and every clause holds: the headline error (the sweep's error metric:
``claimed_error`` of a path, ``peak_rel_l2`` of a motion, both peak-normalised over references the
training never used) and the haptic rate or latency **on the p99 step** (a haptic loop misses its
frame on its slow steps), with ``>=``/``<=`` inclusive and ``>``/``<`` strict, as the report reads
them (:mod:`tissuebench.reports.recommend`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Clause", "Target", "QUANTITIES"]

#: the quantities of a requirement and the direction each must hold in
QUANTITIES = {"rate": (">=", ">"), "latency": ("<=", "<"), "error": ("<=", "<")}


@dataclass(frozen=True)
class Clause:
    """``quantity`` (rate [Hz] | latency [s] | error [fraction]) ``op`` ``value``."""

    quantity: str
    op: str
    value: float

    def __post_init__(self):
        if self.quantity not in QUANTITIES:
            raise ValueError(f"clause quantity = {self.quantity!r}: valid: {list(QUANTITIES)}")
        if self.op not in QUANTITIES[self.quantity]:
            raise ValueError(f"clause {self.quantity} op = {self.op!r}: valid: {list(QUANTITIES[self.quantity])}")
        if not (isinstance(self.value, (int, float)) and math.isfinite(self.value) and self.value > 0):
            raise ValueError(f"clause {self.quantity} value = {self.value!r}: expected a positive finite number")

    def headroom(self, error: float, p99_s: float) -> float:
        """> 1 when the clause holds with room to spare (the report's ratio); NaN unmeasured."""
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.quantity == "rate":
                return float((1.0 / p99_s) / self.value) if p99_s > 0 else float("nan")
            if self.quantity == "latency":
                return float(self.value / p99_s) if p99_s > 0 else float("nan")
            return float("inf") if error == 0 else float(self.value / error)

    def holds(self, error: float, p99_s: float) -> bool:
        r = self.headroom(error, p99_s)
        if not np.isfinite(r) and not r == np.inf:
            return False
        return r > 1.0 if self.op in (">", "<") else r >= 1.0

    def text(self) -> str:
        if self.quantity == "rate":
            return f"rate{self.op}{self.value:g}Hz (p99 {'<' if self.op == '>' else '<='} {1e3 / self.value:.3g} ms)"
        if self.quantity == "latency":
            return f"latency{self.op}{self.value * 1e3:.3g}ms (p99)"
        return f"error{self.op}{self.value * 100:.3g}%"


@dataclass(frozen=True)
class Target:
    """The clauses of a requirement (at least one; each quantity at most once)."""

    clauses: tuple

    @classmethod
    def of(cls, clauses) -> Target:
        """From ``[(quantity, op, value), ...]`` (SI units; ValueError naming a bad clause)."""
        out = tuple(c if isinstance(c, Clause) else Clause(str(c[0]), str(c[1]), float(c[2])) for c in clauses)
        if not out:
            raise ValueError("require: no clause; expected e.g. 'rate>=1kHz, error<=2%'")
        names = [c.quantity for c in out]
        if len(set(names)) != len(names):
            raise ValueError(f"require: a quantity given twice: {names}")
        return cls(out)

    def error_clause(self) -> Clause | None:
        return next((c for c in self.clauses if c.quantity == "error"), None)

    def speed_clauses(self) -> tuple:
        return tuple(c for c in self.clauses if c.quantity != "error")

    def meets(self, row) -> bool:
        """Whether a unit row (``unit_status``, ``seen``, ``error``, ``haptic_p99_s``) meets every
        clause: the stopping rule (module docstring)."""
        return self.missed(row) == []

    def meets_speed(self, row) -> bool:
        """Every rate / latency clause holds for ``row`` (its error aside)."""
        return _usable(row) and all(c.holds(_f(row, "error"), _f(row, "haptic_p99_s")) for c in self.speed_clauses())

    def meets_error(self, row) -> bool:
        """The error clause holds for ``row`` (its speed aside; True without an error clause)."""
        c = self.error_clause()
        return _usable(row) and (c is None or c.holds(_f(row, "error"), _f(row, "haptic_p99_s")))

    def missed(self, row) -> list[str]:
        """The clauses ``row`` misses, in words (``[]``: it meets the target)."""
        if row.get("unit_status") != "ok":
            return [f"the unit failed: {str(row.get('message', ''))[:200]}"]
        if bool(row.get("seen", False)):
            return ["measured only where it was trained (seen)"]
        error, p99 = _f(row, "error"), _f(row, "haptic_p99_s")
        out = []
        for c in self.clauses:
            if not c.holds(error, p99):
                got = f"{error * 100:.3g}%" if c.quantity == "error" else f"p99 {p99 * 1e3:.3g} ms"
                out.append(f"{c.text()}: {got}")
        return out

    def text(self) -> str:
        return ", ".join(c.text() for c in self.clauses)


def _f(row, key) -> float:
    try:
        v = float(row.get(key, float("nan")))
    except (TypeError, ValueError):
        return float("nan")
    return v


def _usable(row) -> bool:
    return row.get("unit_status") == "ok" and not bool(row.get("seen", False))
