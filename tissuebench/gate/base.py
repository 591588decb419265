"""The gate's contract: what it finds, one :class:`Finding` per regression gathered in a
:class:`CheckResult`, and how its A/B runs (:class:`ABSettings`). Imports nothing of the gate:
every other module of :mod:`tissuebench.gate` reads these."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

__all__ = ["Finding", "CheckResult", "ABSettings"]


@dataclass
class Finding:
    """One regression of one unit (``case``, ``method``, ``options``): the metric, the value it
    is compared with (the baseline's or REF's), the value now and the rule it broke."""

    case: str
    method: str
    options: str
    metric: str
    baseline: float
    now: float
    tolerance: str

    def line(self) -> str:
        return (f"{self.case:24s} {self.method:14s} {self.metric:20s} was {_fmt(self.baseline):>11s} "
                f"now {_fmt(self.now):>11s}  ({self.tolerance})  {self.options}")


@dataclass
class ABSettings:
    """How the A/B latency comparison runs (:func:`tissuebench.gate.latency.run_ab`)."""

    min_rounds: int = 3
    max_rounds: int = 8
    blocks: int = 3
    budget_s: float = 900.0
    inject: dict | None = None  # {(case, method, options JSON): factor} on HEAD's side: power tests only


@dataclass
class CheckResult:
    """Every unit checked (``per_unit``: identity -> its findings), the regressions, the units
    the baseline does not know, notes (what was compared with what, and what could not be),
    how latency was checked (``ab``, ``file`` or ``none``), the A/B verdicts, and with REF the
    project under test and what each side ran."""

    compared: int = 0
    regressions: list = field(default_factory=list)
    new_units: list = field(default_factory=list)
    new_failed: set = field(default_factory=set)  # the new units that failed (--update-baseline leaves them out)
    per_unit: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    latency_mode: str = "none"  # ab | file (information only, never a regression) | none
    errors_against: str = "none"  # ref | baseline | none
    ab: dict = field(default_factory=dict)
    project: str = ""  # with --against: the repository REF is found in, and why that one
    sides: list = field(default_factory=list)  # with REF: what each side runs (repository, commit, package versions)
    # identity -> what this commit's baseline update declared and the gate accepted (an error change, a slowdown),
    # each also a note; the JUnit file gives them as the unit's system-out
    declared: dict = field(default_factory=dict)

    @property
    def held_by_floor(self) -> list:
        """The units whose A/B ratio says slower while their step grew by less than the floor."""
        return sorted(k for k, v in self.ab.items() if v.held_by_floor)

    @property
    def ok(self) -> bool:
        return not self.regressions

    @property
    def declared_slowdowns(self) -> list:
        """The units whose A/B was judged against a slowdown declared in this commit (``latency_change``)."""
        return sorted(k for k, v in self.ab.items() if v.expected != 1.0)

    def declare(self, key, text: str) -> None:
        """Note a change this commit declared for unit ``key`` (in the notes and in ``declared``)."""
        self.notes.append(f"{' '.join(key)}: {text}")
        self.declared.setdefault(key, []).append(text)

    def add(self, key, finding: Finding | None = None) -> None:
        """Record that unit ``key`` was checked, with ``finding`` when it regressed."""
        self.per_unit.setdefault(key, [])
        if finding is not None:
            self.per_unit[key].append(finding)
            self.regressions.append(finding)


def _fmt(v) -> str:
    return "missing" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"
