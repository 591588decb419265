"""One entry of the reference cache read back like user input (:mod:`.cache`).

An entry is read only when everything checks: the meta's own checksum (an edited ``status``
is a miss), the key it records equals the folder's name (an entry moved or swapped into
another key's folder is a miss), the data files' sizes and SHA-256, then the arrays' names,
types and shapes (loaded with ``allow_pickle=False``). The data files are checked on the bytes
that are then parsed, so a file replaced between the check and the read is never read.
Every function takes the cache's root (:func:`.location.open_cache`): a local folder or an
fsspec file system.
"""
from __future__ import annotations

import hashlib
import json

import numpy as np

from ..cases.schema import is_num
from .location import as_buffer

__all__ = ["FILES", "STATUSES", "EntryUnreadable", "meta_checksum", "check_meta", "read_files", "arrays_of"]

FILES = ("fields.npz", "table.parquet")
STATUSES = ("success", "stalled", "failed", "newton_failed", "blow_up", "energy_growth")
_MAX_META_BYTES = 16 << 20
_ARRAYS = {"steps": 1, "points": 2, "cells": 2, "displacement": 3, "velocity": 3}


def meta_checksum(meta: dict) -> str:
    """SHA-256 of the meta without its own checksum (sorted keys)."""
    body = {k: v for k, v in meta.items() if k != "meta_sha256"}
    return hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()


class EntryUnreadable(OSError):
    """A file of an entry could not be read just now (an I/O error: a timeout or throttling of an
    object store, a permission): not evidence of damage, so never a reason to remove the entry
    that every worker of a cluster shares. A file that is missing, or a folder where a file
    belongs, is damage, not this."""


def check_meta(root, entry) -> tuple[dict | None, str]:
    """``(meta, "")`` when ``meta.json`` of ``entry`` is one the cache wrote for this address,
    else ``(None, why)``; :class:`EntryUnreadable` when it cannot be read now."""
    path = root.child(entry, "meta.json")
    try:
        if root.size(path) > _MAX_META_BYTES:
            return None, "meta.json is too large"
        meta = json.loads(root.read_bytes(path).decode("utf-8"))
    except FileNotFoundError:
        return None, "no meta.json"
    except (IsADirectoryError, NotADirectoryError) as exc:  # the entry's shape is wrong: damage
        return None, f"meta.json unreadable ({type(exc).__name__})"
    except OSError as exc:
        raise EntryUnreadable(f"meta.json: {type(exc).__name__}: {exc}") from exc
    except (ValueError, RecursionError) as exc:
        return None, f"meta.json unreadable ({type(exc).__name__})"
    if not isinstance(meta, dict):
        return None, "meta.json is not a JSON object"
    if meta.get("meta_sha256") != meta_checksum(meta):
        return None, "meta.json does not match its checksum (edited or damaged)"
    if meta.get("key") != root.name(entry):
        return None, f"meta.json records the key {str(meta.get('key'))[:16]}, not its folder's (moved or swapped)"
    files = meta.get("files")
    if not isinstance(files, dict) or any(
            not isinstance(files.get(f), dict) or not isinstance(files[f].get("sha256"), str)
            or not isinstance(files[f].get("bytes"), int) for f in FILES):
        return None, "meta.json lacks the data files' checksums"
    if meta.get("status") not in STATUSES or not isinstance(meta.get("message"), str):
        return None, f"meta.json status {str(meta.get('status'))[:40]!r} is not a reference status"
    plan = meta.get("plan")
    if not isinstance(plan, dict) or not isinstance(plan.get("reasons"), list) or not all(
            isinstance(r, list) for r in plan["reasons"]) \
            or plan.get("formulation", "displacement") not in ("displacement", "anp", "mixed", "mean_dilatation"):
        return None, "meta.json plan is malformed"
    for k in ("case", "resolution", "backend", "cell_type"):
        if not isinstance(meta.get(k), str):
            return None, f"meta.json {k} is not a string"
    # is_num: not a bool, finite, no integer beyond the float range (math.isfinite would overflow)
    if not isinstance(meta.get("components"), list) or not isinstance(meta.get("info"), dict) \
            or not is_num(meta.get("wall_s")):
        return None, "meta.json components, info or wall_s malformed"
    return meta, ""


def read_files(root, entry, meta: dict) -> tuple[dict, str]:
    """``({file: bytes}, "")`` when every data file of ``entry`` has the size and SHA-256 that
    ``meta`` records, else ``({}, why)``; a file larger than recorded is not read;
    :class:`EntryUnreadable` when one cannot be read now."""
    data = {}
    for f in FILES:
        rec, path = meta["files"][f], root.child(entry, f)
        try:
            if not root.is_file(path) or root.size(path) != rec["bytes"]:
                return {}, f"{f} does not match its recorded size and checksum"
            raw = root.read_bytes(path)
        except (FileNotFoundError, IsADirectoryError, NotADirectoryError):
            return {}, f"{f} does not match its recorded size and checksum"
        except OSError as exc:
            raise EntryUnreadable(f"{f}: {type(exc).__name__}: {getattr(exc, 'strerror', None) or exc}") from exc
        if len(raw) != rec["bytes"] or hashlib.sha256(raw).hexdigest() != rec["sha256"]:
            return {}, f"{f} does not match its recorded size and checksum"
        data[f] = raw
    return data, ""


def arrays_of(raw: bytes, meta: dict) -> dict:
    """The arrays of ``fields.npz`` (its checked bytes), their names, types and shapes checked (ValueError)."""
    with np.load(as_buffer(raw), allow_pickle=False) as z:
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
