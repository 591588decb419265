"""The reference cache read back like user input (issue 26, items 10, 11, 19): an edited meta,
entries swapped between two folders, arrays damaged behind checksums that were recomputed, and
stray files in ``references/`` are never read as a reference run, never listed or removed as one."""
from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.cli import main
from tissuebench.reference.cache import (_meta_checksum, cached_solve, cached_table, clear, list_entries,
                                                 reference_key, stray_items)


@pytest.fixture()
def scenes():
    base = load("frame_2dof")
    return base, base.at({"load_scale": 0.5})


def _entry(cache, scene):
    return cache / "references" / reference_key(scene)


def _reseal(entry, files=True):
    """Recompute the checksums of an edited entry (a hostile user who knows the format)."""
    meta = json.loads((entry / "meta.json").read_text())
    if files:
        for f in ("fields.npz", "table.parquet"):
            data = (entry / f).read_bytes()
            meta["files"][f] = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    meta["meta_sha256"] = _meta_checksum(meta)
    (entry / "meta.json").write_text(json.dumps(meta))


@pytest.mark.parametrize("status", ["failed", "stalled", "anything", "success "])
def test_10_an_edited_meta_is_a_miss_recomputed_with_a_warning(tmp_path, scenes, status):
    scene = scenes[0]
    first, _ = cached_solve(scene, cache=tmp_path)
    entry = _entry(tmp_path, scene)
    meta = json.loads((entry / "meta.json").read_text())
    meta["status"] = status
    (entry / "meta.json").write_text(json.dumps(meta))
    assert list_entries(tmp_path).empty and stray_items(tmp_path) == [entry]  # not called valid
    with pytest.warns(UserWarning, match="does not match its checksum"):
        again, hit = cached_solve(scene, cache=tmp_path)
    assert not hit and again.status == "success" == first.status
    assert cached_solve(scene, cache=tmp_path)[1] and list_entries(tmp_path)["valid"].tolist() == [True]


def test_11_entries_swapped_between_two_folders_are_misses(tmp_path, scenes):
    (a, ra), (b, rb) = [(s, cached_solve(s, cache=tmp_path)[0]) for s in scenes]
    assert not np.allclose(ra.displacement, rb.displacement)
    ea, eb = _entry(tmp_path, a), _entry(tmp_path, b)
    ea.rename(tmp_path / "x")
    eb.rename(ea)
    (tmp_path / "x").rename(eb)
    assert cached_table(a, cache=tmp_path) is None
    for scene, ref in ((a, ra), (b, rb)):
        with pytest.warns(UserWarning, match="not its folder's \\(moved or swapped\\)"):
            again, hit = cached_solve(scene, cache=tmp_path)
        assert not hit
        np.testing.assert_array_equal(again.displacement, ref.displacement)


@pytest.mark.parametrize("damage", ["shape", "dtype", "missing", "cells", "nan_points"])
def test_damaged_arrays_behind_resealed_checksums_are_misses(tmp_path, scenes, damage):
    scene = scenes[0]
    first, _ = cached_solve(scene, cache=tmp_path)
    entry = _entry(tmp_path, scene)
    with np.load(entry / "fields.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    if damage == "shape":
        arrays["displacement"] = arrays["displacement"][:, :1]
    elif damage == "dtype":
        arrays["steps"] = np.array(["a"] * len(arrays["steps"]))
    elif damage == "missing":
        del arrays["points"]
    elif damage == "cells":
        arrays["cells"] = arrays["cells"] + 10 ** 6
    else:
        arrays["points"] = arrays["points"] * np.nan
    np.savez(entry / "fields.npz", **arrays)
    _reseal(entry)
    with pytest.warns(UserWarning, match="do not read back"):
        again, hit = cached_solve(scene, cache=tmp_path)
    assert not hit
    np.testing.assert_array_equal(again.displacement, first.displacement)


def test_19_cache_commands_touch_only_entries_with_a_valid_meta(tmp_path, scenes, monkeypatch, capsys):
    monkeypatch.setenv("TISSUEBENCH_CACHE", str(tmp_path))
    for s in scenes:
        cached_solve(s)
    refs = tmp_path / "references"
    (refs / "notes.txt").write_text("mine")
    (refs / ("f" * 64)).mkdir()  # a folder named like a key, no meta
    (refs / ("f" * 64) / "data.bin").write_text("mine too")
    (refs / "photos").mkdir()
    edited = _entry(tmp_path, scenes[1])
    (edited / "meta.json").write_text((edited / "meta.json").read_text().replace('"success"', '"failed"'))
    assert main(["cache", "ls"]) == 0
    captured = capsys.readouterr()
    assert "1 reference runs" in captured.out
    assert "4 items" in captured.err and "notes.txt" in captured.err and "were left alone" in captured.err
    assert main(["cache", "clear"]) == 0
    assert "removed 1 reference runs" in capsys.readouterr().out
    assert sorted(p.name for p in refs.iterdir()) == sorted(["notes.txt", "f" * 64, "photos", edited.name])
    assert (refs / "notes.txt").read_text() == "mine" and clear(tmp_path) == 0


def test_19_a_cache_folder_that_is_a_file_or_empty_lists_nothing(tmp_path, monkeypatch, capsys):
    (tmp_path / "references").write_text("not a folder")
    monkeypatch.setenv("TISSUEBENCH_CACHE", str(tmp_path))
    assert main(["cache", "ls"]) == 0 and main(["cache", "clear"]) == 0
    assert (tmp_path / "references").read_text() == "not a folder"
    shutil.rmtree(tmp_path)
    assert main(["cache", "ls"]) == 0 and "0 reference runs" in capsys.readouterr().out


@pytest.mark.parametrize("edit", [{"wall_s": 10 ** 400}, {"plan": []}, {"files": {"fields.npz": 1}}, {"key": None},
                                  {"components": "xyz"}])
def test_a_resealed_meta_with_hostile_values_is_a_miss(tmp_path, scenes, edit):
    """Found by the 10 000-example fuzzing: an integer beyond the float range in a resealed meta."""
    scene = scenes[0]
    cached_solve(scene, cache=tmp_path)
    entry = _entry(tmp_path, scene)
    meta = json.loads((entry / "meta.json").read_text())
    meta.update(edit)
    (entry / "meta.json").write_text(json.dumps(meta))
    _reseal(entry, files=False)
    with pytest.warns(UserWarning, match="corrupted"):
        assert not cached_solve(scene, cache=tmp_path)[1]
