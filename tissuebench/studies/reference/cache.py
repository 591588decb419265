"""The on-disk cache of reference runs, keyed by content (``tissuebench cache ls|clear``).

A reference run is computed once and reused by every sweep unit and every later sweep. Its
key is the SHA-256 of everything that changes it: the scene's content
(:meth:`~tissuebench.cases.scene.Scene.content`, with ``mu`` and the mesh files' hashes),
the backend, the solver settings, the package versions and the source hash of the code
that computes it (``refsolvers``, ``cases``, ``studies/reference``).

An entry is a folder ``<cache>/references/<key>/`` holding ``fields.npz`` (steps, points,
cells, displacement, velocity), ``table.parquet`` (one row per load increment or time step)
and ``meta.json`` (its key, status, message, plan, info, the SHA-256 and size of both data
files, and the SHA-256 of the meta itself). It is written into a temporary sibling and
renamed into place, so a killed run leaves no entry. An entry is read only when everything
checks: the meta's own checksum (an edited ``status`` is a miss), the key it records equals
the folder's name, its address (an entry moved or swapped into another key's folder is a
miss), the data files' sizes and checksums, the arrays' names, types and shapes; anything
else is reported (a warning saying why) and recomputed, never read. Arrays are loaded with
``allow_pickle=False``. ``cache ls`` and ``cache clear`` touch only the folders with a valid
meta: any other file or folder in ``references/`` is not an entry, and is left alone and named
(:func:`stray_items`).

The cache folder is ``$TISSUEBENCH_CACHE`` when set, else ``$XDG_CACHE_HOME/tissuebench``
(``~/.cache/tissuebench``).
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import time
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from ...cases.schema import is_num
from ..store import code_hash, package_versions
from .plan import ModelPlan
from .result import ReferenceResult
from .runner import solve

__all__ = ["CACHE_ENV", "cache_dir", "reference_key", "cached_solve", "cached_table", "list_entries", "clear",
           "stray_items", "entry_problem"]

CACHE_ENV = "TISSUEBENCH_CACHE"
_FILES = ("fields.npz", "table.parquet")
_PACKAGES = ("numpy", "scipy", "ngsolve", "scikit-fem", "pyamg")
_KEY = re.compile(r"[0-9a-f]{64}")
_TEMPORARY = re.compile(r"\.[0-9a-f]{16}\..+")  # a writer's temporary folder (mkdtemp beside the entry)
_MAX_META_BYTES = 16 << 20
_STATUSES = ("success", "stalled", "failed", "newton_failed", "blow_up", "energy_growth")
_ARRAYS = {"steps": 1, "points": 2, "cells": 2, "displacement": 3, "velocity": 3}


def cache_dir() -> Path:
    """The cache folder (see the module docstring); created on first write."""
    env = os.environ.get(CACHE_ENV, "").strip()
    if env:
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or Path.home() / ".cache"
    return Path(base) / "tissuebench"


def reference_key(scene, backend: str = "skfem", linear_solver: str = "auto") -> str:
    """SHA-256 identifying the reference run of ``scene`` (module docstring)."""
    versions = package_versions()
    content = {"scene": scene.content(), "backend": backend if scene.is_fe else "line",
               "solver": {"linear_solver": linear_solver},
               "versions": {k: versions.get(k) for k in _PACKAGES},
               "code": code_hash("refsolvers", "cases", "studies/reference")}
    return hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode()).hexdigest()


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _write(entry: Path, result: ReferenceResult, scene, key: str) -> None:
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{key[:16]}.", dir=entry.parent))
    try:
        arrays = dict(steps=result.steps, points=result.points, cells=result.cells,
                      displacement=result.displacement)
        if result.velocity is not None:
            arrays["velocity"] = result.velocity
        np.savez(tmp / "fields.npz", **arrays)
        result.table.to_parquet(tmp / "table.parquet", index=False)
        meta = {"key": key, "case": result.case, "variant": result.variant, "resolution": result.resolution,
                "backend": result.backend, "mu": scene.mu, "status": result.status, "message": result.message,
                "wall_s": result.wall_s, "cell_type": result.cell_type, "components": list(result.components),
                "plan": {k: getattr(result.plan, k) for k in ("analysis", "model", "linear", "mass", "tangent",
                                                              "algorithm", "reasons")},
                "info": result.info, "files": {f: {"sha256": _sha256(tmp / f), "bytes": (tmp / f).stat().st_size}
                                               for f in _FILES}}
        meta = json.loads(json.dumps(meta, default=str))  # as it reads back
        meta["meta_sha256"] = _meta_checksum(meta)
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
        os.chmod(tmp, 0o755)
        try:
            tmp.rename(entry)
        except OSError:  # another process stored the same key first: keep theirs
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _meta_checksum(meta: dict) -> str:
    body = {k: v for k, v in meta.items() if k != "meta_sha256"}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


def _finite_number(v) -> bool:
    return is_num(v)  # not a bool, finite, no integer beyond the float range (math.isfinite would overflow)


def _check_meta(entry: Path) -> tuple[dict | None, str]:
    """``(meta, "")`` when ``meta.json`` of ``entry`` is one the cache wrote for this address,
    else ``(None, why)``."""
    path = entry / "meta.json"
    try:
        if path.stat().st_size > _MAX_META_BYTES:
            return None, "meta.json is too large"
        meta = json.loads(path.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        return None, "no meta.json"
    except (OSError, ValueError, RecursionError) as exc:
        return None, f"meta.json unreadable ({type(exc).__name__})"
    if not isinstance(meta, dict):
        return None, "meta.json is not a JSON object"
    if meta.get("meta_sha256") != _meta_checksum(meta):
        return None, "meta.json does not match its checksum (edited or damaged)"
    if meta.get("key") != entry.name:
        return None, f"meta.json records the key {str(meta.get('key'))[:16]}, not its folder's (moved or swapped)"
    files = meta.get("files")
    if not isinstance(files, dict) or any(
            not isinstance(files.get(f), dict) or not isinstance(files[f].get("sha256"), str)
            or not isinstance(files[f].get("bytes"), int) for f in _FILES):
        return None, "meta.json lacks the data files' checksums"
    if meta.get("status") not in _STATUSES or not isinstance(meta.get("message"), str):
        return None, f"meta.json status {str(meta.get('status'))[:40]!r} is not a reference status"
    plan = meta.get("plan")
    if not isinstance(plan, dict) or not isinstance(plan.get("reasons"), list) or not all(
            isinstance(r, list) for r in plan["reasons"]):
        return None, "meta.json plan is malformed"
    for k in ("case", "resolution", "backend", "cell_type"):
        if not isinstance(meta.get(k), str):
            return None, f"meta.json {k} is not a string"
    if not isinstance(meta.get("components"), list) or not isinstance(meta.get("info"), dict) \
            or not _finite_number(meta.get("wall_s")):
        return None, "meta.json components, info or wall_s malformed"
    return meta, ""


def _check_files(entry: Path, meta: dict) -> str:
    """Why a data file of ``entry`` does not match the size and checksum ``meta`` records ("" if all do)."""
    for f in _FILES:
        rec, path = meta["files"][f], entry / f
        try:
            if not path.is_file() or path.stat().st_size != rec["bytes"] or _sha256(path) != rec["sha256"]:
                return f"{f} does not match its recorded size and checksum"
        except OSError as exc:
            return f"{f} unreadable ({exc.strerror or exc})"
    return ""


def entry_problem(entry: Path) -> str:
    """Why ``entry`` (a folder of the cache) is not a valid entry ("" when it is)."""
    meta, why = _check_meta(Path(entry))
    return why or _check_files(Path(entry), meta)


def _valid(entry: Path) -> dict | None:
    """The entry's meta when it and every data file check (module docstring), else None."""
    meta, why = _check_meta(entry)
    return meta if meta is not None and not _check_files(entry, meta) else None


def _arrays(entry: Path, meta: dict) -> dict:
    """The arrays of ``fields.npz``, their names, types and shapes checked (ValueError)."""
    with np.load(entry / "fields.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    for name, ndim in _ARRAYS.items():
        a = arrays.get(name)
        if a is None:
            if name == "velocity":
                continue
            raise ValueError(f"fields.npz has no {name!r}")
        if a.ndim != ndim or a.dtype.kind not in ("f", "i", "u"):
            raise ValueError(f"fields.npz {name!r} has shape {a.shape} and type {a.dtype}")
    n_states, (n_nodes, n_comp) = len(arrays["steps"]), arrays["points"].shape
    if arrays["displacement"].shape != (n_states, n_nodes, len(meta["components"])) or n_comp not in (1, 2, 3):
        raise ValueError(f"fields.npz displacement {arrays['displacement'].shape} does not match steps, points and "
                         "components")
    if "velocity" in arrays and arrays["velocity"].shape != arrays["displacement"].shape:
        raise ValueError("fields.npz velocity and displacement differ in shape")
    cells = arrays["cells"]
    if cells.dtype.kind not in ("i", "u") or (cells.size and (cells.min() < 0 or cells.max() >= n_nodes)):
        raise ValueError("fields.npz cells index outside the points")
    if not all(np.isfinite(arrays[k]).all() for k in ("steps", "points")):
        raise ValueError("fields.npz steps or points not finite")
    return arrays


def _read(entry: Path, meta: dict, scene) -> ReferenceResult:
    arrays = _arrays(entry, meta)
    plan = ModelPlan(**{**meta["plan"], "reasons": [tuple(r) for r in meta["plan"]["reasons"]]})
    return ReferenceResult(case=meta["case"], variant=meta.get("variant"), resolution=meta["resolution"],
                           backend=meta["backend"], plan=plan, status=meta["status"], message=meta["message"],
                           table=pd.read_parquet(entry / "table.parquet"), points=arrays["points"],
                           cells=arrays["cells"], cell_type=meta["cell_type"], components=tuple(meta["components"]),
                           steps=arrays["steps"], displacement=arrays["displacement"],
                           velocity=arrays.get("velocity"), wall_s=meta["wall_s"], info=meta["info"],
                           problem=scene.to_problem() if scene.is_fe else None)


def _remove(entry: Path) -> None:
    if entry.is_dir() and not entry.is_symlink():
        shutil.rmtree(entry, ignore_errors=True)
    else:
        entry.unlink(missing_ok=True)


def cached_solve(scene, backend: str = "skfem", linear_solver: str = "auto", progress=None,
                 cache: Path | None = None) -> tuple[ReferenceResult, bool]:
    """``(reference result, hit)``: read from the cache when a valid entry exists, else solved
    (:func:`~.runner.solve`) and stored. An entry that does not check (module docstring) is
    replaced, with a warning saying why."""
    key = reference_key(scene, backend, linear_solver)
    entry = Path(cache or cache_dir()) / "references" / key
    if entry.exists() or entry.is_symlink():
        meta, why = _check_meta(entry) if entry.is_dir() else (None, "not a folder")
        why = why or _check_files(entry, meta)
        if not why:
            try:
                return _read(entry, meta, scene), True
            except Exception as exc:  # noqa: BLE001 - whatever a damaged entry makes numpy/pandas raise
                why = f"its data do not read back ({type(exc).__name__}: {exc})"
        warnings.warn(f"reference cache entry {entry} is corrupted ({why}): recomputed", stacklevel=2)
        _remove(entry)
    result = solve(scene, backend=backend, progress=progress, linear_solver=linear_solver)
    _write(entry, result, scene, key)
    return result, False


def cached_table(scene, backend: str = "skfem", linear_solver: str = "auto", cache: Path | None = None):
    """The table of the cached reference run of ``scene`` (None when not cached or not valid);
    nothing is solved."""
    entry = Path(cache or cache_dir()) / "references" / reference_key(scene, backend, linear_solver)
    if not entry.is_dir() or _valid(entry) is None:
        return None
    try:
        return pd.read_parquet(entry / "table.parquet")
    except Exception:  # noqa: BLE001
        return None


def _items(cache: Path | None):
    root = Path(cache or cache_dir()) / "references"
    try:
        return sorted(root.iterdir()) if root.is_dir() else []
    except OSError:
        return []


def _is_entry(item: Path) -> bool:
    """A folder named by a key whose meta checks (its data files may be damaged)."""
    return bool(_KEY.fullmatch(item.name)) and item.is_dir() and not item.is_symlink() \
        and _check_meta(item)[0] is not None


def stray_items(cache: Path | None = None) -> list:
    """What lies in ``references/`` and is not an entry with a valid meta (nor a writer's
    temporary folder): left alone by :func:`list_entries` and :func:`clear`."""
    return [p for p in _items(cache) if not _TEMPORARY.fullmatch(p.name) and not _is_entry(p)]


def list_entries(cache: Path | None = None) -> pd.DataFrame:
    """One row per cache entry with a valid meta: key, case, variant, resolution, backend, mu,
    status, size, valid (its data files match their checksums)."""
    rows = []
    for entry in _items(cache):
        if _TEMPORARY.fullmatch(entry.name) or not _is_entry(entry):
            continue
        meta, _ = _check_meta(entry)
        size = sum(f.stat().st_size for f in entry.iterdir() if f.is_file() and not f.is_symlink())
        row = {"key": entry.name[:16], "valid": not _check_files(entry, meta), "bytes": size}
        row.update({k: meta.get(k) for k in ("case", "variant", "resolution", "backend", "status")},
                   mu=json.dumps(meta.get("mu") or {}), wall_s=meta.get("wall_s"))
        rows.append(row)
    return pd.DataFrame(rows, columns=["key", "case", "variant", "resolution", "backend", "mu", "status",
                                       "wall_s", "bytes", "valid"])


def clear(cache: Path | None = None, min_age_s: float = 3600.0) -> int:
    """Remove every entry with a valid meta (and writers' temporary folders older than
    ``min_age_s``: their run was killed); returns how many entries went. Anything else in
    ``references/`` is left alone (:func:`stray_items`)."""
    n = 0
    for item in _items(cache):
        if _TEMPORARY.fullmatch(item.name) and item.is_dir() and not item.is_symlink():
            if time.time() - item.stat().st_mtime > min_age_s:
                shutil.rmtree(item, ignore_errors=True)
        elif _is_entry(item):
            shutil.rmtree(item, ignore_errors=True)
            n += 1
    return n
