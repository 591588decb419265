"""Where the reference cache lives: a local folder, or a folder on any fsspec file system.

The location is, first to last: the ``cache`` argument of a cache function, the one a sweep
unit runs under (:func:`using_cache`: an executor sets it around each unit, so that a worker
of a cluster uses the location the sweep was given, never its own environment by accident),
``$TISSUEBENCH_CACHE``, else ``$XDG_CACHE_HOME/tissuebench`` (``~/.cache/tissuebench``).

A bare path and a ``file://`` URL are the local file system, handled with :mod:`pathlib` as
always (a folder renamed into place is atomic there). Any other URL (``s3://bucket/cache``,
``gcs://...``, ``memory://...`` in tests) goes through fsspec's file system of that protocol:
its package must be installed (``s3fs`` for ``s3://``). An unknown protocol, one whose
package is missing, or one of a file system the cache cannot be written to and listed on (an
archive such as ``zip://``, ``data://``, ``http(s)://``, ``github://``, ``dask://``: only
:data:`~.cache_protocols.WRITABLE_PROTOCOLS` are accepted, :mod:`.cache_protocols`) is a
ValueError naming the value. A sweep also writes and removes a probe file before any work
(:func:`probe_cache`): a read-only cache is refused then, not after each unit's reference solve.
"""
from __future__ import annotations

import contextlib
import contextvars
import io
import os
import secrets
import shutil
import tempfile
import time
from pathlib import Path

from fsspec.core import split_protocol, url_to_fs

from .cache_protocols import WRITABLE_PROTOCOLS, check_cache_url, one_line

__all__ = ["CACHE_ENV", "WRITABLE_PROTOCOLS", "cache_url", "check_cache_url", "probe_cache", "using_cache",
           "open_cache", "LocalRoot", "RemoteRoot"]

CACHE_ENV = "TISSUEBENCH_CACHE"
_CURRENT: contextvars.ContextVar = contextvars.ContextVar("tissuebench_cache", default=None)


def cache_url(cache=None) -> str:
    """The cache location as a string (path or URL), resolved as the module docstring says."""
    if cache is not None:
        if not str(cache).strip():
            raise ValueError(f"cache = {cache!r}: expected a folder or a URL (an empty value is refused, not read as "
                             "the default location)")
        return str(cache).strip()
    current = _CURRENT.get()
    if current:
        return current
    env = os.environ.get(CACHE_ENV, "").strip()
    if env:
        return env
    base = os.environ.get("XDG_CACHE_HOME", "").strip() or Path.home() / ".cache"
    return str(Path(base) / "tissuebench")


def probe_cache(cache=None, name: str = "--cache") -> str:
    """Check, before any work, that the cache location can be written: a small file written
    into its root (created if missing) and removed. Returns the location (:func:`cache_url`);
    ValueError naming ``name``, the value and the error (a read-only folder, no permission,
    credentials refused), so that no unit fails after its reference solve for a cache it
    cannot store in."""
    url = cache_url(cache)
    root = open_cache(url, name)
    probe = f".tissuebench-probe-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        if isinstance(root, LocalRoot):
            root.root.mkdir(parents=True, exist_ok=True)
        elif root.root:
            root.fs.makedirs(root.root, exist_ok=True)
        path = root.child(root.root, probe)
        root.write_bytes(path, b"tissuebench cache probe\n")
        root.remove(path)
    except Exception as exc:  # noqa: BLE001 - an OSError, or a remote file system's own (credentials)
        why = getattr(exc, "strerror", None) or one_line(exc)
        raise ValueError(f"{name} = {url!r}: the reference cache cannot be written there: {why}") from None
    return url


@contextlib.contextmanager
def using_cache(url):
    """Run the block with the cache at ``url`` (None: leave the location as it is)."""
    if url is None:
        yield
        return
    token = _CURRENT.set(check_cache_url(url))
    try:
        yield
    finally:
        _CURRENT.reset(token)


def open_cache(cache=None, name: str | None = None):
    """The :class:`LocalRoot` or :class:`RemoteRoot` of the cache location: ValueError naming the
    URL (and ``name``, the option or variable it came from) for a bad one, or a file system that
    cannot be opened (no connection, no credentials, a native library missing: ``hdfs://``
    without libhdfs)."""
    url = cache_url(cache)
    name = name or ("cache" if cache is not None else "--cache" if _CURRENT.get() else CACHE_ENV)
    checked = check_cache_url(url, name)
    protocol, rest = split_protocol(checked)
    if protocol in (None, "file", "local"):
        return LocalRoot(Path(rest if protocol else checked).expanduser())
    try:
        fs, root = url_to_fs(checked)
    except Exception as exc:  # noqa: BLE001 - whatever the file system's package raises on opening
        raise ValueError(f"{name} = {checked!r}: the {protocol} file system cannot be opened: "
                         f"{type(exc).__name__}: {one_line(exc)}") from None
    return RemoteRoot(fs, root.rstrip("/"))


class LocalRoot:
    """The cache on the local file system (paths are :class:`~pathlib.Path`)."""

    #: :meth:`publish` renames a finished folder: an entry without its meta was never published whole
    atomic_publish = True

    def __init__(self, root: Path):
        self.root = Path(root)

    def references(self) -> Path:
        return self.root / "references"

    def child(self, parent, name: str) -> Path:
        return Path(parent) / name

    def name(self, p) -> str:
        return Path(p).name

    def show(self, p) -> str:
        return str(p)

    def exists(self, p) -> bool:  # a dangling symlink exists: it is in the way
        return Path(p).exists() or Path(p).is_symlink()

    def is_dir(self, p) -> bool:
        return Path(p).is_dir()

    def is_plain_dir(self, p) -> bool:
        return Path(p).is_dir() and not Path(p).is_symlink()

    def is_file(self, p) -> bool:
        return Path(p).is_file()

    def size(self, p) -> int:
        return Path(p).stat().st_size

    def read_bytes(self, p) -> bytes:
        return Path(p).read_bytes()

    def listdir(self, p) -> list:
        return sorted(Path(p).iterdir()) if Path(p).is_dir() else []

    def files(self, p) -> list:
        return [f for f in Path(p).iterdir() if f.is_file() and not f.is_symlink()]

    def age_s(self, p) -> float:
        return time.time() - Path(p).stat().st_mtime

    def remove(self, p) -> None:
        p = Path(p)
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            p.unlink(missing_ok=True)

    def temporary(self, parent, prefix: str) -> Path:
        Path(parent).mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=prefix, dir=parent))

    def write_bytes(self, p, data: bytes) -> None:
        Path(p).write_bytes(data)

    def publish(self, tmp, entry, order) -> bool:
        """Rename the finished folder ``tmp`` into place (atomic); False when another writer was first."""
        os.chmod(tmp, 0o755)
        try:
            Path(tmp).rename(entry)
            return True
        except OSError:  # another process stored the same key first: keep theirs
            shutil.rmtree(tmp, ignore_errors=True)
            return False


class RemoteRoot:
    """The cache on an fsspec file system (paths are strings without the protocol).

    An object store has no atomic rename of a folder: :meth:`publish` moves the data files first
    and ``meta.json`` last, and a reader checks the meta, then every data file's size and SHA-256
    against it, so a reader that comes while the move is under way sees no entry, or an entry
    whose files do not match (a warning and a recompute), never a mix it would read.
    """

    #: :meth:`publish` moves file by file: an entry without its meta may be a move under way
    atomic_publish = False

    def __init__(self, fs, root: str):
        self.fs, self.root = fs, root

    def references(self) -> str:
        return f"{self.root}/references"

    def child(self, parent, name: str) -> str:
        return f"{parent}/{name}"

    def name(self, p) -> str:
        return str(p).rstrip("/").rsplit("/", 1)[-1]

    def show(self, p) -> str:
        return self.fs.unstrip_protocol(p)

    def exists(self, p) -> bool:
        return self.fs.exists(p)

    def is_dir(self, p) -> bool:
        return self.fs.isdir(p)

    is_plain_dir = is_dir  # no symbolic links on an object store

    def is_file(self, p) -> bool:
        return self.fs.isfile(p)

    def size(self, p) -> int:
        return int(self.fs.size(p))

    def read_bytes(self, p) -> bytes:
        return self.fs.cat_file(p)

    def listdir(self, p) -> list:
        try:
            return sorted(str(x).rstrip("/") for x in self.fs.ls(p, detail=False))
        except FileNotFoundError:
            return []

    def files(self, p) -> list:
        return [f for f in self.listdir(p) if self.fs.isfile(f)]

    def age_s(self, p) -> float:
        """Seconds since the newest file under ``p`` was written (0 when it cannot be told: kept)."""
        try:
            stamps = [self.fs.modified(f) for f in self.fs.find(p)]
        except (NotImplementedError, OSError, ValueError):
            return 0.0
        return max(0.0, time.time() - max(s.timestamp() for s in stamps)) if stamps else 0.0

    def remove(self, p) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.fs.rm(p, recursive=True)

    def temporary(self, parent, prefix: str) -> str:
        tmp = f"{parent}/{prefix}{secrets.token_hex(4)}"
        self.fs.makedirs(tmp, exist_ok=True)
        return tmp

    def write_bytes(self, p, data: bytes) -> None:
        with self.fs.open(p, "wb") as fh:
            fh.write(data)

    def publish(self, tmp, entry, order) -> bool:
        """Move the files of ``tmp`` into ``entry`` in ``order`` (meta last, class docstring);
        False when an entry is already there (another writer was first: theirs is kept)."""
        try:
            if self.fs.exists(f"{entry}/meta.json"):
                return False
            for f in order:
                self.fs.mv(f"{tmp}/{f}", f"{entry}/{f}")
            return True
        finally:
            self.remove(tmp)


def as_buffer(data: bytes) -> io.BytesIO:
    """A file object over bytes already checked (numpy and pandas read from it)."""
    return io.BytesIO(data)
