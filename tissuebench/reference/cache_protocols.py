"""Which URLs the reference cache may live at (:mod:`.location`): a local folder, ``file://``, or
a file system fsspec knows that the cache can be written to and listed on.

A cache is written (entries, a probe file) and listed (``cache ls``, stale temporaries), so a
read-only file system (``http(s)://``, ``github://``, ``data://``), an archive (``zip://``,
``tar://``), a transport to another process (``dask://``) or a wrapper (``simplecache::``,
chained URLs) would accept the value and fail every unit later with a raw fsspec error
(issue 37): such URLs are refused naming the URL and the protocol.
"""
from __future__ import annotations

from pathlib import Path

import fsspec
from fsspec.core import split_protocol

__all__ = ["WRITABLE_PROTOCOLS", "check_cache_url", "one_line"]

#: the fsspec protocols of file systems a cache can be written to and listed on (object stores,
#: shared and remote file systems; ``memory`` for tests). Any other protocol fsspec knows is read-only,
#: an archive or a transport (zip, tar, data, http, github, dask, a caching wrapper ...): refused.
WRITABLE_PROTOCOLS = frozenset({
    "memory", "s3", "s3a", "gcs", "gs", "abfs", "az", "adl", "oci", "ocilake", "oss", "tos", "tosfs",
    "hdfs", "webhdfs", "sftp", "ssh", "ftp", "smb", "webdav", "dbfs", "lakefs", "root",
})
_WHAT = ("give a folder, file://, or a writable file system's URL (s3, gcs, abfs, sftp, hdfs, ...: "
         "tissuebench.reference.cache_protocols.WRITABLE_PROTOCOLS)")


def check_cache_url(url, name: str = "--cache") -> str:
    """``url`` stripped, or ValueError naming ``name`` and the value: not a non-empty string, a NUL
    byte, a chained URL (``a::b``), a protocol fsspec does not know, one that is not a writable file
    system (:data:`WRITABLE_PROTOCOLS`), or one whose package is not installed."""
    if not isinstance(url, (str, Path)) or not str(url).strip() or "\x00" in str(url):
        raise ValueError(f"{name} = {url!r}: expected a folder path or a URL such as s3://bucket/cache")
    url = str(url).strip()
    if "::" in url:
        raise ValueError(f"{name} = {url!r}: a chained URL (::) is not a location the cache can be written to; "
                         "give a folder or one file system's URL, e.g. s3://bucket/cache")
    protocol, _ = split_protocol(url)
    if protocol in (None, "file", "local"):
        return url
    if protocol not in WRITABLE_PROTOCOLS:
        if protocol in fsspec.available_protocols():
            raise ValueError(f"{name} = {url!r}: protocol {protocol!r} is not a file system the cache can be "
                             f"written to and listed on (read-only, an archive or a transport); {_WHAT}")
        raise ValueError(f"{name} = {url!r}: unknown protocol {protocol!r}; {_WHAT}")
    try:
        fsspec.get_filesystem_class(protocol)
    except ValueError:  # pragma: no cover - every protocol of the list is one fsspec registers
        raise ValueError(f"{name} = {url!r}: unknown protocol {protocol!r}") from None
    except ImportError as exc:
        raise ValueError(f"{name} = {url!r}: protocol {protocol!r} needs a package that is not installed "
                         f"({one_line(exc)})") from None
    return url


def one_line(exc: BaseException) -> str:
    """An exception as one line of at most 300 characters (a remote file system's errors can be
    many lines)."""
    text = " | ".join(ln.strip() for ln in str(exc).splitlines() if ln.strip()) or type(exc).__name__
    return text[:300]
