"""Why ``sweep --resume`` recomputes a stored unit: what changed between its stored row and now.

A unit whose stored result has another key than the one planned now is recomputed (its key
hashes the code, the scene, the versions, the protocol: :func:`~.units.unit_key`). The stored
row records most of what the key hashed (``code_hash``, ``scene_hash``, the package versions,
and for a method from another package its distribution, version and code hash), so the sweep
can say which of them changed: ``plugin myrom 0.1.0 changed (code hash a1b2c3d4 -> c3d4e5f6)``.
"""
from __future__ import annotations

import pyarrow.parquet as pq

from ..reference.provenance import code_hash, package_versions
from ..rom.plugins import third_party
from .training import case_scene

__all__ = ["why_stale", "stored_provenance"]

_COLUMNS = ("code_hash", "scene_hash", "tissuebench", "numpy", "scipy", "method_source", "method_distribution",
            "method_version", "method_code_hash")


def stored_provenance(path) -> dict:
    """The provenance columns of the unit row file ``path`` ({} when it cannot be read)."""
    try:
        table = pq.read_table(path)
    except Exception:  # noqa: BLE001 - a damaged row: the reason stays generic
        return {}
    return {c: table.column(c)[0].as_py() for c in _COLUMNS if c in table.column_names}


def _short(h) -> str:
    return str(h)[:8] if h else "none"


def why_stale(old: dict, unit) -> str:
    """What changed between a stored row's provenance ``old`` and ``unit`` as planned now."""
    reasons = []
    try:
        plugin = third_party(unit.source or unit.method)
    except (ValueError, TypeError):
        plugin = {}
    if plugin or old.get("method_code_hash"):
        name = plugin.get("distribution") or old.get("method_distribution") or unit.method
        was, now = old.get("method_version") or None, plugin.get("version")
        changes = [f"version {was} -> {now}"] if was != now else []
        if (old.get("method_code_hash") or None) != plugin.get("code_hash"):
            changes.append(f"code hash {_short(old.get('method_code_hash'))} -> {_short(plugin.get('code_hash'))}")
        if changes:
            reasons.append(f"plugin {name} changed ({', '.join(changes)})")
    if old.get("code_hash") and old["code_hash"] != code_hash():
        reasons.append(f"tissuebench's code changed (code hash {_short(old['code_hash'])} -> {_short(code_hash())})")
    versions = package_versions()
    reasons += [f"{pkg} {old[pkg]} -> {versions.get(pkg)}" for pkg in ("tissuebench", "numpy", "scipy")
                if old.get(pkg) and old[pkg] != versions.get(pkg)]
    if old.get("scene_hash"):
        try:
            now = case_scene(unit.case).content_hash()
        except Exception:  # noqa: BLE001 - the unit's own run meets the error and stores it
            now = None
        if now != old["scene_hash"]:
            reasons.append(f"the scene changed (content hash {_short(old['scene_hash'])} -> {_short(now)})")
    return "; ".join(reasons) or "its protocol, case entry or another package's version changed"
