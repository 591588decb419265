"""Provenance of a computed result: the installed versions it depends on, the git commit and
the source hash of the code that computed it.

Owned by the reference layer because the reference cache keys every entry by them
(:func:`~tissuebench.reference.cache.reference_key`); the sweep's manifests and the result
folders of :mod:`tissuebench.studies.atomic_folders` record them too. Each is computed once
per process.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import subprocess
from pathlib import Path

__all__ = ["git_commit", "package_versions", "code_hash"]

_PACKAGES = ("tissuebench", "numpy", "scipy", "ngsolve", "scikit-fem", "pyamg", "meshio", "pandas",
             "pyarrow", "pyvista", "matplotlib")


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

