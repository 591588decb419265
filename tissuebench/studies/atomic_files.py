"""Files the tool writes: the path checked before any work, then written through a temporary
file beside it that is renamed into place (a reader sees the old file or the new one).

Every writer of the package goes through here (``check --junit``, ``--baseline``, ``report
--out``, ``scene check --out``, the files of a results store, of ``_derived/`` and of a run
folder), so one set of rules holds for all of them:

* a path that exists must be a regular file: a folder, a character or block device, a FIFO or
  a socket is refused (:class:`OutputPathError`, naming the option and the path), never
  replaced and never opened (opening a FIFO blocks until someone reads it);
* a symbolic link is written through: the file at the end of its chain of links is replaced
  (created when the link dangles), the link itself stays; a loop of links is refused;
* modes: a new file gets what the umask leaves of 0o666 (what ``open`` gives), a replaced file
  keeps its mode; a new folder gets what the umask leaves of 0o777 (what ``mkdir`` gives), a
  folder that replaces another keeps that one's mode (:func:`new_folder`).
"""
from __future__ import annotations

import contextlib
import errno
import os
import secrets
import stat
from pathlib import Path

__all__ = ["OutputPathError", "output_file", "stat_output", "kind_of", "replacing", "write_text", "new_folder"]


class OutputPathError(ValueError):
    """An output path the tool must not write: not a regular file, a loop of links, a NUL byte
    (the message names the option and the path)."""


def _where(path, option) -> str:
    return f"{option} {path}" if option else str(path)


def kind_of(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, in words ("a FIFO (named pipe)")."""
    kinds = [(stat.S_ISREG, "a file"), (stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISSOCK, "a socket")]
    return next((name for test, name in kinds if test(mode)), "not a regular file")


def stat_output(path, option=None):
    """``os.stat`` of ``path`` (links followed), None when nothing is there (a dangling link
    included). OutputPathError for a NUL byte, a loop of links or a path that cannot be a file
    (a file or a name too long on the way)."""
    if "\0" in str(path):
        raise OutputPathError(f"{_where(repr(str(path)), option)}: contains a NUL byte")
    try:
        return os.stat(path)
    except FileNotFoundError:
        return None
    except OSError as exc:
        if exc.errno == errno.ENOTDIR:  # a file on the way
            above = next((p for p in Path(path).parents if p.exists() and not p.is_dir()), Path(path).parent)
            why = f"{str(above)!r} is not a folder"
        elif exc.errno == errno.ELOOP:
            why = "a loop of symbolic links"
        else:
            why = f"not a usable path ({exc.strerror or type(exc).__name__})"
        raise OutputPathError(f"{_where(path, option)}: {why}") from None


def output_file(path, option=None) -> Path:
    """The file that writing ``path`` replaces: ``path``, or the end of its chain of links.

    Parameters
    ----------
    path : path-like
        Where the user (or the tool) asked for a file.
    option : str, optional
        The option that named it (``"--junit"``), for the messages.

    Raises
    ------
    OutputPathError
        ``path`` (through its links) is a folder, a device, a FIFO or a socket, a loop of links,
        holds a NUL byte; or the nearest existing folder above it is not writable.
    """
    target = _target(path, option)
    folder = next((p for p in [target.parent, *target.parent.parents] if p.exists()), Path("."))
    if not folder.is_dir() or not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"{_where(path, option)}: the folder {folder} is not writable")
    return target


def _target(path, option) -> Path:
    """:func:`output_file` without the check of the folder: a writer that meets an unwritable
    folder raises the file system's own OSError (a store turned read-only mid-sweep)."""
    st = stat_output(path, option)
    if st is not None and not stat.S_ISREG(st.st_mode):
        raise OutputPathError(f"{_where(path, option)}: is {kind_of(st.st_mode)}, not a regular file; "
                              "give the path of a file")
    path = Path(path)
    return Path(os.path.realpath(path)) if st is not None or path.is_symlink() else path


def _mode_of(target: Path, option) -> int | None:
    """The permission bits of the regular file ``target`` (None when missing); refuses anything
    else (it may have changed since :func:`output_file`)."""
    try:
        st = os.lstat(target)
    except FileNotFoundError:
        return None
    if not stat.S_ISREG(st.st_mode):
        raise OutputPathError(f"{_where(target, option)}: is {kind_of(st.st_mode)}, not a regular file")
    return stat.S_IMODE(st.st_mode)


def _temporary_file(target: Path, suffix: str) -> Path:
    # os.open with 0o666 lets the umask decide, as for any new file (tempfile.mkstemp makes 0600)
    for _ in range(100):
        tmp = target.with_name(f".{target.name}.{secrets.token_hex(4)}{suffix}")
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666))
        except FileExistsError:
            continue
        return tmp
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(target))


@contextlib.contextmanager
def replacing(path, option=None, suffix: str = ".tmp"):
    """Yield a new empty temporary file (a :class:`~pathlib.Path` ending in ``suffix``) beside
    :func:`output_file` of ``path``; it replaces that file, with the old file's mode, when the
    block returns, and is removed when the block raises (Ctrl-C included).

    ``suffix`` ``".tmp"`` is what a results store skips and cleans (:mod:`.results`); a writer
    that chooses its format by the name (a PNG) passes ``".png"``. An OSError of the file system
    (unwritable, full) propagates for the caller to name its output."""
    target = _target(path, option)
    tmp = _temporary_file(target, suffix)
    try:
        yield tmp
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        mode = _mode_of(target, option)
        if mode is not None:
            os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text(path, text: str, option=None, encoding: str = "utf-8") -> Path:
    """Write ``text`` to ``path`` through :func:`replacing`; returns the file written."""
    target = _target(path, option)
    with replacing(target, option) as tmp:
        tmp.write_text(text, encoding=encoding)
    return target


def new_folder(parent, prefix: str, like=None) -> Path:
    """A new empty folder ``parent/<prefix><8 hex digits>`` with the mode ``mkdir`` gives (what
    the umask leaves of 0o777; ``tempfile.mkdtemp`` makes 0700), or the mode of the folder
    ``like`` when it exists (the folder this one is to replace)."""
    for _ in range(100):
        folder = Path(parent) / f"{prefix}{secrets.token_hex(4)}"
        try:
            os.mkdir(folder, 0o777)
        except FileExistsError:
            continue
        if like is not None and Path(like).is_dir():
            os.chmod(folder, stat.S_IMODE(Path(like).stat().st_mode))
        return folder
    raise FileExistsError(errno.EEXIST, "no free temporary name", str(Path(parent) / prefix))
