"""``OUT/fit.json``: what a fit decided so far, written atomically after every decision.

A fit killed at any moment (Ctrl-C, SIGTERM, a power cut) is resumed by the same command: the
reference runs it had solved are in the reference cache, the units a round had measured are
in that round's results store (``OUT/rounds/round-K``, resumed by the sweep's own
``--resume``), and everything the fit decided from them (each family's lead options, the runs it
added, its learning curve, the rounds and their state) is in this manifest, replaced atomically
(:func:`~tissuebench.studies.atomic_folders.write_json_atomic`: a reader sees the old file or the
new one, never half of one). A round is ``"running"`` from the moment its spec is written until
its units are measured and the decisions they lead to are recorded (``"done"``): a round found
running is run again with the sweep's resume (its finished units kept) and decided again from
the same rows.

The manifest records the fit's settings (:data:`SETTINGS`); resuming with other settings is
refused, naming the first that differs (the budgets may change: a fit stopped by its budget
goes on with a larger one).
"""
from __future__ import annotations

import json
from pathlib import Path

from ..atomic_folders import provenance, write_json_atomic

__all__ = ["MANIFEST", "SETTINGS", "FORMAT", "new_manifest", "read_manifest", "write_manifest", "check_settings"]

MANIFEST = "fit.json"
FORMAT = 1
#: what makes a fit the same fit (the budgets aside)
SETTINGS = ("scene", "variant", "resolution", "backend", "require", "methods")


def new_manifest(settings: dict) -> dict:
    """A fresh manifest of a fit with ``settings`` (:data:`SETTINGS` and the budgets)."""
    return {"format": FORMAT, "kind": "tissuebench fit", "settings": dict(settings), "state": "running",
            "elapsed_s": 0.0, "families": {}, "rounds": [], "answer": None, "dense": None,
            "provenance": provenance()}


def read_manifest(out) -> dict | None:
    """The manifest of ``out`` (None when there is none); ValueError naming the file when it is
    not a fit's manifest."""
    path = Path(out) / MANIFEST
    if not path.exists():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: not a readable fit manifest ({exc})") from None
    if not isinstance(data, dict) or data.get("kind") != "tissuebench fit" or data.get("format") != FORMAT:
        raise ValueError(f"{path}: not the manifest of a tissuebench fit (format {FORMAT}); choose another --out")
    for key in ("settings", "families", "rounds"):
        if key not in data:
            raise ValueError(f"{path}: the manifest lacks {key!r}; choose another --out")
    for name, st in data["families"].items() if isinstance(data["families"], dict) else ():
        _check_growth(path, name, (st or {}).get("next") if isinstance(st, dict) else None)
    return data


def _check_growth(path, family, step) -> None:
    """A pending growth's alternatives, which the next round runs: a list of ``{"options": {...},
    "option": name, "value": number}`` (ValueError naming the family and the entry otherwise)."""
    alternatives = step.get("alternatives") if isinstance(step, dict) else None
    if alternatives is None:
        return
    ok = isinstance(alternatives, list) and alternatives and all(
        isinstance(a, dict) and isinstance(a.get("options"), dict) and isinstance(a.get("option"), str)
        and isinstance(a.get("value"), (int, float)) and not isinstance(a.get("value"), bool) for a in alternatives)
    if not ok:
        raise ValueError(f"{path}: families.{family}.next.alternatives = {alternatives!r}: expected a list of "
                         "{options: {...}, option: name, value: number}; the manifest is damaged, choose another --out")


def check_settings(manifest: dict, settings: dict, out) -> None:
    """Refuse to resume a fit of other settings (:data:`SETTINGS`), naming the first that differs."""
    for key in SETTINGS:
        old, new = manifest["settings"].get(key), settings.get(key)
        if old != new:
            raise ValueError(f"--out = {out}: holds a fit with {key} = {old!r}, not {new!r}; resume it with the same "
                             f"settings, or choose another --out")


def write_manifest(out, manifest: dict) -> None:
    """Replace ``out/fit.json`` atomically."""
    write_json_atomic(Path(out) / MANIFEST, manifest)
