"""The gate's baseline file (TOML, committed with the project), read and written like user input.

::

    [defaults]                      # tolerances; each may be overridden in a [[unit]]
    error_rtol = 1e-3               # errors are deterministic up to BLAS round-off
    error_atol = 1e-9
    latency_tolerance = 1.3         # the slowdown the A/B must catch (--against REF)
    latency_floor_s = 1e-5          # A/B: the least step increase [s] that counts (1 % of 1 kHz)
    file_latency_tolerance = 1.3    # file mode (no REF): information only, never gated
    latency_floor = 0.0             # file mode: calibrations a baseline ratio is raised to first

    [[unit]]
    case = "cornea_pinch"
    method = "anm_pod"
    options = '{"n_modes":4,"order":6}'  # JSON; compared parsed (key order irrelevant)
    error = 0.0123                  # the sweep's error metric
    latency_per_calibration = 0.012 # haptic median / 256x256 matmul (file mode; in the report)
    latency_per_reference = 0.0004  # haptic median / the reference's step (in the report)
    flagged_steps = 0               # failed + extrapolated + beyond validity + not reached
    latency_change = 2.2            # optional: an intended slowdown, the factor the step grows by
    latency_change_reason = "mean-dilatation hexahedra: assembly ~2x Q1's"  # required with it

Latency is gated by the A/B only (``--against REF``); the file's latency ratios are printed
for information, never a regression (:mod:`tissuebench.gate`). ``latency_change`` (> 1) and its
``latency_change_reason`` (:data:`DECLARATION_KEYS`) declare an intended slowdown of a unit: the
A/B of the commit that adds or edits them expects that factor (:mod:`tissuebench.gate`); the
next commits, the entry unchanged against their REF, ignore them. :data:`DEFAULT_NOTES`
are the comments a new file's ``[defaults]`` is written with: what each key is, its default,
and how to set ``latency_floor_s`` for a microsecond ROM.

Every value is checked (type, range, finite, duplicates) and a bad one raises
:class:`BaselineError` naming the key and the value: ``inf`` and ``nan`` are refused everywhere
(an infinite error or tolerance would make every comparison hold). :func:`update_baseline`
rewrites the units from a results folder with tomlkit (comments, defaults and per-unit
overrides kept) through a temporary file renamed into place: a kill at any moment leaves the
old file or the new one, never a torn one.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import tomlkit

from ..studies.atomic_files import output_file, write_text

__all__ = ["DEFAULTS", "DEFAULT_NOTES", "UNIT_KEYS", "DECLARATION_KEYS", "BaselineError", "load_baseline",
           "unit_identity", "update_baseline"]

DEFAULTS = {"error_rtol": 1e-3, "error_atol": 1e-9, "latency_tolerance": 1.3, "file_latency_tolerance": 1.3,
            "latency_floor": 0.0, "latency_floor_s": 1e-5}
#: the comment of each key of a new baseline's [defaults] (a [[unit]] may override any of them)
DEFAULT_NOTES = {
    "error_rtol": "errors must equal REF's (or this file's) within max(error_rtol * error, error_atol)",
    "error_atol": "the absolute part: errors at round-off level",
    "latency_tolerance": "A/B (--against REF): the slowdown to catch; slower when the ratio's interval is above "
                         "sqrt(latency_tolerance)",
    "latency_floor_s": "A/B: the least step increase [s] that counts as slower (default 1e-5, 1 % of a 1 kHz step); "
                       "a microsecond ROM: 0 (the ratio alone decides) or the least increase that matters, e.g. 1e-6; "
                       "check --latency-floor-s overrides this default",
    "file_latency_tolerance": "no REF (no --against, a shallow clone): latency ratios shown for information only, "
                              "never gated (they move 2-3x between runs of identical code)",
    "latency_floor": "no REF: calibrations a baseline ratio is raised to before the information above",
}
# the tolerance keys of older baselines, still read (ignored: the reference ratio is not gated)
_RETIRED = {"reference_latency_tolerance"}
UNIT_KEYS = {"case": str, "method": str, "options": str, "error": float, "latency_per_calibration": float,
             "latency_per_reference": float, "flagged_steps": int}
#: a unit's optional declaration of an intended slowdown (both or neither): the factor its step is
#: expected to grow by (> 1: a speed-up needs no declaration) and why (printed by the gate)
DECLARATION_KEYS = {"latency_change": float, "latency_change_reason": str}
# (lowest value, whether the lowest is allowed)
_RANGES = {"error_rtol": (0.0, True), "error_atol": (0.0, True), "latency_tolerance": (1.0, False),
           "file_latency_tolerance": (1.0, False),
           "latency_floor": (0.0, True), "latency_floor_s": (0.0, True), "error": (0.0, True),
           "latency_per_calibration": (0.0, True),
           "latency_per_reference": (0.0, True), "flagged_steps": (0, True), "latency_change": (1.0, False)}


class BaselineError(ValueError):
    """A malformed baseline (the message names the key)."""


def unit_identity(case: str, method: str, options: str) -> tuple:
    """``(case, method, canonical options JSON)``: options compared parsed, key order irrelevant."""
    try:
        parsed = json.loads(options)
    except (TypeError, ValueError):
        raise BaselineError(f"options = {options!r}: not JSON") from None
    if not isinstance(parsed, dict):
        raise BaselineError(f"options = {options!r}: expected a JSON object")
    return case, method, json.dumps(parsed, sort_keys=True, separators=(",", ":"))


def _number(path, v, kind):
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not isinstance(v, int)):
        raise BaselineError(f"{path} = {v!r}: expected {'an integer' if kind is int else 'a number'}")
    try:
        as_float = float(v)
    except OverflowError:
        raise BaselineError(f"{path} = {str(v)[:20]}...: a number too large") from None
    if not math.isfinite(as_float):
        # an infinite error or tolerance makes every comparison hold: the gate would pass anything
        raise BaselineError(f"{path} = {v!r}: must be a finite number (a non-finite baseline value or tolerance "
                            "gates nothing)")
    name = path.rsplit(".", 1)[-1]
    if name in _RANGES:
        low, inclusive = _RANGES[name]
        if v < low or (v == low and not inclusive):
            raise BaselineError(f"{path} = {v!r}: must be {'>=' if inclusive else '>'} {low:g}")
    return v


def load_baseline(path) -> tuple[dict, list]:
    """``(tolerance defaults, units)`` of a baseline file; :class:`BaselineError` naming the file
    and the bad key.

    Refused: a missing or unreadable file, TOML errors, unknown keys, wrong types, values out
    of range (negative errors or counts, tolerances <= 1 or negative), non-finite values
    (``inf``, ``nan``), a baseline with no unit, and the same unit (options compared parsed)
    twice."""
    try:
        return _load(Path(path))
    except BaselineError as exc:
        if str(path) in str(exc):
            raise
        raise BaselineError(f"{path}: {exc}") from None


def _load(path: Path) -> tuple[dict, list]:
    if not path.is_file():
        raise BaselineError(f"baseline {path} does not exist or is not a file (create it with --update-baseline)")
    try:
        doc = tomlkit.parse(path.read_text()).unwrap()
    except (OSError, UnicodeDecodeError) as exc:
        raise BaselineError(f"baseline {path}: cannot be read: {exc}") from None
    except Exception as exc:  # tomlkit raises its own ParseError subclasses
        raise BaselineError(f"{path}: not valid TOML: {exc}") from None
    for key in doc:
        if key not in ("defaults", "unit"):
            raise BaselineError(f"{key}: unknown top-level key in {path} (valid: ['defaults', 'unit'])")
    defaults = dict(DEFAULTS)
    if not isinstance(doc.get("defaults", {}), dict):
        raise BaselineError(f"defaults: expected a table in {path}")
    for k, v in doc.get("defaults", {}).items():
        if k in _RETIRED:
            continue
        if k not in DEFAULTS:
            raise BaselineError(f"defaults.{k}: unknown key (valid: {sorted(DEFAULTS)})")
        defaults[k] = _number(f"defaults.{k}", v, float)
    units = doc.get("unit", [])
    if not isinstance(units, list) or not all(isinstance(u, dict) for u in units):
        raise BaselineError("unit: expected an array of tables ([[unit]])")
    if not units:
        raise BaselineError(f"unit: {path} has no [[unit]]: a gate that compares nothing passes vacuously "
                            f"(write one with --update-baseline)")
    seen = {}
    for i, u in enumerate(units):
        _check_unit(i, u)
        ident = unit_identity(u["case"], u["method"], u["options"])
        if ident in seen:
            raise BaselineError(f"unit[{i}]: the same unit as unit[{seen[ident]}] ({' '.join(ident)})")
        seen[ident] = i
        u["_identity"] = ident
    return defaults, units


def _check_unit(i, u):
    for k, kind in UNIT_KEYS.items():
        if k not in u:
            raise BaselineError(f"unit[{i}].{k}: missing required key")
        if kind is str and not isinstance(u[k], str):
            raise BaselineError(f"unit[{i}].{k} = {u[k]!r}: expected a string")
        if kind is not str:
            _number(f"unit[{i}].{k}", u[k], kind)
    for k in u:
        if k not in UNIT_KEYS and k not in DEFAULTS and k not in DECLARATION_KEYS and k not in _RETIRED:
            raise BaselineError(f"unit[{i}].{k}: unknown key (valid: "
                                f"{sorted(UNIT_KEYS) + sorted(DEFAULTS) + sorted(DECLARATION_KEYS)})")
        if k in DEFAULTS:
            _number(f"unit[{i}].{k}", u[k], float)
    try:
        unit_identity(u["case"], u["method"], u["options"])
    except BaselineError as exc:
        raise BaselineError(f"unit[{i}].{exc}") from None
    _check_declaration(i, u)


def _check_declaration(i, u):
    """``latency_change`` (a finite number > 1) and ``latency_change_reason`` (a non-empty string),
    both or neither; the message names the key, the unit and the value."""
    if not any(k in u for k in DECLARATION_KEYS):
        return
    unit = f"unit[{i}] ({u['case']} {u['method']} {u['options']})"
    if "latency_change" not in u:
        raise BaselineError(f"{unit}.latency_change_reason = {u['latency_change_reason']!r}: needs latency_change, "
                            "the factor the step is expected to grow by (e.g. latency_change = 2.2)")
    try:
        _number(f"{unit}.latency_change", u["latency_change"], float)
    except BaselineError as exc:
        # > 1: the A/B expects the step that much slower; a speed-up or no change needs no declaration
        raise BaselineError(f"{exc} (the factor the step is expected to grow by; a speed-up needs no "
                            "declaration)") from None
    reason = u.get("latency_change_reason")
    if reason is None:
        raise BaselineError(f"{unit}.latency_change_reason: missing, required with latency_change = "
                            f"{u['latency_change']!r} (why the step is slower on purpose: the gate prints it)")
    if not isinstance(reason, str) or not reason.strip():
        raise BaselineError(f"{unit}.latency_change_reason = {reason!r}: expected a non-empty string (why the step "
                            "is slower on purpose: the gate prints it)")


def update_baseline(rows: dict, baseline) -> int:
    """Rewrite the units of ``baseline`` from ``rows`` (``{identity: {"case", "method",
    "options", "error", "latency_per_calibration", "latency_per_reference", "flagged_steps"}}``,
    the ok units of a results folder), keeping comments, defaults and per-unit overrides of
    the units still there. Atomic (module docstring). Returns the unit count."""
    if not rows:
        raise BaselineError(f"--update-baseline: the results have no unit that finished ok; {baseline} is left "
                            "as it was (a baseline of failed units would gate nothing)")
    path = Path(baseline)
    if path.exists() and not path.is_file():
        raise BaselineError(f"baseline {path}: not a file")
    output_file(path, "--baseline")  # a loop of links, an unwritable folder: before reading
    try:
        doc = tomlkit.parse(path.read_text()) if path.is_file() else tomlkit.document()
    except Exception as exc:
        raise BaselineError(f"{path}: not valid TOML, not overwritten: {exc}") from None
    if "defaults" not in doc:
        doc["defaults"] = tomlkit.table()
        for k, v in DEFAULTS.items():
            item = tomlkit.item(v)
            item.comment(DEFAULT_NOTES[k])
            doc["defaults"][k] = item
    old = {}
    for t in doc.get("unit", []):
        try:
            old[unit_identity(t["case"], t["method"], t["options"])] = t
        except (KeyError, BaselineError):
            continue  # a damaged old entry is replaced, not kept
    units = tomlkit.aot()
    for ident in sorted(rows):
        t = old.get(ident) or tomlkit.table()
        for k, v in rows[ident].items():
            t[k] = v
        units.append(t)
    doc["unit"] = units
    _atomic_write(path, tomlkit.dumps(doc))
    return len(units)


def _atomic_write(path: Path, text: str) -> None:
    """Through a temporary file (:func:`~tissuebench.studies.atomic_files.write_text`: a link is
    written through, a device or FIFO refused, the file's mode kept)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_text(path, text, "--baseline")
    except OSError as exc:
        raise BaselineError(f"baseline {path}: cannot be written: {exc.strerror or exc}") from None
