"""The results store of a sweep: one Parquet dataset, written atomically per unit.

Layout of a results folder ``DIR``::

    DIR/case=<id>/method=<name>/<key>.parquet          one row per unit (UNIT_COLUMNS)
    DIR/_points/case=<id>/method=<name>/<key>.parquet  one row per evaluation point
    DIR/_outputs/case=<id>/method=<name>/<key>.parquet one row per (point, monitored output)
    DIR/_latency/case=<id>/method=<name>/<key>.parquet one row per timed haptic step
    DIR/_derived/                                      pareto.parquet, radius.parquet, PNG plots
    DIR/_sweep.json                                    the spec, its hash, provenance, unit keys
    DIR/.lock                                          held while a sweep writes (pid, host)

``pandas.read_parquet(DIR)`` reads the unit rows (folders and files starting with ``_`` or
``.`` are not part of the dataset). A unit's points, outputs and latency samples are written first, its row
last: each file goes to a temporary name and is renamed into place, so the row file is
the unit's completion marker; a killed sweep leaves at most temporary files, removed at
the next start. A row file that cannot be read back (truncated by a disk fault) does not
count as finished.

Everything read back is validated like user input: :func:`read_units` and the side-table
readers read only files at their place in the layout whose columns and types are the
schema's (a foreign or damaged Parquet file, or any other file, is named and ignored, or
refused with ``foreign="raise"``: :class:`StoreError`), and :func:`~.sweep_manifest.read_sweep_manifest`
checks ``_sweep.json`` (:class:`~.sweep_manifest.SweepManifestError` names the file and the key).
"""
from __future__ import annotations

import json
import os
import platform
import warnings
from pathlib import Path
from urllib.parse import unquote

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from .schema import LATENCY_COLUMNS, OUTPUT_COLUMNS, POINT_COLUMNS, SAFE_NAME, UNIT_COLUMNS, conform
from .sweep_manifest import MANIFEST, SweepManifestError, read_sweep_manifest
from .atomic_files import replacing
from .atomic_folders import process_alive, write_json_atomic

__all__ = ["ResultsStore", "SweepLocked", "StoreError", "read_units", "read_points", "read_outputs", "read_latency",
           "foreign_files"]

_SIDE_TABLES = ("_points", "_outputs", "_latency")



class SweepLocked(RuntimeError):
    """Another sweep holds the results folder."""


def _safe(name: str, what: str) -> str:
    if not SAFE_NAME.fullmatch(name) or name in (".", ".."):
        raise ValueError(f"{what} = {name!r}: only letters, digits, '_', '.', '-' may name a results partition")
    return name


def _write_table(table, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with replacing(path) as tmp:  # .NAME.xxxxxxxx.tmp: skipped by readers, cleaned at the next start
        pq.write_table(table, tmp)


def write_table(frame: pd.DataFrame, path) -> None:
    """Write a DataFrame as Parquet atomically (a side table of a results folder, e.g.
    ``_anchors.parquet``: names starting with ``_`` are not read as unit rows)."""
    import pyarrow as pa

    _write_table(pa.Table.from_pandas(frame, preserve_index=False), Path(path))


class ResultsStore:
    """A results folder being written by one sweep (see the module docstring)."""

    def __init__(self, root):
        self.root = Path(root)

    # ------------------------------------------------------------- locking
    def acquire(self) -> None:
        """Create ``.lock`` exclusively; SweepLocked names the holder when it exists and its
        process is alive on this host (a stale lock of a dead process is taken over)."""
        self.root.mkdir(parents=True, exist_ok=True)
        lock = self.root / ".lock"
        me = {"pid": os.getpid(), "host": platform.node()}
        for _ in range(2):
            try:
                fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = _read_lock(lock)
                if holder and holder.get("host") == me["host"] and not process_alive(holder.get("pid")):
                    lock.unlink(missing_ok=True)  # stale: its sweep was killed
                    continue
                raise SweepLocked(f"results folder {self.root} is in use by another sweep ({holder or 'unknown'}); "
                                  f"wait for it or remove {lock} if that sweep is gone") from None
            with os.fdopen(fd, "w") as fh:
                json.dump(me, fh)
            return
        raise SweepLocked(f"could not take the lock {lock}")

    def release(self) -> None:
        """Remove the lock; a folder that turned read-only keeps it (said: a later sweep on this
        host takes a lock of a dead process over)."""
        try:
            (self.root / ".lock").unlink(missing_ok=True)
        except OSError as exc:
            warnings.warn(f"could not remove the lock {self.root / '.lock'} ({exc.strerror or exc}); the next sweep "
                          "into this folder takes it over", stacklevel=2)

    def clean_temporaries(self) -> int:
        n = 0
        for p in self.root.rglob(".*.tmp"):
            p.unlink(missing_ok=True)
            n += 1
        return n

    # ------------------------------------------------------------- units
    def _rel(self, case: str, method: str, key: str) -> Path:
        return Path(f"case={_safe(case, 'case id')}") / f"method={_safe(method, 'method')}" / f"{key}.parquet"

    def finished(self) -> dict:
        """``{unit_key: (case, method, options)}`` of the readable unit rows in the folder."""
        out = {}
        for f in self.root.glob("case=*/method=*/*.parquet"):
            try:
                t = pq.read_table(f, columns=["unit_key", "options"])
            except Exception:  # truncated or foreign file: not a finished unit
                continue
            if t.num_rows == 1 and t.column("unit_key")[0].as_py() == f.stem:
                case, method = f.parent.parent.name[5:], f.parent.name[7:]
                out[f.stem] = (case, method, t.column("options")[0].as_py())
        return out

    def write_unit(self, outcome) -> Path:
        """Write a unit's points, outputs, latency samples, then its row (the completion marker)."""
        row = dict(outcome.row)
        case, method, key = row.pop("case"), row.pop("method"), row["unit_key"]
        rel = self._rel(case, method, key)
        _write_table(conform([{**p, "unit_key": key} for p in outcome.points], POINT_COLUMNS),
                     self.root / "_points" / rel)
        _write_table(conform([{**o, "unit_key": key} for o in outcome.outputs], OUTPUT_COLUMNS),
                     self.root / "_outputs" / rel)
        _write_table(conform([{**s, "unit_key": key} for s in outcome.latency], LATENCY_COLUMNS),
                     self.root / "_latency" / rel)
        _write_table(conform([row], UNIT_COLUMNS), self.root / rel)
        return self.root / rel

    def remove_unit(self, case: str, method: str, key: str) -> None:
        rel = self._rel(case, method, key)
        for base in (self.root, *(self.root / t for t in _SIDE_TABLES)):
            (base / rel).unlink(missing_ok=True)

    def write_manifest(self, data: dict) -> None:
        write_json_atomic(self.root / MANIFEST, data)


def _read_lock(lock: Path) -> dict | None:
    try:
        return json.loads(lock.read_text())
    except (OSError, ValueError):
        return None


class StoreError(ValueError):
    """A file of a results folder that is not what the store wrote there (the message names it)."""


_DATASETS = {"": UNIT_COLUMNS, "_points": POINT_COLUMNS, "_outputs": OUTPUT_COLUMNS, "_latency": LATENCY_COLUMNS}
# files of a results folder's top level that are not unit rows (written by sweep, verify, report)
_KNOWN_TOP = {"_sweep.json", ".lock", "_anchors.parquet", "_backends.parquet"}


def _scan(root: Path, dataset: str) -> tuple[list, list]:
    """``(files, foreign)`` of one dataset: the Parquet files at their place in the layout
    (``case=<id>/method=<name>/<key>.parquet``) and ``(path, why)`` of every other file in
    the dataset's folders. The units dataset skips the top-level ``_``/``.`` entries (side
    tables, derived tables, reports, the lock and temporaries)."""
    base = root / dataset if dataset else root
    files, foreign = [], []
    if not base.is_dir():
        return files, foreign
    for dirpath, dirnames, filenames in os.walk(base):
        here = Path(dirpath)
        depth = len(here.relative_to(base).parts)
        if depth == 0 and not dataset:
            dirnames[:] = [d for d in dirnames if not d.startswith(("_", "."))]
            filenames = [f for f in filenames if f not in _KNOWN_TOP and not f.startswith(("_", "."))]
        dirnames.sort()
        for name in sorted(filenames):
            path = here / name
            if name.startswith(".") and name.endswith(".tmp"):
                continue  # a unit being written (removed at the next start)
            parts = path.relative_to(base).parts
            if (len(parts) == 3 and parts[0].startswith("case=") and len(parts[0]) > 5
                    and parts[1].startswith("method=") and len(parts[1]) > 7
                    and name.endswith(".parquet") and SAFE_NAME.fullmatch(name[:-8])):
                files.append(path)
            else:
                foreign.append((path, "not at a place of the store's layout case=<id>/method=<name>/<key>.parquet"))
    return files, foreign


def _check_table(path: Path, table: pa.Table, columns: dict, one_row: bool) -> str | None:
    """Why ``table`` (read from ``path``) is not one the store wrote there, or None."""
    extra = [n for n in table.column_names if n not in columns]
    if extra:
        return f"columns not in the store schema: {extra[:5]}"
    if "unit_key" not in table.column_names:
        return "no unit_key column"
    wrong = [n for n in table.column_names if table.schema.field(n).type != columns[n]]
    if wrong:
        n = wrong[0]
        return f"column {n!r} is {table.schema.field(n).type}, the schema says {columns[n]}"
    if one_row and table.num_rows != 1:
        return f"{table.num_rows} rows (a unit row file holds one)"
    keys = set(table.column("unit_key").to_pylist())
    if keys - {path.stem}:
        return f"its unit_key {sorted(keys - {path.stem}, key=str)[0]!r} is not its file name's"
    return None


def _listed_units(root: Path) -> dict:
    """``{unit key: (case, method)}`` as the folder's valid ``_sweep.json`` lists them ({} if none)."""
    try:
        units = read_sweep_manifest(root, missing_ok=True).get("units", [])
    except SweepManifestError:
        return {}
    return {u["key"]: (u["case"], u["method"]) for u in units}


def _single_copies(found: list, root: Path, stray: list) -> list:
    """``found`` (path, case, method, table) without the copies of a unit key stored in several
    partitions: the copy ``_sweep.json`` lists is kept, the others (all, when it decides none)
    are named as foreign."""
    by_key: dict = {}
    for item in found:
        by_key.setdefault(item[0].stem, []).append(item)
    if all(len(v) == 1 for v in by_key.values()):
        return found
    listed = _listed_units(root)
    keep = []
    for key, items in by_key.items():
        if len(items) == 1:
            keep += items
            continue
        genuine = [it for it in items if listed.get(key) == (it[1], it[2])][:1]
        keep += genuine
        for it in items:
            if it not in genuine:
                others = ", ".join(str(o[0]) for o in items if o is not it)
                stray.append((it[0], f"unit {key} is stored more than once (also {others}); _sweep.json lists "
                                     + (f"the one in case={genuine[0][1]}/method={genuine[0][2]}" if genuine
                                        else "none of them")))
    return sorted(keep, key=lambda it: str(it[0]))


def _read_dataset(root: Path, dataset: str, foreign, as_frame: bool = True) -> pd.DataFrame | None:
    files, stray = _scan(root, dataset)
    columns = _DATASETS[dataset]
    found = []
    for path in files:
        try:
            table = pq.read_table(path)
        except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for a damaged file
            stray.append((path, f"not a readable Parquet file ({type(exc).__name__})"))
            continue
        why = _check_table(path, table, columns, one_row=not dataset)
        if why is not None:
            stray.append((path, why))
            continue
        # partition values as pyarrow's hive partitioning reads them (URI-decoded)
        found.append((path, unquote(path.parent.parent.name[5:]), unquote(path.parent.name[7:]), table))
    kept = _single_copies(found, root, stray)
    _report_foreign(stray, foreign)
    if not as_frame:
        return None
    tables = []
    for _, case, method, table in kept:
        n = table.num_rows
        table = table.append_column("case", pa.array([case] * n, pa.string()))
        tables.append(table.append_column("method", pa.array([method] * n, pa.string())))
    if not tables:
        return pd.DataFrame()
    df = pa.concat_tables(tables, promote_options="default").to_pandas()
    for c in ("case", "method"):
        df[c] = df[c].astype(str)
    return df


def _report_foreign(stray: list, foreign) -> None:
    if not stray:
        return
    if isinstance(foreign, list):
        foreign.extend(stray)
        return
    if foreign == "raise":
        path, why = stray[0]
        more = f" (and {len(stray) - 1} more)" if len(stray) > 1 else ""
        raise StoreError(f"{path}: not a file of this results store: {why}{more}; move it out of the folder")
    if foreign == "warn":
        for path, why in stray[:5]:
            warnings.warn(f"{path}: not a file of this results store ({why}): ignored", stacklevel=3)
        if len(stray) > 5:
            warnings.warn(f"{len(stray) - 5} more files that are not part of the store were ignored", stacklevel=3)


def foreign_files(root) -> list:
    """``(path, why)`` of every file in a results folder's datasets that the readers ignore."""
    out: list = []
    for dataset in _DATASETS:
        _read_dataset(Path(root), dataset, out, as_frame=False)
    return out


def read_units(root, foreign="warn") -> pd.DataFrame:
    """All unit rows of a results folder (``case`` and ``method`` as plain strings); a file that
    is not a unit row of the store is ignored with a warning naming it (``foreign="warn"``),
    silently (``"ignore"``), refused (``"raise"``: :class:`StoreError`), or ignored and its
    ``(path, why)`` appended to ``foreign`` when that is a list."""
    return _read_dataset(Path(root), "", foreign)


def read_points(root, foreign="warn") -> pd.DataFrame:
    return _read_dataset(Path(root), "_points", foreign)


def read_outputs(root, foreign="warn") -> pd.DataFrame:
    return _read_dataset(Path(root), "_outputs", foreign)


def read_latency(root, foreign="warn") -> pd.DataFrame:
    """The timed haptic steps of every unit (``LATENCY_COLUMNS``; empty for a folder written
    before they were stored)."""
    return _read_dataset(Path(root), "_latency", foreign)
