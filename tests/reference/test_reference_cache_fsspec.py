"""The reference cache on an fsspec file system (issue 30, ``--cache URL``): on ``memory://`` and
``file://`` an entry is written, read back, and refused when damaged, with the same checks as on a
local folder (tests/reference/test_reference_cache.py); a URL fsspec cannot open is a clear ValueError."""
from __future__ import annotations

import hashlib
import io
import json
import os
import re
import uuid
from pathlib import Path

import fsspec
import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.reference.cache import (_meta_checksum, cached_solve, cached_table, clear, list_entries,
                                                 reference_key, stray_items)
from tissuebench.reference.location import check_cache_url, open_cache, probe_cache, using_cache


@pytest.fixture()
def scene():
    return load("frame_2dof")


@pytest.fixture(params=["memory", "file"])
def url(request, tmp_path):
    if request.param == "memory":
        name = f"tb-{uuid.uuid4().hex[:8]}"
        yield f"memory://{name}/cache"
        fsspec.filesystem("memory").rm(f"/{name}", recursive=True)
    else:
        yield f"file://{tmp_path}/cache"


def _fs_entry(url, scene):
    fs, root = fsspec.core.url_to_fs(url)
    return fs, f"{root.rstrip('/')}/references/{reference_key(scene)}"


def test_write_then_read_back(url, scene):
    first, hit = cached_solve(scene, cache=url)
    assert not hit
    fs, entry = _fs_entry(url, scene)
    assert sorted(p.rsplit("/", 1)[-1] for p in fs.ls(entry, detail=False)) == ["fields.npz", "meta.json",
                                                                                "table.parquet"]
    again, hit = cached_solve(scene, cache=url)
    assert hit
    np.testing.assert_array_equal(again.displacement, first.displacement)
    assert cached_table(scene, cache=url) is not None
    assert list_entries(url)["valid"].tolist() == [True] and stray_items(url) == []
    # nothing but the entry: no temporary folder left beside it
    assert [p.rsplit("/", 1)[-1] for p in fs.ls(entry.rsplit("/", 1)[0], detail=False)] == [entry.rsplit("/", 1)[-1]]
    assert clear(url) == 1 and list_entries(url).empty


def test_the_environment_variable_takes_a_url(monkeypatch, scene):
    url = f"memory://tb-{uuid.uuid4().hex[:8]}/env"
    monkeypatch.setenv("TISSUEBENCH_CACHE", url)
    assert not cached_solve(scene)[1] and cached_solve(scene)[1]
    fs, entry = _fs_entry(url, scene)
    assert fs.exists(f"{entry}/meta.json")


def test_using_cache_overrides_the_environment(monkeypatch, tmp_path, scene):
    monkeypatch.setenv("TISSUEBENCH_CACHE", str(tmp_path / "env"))
    url = f"memory://tb-{uuid.uuid4().hex[:8]}/unit"
    with using_cache(url):
        assert not cached_solve(scene)[1]
    assert not (tmp_path / "env").exists() and _fs_entry(url, scene)[0].exists(_fs_entry(url, scene)[1])


def _reseal(fs, entry, files=True):
    meta = json.loads(fs.cat_file(f"{entry}/meta.json"))
    if files:
        for f in ("fields.npz", "table.parquet"):
            data = fs.cat_file(f"{entry}/{f}")
            meta["files"][f] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    meta["meta_sha256"] = _meta_checksum(meta)
    fs.pipe_file(f"{entry}/meta.json", json.dumps(meta).encode())


def _damage(fs, entry, how):
    if how == "edited status":
        meta = json.loads(fs.cat_file(f"{entry}/meta.json"))
        meta["status"] = "failed"
        fs.pipe_file(f"{entry}/meta.json", json.dumps(meta).encode())
        return "does not match its checksum"
    if how == "truncated fields":
        fs.pipe_file(f"{entry}/fields.npz", fs.cat_file(f"{entry}/fields.npz")[:-10])
        return "fields.npz does not match"
    if how == "no meta (half-moved)":
        fs.rm(f"{entry}/meta.json")
        return "no meta.json"
    if how == "resealed bad shape":
        with np.load(io.BytesIO(fs.cat_file(f"{entry}/fields.npz")), allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["displacement"] = arrays["displacement"][:, :1]
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        fs.pipe_file(f"{entry}/fields.npz", buf.getvalue())
        _reseal(fs, entry)
        return "do not read back"
    assert how == "pickled array"
    buf = io.BytesIO()
    np.savez(buf, steps=np.array([object()], dtype=object))
    fs.pipe_file(f"{entry}/fields.npz", buf.getvalue())
    _reseal(fs, entry)
    return "do not read back"


@pytest.mark.parametrize("how", ["edited status", "truncated fields", "no meta (half-moved)", "resealed bad shape",
                                 "pickled array"])
def test_a_damaged_entry_is_a_warning_and_a_recompute_never_read(url, scene, how):
    first, _ = cached_solve(scene, cache=url)
    fs, entry = _fs_entry(url, scene)
    why = _damage(fs, entry, how)
    if "resealed" not in how and "pickled" not in how:  # the table alone is read by cached_table: its checksum fails
        assert cached_table(scene, cache=url) is None
    with pytest.warns(UserWarning, match=why):
        again, hit = cached_solve(scene, cache=url)
    assert not hit
    np.testing.assert_array_equal(again.displacement, first.displacement)
    assert cached_solve(scene, cache=url)[1]  # the replacement reads back


def test_an_entry_swapped_into_another_keys_folder_is_a_miss(scene):
    url = f"memory://tb-{uuid.uuid4().hex[:8]}/swap"
    other = scene.at({"load_scale": 0.5})
    cached_solve(scene, cache=url)
    cached_solve(other, cache=url)
    fs, a = _fs_entry(url, scene)
    _, b = _fs_entry(url, other)
    fs.rm(b, recursive=True)
    fs.copy(a, b, recursive=True)
    with pytest.warns(UserWarning, match="moved or swapped"):
        assert not cached_solve(other, cache=url)[1]


@pytest.mark.parametrize("bad", ["nosuchproto://bucket/x", "", "   ", "a\x00b", 3])
def test_a_url_fsspec_cannot_open_is_a_value_error_naming_it(bad):
    with pytest.raises(ValueError, match="--cache = "):
        check_cache_url(bad)


def test_a_bare_path_and_file_url_are_the_same_local_folder(tmp_path):
    assert open_cache(str(tmp_path)).root == open_cache(f"file://{tmp_path}").root == tmp_path


def test_sweep_refuses_a_cache_url_it_cannot_open_before_any_work(tmp_path, capsys):
    from tissuebench.cli import main

    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "s"\n[[case]]\nname = "cornea_pinch"\n[[method]]\nname = "nearest"\n')
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--quiet", "--cache", "nosuchproto://bucket/c"]) == 2
    assert "--cache = 'nosuchproto://bucket/c': unknown protocol 'nosuchproto'" in capsys.readouterr().err
    assert not out.exists()


def test_a_bad_url_in_the_environment_is_refused_naming_it(tmp_path, monkeypatch, capsys):
    from tissuebench.cli import main

    monkeypatch.setenv("TISSUEBENCH_CACHE", "nosuchproto://bucket/c")
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "s"\n[[case]]\nname = "cornea_pinch"\n[[method]]\nname = "nearest"\n')
    assert main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "TISSUEBENCH_CACHE = 'nosuchproto://bucket/c': unknown protocol" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    assert main(["cache", "ls"]) == 2
    assert "TISSUEBENCH_CACHE = 'nosuchproto://bucket/c'" in capsys.readouterr().err


def test_cache_ls_and_clear_on_a_url(monkeypatch, capsys, scene):
    from tissuebench.cli import main

    url = f"memory://tb-{uuid.uuid4().hex[:8]}/ls"
    monkeypatch.setenv("TISSUEBENCH_CACHE", url)
    cached_solve(scene)
    fs, entry = _fs_entry(url, scene)
    fs.pipe_file(entry.rsplit("/", 1)[0] + "/notes.txt", b"mine")
    assert main(["cache", "ls"]) == 0
    captured = capsys.readouterr()
    assert f"{url}: 1 reference runs" in captured.out and "frame_2dof" in captured.out
    assert "1 items" in captured.err and "notes.txt" in captured.err
    assert main(["cache", "clear"]) == 0 and "removed 1 reference runs" in capsys.readouterr().out
    assert fs.cat_file(entry.rsplit("/", 1)[0] + "/notes.txt") == b"mine"


def test_a_reader_leaves_an_entry_being_published_to_its_writer(scene):
    """On an object store the writer moves the data files first and meta.json last. A reader that
    comes in between sees no meta: a miss, and the files stay (removing them made the writer's
    entry unreadable, and a third solve of a reference in a 2-worker sweep). Once the meta lands,
    the entry reads back."""
    url = f"memory://tb-{uuid.uuid4().hex[:8]}/race"
    cached_solve(scene, cache=url)
    fs, entry = _fs_entry(url, scene)
    meta = fs.cat_file(f"{entry}/meta.json")
    fs.rm(f"{entry}/meta.json")  # the writer between its last data file and its meta
    root = open_cache(url)
    from tissuebench.reference.cache import _lookup

    with pytest.warns(UserWarning, match="no meta.json yet"):
        assert _lookup(root, entry, scene) is None
    assert sorted(p.rsplit("/", 1)[-1] for p in fs.ls(entry, detail=False)) == ["fields.npz", "table.parquet"]
    fs.pipe_file(f"{entry}/meta.json", meta)  # the writer's last move
    assert cached_solve(scene, cache=url)[1]


@pytest.mark.parametrize("failing", ["meta.json", "fields.npz"])
def test_an_io_error_reading_an_entry_is_a_miss_that_leaves_the_entry(url, scene, failing, monkeypatch):
    """A timeout or throttling of the object store while reading an entry is not damage: the
    read is a miss (warned), the entry every worker shares stays and reads back afterwards."""
    cached_solve(scene, cache=url)
    fs, entry = _fs_entry(url, scene)
    root = open_cache(url)
    from tissuebench.reference.cache import _lookup

    real = type(root).read_bytes

    def flaky(self, path):
        if str(path).endswith(failing):
            raise TimeoutError(f"read of {failing} timed out")
        return real(self, path)

    monkeypatch.setattr(type(root), "read_bytes", flaky)
    with pytest.warns(UserWarning, match=f"could not be read just now .*{failing}.*TimeoutError"):
        assert _lookup(root, entry, scene) is None
    listed = list_entries(url)
    assert listed["valid"].tolist() == [False] and stray_items(url) == []
    monkeypatch.setattr(type(root), "read_bytes", real)
    assert cached_solve(scene, cache=url)[1] and list_entries(url)["valid"].tolist() == [True]


@pytest.mark.parametrize("empty", ["", "  "])
def test_an_empty_cache_argument_is_refused_not_read_as_the_default(scene, empty):
    with pytest.raises(ValueError, match="cache = '.*': expected a folder or a URL"):
        cached_solve(scene, cache=empty)


def test_cache_report_and_verify_take_the_cache_a_sweep_used(monkeypatch, capsys, scene, tmp_path):
    """After ``sweep --cache URL`` the other commands that read references reach the same cache
    with ``--cache URL`` (not only through $TISSUEBENCH_CACHE); a bad URL is refused, named."""
    from tissuebench.cli import main

    url = f"memory://tb-{uuid.uuid4().hex[:8]}/flag"
    monkeypatch.setenv("TISSUEBENCH_CACHE", str(tmp_path / "elsewhere"))
    cached_solve(scene, cache=url)
    assert main(["cache", "ls", "--cache", url]) == 0
    assert f"{url}: 1 reference runs" in capsys.readouterr().out
    assert main(["cache", "ls"]) == 0 and "0 reference runs" in capsys.readouterr().out
    assert main(["cache", "clear", "--cache", url]) == 0 and "removed 1" in capsys.readouterr().out
    assert main(["report", str(tmp_path / "none"), "--cache", "nope://x"]) == 2
    assert "nope://x" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["meta.json", "fields.npz"])
def test_a_folder_where_a_file_belongs_is_damage_not_an_io_hiccup(tmp_path, scene, name):
    """IsADirectoryError is an OSError, but a folder in place of an entry's file is damage: the
    entry is removed and recomputed, said "corrupted" (found by the fuzz test of the cache)."""
    url = f"file://{tmp_path}/cache"
    cached_solve(scene, cache=url)
    _, entry = _fs_entry(url, scene)
    target = Path(entry) / name
    target.unlink()
    target.mkdir()
    with pytest.warns(UserWarning, match="corrupted"):
        assert not cached_solve(scene, cache=url)[1]
    assert cached_solve(scene, cache=url)[1]


def test_report_and_verify_read_the_cache_the_sweep_was_given(monkeypatch, capsys, tmp_path):
    """``sweep --cache URL`` records URL in ``_sweep.json``; ``report`` and ``verify`` on that folder
    read their references there unless given ``--cache`` (before, they fell back to
    $TISSUEBENCH_CACHE, another cache, and recomputed); a sweep without --cache records none, and a
    damaged record is refused naming the key."""
    from tissuebench.cli import main
    from tissuebench.reference.location import cache_url
    from tissuebench.studies.sweep_manifest import SweepManifestError, read_sweep_manifest
    from tissuebench.studies.spec import load_spec
    from tissuebench.studies.sweep import run_sweep

    spec = tmp_path / "g.toml"
    spec.write_text('[sweep]\nname = "g"\n[[case]]\nname = "heat1d_source"\ntraining = { kind = "operators" }\n'
                    'evaluation = { kind = "map", mus = [{ position = 0.3 }] }\n[[method]]\nname = "pgd"\n'
                    'list = [{ n_modes = 2, projection = "srb" }]\n')
    url = f"memory://tb-{uuid.uuid4().hex[:8]}/swept"
    monkeypatch.setenv("TISSUEBENCH_CACHE", str(tmp_path / "elsewhere"))
    run_sweep(load_spec(spec), tmp_path / "with", progress=False, cache=url)
    run_sweep(load_spec(spec), tmp_path / "without", progress=False)
    assert read_sweep_manifest(tmp_path / "with")["cache"] == url
    assert "cache" not in read_sweep_manifest(tmp_path / "without")

    seen = []
    monkeypatch.setattr("tissuebench.cli._report", lambda args: seen.append(cache_url()) or 0)
    assert main(["report", str(tmp_path / "with")]) == 0
    assert f"the reference cache the sweep used, {url}" in capsys.readouterr().out
    assert main(["report", str(tmp_path / "with"), "--cache", str(tmp_path / "mine")]) == 0
    assert main(["report", str(tmp_path / "without")]) == 0
    assert seen[0].rstrip("/") == url and seen[1].rstrip("/").endswith("mine")
    assert seen[2].rstrip("/").endswith("elsewhere")

    manifest = tmp_path / "with" / "_sweep.json"
    manifest.write_text(json.dumps({**json.loads(manifest.read_text()), "cache": 5}))
    with pytest.raises(SweepManifestError, match=r"cache = 5: expected a folder path or URL"):
        read_sweep_manifest(tmp_path / "with")


# ------------------------------------------------------------------------ issue 37: which file systems
@pytest.mark.parametrize("bad, protocol", [
    ("zip://x", "zip"), ("data://abc", "data"), ("dask://x", "dask"), ("tar://x", "tar"), ("http://h/x", "http"),
    ("https://h/x", "https"), ("github://o:r@main/x", "github"), ("reference://x", "reference"),
    ("simplecache://x", "simplecache"), ("libarchive://x", "libarchive")])
def test_a_read_only_or_archive_protocol_is_refused_naming_it(bad, protocol):
    """Accepted once, then every unit failed with a raw fsspec error (``cache ls``: NotImplementedError)."""
    with pytest.raises(ValueError, match=rf"--cache = '{re.escape(bad)}': protocol '{protocol}' is not a file system "
                                         "the cache can be written to and listed on"):
        check_cache_url(bad)


def test_the_writable_protocols_are_accepted_or_name_their_missing_package(tmp_path):
    for good in (str(tmp_path), f"file://{tmp_path}", "memory://x/cache", "relative/cache", "~/cache"):
        assert check_cache_url(good) == good
    for url in ("s3://bucket/cache", "gcs://bucket/cache", "sftp://host/cache"):
        try:
            assert check_cache_url(url) == url
        except ValueError as exc:  # its package (s3fs, gcsfs, paramiko) is not installed here
            assert f"--cache = '{url}': protocol" in str(exc) and "needs a package that is not installed" in str(exc)
    with pytest.raises(ValueError, match=r"--cache = 'simplecache::s3://b/x': a chained URL \(::\)"):
        check_cache_url("simplecache::s3://b/x")


def test_cache_ls_of_a_data_url_exits_2_naming_it(capsys):
    from tissuebench.cli import main

    assert main(["cache", "ls", "--cache", "data://abc"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("tissuebench: error: --cache = 'data://abc': protocol 'data'") and err.count("\n") == 1


def _spec(tmp_path):
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\nname = "s"\n[protocol]\nlatency_steps = 5\n[[case]]\nname = "cornea_pinch"\n'
                    '[[method]]\nname = "nearest"\n')
    return spec


def test_a_cache_that_cannot_be_written_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    """A read-only cache was found only when each unit tried to store its reference, after solving it."""
    import errno

    from tissuebench.cli import main
    from tissuebench.reference import location

    (tmp_path / "afile").write_text("")
    out, under_a_file = tmp_path / "out", str(tmp_path / "afile" / "c")
    assert main(["sweep", str(_spec(tmp_path)), "--out", str(out), "--quiet", "--cache", under_a_file]) == 2
    assert f"--cache = '{under_a_file}': the reference cache cannot be written there: Not a directory" \
        in capsys.readouterr().err and not out.exists()

    def read_only(self, path, data):  # a read-only mount (root ignores file modes: simulated)
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    monkeypatch.setattr(location.LocalRoot, "write_bytes", read_only)
    assert main(["sweep", str(_spec(tmp_path)), "--out", str(out), "--quiet", "--cache", str(tmp_path / "ro")]) == 2
    assert "the reference cache cannot be written there: Read-only file system" in capsys.readouterr().err
    assert not out.exists()
    monkeypatch.setenv("TISSUEBENCH_CACHE", str(tmp_path / "ro"))  # the environment's, probed likewise
    assert main(["sweep", str(_spec(tmp_path)), "--out", str(out), "--quiet"]) == 2
    assert f"TISSUEBENCH_CACHE = '{tmp_path / 'ro'}': the reference cache cannot be written" in capsys.readouterr().err


@pytest.mark.skipif(os.geteuid() == 0, reason="root ignores file permissions")
def test_a_read_only_cache_folder_is_refused_before_any_work(tmp_path, capsys):
    from tissuebench.cli import main

    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main(["sweep", str(_spec(tmp_path)), "--out", str(tmp_path / "out"), "--quiet", "--cache", str(ro)]) == 2
    finally:
        ro.chmod(0o755)
    assert "the reference cache cannot be written there: Permission denied" in capsys.readouterr().err


def test_the_probe_leaves_nothing_in_the_cache(tmp_path):
    url = f"memory://tb-{uuid.uuid4().hex[:8]}/probe"
    assert probe_cache(url) == url and probe_cache(str(tmp_path / "c")) == str(tmp_path / "c")
    assert list((tmp_path / "c").iterdir()) == []
    fs, root = fsspec.core.url_to_fs(url)
    assert fs.ls(root, detail=False) == []


def test_a_file_system_that_cannot_be_opened_exits_2_on_one_line(monkeypatch, capsys):
    """Found by tests/studies/test_fuzz_surfaces.py: ``cache ls --cache arrow_hdfs://`` (pyarrow
    without libhdfs) was "cache: cannot use ?: OSError", exit 1."""
    from tissuebench.cli import main
    from tissuebench.reference import location

    def unopenable(url, **kwargs):
        raise OSError("HDFS connection failed\nlibhdfs.so: cannot open shared object file")

    monkeypatch.setattr(location, "url_to_fs", unopenable)
    assert main(["cache", "ls", "--cache", "hdfs://namenode/cache"]) == 2
    err = capsys.readouterr().err
    assert err == ("tissuebench: error: --cache = 'hdfs://namenode/cache': the hdfs file system cannot be opened: "
                   "OSError: HDFS connection failed | libhdfs.so: cannot open shared object file\n")
