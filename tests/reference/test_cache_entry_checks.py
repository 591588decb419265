"""One entry of the reference cache read back like user input (:mod:`tissuebench.reference.entry`,
issue 41): every check of the meta, of the data files and of the arrays, on both sides, with the
reason it gives. An entry is built by hand here (not solved), so each test edits one thing."""
from __future__ import annotations

import hashlib
import io
import json
import os

import numpy as np
import pandas as pd
import pytest

from tissuebench.reference.entry import (FILES, STATUSES, EntryUnreadable, arrays_of, check_meta, meta_checksum,
                                         read_files)
from tissuebench.reference.location import LocalRoot

KEY = "ab" * 32


def _arrays(**edits):
    arrays = {"steps": np.array([0.0, 1.0]), "points": np.array([[0.0], [0.5], [1.0]]),
              "cells": np.array([[0, 1], [1, 2]]), "displacement": np.arange(6.0).reshape(2, 3, 1),
              "velocity": np.ones((2, 3, 1))}
    arrays.update(edits)
    return {k: v for k, v in arrays.items() if v is not None}


def _npz(arrays) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def _meta(data: dict, key=KEY, **edits) -> dict:
    meta = {"key": key, "case": "frame_2dof", "variant": None, "resolution": "ci", "backend": "line",
            "mu": {"load_scale": 0.5}, "status": "success", "message": "", "wall_s": 0.25, "cell_type": "line",
            "components": ["x"], "plan": {"analysis": "static", "reasons": [["model", "why"]]}, "info": {"n": 1},
            "files": {f: {"sha256": hashlib.sha256(data[f]).hexdigest(), "bytes": len(data[f])} for f in FILES}}
    meta.update(edits)
    meta["meta_sha256"] = meta_checksum(meta)
    return meta


def _entry(tmp_path, key=KEY, arrays=None, **edits):
    """(root, entry folder, meta) of a valid entry whose meta carries ``edits`` (resealed)."""
    root = LocalRoot(tmp_path)
    entry = root.references() / key
    entry.mkdir(parents=True)
    table = io.BytesIO()
    pd.DataFrame({"step": [0, 1], "load_factor": [0.0, 1.0]}).to_parquet(table, index=False)
    data = {"fields.npz": _npz(arrays or _arrays()), "table.parquet": table.getvalue()}
    for f in FILES:
        (entry / f).write_bytes(data[f])
    meta = _meta(data, key, **edits)
    (entry / "meta.json").write_text(json.dumps(meta))
    return root, entry, meta


def _reseal(entry, meta):
    meta = dict(meta)
    meta["meta_sha256"] = meta_checksum(meta)
    (entry / "meta.json").write_text(json.dumps(meta))


# ---------------------------------------------------------------- the meta
def test_a_valid_meta_is_returned_as_written(tmp_path):
    root, entry, meta = _entry(tmp_path)
    assert check_meta(root, entry) == (meta, "")
    for status in STATUSES:  # every status of a reference run is one
        _reseal(entry, {**meta, "status": status})
        assert check_meta(root, entry)[1] == "", status
    assert STATUSES == ("success", "stalled", "failed", "newton_failed", "blow_up", "energy_growth")


def test_the_meta_size_limit_on_both_sides(tmp_path):
    root, entry, meta = _entry(tmp_path)
    text = json.dumps(meta)
    limit = 16 << 20  # 16 MiB: read; one byte more: not read
    (entry / "meta.json").write_text(text + " " * (limit - len(text)))
    assert check_meta(root, entry) == (meta, "")
    (entry / "meta.json").write_text(text + " " * (limit + 1 - len(text)))
    assert check_meta(root, entry) == (None, "meta.json is too large")


@pytest.mark.parametrize("content, why", [
    (b"{", "meta.json unreadable (JSONDecodeError)"),
    (b"\xff\xfe{}", "meta.json unreadable (UnicodeDecodeError)"),
    (b"[" * 200_000 + b"]" * 200_000, "meta.json unreadable (RecursionError)"),
    (b"[1, 2]", "meta.json is not a JSON object"),
    (b'"success"', "meta.json is not a JSON object"),
    (b"{}", "meta.json does not match its checksum (edited or damaged)"),
])
def test_a_meta_that_does_not_parse_to_an_object_is_refused_with_why(tmp_path, content, why):
    root, entry, _ = _entry(tmp_path)
    (entry / "meta.json").write_bytes(content)
    assert check_meta(root, entry) == (None, why)


def test_a_missing_meta_a_folder_for_a_meta_and_a_file_for_an_entry(tmp_path):
    root, entry, _ = _entry(tmp_path)
    (entry / "meta.json").unlink()
    assert check_meta(root, entry) == (None, "no meta.json")
    (entry / "meta.json").mkdir()
    assert check_meta(root, entry) == (None, "meta.json unreadable (IsADirectoryError)")
    plain = tmp_path / "plain"
    plain.write_text("x")
    assert check_meta(root, plain) == (None, "meta.json unreadable (NotADirectoryError)")


class _Failing(LocalRoot):
    """A root whose reads of the files named ``failing`` raise ``exc`` (an object store timing out)."""

    def __init__(self, root, failing, exc):
        super().__init__(root)
        self.failing, self.exc, self.read = failing, exc, []

    def read_bytes(self, p):
        self.read.append(os.path.basename(p))
        if os.path.basename(p) in self.failing:
            raise self.exc
        return super().read_bytes(p)


def test_an_io_error_reading_the_meta_is_unreadable_not_damage(tmp_path):
    _, entry, _ = _entry(tmp_path)
    with pytest.raises(EntryUnreadable, match=r"^meta.json: TimeoutError: the store took too long$") as exc:
        check_meta(_Failing(tmp_path, {"meta.json"}, TimeoutError("the store took too long")), entry)
    assert isinstance(exc.value, OSError) and isinstance(exc.value.__cause__, TimeoutError)


@pytest.mark.parametrize("edit, why", [
    ({"files": []}, "meta.json lacks the data files' checksums"),
    ({"files": {"fields.npz": {"sha256": "0", "bytes": 1}}}, "meta.json lacks the data files' checksums"),
    ({"files": {"fields.npz": {"sha256": "0", "bytes": 1}, "table.parquet": []}},
     "meta.json lacks the data files' checksums"),
    ({"files": {"fields.npz": {"sha256": 0, "bytes": 1}, "table.parquet": {"sha256": "0", "bytes": 1}}},
     "meta.json lacks the data files' checksums"),
    ({"files": {"fields.npz": {"sha256": "0", "bytes": 1}, "table.parquet": {"sha256": "0", "bytes": "1"}}},
     "meta.json lacks the data files' checksums"),
    ({"files": {"fields.npz": {"sha256": "0", "bytes": 1}, "table.parquet": {"bytes": 1}}},
     "meta.json lacks the data files' checksums"),
    ({"status": "anything"}, "meta.json status 'anything' is not a reference status"),
    ({"status": None}, "meta.json status 'None' is not a reference status"),
    ({"status": "s" * 60}, f"meta.json status {'s' * 40!r} is not a reference status"),
    ({"message": None}, "meta.json status 'success' is not a reference status"),
    ({"plan": []}, "meta.json plan is malformed"),
    ({"plan": {"reasons": "model"}}, "meta.json plan is malformed"),
    ({"plan": {"reasons": [["a", "b"], "c"]}}, "meta.json plan is malformed"),
    ({"case": 3}, "meta.json case is not a string"),
    ({"resolution": None}, "meta.json resolution is not a string"),
    ({"backend": ["line"]}, "meta.json backend is not a string"),
    ({"cell_type": 1.0}, "meta.json cell_type is not a string"),
    ({"components": "x"}, "meta.json components, info or wall_s malformed"),
    ({"info": []}, "meta.json components, info or wall_s malformed"),
    ({"wall_s": "0.25"}, "meta.json components, info or wall_s malformed"),
    ({"wall_s": True}, "meta.json components, info or wall_s malformed"),
    ({"wall_s": 10 ** 400}, "meta.json components, info or wall_s malformed"),
])
def test_a_resealed_meta_with_one_bad_field_is_refused_naming_it(tmp_path, edit, why):
    root, entry, meta = _entry(tmp_path)
    _reseal(entry, {**meta, **edit})
    assert check_meta(root, entry) == (None, why)


def test_an_edited_meta_and_a_meta_moved_to_another_key(tmp_path):
    root, entry, meta = _entry(tmp_path)
    (entry / "meta.json").write_text(json.dumps({**meta, "wall_s": 0.5}))  # not resealed
    assert check_meta(root, entry) == (None, "meta.json does not match its checksum (edited or damaged)")
    _reseal(entry, {**meta, "key": "cd" * 32})
    assert check_meta(root, entry) == (
        None, "meta.json records the key cdcdcdcdcdcdcdcd, not its folder's (moved or swapped)")
    _reseal(entry, {**meta, "wall_s": 3, "components": [], "info": {}})  # an int is a number; empty lists
    assert check_meta(root, entry)[1] == ""


# ---------------------------------------------------------------- the data files
def test_the_data_files_read_back_as_their_bytes(tmp_path):
    root, entry, meta = _entry(tmp_path)
    data, why = read_files(root, entry, meta)
    assert why == "" and data == {f: (entry / f).read_bytes() for f in FILES}


@pytest.mark.parametrize("name", FILES)
@pytest.mark.parametrize("damage", ["missing", "folder", "longer", "shorter", "same size"])
def test_a_damaged_data_file_is_refused_naming_it(tmp_path, name, damage):
    root, entry, meta = _entry(tmp_path)
    path = entry / name
    raw = path.read_bytes()
    path.unlink()
    if damage == "folder":
        path.mkdir()
    elif damage == "longer":
        path.write_bytes(raw + b"\0")
    elif damage == "shorter":
        path.write_bytes(raw[:-1])
    elif damage == "same size":
        path.write_bytes(raw[:-1] + bytes([raw[-1] ^ 1]))
    assert read_files(root, entry, meta) == ({}, f"{name} does not match its recorded size and checksum")


def test_a_data_file_larger_than_recorded_is_never_read(tmp_path):
    _, entry, meta = _entry(tmp_path)
    (entry / "table.parquet").write_bytes(b"x" * (10 + meta["files"]["table.parquet"]["bytes"]))
    root = _Failing(tmp_path, set(), None)
    assert read_files(root, entry, meta)[1] == "table.parquet does not match its recorded size and checksum"
    assert root.read == ["fields.npz"]


def test_a_file_replaced_after_its_size_was_checked_is_refused(tmp_path):
    """The checksum is of the bytes that are parsed: a file swapped between the size check and the read."""
    _, entry, meta = _entry(tmp_path)

    class Swapped(LocalRoot):
        def read_bytes(self, p):
            raw = super().read_bytes(p)
            return raw[:-1] if p.name == "fields.npz" else raw

    assert read_files(Swapped(tmp_path), entry, meta)[1] == "fields.npz does not match its recorded size and checksum"


@pytest.mark.parametrize("exc, text", [
    (PermissionError(13, "Permission denied"), "PermissionError: Permission denied"),
    (TimeoutError("the store took too long"), "TimeoutError: the store took too long"),
])
def test_an_io_error_reading_a_data_file_is_unreadable_not_damage(tmp_path, exc, text):
    _, entry, meta = _entry(tmp_path)
    with pytest.raises(EntryUnreadable) as caught:
        read_files(_Failing(tmp_path, {"table.parquet"}, exc), entry, meta)
    assert str(caught.value) == f"table.parquet: {text}" and caught.value.__cause__ is exc


# ---------------------------------------------------------------- the arrays
def test_the_arrays_read_back_as_written_with_and_without_velocity():
    for arrays in (_arrays(), _arrays(velocity=None)):
        got = arrays_of(_npz(arrays), {"components": ["x"]})
        assert sorted(got) == sorted(arrays)
        for k, a in arrays.items():
            np.testing.assert_array_equal(got[k], a)
            assert got[k].dtype == a.dtype


@pytest.mark.parametrize("edits, components", [
    ({"steps": np.array([0, 1])}, ["x"]),  # integers
    ({"steps": np.array([0, 1], dtype=np.uint8), "cells": np.array([[0, 1], [1, 2]], dtype=np.uint32)}, ["x"]),
    ({"cells": np.zeros((0, 2), dtype=np.int64)}, ["x"]),  # no cells
    ({"cells": np.array([[0, 2], [2, 2]])}, ["x"]),  # the last point
    ({"points": np.zeros((3, 2)), "displacement": np.zeros((2, 3, 2)), "velocity": None}, ["x", "y"]),
    ({"points": np.zeros((3, 3)), "displacement": np.zeros((2, 3, 3)), "velocity": np.zeros((2, 3, 3))},
     ["x", "y", "z"]),
    ({"displacement": np.array([[[np.nan]] * 3] * 2)}, ["x"]),  # a blown-up run is stored as it was
])
def test_arrays_of_every_accepted_kind_and_shape(edits, components):
    arrays = _arrays(**edits)
    got = arrays_of(_npz(arrays), {"components": components})
    assert sorted(got) == sorted(arrays)


@pytest.mark.parametrize("edits, components, why", [
    ({"steps": None}, ["x"], "fields.npz has no 'steps'"),
    ({"points": None}, ["x"], "fields.npz has no 'points'"),
    ({"cells": None}, ["x"], "fields.npz has no 'cells'"),
    ({"displacement": None}, ["x"], "fields.npz has no 'displacement'"),
    ({"steps": np.zeros((2, 1))}, ["x"], "fields.npz 'steps' has shape (2, 1) and type float64"),
    ({"steps": np.array([True, False])}, ["x"], "fields.npz 'steps' has shape (2,) and type bool"),
    ({"steps": np.array(["a", "b"])}, ["x"], "fields.npz 'steps' has shape (2,) and type <U1"),
    ({"velocity": np.ones((2, 3))}, ["x"], "fields.npz 'velocity' has shape (2, 3) and type float64"),
    ({"displacement": np.zeros((2, 3, 2))}, ["x"], "fields.npz displacement (2, 3, 2) does not match steps, points "
                                                   "and components"),
    ({"displacement": np.zeros((3, 3, 1))}, ["x"], "fields.npz displacement (3, 3, 1) does not match steps, points "
                                                   "and components"),
    ({"displacement": np.zeros((2, 2, 1))}, ["x"], "fields.npz displacement (2, 2, 1) does not match steps, points "
                                                   "and components"),
    ({"points": np.zeros((3, 4)), "velocity": None}, ["x"], "fields.npz displacement (2, 3, 1) does not match steps, "
                                                            "points and components"),
    ({"velocity": np.ones((2, 3, 2))}, ["x"], "fields.npz velocity and displacement differ in shape"),
    ({"cells": np.array([[0, 1], [1, 3]])}, ["x"], "fields.npz cells index outside the points"),
    ({"cells": np.array([[0, 1], [-1, 2]])}, ["x"], "fields.npz cells index outside the points"),
    ({"cells": np.array([[0.0, 1.0], [1.0, 2.0]])}, ["x"], "fields.npz cells index outside the points"),
    ({"steps": np.array([0.0, np.inf])}, ["x"], "fields.npz steps or points not finite"),
    ({"points": np.array([[0.0], [np.nan], [1.0]])}, ["x"], "fields.npz steps or points not finite"),
])
def test_arrays_that_do_not_match_are_refused_with_why(edits, components, why):
    with pytest.raises(ValueError) as exc:
        arrays_of(_npz(_arrays(**edits)), {"components": components})
    assert str(exc.value) == why


class _Planted:
    """An object whose unpickling would create the folder ``path``."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return os.mkdir, (self.path,)


def test_a_pickle_in_the_fields_is_never_unpickled(tmp_path):
    planted = tmp_path / "planted"
    steps = np.empty(2, dtype=object)
    steps[:] = [_Planted(str(planted)), 1.0]
    with pytest.raises(ValueError, match="allow_pickle=False"):
        arrays_of(_npz(_arrays(steps=steps)), {"components": ["x"]})
    assert not planted.exists()


@pytest.mark.parametrize("formulation, ok", [(None, True), ("displacement", True), ("anp", True), ("mixed", True),
                                             ("ANP", False), ("mixed_up", False), ("", False)])
def test_the_plans_formulation_on_both_sides(tmp_path, formulation, ok):
    plan = {"analysis": "static", "reasons": [["model", "why"]]}
    if formulation is not None:
        plan["formulation"] = formulation
    root, entry, meta = _entry(tmp_path, plan=plan)
    got, why = check_meta(root, entry)
    assert (got == meta, why) if ok else (got, why) == (None, "meta.json plan is malformed")


def test_an_entry_with_a_damaged_data_file_is_a_problem_and_not_cleared_as_valid(tmp_path):
    from tissuebench.reference.cache import _problem, clear
    root, entry, meta = _entry(tmp_path)
    assert _problem(root, entry) == (meta, {f: (entry / f).read_bytes() for f in FILES}, "")
    (entry / "table.parquet").write_bytes(b"damaged")
    got = _problem(root, entry)
    assert got[:2] == (None, {}) and got[2].startswith("table.parquet")
    assert _problem(root, root.references() / ("cd" * 32)) == (None, {}, "not a folder")
    # a second valid entry and a link named like one: clear counts the two real entries, leaves the link
    _entry(tmp_path, key="ef" * 32)
    os.symlink(root.references() / ("ef" * 32), root.references() / ("01" * 32))
    assert clear(tmp_path) == 2
    assert sorted(p.name for p in root.references().iterdir()) == ["01" * 32]


def test_the_cached_table_is_found_under_its_scenes_key_and_the_default_backend(tmp_path):
    import inspect

    from tissuebench.cases.scene import load
    from tissuebench.reference.cache import cached_solve, cached_table, reference_key
    scene = load("cube_tension_twist", resolution="ci", variant="tension")  # a finite-element scene: backend in the key
    for f in (cached_table, cached_solve):
        assert inspect.signature(f).parameters["backend"].default == "skfem"
    _entry(tmp_path, key=reference_key(scene, "skfem", "auto"))
    table = cached_table(scene, cache=tmp_path)
    assert table is not None and table["load_factor"].tolist() == [0.0, 1.0]
    assert cached_table(scene, "ngsolve", cache=tmp_path) is None
