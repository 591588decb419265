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
"""
from __future__ import annotations

import json
import os
import platform
import re
from pathlib import Path

import pandas as pd
import pyarrow.parquet as pq

from .schema import LATENCY_COLUMNS, OUTPUT_COLUMNS, POINT_COLUMNS, UNIT_COLUMNS, conform
from .store import write_json_atomic

__all__ = ["ResultsStore", "SweepLocked", "read_units", "read_points", "read_outputs", "read_latency"]

_SIDE_TABLES = ("_points", "_outputs", "_latency")

_SAFE = re.compile(r"[A-Za-z0-9_.-]+")


class SweepLocked(RuntimeError):
    """Another sweep holds the results folder."""


def _safe(name: str, what: str) -> str:
    if not _SAFE.fullmatch(name) or name in (".", ".."):
        raise ValueError(f"{what} = {name!r}: only letters, digits, '_', '.', '-' may name a results partition")
    return name


def _write_table(table, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    pq.write_table(table, tmp)
    with open(tmp, "rb") as fh:
        os.fsync(fh.fileno())
    os.replace(tmp, path)


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
                if holder and holder.get("host") == me["host"] and not _alive(holder.get("pid")):
                    lock.unlink(missing_ok=True)  # stale: its sweep was killed
                    continue
                raise SweepLocked(f"results folder {self.root} is in use by another sweep ({holder or 'unknown'}); "
                                  f"wait for it or remove {lock} if that sweep is gone") from None
            with os.fdopen(fd, "w") as fh:
                json.dump(me, fh)
            return
        raise SweepLocked(f"could not take the lock {lock}")

    def release(self) -> None:
        (self.root / ".lock").unlink(missing_ok=True)

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
        write_json_atomic(self.root / "_sweep.json", data)


def _read_lock(lock: Path) -> dict | None:
    try:
        return json.loads(lock.read_text())
    except (OSError, ValueError):
        return None


def _alive(pid) -> bool:
    try:
        os.kill(int(pid), 0)
    except (OSError, TypeError, ValueError):
        return False
    return True


def _read(root: Path) -> pd.DataFrame:
    if not root.is_dir() or not any(root.glob("case=*/method=*/*.parquet")):
        return pd.DataFrame()
    df = pd.read_parquet(root)
    for c in ("case", "method"):
        if c in df:
            df[c] = df[c].astype(str)
    return df


def read_units(root) -> pd.DataFrame:
    """All unit rows of a results folder (``case`` and ``method`` as plain strings)."""
    return _read(Path(root))


def read_points(root) -> pd.DataFrame:
    return _read(Path(root) / "_points")


def read_outputs(root) -> pd.DataFrame:
    return _read(Path(root) / "_outputs")


def read_latency(root) -> pd.DataFrame:
    """The timed haptic steps of every unit (``LATENCY_COLUMNS``; empty for a folder written
    before they were stored)."""
    return _read(Path(root) / "_latency")
