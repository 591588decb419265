"""The cache of reference runs, keyed by content (``tissuebench cache ls|clear``).

A reference run is computed once and reused by every sweep unit and every later sweep. Its
key is the SHA-256 of everything that changes it: the scene's content
(:meth:`~tissuebench.cases.scene.Scene.content`, with ``mu`` and the mesh files' hashes),
the backend, the solver settings, the package versions and the source hash of the code
that computes it (``refsolvers``, ``cases``, ``reference``).

An entry is a folder ``<cache>/references/<key>/`` holding ``fields.npz`` (steps, points,
cells, displacement, velocity), ``table.parquet`` (one row per load increment or time step)
and ``meta.json`` (its key, status, message, plan, info, the SHA-256 and size of both data
files, and the SHA-256 of the meta itself), written last. It is written into a temporary
sibling and moved into place, so a killed run leaves no entry: a rename on a local disk; on
an object store (``--cache s3://...``), where a move is a copy per file and not atomic, the
data files are moved first and the meta last, and the meta is checked on read, so a half-moved
entry is a miss. An entry is read only when everything checks (:mod:`.entry`); anything else
is reported (a warning saying why) and recomputed, never read. ``cache ls`` and ``cache
clear`` touch only the folders with a valid meta: any other item in ``references/`` is not an
entry, and is left alone and named (:func:`stray_items`).

The cache is a local folder or any fsspec file system (:mod:`.location`: ``$TISSUEBENCH_CACHE``
or ``tissuebench sweep --cache URL``). Inside a worker of a dask cluster, a reference is
computed under a cluster-wide lock named by its key, and the cache looked at again once the
lock is held: the units of a sweep never compute one reference twice at the same time, on
one machine or many (the sweep also submits each reference a unit declares as its own task:
:mod:`~tissuebench.studies.executors`).
"""
from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import re
import warnings

import numpy as np
import pandas as pd

from .entry import FILES, EntryUnreadable, arrays_of, check_meta, read_files
from .entry import meta_checksum as _meta_checksum  # the tests reseal entries with it
from .location import CACHE_ENV, as_buffer, cache_url, open_cache
from .formulation import formulation_of
from .plan import ModelPlan
from .provenance import code_hash, package_versions
from .result import ReferenceResult
from .runner import progress_bar, solve

__all__ = ["CACHE_ENV", "cache_url", "reference_key", "cached_solve", "cached_table", "list_entries",
           "clear", "stray_items", "PROGRESS_ENV"]

_PACKAGES = ("numpy", "scipy", "ngsolve", "scikit-fem", "pyamg")
_KEY = re.compile(r"[0-9a-f]{64}")
_TEMPORARY = re.compile(r"\.[0-9a-f]{16}\..+")  # a writer's temporary folder (beside the entry)

#: set to "1" (the sweep does, when it shows progress): a reference computed for a unit shows a bar
PROGRESS_ENV = "TISSUEBENCH_REFERENCE_PROGRESS"


def reference_key(scene, backend: str = "skfem", linear_solver: str = "auto") -> str:
    """SHA-256 identifying the reference run of ``scene`` (module docstring)."""
    versions = package_versions()
    content = {"scene": scene.content(), "backend": backend if scene.is_fe else "line",
               # the formulation the reference chose (:mod:`.formulation`): a scene without an element
               # gets P1 or ANP by its locking indicator, and a run of one is no run of the other
               "formulation": formulation_of(scene).name if scene.is_fe else None,
               "solver": {"linear_solver": linear_solver},
               "versions": {k: versions.get(k) for k in _PACKAGES},
               "code": code_hash("refsolvers", "cases", "reference")}
    return hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode()).hexdigest()


def _write(root, entry, result: ReferenceResult, scene, key: str) -> None:
    tmp = root.temporary(root.references(), f".{key[:16]}.")
    try:
        arrays = dict(steps=result.steps, points=result.points, cells=result.cells,
                      displacement=result.displacement)
        if result.velocity is not None:
            arrays["velocity"] = result.velocity
        fields, table = io.BytesIO(), io.BytesIO()
        np.savez(fields, **arrays)
        result.table.to_parquet(table, index=False)
        data = {"fields.npz": fields.getvalue(), "table.parquet": table.getvalue()}
        for f in FILES:
            root.write_bytes(root.child(tmp, f), data[f])
        meta = {"key": key, "case": result.case, "variant": result.variant, "resolution": result.resolution,
                "backend": result.backend, "mu": scene.mu, "status": result.status, "message": result.message,
                "wall_s": result.wall_s, "cell_type": result.cell_type, "components": list(result.components),
                "plan": {k: getattr(result.plan, k) for k in ("analysis", "model", "linear", "mass", "tangent",
                                                              "algorithm", "reasons", "formulation")},
                "info": result.info, "files": {f: {"sha256": hashlib.sha256(data[f]).hexdigest(),
                                                   "bytes": len(data[f])} for f in FILES}}
        meta = json.loads(json.dumps(meta, default=str))  # as it reads back
        meta["meta_sha256"] = _meta_checksum(meta)
        root.write_bytes(root.child(tmp, "meta.json"), json.dumps(meta, indent=1).encode())
        root.publish(tmp, entry, (*FILES, "meta.json"))
    except BaseException:
        root.remove(tmp)
        raise


def _problem(root, entry) -> tuple[dict | None, dict, str]:
    """``(meta, {file: bytes}, "")`` of a valid entry, else ``(None, {}, why)``."""
    if not root.is_dir(entry):
        return None, {}, "not a folder"
    meta, why = check_meta(root, entry)
    if meta is None:
        return None, {}, why
    data, why = read_files(root, entry, meta)
    return (meta, data, "") if not why else (None, {}, why)


def _read(meta: dict, data: dict, scene) -> ReferenceResult:
    arrays = arrays_of(data["fields.npz"], meta)
    plan = ModelPlan(**{**meta["plan"], "reasons": [tuple(r) for r in meta["plan"]["reasons"]]})
    return ReferenceResult(case=meta["case"], variant=meta.get("variant"), resolution=meta["resolution"],
                           backend=meta["backend"], plan=plan, status=meta["status"], message=meta["message"],
                           table=pd.read_parquet(as_buffer(data["table.parquet"])), points=arrays["points"],
                           cells=arrays["cells"], cell_type=meta["cell_type"], components=tuple(meta["components"]),
                           steps=arrays["steps"], displacement=arrays["displacement"],
                           velocity=arrays.get("velocity"), wall_s=meta["wall_s"], info=meta["info"],
                           problem=scene.to_problem() if scene.is_fe else None)


def _lookup(root, entry, scene) -> ReferenceResult | None:
    """The entry read back when valid; a damaged one is removed with a warning (None)."""
    if not root.exists(entry):
        return None
    try:
        meta, data, why = _problem(root, entry)
    except EntryUnreadable as exc:  # an I/O error, not damage: the shared entry stays
        warnings.warn(f"reference cache entry {root.show(entry)} could not be read just now ({exc}): recomputed, "
                      "the entry left in place", stacklevel=3)
        return None
    if not why:
        try:
            return _read(meta, data, scene)
        except Exception as exc:  # noqa: BLE001 - whatever a damaged entry makes numpy/pandas raise
            why = f"its data do not read back ({type(exc).__name__}: {exc})"
    if not root.atomic_publish and not root.exists(root.child(entry, "meta.json")):
        # a writer may be moving its files in (meta last): removing them would break its entry
        # (measured: a unit of a 2-worker sweep removed the files another was publishing, and the
        # reference was solved a third time); the next publish completes a half-moved entry
        warnings.warn(f"reference cache entry {root.show(entry)} has no meta.json yet (being written, or half-moved "
                      f"by a writer that died): recomputed, the entry left to its writer", stacklevel=3)
        return None
    warnings.warn(f"reference cache entry {root.show(entry)} is corrupted ({why}): recomputed", stacklevel=3)
    root.remove(entry)
    return None


def _cluster_lock(key: str):
    """A lock held by one task of the dask cluster at a time, named by the reference key, when this
    runs inside a dask worker; else nothing to hold (serial and process pools: the atomic write
    keeps one entry). The lock is a lease of a ``distributed.Semaphore``: when the worker holding
    it dies, the scheduler releases it after ``distributed.scheduler.locks.lease-timeout`` (30 s)."""
    try:  # lazy: distributed is imported only where a sweep runs on dask
        from distributed import Lock, get_worker
        get_worker()
    except (ImportError, ValueError):  # ValueError: not inside a worker
        return contextlib.nullcontext()
    return Lock(f"tissuebench-reference-{key}")


def cached_solve(scene, backend: str = "skfem", linear_solver: str = "auto", progress=None,
                 cache=None) -> tuple[ReferenceResult, bool]:
    """``(reference result, hit)``: read from the cache (``cache``: a folder or URL, default
    :func:`cache_url`) when a valid entry exists, else solved (:func:`~.runner.solve`) and
    stored. An entry that does not check (module docstring) is replaced, with a warning saying why."""
    key = reference_key(scene, backend, linear_solver)
    root = open_cache(cache)
    entry = root.child(root.references(), key)
    found = _lookup(root, entry, scene)
    if found is not None:
        return found, True
    with _cluster_lock(key):
        found = _lookup(root, entry, scene)  # computed by the task that held the lock before us
        if found is not None:
            return found, True
        bar = None
        if progress is None and os.environ.get(PROGRESS_ENV, "").strip() == "1":
            bar, progress = _reference_bar(scene, backend)
        try:
            result = solve(scene, backend=backend, progress=progress, linear_solver=linear_solver)
        finally:
            if bar is not None:
                bar.close()
        _write(root, entry, result, scene, key)
    return result, False


def _reference_bar(scene, backend):
    """A bar naming the reference being computed: its case, variant, parameters and backend
    (``reference kidney [load_steps=20] skfem: 45%|... load factor 0.9/2 [00:41<00:50]``)."""
    mu = ", ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in sorted(scene.mu.items()))
    label = f"reference {scene.name}" + (f" [{scene.variant}]" if scene.variant else "") + (f" ({mu})" if mu else "")
    return progress_bar(f"{label} {backend if scene.is_fe else 'line'}", scene.analysis["type"],
                        scene.units.get("time", "s"), leave=False)


def cached_table(scene, backend: str = "skfem", linear_solver: str = "auto", cache=None):
    """The table of the cached reference run of ``scene`` (None when not cached or not valid);
    nothing is solved."""
    root = open_cache(cache)
    meta, data, why = _problem(root, root.child(root.references(), reference_key(scene, backend, linear_solver)))
    if why:
        return None
    try:
        return pd.read_parquet(as_buffer(data["table.parquet"]))
    except Exception:  # noqa: BLE001
        return None


def _items(root) -> list:
    try:
        return root.listdir(root.references())
    except OSError:
        return []


def _is_entry(root, item) -> bool:
    """A folder named by a key whose meta checks (its data files may be damaged)."""
    if not (_KEY.fullmatch(root.name(item)) and root.is_plain_dir(item)):
        return False
    try:
        return check_meta(root, item)[0] is not None
    except EntryUnreadable:  # an entry that cannot be read now is still an entry
        return True


def stray_items(cache=None) -> list:
    """What lies in ``references/`` and is not an entry with a valid meta (nor a writer's
    temporary folder): left alone by :func:`list_entries` and :func:`clear`."""
    root = open_cache(cache)
    return [p for p in _items(root) if not _TEMPORARY.fullmatch(root.name(p)) and not _is_entry(root, p)]


def list_entries(cache=None) -> pd.DataFrame:
    """One row per cache entry with a valid meta: key, case, variant, resolution, backend, mu,
    status, size, valid (its data files match their checksums)."""
    root, rows = open_cache(cache), []
    for entry in _items(root):
        if _TEMPORARY.fullmatch(root.name(entry)) or not _is_entry(root, entry):
            continue
        size = sum(root.size(f) for f in root.files(entry))
        try:
            meta, _ = check_meta(root, entry)
            row = {"key": root.name(entry)[:16], "valid": not read_files(root, entry, meta)[1], "bytes": size}
        except EntryUnreadable:
            meta, row = {}, {"key": root.name(entry)[:16], "valid": False, "bytes": size}
        row.update({k: meta.get(k) for k in ("case", "variant", "resolution", "backend", "status")},
                   mu=json.dumps(meta.get("mu") or {}), wall_s=meta.get("wall_s"))
        rows.append(row)
    return pd.DataFrame(rows, columns=["key", "case", "variant", "resolution", "backend", "mu", "status",
                                       "wall_s", "bytes", "valid"])


def clear(cache=None, min_age_s: float = 3600.0) -> int:
    """Remove every entry with a valid meta (and writers' temporary folders older than
    ``min_age_s``: their run was killed); returns how many entries went. Anything else in
    ``references/`` is left alone (:func:`stray_items`)."""
    root, n = open_cache(cache), 0
    for item in _items(root):
        if _TEMPORARY.fullmatch(root.name(item)) and root.is_plain_dir(item):
            if root.age_s(item) > min_age_s:
                root.remove(item)
        elif _is_entry(root, item):
            root.remove(item)
            n += 1
    return n
