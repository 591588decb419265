"""The scratch folder of ``tissuebench check --against REF`` and the processes run in it, cleaned
up even when the check is killed (SIGKILL cannot be caught: nothing runs at its end).

* **Children die with the check.** Every child the gate starts (REF's import check, REF's sweep,
  the A/B's worker processes) is started with :func:`child_options`: on Linux the kernel sends
  it SIGKILL when the check dies (``prctl(PR_SET_PDEATHSIG)``, set between fork and exec), so a
  killed check leaves no REF sweep running on. The signal follows the *thread* that started
  the child: the gate starts and waits for its children in one thread. Elsewhere (macOS,
  Windows) the children of a killed check run to their end.
* **A killed check's folder is removed by the next.** The scratch folder
  (``$TMPDIR/tissuebench-ref.XXXXXXXX``: REF's exported code, its sweep's store, the A/B's jobs;
  a few MB) records its owner in ``owner.json`` (pid, the process's start time, host). Each
  check first removes the folders whose owner no longer runs: its pid gone, or taken by another
  process (another start time). A folder of a live check, of another user or another host, or
  without a readable ``owner.json`` (one being created, or one of a version before this) is
  left alone.
"""
from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import json
import os
import platform
import shutil
import signal
import sys
import tempfile
from pathlib import Path

from ..studies.atomic_folders import process_alive

__all__ = ["PREFIX", "OWNER_FILE", "child_options", "ref_scratch", "clean_stale_scratch", "process_start"]

PREFIX = "tissuebench-ref."
OWNER_FILE = "owner.json"
_PR_SET_PDEATHSIG = 1  # linux/prctl.h


def _prctl():
    """libc's ``prctl`` (Linux), loaded in this process: the child only calls it."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True).prctl
    except (OSError, AttributeError):
        return None


def child_options() -> dict:
    """Keyword arguments of :class:`subprocess.Popen` (and ``subprocess.run``) for a child that
    is killed when this process dies (module docstring); ``{}`` where the platform cannot."""
    prctl = _prctl()
    if prctl is None:
        return {}
    parent = os.getpid()

    def die_with_parent():
        prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        if os.getppid() != parent:  # the parent died before prctl: no signal will come
            os._exit(1)

    return {"preexec_fn": die_with_parent}


def _stat(pid: int) -> list | None:
    """The fields of Linux ``/proc/PID/stat`` from field 3 (state) on; None where it cannot be read."""
    try:
        stat = Path(f"/proc/{int(pid)}/stat").read_text()
        return stat[stat.rindex(")") + 2:].split()  # after the command name, which may hold spaces
    except (OSError, ValueError, OverflowError):
        return None


def process_start(pid: int) -> str | None:
    """When process ``pid`` started (clock ticks since boot, ``/proc/PID/stat`` field 22), None
    where it cannot be read (no /proc, no such process)."""
    fields = _stat(pid)
    return fields[19] if fields and len(fields) > 19 else None


def _owner_runs(owner: dict) -> bool:
    """Whether the check that wrote ``owner`` (``owner.json``) still runs: its pid alive, not a
    zombie, and started when the owner says (else the pid was reused)."""
    pid, start = owner["pid"], owner.get("start")
    if not process_alive(pid):
        return False
    fields = _stat(pid)
    if fields is None:  # no /proc: the pid is all there is to go by
        return True
    return fields[0] not in ("Z", "X") and (start is None or len(fields) <= 19 or fields[19] == start)


def _read_owner(folder: Path) -> dict | None:
    """The folder's ``owner.json`` when it is one this module wrote, else None."""
    try:
        owner = json.loads((folder / OWNER_FILE).read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(owner, dict) or isinstance(owner.get("pid"), bool) or not isinstance(owner.get("pid"), int) \
            or not isinstance(owner.get("host"), str) or not isinstance(owner.get("start"), (str, type(None))):
        return None
    return owner


def clean_stale_scratch(base=None) -> list[Path]:
    """Remove the scratch folders under ``base`` (default: the temporary folder) whose owner no
    longer runs (module docstring); returns the folders removed."""
    base = Path(base or tempfile.gettempdir())
    removed = []
    try:
        candidates = sorted(base.glob(f"{PREFIX}*"))
    except OSError:
        return removed
    for folder in candidates:
        try:
            if folder.is_symlink() or not folder.is_dir() or folder.stat().st_uid != os.getuid():
                continue
        except OSError:
            continue
        owner = _read_owner(folder)
        if owner is None or owner["host"] != platform.node() or _owner_runs(owner):
            continue
        shutil.rmtree(folder, ignore_errors=True)
        if not folder.exists():
            removed.append(folder)
    return removed


@contextlib.contextmanager
def ref_scratch(log=None, base=None):
    """A fresh scratch folder under ``base`` (default: the temporary folder) owned by this process
    (``owner.json``), removed at the end of the block; the stale folders of killed checks are
    removed first (said through ``log``)."""
    stale = clean_stale_scratch(base)
    if stale and log is not None:
        log(f"removed {len(stale)} scratch folders of checks that were killed: {', '.join(p.name for p in stale)}")
    folder = Path(tempfile.mkdtemp(prefix=PREFIX, dir=base))
    try:
        owner = {"pid": os.getpid(), "start": process_start(os.getpid()), "host": platform.node()}
        tmp = folder / f".{OWNER_FILE}.tmp"
        tmp.write_text(json.dumps(owner))
        tmp.replace(folder / OWNER_FILE)  # whole or absent: a half-written owner would leave the folder
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)
