"""Atomic writes and provenance for result folders.

A run writes into a temporary sibling folder and renames it into place at the end, so
an interrupted or failed run never leaves a half-written result folder behind.
"""
from __future__ import annotations

import contextlib
import functools
import datetime as _dt
import hashlib
import importlib.metadata
import json
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

_PACKAGES = ("tissuebench", "numpy", "scipy", "ngsolve", "scikit-fem", "pyamg", "meshio", "pandas",
             "pyarrow", "pyvista", "matplotlib")


@contextlib.contextmanager
def atomic_directory(out: Path, overwrite: bool = False):
    """Yield a temporary folder that replaces ``out`` only if the block succeeds."""
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"output folder {out} exists; pass overwrite (--force) to replace it")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    os.chmod(tmp, 0o755)  # mkdtemp makes it private; a result folder is meant to be shared
    try:
        yield tmp
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if out.exists():
        old = out.with_name(f".{out.name}.old")
        shutil.rmtree(old, ignore_errors=True)
        out.rename(old)
        tmp.rename(out)
        shutil.rmtree(old, ignore_errors=True)
    else:
        tmp.rename(out)


def write_json_atomic(path: Path, data) -> None:
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    with os.fdopen(fd, "w") as fh:
        json.dump(data, fh, indent=2, default=str)
    os.chmod(tmp, 0o644)
    os.replace(tmp, path)


@functools.lru_cache(maxsize=1)
def git_commit() -> str:
    """HEAD of the repository the package lives in ("unknown" outside one)."""
    try:
        root = Path(__file__).resolve().parents[2]
        return subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True,
                              timeout=5).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


@functools.lru_cache(maxsize=1)
def package_versions() -> dict:
    """Installed versions of the packages a result depends on (None when absent)."""
    versions = {}
    for pkg in _PACKAGES:
        try:
            versions[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            versions[pkg] = None
    return versions


@functools.lru_cache(maxsize=8)
def code_hash(*subpackages: str) -> str:
    """SHA-256 over the Python sources (and scene/preset TOMLs) of the named subpackages of
    tissuebench (all of it without arguments): a result computed by other code differs by
    this, committed or not."""
    root = Path(__file__).resolve().parents[1]
    dirs = [root / p for p in subpackages] if subpackages else [root]
    h = hashlib.sha256()
    for d in dirs:
        for f in sorted(d.rglob("*")):
            if f.suffix in (".py", ".toml") and "__pycache__" not in f.parts:
                h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes())
    return h.hexdigest()


def provenance(**extra) -> dict:
    """Package versions, git commit, source hash, machine and date (UTC)."""
    return {"versions": package_versions(), "git_commit": git_commit(), "code_hash": code_hash(),
            "machine": {"node": platform.node(), "platform": platform.platform(), "python": platform.python_version(),
                        "cpus": os.cpu_count()},
            "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"), **extra}


def hash_json(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()
