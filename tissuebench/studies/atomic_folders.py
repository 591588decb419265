"""Atomic writes and provenance for result folders.

A run writes into a temporary sibling folder and renames it into place at the end, so
an interrupted or failed run never leaves a half-written result folder behind; what a
SIGKILL leaves (the hidden temporary folder) is removed by the next run into the same
place. Output locations are checked before any work (:func:`check_output_location`). An
output folder that is a symbolic link is written through (the folder it points to is replaced,
the link stays), as every file the tool writes is (:mod:`.atomic_files`).
"""
from __future__ import annotations

import contextlib
import datetime as _dt
import hashlib
import json
import os
import platform
import re
import shutil
import tempfile
import time
from pathlib import Path

from ..reference.provenance import code_hash, git_commit, package_versions
from .atomic_files import kind_of, new_folder, replacing, stat_output


def check_output_location(out: Path, overwrite: bool = False) -> None:
    """Refuse, before any work, an output folder that cannot be written: a NUL byte in the
    path, a path that is a file or lies under one, an unwritable parent, or an existing folder
    without ``overwrite`` (FileExistsError). Other problems are ValueError naming ``out``."""
    text = str(out)
    if "\0" in text:
        raise ValueError(f"--out = {text!r}: contains a NUL byte")
    out = Path(out)
    st = stat_output(out, "--out =")  # a loop of links, a name too long ...: OutputPathError
    exists, is_dir = st is not None, out.is_dir()
    if exists and not is_dir:
        raise ValueError(f"--out = {out}: exists and is not a folder ({kind_of(st.st_mode)})")
    if exists and not overwrite:
        raise FileExistsError(f"output folder {out} exists; pass overwrite (--force) to replace it")
    parent = next((p for p in out.absolute().parents if p.exists()), None)
    if parent is None or not parent.is_dir():
        raise ValueError(f"--out = {out}: {parent} is not a folder")
    if not _writable(parent):
        raise ValueError(f"--out = {out}: {parent} is not writable")


def _writable(folder: Path) -> bool:
    try:
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def _leftover_pattern(name: str):
    # .NAME.tmp-PID-xxxx (a run writing), .NAME.old-PID (the folder it replaces), and the
    # .NAME.xxxxxxxx of earlier versions (mkdtemp's 8 random characters, no owner recorded)
    return re.compile(rf"\.{re.escape(name)}\.(?:(?P<kind>tmp|old)-(?P<pid>\d+)(?:-.*)?|[a-z0-9_]{{8}})")


def clean_leftovers(out: Path, min_age_s: float = 3600.0) -> list:
    """Remove what killed runs into ``out`` left beside it: temporary folders of processes
    that no longer run (and, older than ``min_age_s``, those of earlier versions). When ``out``
    itself is missing because a run was killed between its two renames, the previous result
    (``.NAME.old-PID``) is put back. Returns the paths removed."""
    out = Path(out)
    try:
        entries = sorted(out.parent.iterdir()) if out.parent.is_dir() else []
    except (OSError, ValueError):  # unreadable, a NUL byte: check_output_location says why
        return []
    pattern, removed = _leftover_pattern(out.name), []
    for p in entries:
        m = pattern.fullmatch(p.name)
        if m is None or not p.is_dir():
            continue
        if m["pid"] is not None and int(m["pid"]) != os.getpid() and process_alive(int(m["pid"])):
            continue  # a run in progress
        if m["pid"] is None and time.time() - p.stat().st_mtime < min_age_s:
            continue
        if m["kind"] == "old" and not out.exists():
            p.rename(out)  # killed between the renames: the previous result comes back
            continue
        shutil.rmtree(p, ignore_errors=True)
        removed.append(p)
    return removed


def process_alive(pid) -> bool:
    """Whether process ``pid`` (of this host) runs: one of another user counts (signal 0 is
    refused with PermissionError), a pid that is not a positive number does not (0 and negative
    pids would signal process groups and always look alive)."""
    if isinstance(pid, bool):
        return False
    try:
        pid = int(pid)
        if pid <= 0:
            return False
        os.kill(pid, 0)
    except (TypeError, ValueError, OverflowError, ProcessLookupError):
        return False
    except OSError:  # PermissionError: it exists, owned by someone else
        return True
    return True


@contextlib.contextmanager
def atomic_directory(out: Path, overwrite: bool = False):
    """Yield a temporary folder that replaces ``out`` only if the block succeeds.

    The temporary folder ``.NAME.tmp-PID-xxxx`` is removed when the block raises (Ctrl-C
    included); a SIGKILL cannot be caught, so the next run into ``out`` removes it
    (:func:`clean_leftovers`, by its dead PID)."""
    out = Path(out)
    if stat_output(out, "--out =") is not None and not overwrite:
        raise FileExistsError(f"output folder {out} exists; pass overwrite (--force) to replace it")
    if out.is_symlink():  # written through: the folder it points to is replaced, the link stays
        out = Path(os.path.realpath(out))
    out.parent.mkdir(parents=True, exist_ok=True)
    clean_leftovers(out)
    tmp = new_folder(out.parent, f".{out.name}.tmp-{os.getpid()}-", like=out)  # the umask's mode, or out's
    try:
        yield tmp
        if out.exists():
            old = out.with_name(f".{out.name}.old-{os.getpid()}")
            shutil.rmtree(old, ignore_errors=True)
            out.rename(old)
            tmp.rename(out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_json_atomic(path: Path, data) -> None:
    """Write ``data`` as JSON to ``path`` through a temporary file renamed into place
    (removed when the write fails: a full disk leaves nothing behind; :func:`.atomic_files.replacing`)."""
    with replacing(path) as tmp, open(tmp, "w") as fh:
        json.dump(data, fh, indent=2, default=str)


def provenance(**extra) -> dict:
    """Package versions, git commit, source hash, machine and date (UTC)."""
    return {"versions": package_versions(), "git_commit": git_commit(), "code_hash": code_hash(),
            "machine": {"node": platform.node(), "platform": platform.platform(), "python": platform.python_version(),
                        "cpus": os.cpu_count()},
            "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"), **extra}


def hash_json(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()
