"""The on-disk cache of reference runs, keyed by content (``tissuebench cache ls|clear``).

A reference run is computed once and reused by every sweep unit and every later sweep. Its
key is the SHA-256 of everything that changes it: the scene's content
(:meth:`~tissuebench.cases.scene.Scene.content`, with ``mu`` and the mesh files' hashes),
the backend, the solver settings, the package versions and the source hash of the code
that computes it (``refsolvers``, ``cases``, ``studies/reference``).

An entry is a folder ``<cache>/references/<key>/`` holding ``fields.npz`` (steps, points,
cells, displacement, velocity), ``table.parquet`` (one row per load increment or time step)
and ``meta.json`` (status, message, plan, info, and the SHA-256 and size of both data
files). It is written into a temporary sibling and renamed into place, so a killed run
leaves no entry; an entry whose files do not match their recorded checksums is reported
and recomputed, never read. Arrays are loaded with ``allow_pickle=False``.

The cache folder is ``$TISSUEBENCH_CACHE`` when set, else ``$XDG_CACHE_HOME/tissuebench``
(``~/.cache/tissuebench``).
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from ..store import code_hash, package_versions
from .plan import ModelPlan
from .result import ReferenceResult
from .runner import solve

__all__ = ["CACHE_ENV", "cache_dir", "reference_key", "cached_solve", "list_entries", "clear"]

CACHE_ENV = "TISSUEBENCH_CACHE"
_FILES = ("fields.npz", "table.parquet")
_PACKAGES = ("numpy", "scipy", "ngsolve", "scikit-fem", "pyamg")


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
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1, default=str))
        os.chmod(tmp, 0o755)
        try:
            tmp.rename(entry)
        except OSError:  # another process stored the same key first: keep theirs
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _valid(entry: Path) -> dict | None:
    """The entry's meta when every data file matches its recorded size and checksum, else None."""
    try:
        meta = json.loads((entry / "meta.json").read_text())
        for f in _FILES:
            rec, path = meta["files"][f], entry / f
            if path.stat().st_size != rec["bytes"] or _sha256(path) != rec["sha256"]:
                return None
        return meta
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _read(entry: Path, meta: dict, scene) -> ReferenceResult:
    with np.load(entry / "fields.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    plan = ModelPlan(**{**meta["plan"], "reasons": [tuple(r) for r in meta["plan"]["reasons"]]})
    return ReferenceResult(case=meta["case"], variant=meta["variant"], resolution=meta["resolution"],
                           backend=meta["backend"], plan=plan, status=meta["status"], message=meta["message"],
                           table=pd.read_parquet(entry / "table.parquet"), points=arrays["points"],
                           cells=arrays["cells"], cell_type=meta["cell_type"], components=tuple(meta["components"]),
                           steps=arrays["steps"], displacement=arrays["displacement"],
                           velocity=arrays.get("velocity"), wall_s=meta["wall_s"], info=meta["info"],
                           problem=scene.to_problem() if scene.is_fe else None)


def cached_solve(scene, backend: str = "skfem", linear_solver: str = "auto", progress=None,
                 cache: Path | None = None) -> tuple[ReferenceResult, bool]:
    """``(reference result, hit)``: read from the cache when a valid entry exists, else solved
    (:func:`~.runner.solve`) and stored. A corrupted entry is replaced, with a warning."""
    key = reference_key(scene, backend, linear_solver)
    entry = Path(cache or cache_dir()) / "references" / key
    if entry.is_dir():
        meta = _valid(entry)
        if meta is not None:
            return _read(entry, meta, scene), True
        warnings.warn(f"reference cache entry {entry} is corrupted (checksum or size mismatch): recomputed",
                      stacklevel=2)
        shutil.rmtree(entry, ignore_errors=True)
    result = solve(scene, backend=backend, progress=progress, linear_solver=linear_solver)
    _write(entry, result, scene, key)
    return result, False


def list_entries(cache: Path | None = None) -> pd.DataFrame:
    """One row per cache entry: key, case, variant, resolution, backend, mu, status, size, valid."""
    root = Path(cache or cache_dir()) / "references"
    rows = []
    for entry in sorted(root.iterdir()) if root.is_dir() else []:
        if entry.name.startswith("."):
            continue
        meta = _valid(entry)
        size = sum(f.stat().st_size for f in entry.iterdir() if f.is_file())
        row = {"key": entry.name[:16], "valid": meta is not None, "bytes": size}
        if meta is not None:
            row.update({k: meta.get(k) for k in ("case", "variant", "resolution", "backend", "status")},
                       mu=json.dumps(meta.get("mu") or {}), wall_s=meta.get("wall_s"))
        rows.append(row)
    return pd.DataFrame(rows, columns=["key", "case", "variant", "resolution", "backend", "mu", "status",
                                       "wall_s", "bytes", "valid"])


def clear(cache: Path | None = None) -> int:
    """Remove every entry (and leftover temporary folders); returns how many entries went."""
    root = Path(cache or cache_dir()) / "references"
    if not root.is_dir():
        return 0
    n = sum(1 for e in root.iterdir() if not e.name.startswith("."))
    shutil.rmtree(root)
    return n
