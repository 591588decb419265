"""The regression gate: ``tissuebench check RESULTS_DIR --baseline FILE``.

The baseline (TOML, committed with the project) holds per unit (case, method, options) the
error of the sweep's error metric and two latency *ratios* measured in the same process
as the unit: the haptic median over the calibration kernel (a 256x256 matmul) and over the
reference's own step. Absolute times are never compared, so the gate holds on another
machine of the same kind. A unit regresses when

* it is missing from the results, or failed;
* its error exceeds ``max(error * (1 + error_rtol), error + error_atol)``;
* a latency ratio exceeds its baseline times ``latency_tolerance`` (calibration) or
  ``reference_latency_tolerance`` (reference step), the baseline being first raised to
  ``latency_floor`` calibrations (the reference ratio by the same factor): a step of a few
  microseconds is dominated by the interpreter and the cache state, whose median moves 2x
  between processes on one machine (anm_pod's 7.5 us baseline ran at 9-12 us in a local CI
  run and 16.6 us on the CI machine), so below the floor only a step slower than
  ``latency_floor * latency_tolerance`` calibrations (about 0.13 ms here) is a regression;
* it has more flagged steps (failed, extrapolation, beyond validity, not reached) than the
  baseline had.

Tolerances come from ``[defaults]`` and may be overridden per unit. ``--update-baseline``
rewrites the units from the results with tomlkit, keeping the file's comments, defaults and
per-unit overrides; ``--junit`` writes one JUnit test case per unit.
"""
from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import tomlkit

from ..studies.results import read_units

__all__ = ["DEFAULTS", "Finding", "CheckResult", "load_baseline", "check", "update_baseline", "write_junit"]

DEFAULTS = {"error_rtol": 0.25, "error_atol": 1e-9, "latency_tolerance": 1.8, "reference_latency_tolerance": 3.0,
            "latency_floor": 0.1}
_UNIT_KEYS = {"case": str, "method": str, "options": str, "error": float, "latency_per_calibration": float,
              "latency_per_reference": float, "flagged_steps": int}
_FLAGGED = ("n_failed", "n_extrapolation", "n_beyond_validity", "n_not_reached")


class BaselineError(ValueError):
    """A malformed baseline (the message names the key)."""


@dataclass
class Finding:
    case: str
    method: str
    options: str
    metric: str
    baseline: float
    now: float
    tolerance: str

    def line(self) -> str:
        return (f"{self.case:24s} {self.method:14s} {self.metric:26s} baseline {_fmt(self.baseline):>11s} "
                f"now {_fmt(self.now):>11s}  ({self.tolerance})  {self.options}")


@dataclass
class CheckResult:
    checked: int
    regressions: list = field(default_factory=list)
    new_units: list = field(default_factory=list)
    per_unit: dict = field(default_factory=dict)  # (case, method, options) -> [Finding]

    @property
    def ok(self) -> bool:
        return not self.regressions


def _fmt(v) -> str:
    return "missing" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.4g}"


def _number(path, v, kind):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not isinstance(v, int)):
        raise BaselineError(f"{path} = {v!r}: expected {'an integer' if kind is int else 'a number'}")
    if kind is float and not (math.isfinite(v) or v == math.inf):
        raise BaselineError(f"{path} = {v!r}: expected a number")
    return v


def load_baseline(path) -> tuple[dict, list]:
    """``(tolerance defaults, units)`` of a baseline file; BaselineError naming a bad key."""
    path = Path(path)
    if not path.is_file():
        raise BaselineError(f"baseline {path} does not exist (create it with --update-baseline)")
    try:
        doc = tomlkit.parse(path.read_text()).unwrap()
    except Exception as exc:  # tomlkit raises its own ParseError subclasses
        raise BaselineError(f"{path}: not valid TOML: {exc}") from None
    for key in doc:
        if key not in ("defaults", "unit"):
            raise BaselineError(f"{key}: unknown top-level key in {path} (valid: ['defaults', 'unit'])")
    defaults = dict(DEFAULTS)
    for k, v in doc.get("defaults", {}).items():
        if k not in DEFAULTS:
            raise BaselineError(f"defaults.{k}: unknown key (valid: {sorted(DEFAULTS)})")
        defaults[k] = _number(f"defaults.{k}", v, float)
    units = doc.get("unit", [])
    if not isinstance(units, list):
        raise BaselineError("unit: expected an array of tables ([[unit]])")
    for i, u in enumerate(units):
        for k, kind in _UNIT_KEYS.items():
            if k not in u:
                raise BaselineError(f"unit[{i}].{k}: missing required key")
            if kind is str and not isinstance(u[k], str):
                raise BaselineError(f"unit[{i}].{k} = {u[k]!r}: expected a string")
            if kind is not str:
                _number(f"unit[{i}].{k}", u[k], kind)
        for k in u:
            if k not in _UNIT_KEYS and k not in DEFAULTS:
                raise BaselineError(f"unit[{i}].{k}: unknown key (valid: {sorted(_UNIT_KEYS) + sorted(DEFAULTS)})")
    return defaults, units


def _now(row) -> dict:
    ratio_ref = row["haptic_median_s"] / row["reference_step_s"] if row["reference_step_s"] > 0 else math.nan
    return {"error": float(row["error"]), "latency_per_calibration": float(row["haptic_per_calibration"]),
            "latency_per_reference": float(ratio_ref), "flagged_steps": int(sum(int(row[c]) for c in _FLAGGED)),
            "failed": row["unit_status"] != "ok", "message": row["message"]}


def _results(results_dir) -> dict:
    units = read_units(results_dir)
    if units.empty:
        raise ValueError(f"{results_dir}: no sweep results (no case=*/method=*/*.parquet)")
    metric = json.loads((Path(results_dir) / "_sweep.json").read_text()).get("error_metric", "max_rel_l2") \
        if (Path(results_dir) / "_sweep.json").is_file() else "max_rel_l2"
    units["error"] = units[metric]
    return {(r["case"], r["method"], r["options"]): r for _, r in units.iterrows()}


def check(results_dir, baseline) -> CheckResult:
    """Compare a results folder with a baseline file (module docstring)."""
    defaults, units = load_baseline(baseline)
    results = _results(results_dir)
    out = CheckResult(checked=len(units))
    for u in units:
        key = (u["case"], u["method"], u["options"])
        tol = {k: u.get(k, defaults[k]) for k in DEFAULTS}
        found = []
        row = results.get(key)
        if row is None:
            found.append(Finding(*key, "unit", 1.0, math.nan, "missing from the results"))
        else:
            now = _now(row)
            if now["failed"]:
                found.append(Finding(*key, "unit_status", 1.0, math.nan, f"failed: {now['message'][:120]}"))
            limit = max(u["error"] * (1 + tol["error_rtol"]), u["error"] + tol["error_atol"])
            if not now["error"] <= limit:
                found.append(Finding(*key, "error", u["error"], now["error"],
                                     f"<= {limit:.4g}: +{tol['error_rtol']:.0%} or +{tol['error_atol']:g}"))
            found += _latency_findings(key, u, now, tol)
            if now["flagged_steps"] > u["flagged_steps"]:
                found.append(Finding(*key, "flagged_steps", u["flagged_steps"], now["flagged_steps"],
                                     "failed/extrapolated/beyond-validity steps may not grow"))
        out.per_unit[key] = found
        out.regressions += found
    out.new_units = sorted(k for k in results if k not in out.per_unit)
    return out


def _latency_findings(key, u, now, tol) -> list:
    """Latency regressions of one unit (module docstring: ratios, tolerances and the floor)."""
    raise_by = max(1.0, tol["latency_floor"] / u["latency_per_calibration"]) \
        if u["latency_per_calibration"] > 0 else 1.0
    found = []
    for metric, name in (("latency_per_calibration", "latency_tolerance"),
                         ("latency_per_reference", "reference_latency_tolerance")):
        limit = u[metric] * raise_by * tol[name]
        if not now[metric] <= limit:
            floor = f", floor {tol['latency_floor']:g} calibrations" if raise_by > 1 else ""
            found.append(Finding(*key, metric, u[metric], now[metric], f"<= {limit:.4g}: x{tol[name]:g}{floor}"))
    return found


def update_baseline(results_dir, baseline) -> int:
    """Rewrite the units of ``baseline`` from the results (comments, defaults and per-unit
    tolerance overrides kept; units no longer in the results dropped). Returns the unit count."""
    path = Path(baseline)
    doc = tomlkit.parse(path.read_text()) if path.is_file() else tomlkit.document()
    if "defaults" not in doc:
        doc["defaults"] = tomlkit.table()
        for k, v in DEFAULTS.items():
            doc["defaults"][k] = v
    old = {(t["case"], t["method"], t["options"]): t for t in doc.get("unit", [])}
    units = tomlkit.aot()
    for key, row in sorted(_results(results_dir).items()):
        if row["unit_status"] != "ok":
            continue
        t = old.get(key) or tomlkit.table()
        now = _now(row)
        t["case"], t["method"], t["options"] = key
        for k in ("error", "latency_per_calibration", "latency_per_reference", "flagged_steps"):
            t[k] = now[k]
        units.append(t)
    doc["unit"] = units
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(tomlkit.dumps(doc))
    return len(units)


def write_junit(result: CheckResult, path) -> None:
    """One test case per baseline unit (a failure per regression) and one per new unit (passed)."""
    suite = ET.Element("testsuite", name="tissuebench.check", tests=str(len(result.per_unit)),
                       failures=str(sum(1 for f in result.per_unit.values() if f)))
    for (case, method, options), found in result.per_unit.items():
        tc = ET.SubElement(suite, "testcase", classname=f"{case}.{method}", name=options)
        for f in found:
            ET.SubElement(tc, "failure", message=f"{f.metric} regressed", type="regression").text = f.line()
    for case, method, options in result.new_units:
        ET.SubElement(suite, "testcase", classname=f"{case}.{method}", name=options).append(
            ET.Element("system-out"))
    ET.ElementTree(suite).write(path, encoding="utf-8", xml_declaration=True)
