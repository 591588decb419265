"""``_sweep.json``, the manifest of a results folder (:mod:`.results`): what a sweep writes there
(the spec and its hash, provenance, the case entries, the unit keys, the state, the counters,
the ``--cache`` it was given) and :func:`read_sweep_manifest`, which validates it like user
input: :class:`SweepManifestError` names the file and the key of anything a sweep does not write."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pyarrow as pa

from ..cases.schema import is_num
from ..choices import RESOLUTIONS
from .schema import SAFE_NAME, UNIT_COLUMNS

__all__ = ["MANIFEST", "MANIFEST_STATES", "SweepManifestError", "read_sweep_manifest"]

_KEY = re.compile(r"[0-9a-f]{64}")
MANIFEST = "_sweep.json"
MANIFEST_STATES = ("running", "finished", "failed", "interrupted")
_MAX_MANIFEST_BYTES = 64 << 20


class SweepManifestError(ValueError):
    """A ``_sweep.json`` that is not what a sweep writes (the message names the file and the key)."""


def _is_str(v):
    return isinstance(v, str)


def _is_count(v):
    return isinstance(v, int) and not isinstance(v, bool) and v >= 0


def _is_seconds(v):
    return is_num(v) and v >= 0  # is_num: not a bool, finite, no integer beyond the float range


def _is_hash(v):
    return isinstance(v, str) and _KEY.fullmatch(v) is not None


_MANIFEST_KEYS = {"spec_name": (_is_str, "a string"), "spec_source": (_is_str, "a string"),
                  "spec_hash": (_is_hash, "64 hexadecimal digits"), "spec_text": (_is_str, "a string"),
                  "resolution": (lambda v: v in RESOLUTIONS, f"one of {list(RESOLUTIONS)}"),
                  "executor": (_is_str, "a string"),
                  "state": (lambda v: v in MANIFEST_STATES, f"one of {MANIFEST_STATES}"),
                  "git_commit": (_is_str, "a string"), "code_hash": (_is_str, "a string"),
                  "date": (_is_str, "a string"), "versions": (lambda v: isinstance(v, dict), "a table"),
                  "machine": (lambda v: isinstance(v, dict), "a table"),
                  "computed": (_is_count, "a count"), "skipped": (_is_count, "a count"),
                  "recomputed": (_is_count, "a count"), "failed": (_is_count, "a count"),
                  "cache": (lambda v: isinstance(v, str) and bool(v.strip()) and "\x00" not in v,
                            "a folder path or URL (the sweep's --cache)"),
                  "wall_s": (_is_seconds, "a finite number of seconds >= 0"),
                  "not_applicable": (lambda v: isinstance(v, list) and all(
                      isinstance(e, dict) and all(isinstance(x, str) for x in e.values()) for e in v),
                      "a list of tables of strings {case, method, options, why}")}
_CASE_KEYS = {"id": _is_str, "name": _is_str, "resolution": lambda v: v in RESOLUTIONS, "backend": _is_str,
              "variant": lambda v: v is None or isinstance(v, str), "training": lambda v: isinstance(v, dict),
              "evaluation": lambda v: isinstance(v, dict), "mu": lambda v: isinstance(v, dict),
              "mesh": lambda v: isinstance(v, dict), "paper_points": lambda v: isinstance(v, list),
              "scaling_group": _is_str}
_POINT_KEYS = {"label": _is_str, "step_ms": _is_seconds, "error": _is_seconds}
_UNIT_KEYS = {"key": lambda v: isinstance(v, str) and SAFE_NAME.fullmatch(v) is not None, "case": _is_str,
              "method": _is_str, "label": _is_str}


def _manifest_fail(path, key, value, what):
    shown = repr(value)
    shown = shown if len(shown) <= 80 else shown[:77] + "..."
    raise SweepManifestError(f"{path}: {key} = {shown}: expected {what}")


def _check_entries(path, key, value, schema, required):
    if not isinstance(value, list):
        _manifest_fail(path, key, value, "a list of tables")
    for i, entry in enumerate(value):
        if not isinstance(entry, dict):
            _manifest_fail(path, f"{key}[{i}]", entry, "a table")
        for k in required:
            if k not in entry:
                raise SweepManifestError(f"{path}: {key}[{i}].{k}: missing")
        for k, ok in schema.items():
            if k in entry and not ok(entry[k]):
                _manifest_fail(path, f"{key}[{i}].{k}", entry[k], "another value (the sweep writes it)")
        if key == "cases" and "paper_points" in entry:
            _check_entries(path, f"{key}[{i}].paper_points", entry["paper_points"], _POINT_KEYS, tuple(_POINT_KEYS))


def read_sweep_manifest(results_dir, missing_ok: bool = False) -> dict:
    """The validated ``_sweep.json`` of a results folder.

    Raises :class:`SweepManifestError` (a ValueError) naming the file and the key when it is
    not a JSON object, truncated or invalid JSON, has an ``error_metric`` that is not one of
    the error columns of the store schema (:data:`~.spec.ERROR_METRICS`), or a value of
    another type than the sweep writes. A missing file is an error too, or ``{}`` with
    ``missing_ok``. ``error_metric`` is filled in (``max_rel_l2``) when absent.
    """
    from .spec import ERROR_METRICS

    path = Path(results_dir) / MANIFEST
    try:
        size = path.stat().st_size
        if size > _MAX_MANIFEST_BYTES:
            raise SweepManifestError(f"{path}: {size} bytes; a sweep manifest is at most {_MAX_MANIFEST_BYTES}")
        text = path.read_bytes().decode("utf-8")
    except FileNotFoundError:
        if missing_ok:
            return {}
        raise SweepManifestError(f"{path}: missing (not a folder written by `tissuebench sweep`)") from None
    except UnicodeDecodeError as exc:
        raise SweepManifestError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start})") from None
    except OSError as exc:
        raise SweepManifestError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise SweepManifestError(f"{path}: not valid JSON (truncated or damaged): {exc}") from None
    except RecursionError:
        raise SweepManifestError(f"{path}: not valid JSON (nested too deeply)") from None
    if not isinstance(data, dict):
        raise SweepManifestError(f"{path}: expected a JSON object, found {type(data).__name__}")
    metric = data.setdefault("error_metric", "max_rel_l2")
    if not isinstance(metric, str) or metric not in ERROR_METRICS or UNIT_COLUMNS.get(metric) != pa.float64():
        _manifest_fail(path, "error_metric", metric, f"one of the error columns {list(ERROR_METRICS)}")
    for key, (ok, what) in _MANIFEST_KEYS.items():
        if key in data and not ok(data[key]):
            _manifest_fail(path, key, data[key], what)
    if "cases" in data:
        _check_entries(path, "cases", data["cases"], _CASE_KEYS, ("id",))
    if "units" in data:
        _check_entries(path, "units", data["units"], _UNIT_KEYS, tuple(_UNIT_KEYS))
    return data
