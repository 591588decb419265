"""The reference cache's reads and writes (:mod:`tissuebench.reference.cache`, issue 41): an entry
written, then read back field by field; a damaged, unreadable or half-moved entry is refused and
recomputed, never used; the second look under the cluster lock; the progress bar; listing and
clearing. The solver is replaced by one returning a hand-made result, so every field is known."""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import os
import sys
import uuid
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from tissuebench.cases.scene import load
from tissuebench.reference import cache
from tissuebench.reference.cache import (cached_solve, cached_table, clear, list_entries, reference_key,
                                         stray_items)
from tissuebench.reference.entry import meta_checksum
from tissuebench.reference.location import LocalRoot
from tissuebench.reference.plan import ModelPlan
from tissuebench.reference.result import ReferenceResult

SCENE = load("frame_2dof").at({"load_scale": 0.5})  # a line model: no finite-element problem
COLUMNS = ["key", "case", "variant", "resolution", "backend", "mu", "status", "wall_s", "bytes", "valid"]


def _result(**edits) -> ReferenceResult:
    fields = dict(case="frame_2dof", variant="soft", resolution="ci", backend="line",
                  plan=ModelPlan("dynamic", "frame2dof", True, "consistent", "once", "integrate:newmark",
                                 [("mass", "the frame's"), ("integrator", "newmark")]),
                  status="stalled", message="stopped at 0.9", table=pd.DataFrame(
                      {"step": [0, 1], "time": [0.0, 0.1], "tip": [0.0, 2.5], "converged": [True, False]}),
                  points=np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]]),
                  cells=np.array([[0, 1], [1, 2]]), cell_type="line", components=("ux", "uy"),
                  steps=np.array([0.0, 0.1]), displacement=np.arange(12.0).reshape(2, 3, 2) / 7,
                  velocity=-np.arange(12.0).reshape(2, 3, 2) / 3, wall_s=1.25,
                  info={"n": 2, "nested": {"a": [1, 2]}, "mesh": Path("/meshes/beam.msh")})
    fields.update(edits)
    return ReferenceResult(**fields)


@pytest.fixture()
def solver(monkeypatch):
    """Replace the reference solver: ``calls`` records its arguments, ``result`` is what it returns."""
    box = SimpleNamespace(calls=[], result=_result())

    def solve(scene, backend, progress, linear_solver):
        box.calls.append((scene, backend, progress, linear_solver))
        return box.result
    monkeypatch.setattr(cache, "solve", solve)
    return box


def _folder(tmp_path, scene=SCENE, backend="skfem", linear_solver="auto") -> Path:
    return tmp_path / "references" / reference_key(scene, backend, linear_solver)


def _same(got: ReferenceResult, want: ReferenceResult, problem=None):
    for f in dataclasses.fields(want):
        a, b = getattr(want, f.name), getattr(got, f.name)
        if f.name == "table":
            pd.testing.assert_frame_equal(b, a)
        elif isinstance(a, np.ndarray):
            assert b.dtype == a.dtype and b.shape == a.shape, f.name
            np.testing.assert_array_equal(b, a, err_msg=f.name)
        elif f.name == "info":
            assert b == json.loads(json.dumps(a, default=str)), f.name
        elif f.name == "problem":
            assert b is problem
        else:
            assert b == a and type(b) is type(a), f.name


# ---------------------------------------------------------------- write, then read back
def test_an_entry_written_then_read_back_field_by_field(tmp_path, solver):
    first, hit = cached_solve(SCENE, "skfem", "direct", cache=tmp_path)
    assert (first, hit) == (solver.result, False)
    assert solver.calls == [(SCENE, "skfem", None, "direct")]
    again, hit = cached_solve(SCENE, "skfem", "direct", cache=tmp_path)
    assert hit is True and len(solver.calls) == 1
    _same(again, solver.result)
    assert again.plan.reasons == [("mass", "the frame's"), ("integrator", "newmark")]
    assert again.info["mesh"] == "/meshes/beam.msh"  # a value JSON has no type for is stored as its text
    assert sorted(p.name for p in (tmp_path / "references").iterdir()) == [
        reference_key(SCENE, "skfem", "direct")]  # no temporary left beside it


def test_the_meta_records_what_the_entry_is_by_hand(tmp_path, solver):
    cached_solve(SCENE, cache=tmp_path)
    entry = _folder(tmp_path)
    meta = json.loads((entry / "meta.json").read_text())
    files = {f: (entry / f).read_bytes() for f in ("fields.npz", "table.parquet")}
    assert meta == {
        "key": entry.name, "case": "frame_2dof", "variant": "soft", "resolution": "ci", "backend": "line",
        "mu": {"load_scale": 0.5}, "status": "stalled", "message": "stopped at 0.9", "wall_s": 1.25,
        "cell_type": "line", "components": ["ux", "uy"],
        "plan": {"analysis": "dynamic", "model": "frame2dof", "linear": True, "mass": "consistent",
                 "tangent": "once", "algorithm": "integrate:newmark",
                 "reasons": [["mass", "the frame's"], ["integrator", "newmark"]], "formulation": "displacement"},
        "info": {"n": 2, "nested": {"a": [1, 2]}, "mesh": "/meshes/beam.msh"},
        "files": {f: {"sha256": hashlib.sha256(b).hexdigest(), "bytes": len(b)} for f, b in files.items()},
        "meta_sha256": meta_checksum(meta)}
    with np.load(entry / "fields.npz", allow_pickle=False) as z:
        assert sorted(z.files) == ["cells", "displacement", "points", "steps", "velocity"]
    pd.testing.assert_frame_equal(pd.read_parquet(entry / "table.parquet"), solver.result.table)


def test_a_run_without_velocities_stores_none(tmp_path, solver):
    solver.result = _result(velocity=None, variant=None, status="success")
    cached_solve(SCENE, cache=tmp_path)
    with np.load(_folder(tmp_path) / "fields.npz", allow_pickle=False) as z:
        assert "velocity" not in z.files
    again, hit = cached_solve(SCENE, cache=tmp_path)
    assert hit and again.velocity is None and again.variant is None and again.status == "success"


@dataclasses.dataclass
class _FeScene:
    """What the cache asks of a finite-element scene: its content, ``mu`` and its problem."""

    is_fe: bool = True
    mu: dict = dataclasses.field(default_factory=lambda: {"load_scale": 2.0})
    problems: list = dataclasses.field(default_factory=list)

    def content(self):
        return {"name": "solid", "mu": self.mu}

    def to_problem(self):
        self.problems.append(object())
        return self.problems[-1]


def test_a_finite_element_entry_reads_back_with_the_scenes_problem_and_its_backend(tmp_path, solver, monkeypatch):
    # the formulation the reference would choose is part of the key (reference/formulation.py): here a given one
    monkeypatch.setattr(cache, "formulation_of", lambda scene: type("F", (), {"name": "displacement"})())
    scene = _FeScene()
    solver.result = _result(backend="ngsolve")
    assert cached_solve(scene, "ngsolve", cache=tmp_path) == (solver.result, False)
    assert not cached_solve(scene, "skfem", cache=tmp_path)[1]  # another backend: another reference
    again, hit = cached_solve(scene, "ngsolve", cache=tmp_path)
    assert hit and len(scene.problems) == 1
    _same(again, solver.result, problem=scene.problems[0])
    assert [c[1] for c in solver.calls] == ["ngsolve", "skfem"]


def test_a_write_that_fails_leaves_nothing_and_raises(tmp_path, solver, monkeypatch):
    def publish(self, tmp, entry, order):
        raise KeyboardInterrupt
    monkeypatch.setattr(LocalRoot, "publish", publish)
    with pytest.raises(KeyboardInterrupt):
        cached_solve(SCENE, cache=tmp_path)
    assert list((tmp_path / "references").iterdir()) == []


# ---------------------------------------------------------------- refused entries
def _warned(record, *messages):
    assert [str(w.message) for w in record] == list(messages)
    # the warning points at the caller of cached_solve (not under mutmut: its trampoline is one
    # more frame between them; tox -e mutation)
    assert "MUTANT_UNDER_TEST" in os.environ or all(w.filename == __file__ for w in record)


def test_an_edited_entry_is_refused_removed_and_recomputed(tmp_path, solver):
    cached_solve(SCENE, cache=tmp_path)
    entry = _folder(tmp_path)
    meta = json.loads((entry / "meta.json").read_text())
    (entry / "meta.json").write_text(json.dumps({**meta, "status": "success"}))
    (entry / "stray.txt").write_text("left by the editor")
    with pytest.warns(UserWarning) as record:
        again, hit = cached_solve(SCENE, cache=tmp_path)
    _warned(record, f"reference cache entry {entry} is corrupted (meta.json does not match its checksum "
                    "(edited or damaged)): recomputed")
    assert (again, hit) == (solver.result, False) and len(solver.calls) == 2
    assert not (entry / "stray.txt").exists()  # the damaged entry went; a new one took its place
    assert json.loads((entry / "meta.json").read_text())["status"] == "stalled"
    assert cached_solve(SCENE, cache=tmp_path)[1]


def test_data_that_do_not_read_back_are_refused_with_numpys_reason(tmp_path, solver):
    cached_solve(SCENE, cache=tmp_path)
    entry = _folder(tmp_path)
    with np.load(entry / "fields.npz", allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files if k != "points"}
    np.savez(entry / "fields.npz", **arrays)
    meta = json.loads((entry / "meta.json").read_text())
    raw = (entry / "fields.npz").read_bytes()
    meta["files"]["fields.npz"] = {"sha256": hashlib.sha256(raw).hexdigest(), "bytes": len(raw)}
    meta["meta_sha256"] = meta_checksum(meta)
    (entry / "meta.json").write_text(json.dumps(meta))
    assert cached_table(SCENE, cache=tmp_path) is not None  # the table alone is fine
    with pytest.warns(UserWarning) as record:
        assert cached_solve(SCENE, cache=tmp_path)[1] is False
    _warned(record, f"reference cache entry {entry} is corrupted (its data do not read back (ValueError: "
                    "fields.npz has no 'points')): recomputed")


def test_a_local_entry_without_its_meta_is_damage_removed(tmp_path, solver):
    cached_solve(SCENE, cache=tmp_path)
    entry = _folder(tmp_path)
    (entry / "meta.json").unlink()
    with pytest.warns(UserWarning) as record:
        assert cached_solve(SCENE, cache=tmp_path)[1] is False
    _warned(record, f"reference cache entry {entry} is corrupted (no meta.json): recomputed")
    assert cached_solve(SCENE, cache=tmp_path)[1]


def test_a_remote_entry_without_its_meta_is_left_to_its_writer(solver):
    url = f"memory://h41-{uuid.uuid4().hex}"
    cached_solve(SCENE, cache=url)
    root = cache.open_cache(url)
    entry = root.child(root.references(), reference_key(SCENE))
    meta = root.read_bytes(root.child(entry, "meta.json"))
    root.fs.rm(root.child(entry, "meta.json"))  # a writer moving its files in (meta last)
    with pytest.warns(UserWarning) as record:
        assert cached_solve(SCENE, cache=url)[1] is False
    half = (f"reference cache entry {root.show(entry)} has no meta.json yet (being written, or half-moved by a "
            "writer that died): recomputed, the entry left to its writer")
    _warned(record, half, half)  # before and under the lock
    assert root.read_bytes(root.child(entry, "meta.json")) == meta  # completed by the next publish
    root.write_bytes(root.child(entry, "meta.json"), b"{")  # a meta, but damaged: removed
    with pytest.warns(UserWarning, match="is corrupted \\(meta.json unreadable \\(JSONDecodeError\\)\\)"):
        assert cached_solve(SCENE, cache=url)[1] is False
    assert cached_solve(SCENE, cache=url)[1]
    root.fs.rm(root.root, recursive=True)


def test_an_entry_that_cannot_be_read_just_now_is_recomputed_and_left_in_place(tmp_path, solver, monkeypatch):
    cached_solve(SCENE, cache=tmp_path)
    entry = _folder(tmp_path)
    before = {p.name: p.read_bytes() for p in entry.iterdir()}
    real = LocalRoot.read_bytes

    def read_bytes(self, p):
        if Path(p).name == "meta.json":
            raise TimeoutError("the store took too long")
        return real(self, p)
    monkeypatch.setattr(LocalRoot, "read_bytes", read_bytes)
    with pytest.warns(UserWarning) as record:
        again, hit = cached_solve(SCENE, cache=tmp_path)
    _warned(record, f"reference cache entry {entry} could not be read just now (meta.json: TimeoutError: the store "
                    "took too long): recomputed, the entry left in place",
            f"reference cache entry {entry} could not be read just now (meta.json: TimeoutError: the store "
            "took too long): recomputed, the entry left in place")  # before and under the lock
    assert (again, hit) == (solver.result, False)
    assert {p.name: p.read_bytes() for p in entry.iterdir()} == before


# ---------------------------------------------------------------- the second look, under the lock
def test_an_entry_stored_while_waiting_for_the_lock_is_read_not_solved_again(tmp_path, solver, monkeypatch):
    stored = {}

    @contextlib.contextmanager
    def lock(key):
        assert key == reference_key(SCENE, "skfem", "direct")
        # the task that held the lock before us stored the reference meanwhile
        real_solve, cache.solve = cache.solve, lambda *a, **k: solver.result
        try:
            stored["first"] = cache._write(cache.open_cache(tmp_path), _folder(tmp_path, linear_solver="direct"),
                                           solver.result, SCENE, key)
        finally:
            cache.solve = real_solve
        yield
    monkeypatch.setattr(cache, "_cluster_lock", lock)
    again, hit = cached_solve(SCENE, "skfem", "direct", cache=tmp_path)
    assert hit is True and solver.calls == [] and "first" in stored
    _same(again, solver.result)


def test_the_cluster_lock_is_named_by_the_key_inside_a_dask_worker(monkeypatch):
    distributed = pytest.importorskip("distributed")
    assert isinstance(cache._cluster_lock("k"), contextlib.nullcontext)  # not in a worker
    monkeypatch.setattr(distributed, "get_worker", lambda: object())
    monkeypatch.setattr(distributed, "Lock", lambda name: ("lock", name))
    assert cache._cluster_lock("k" * 64) == ("lock", "tissuebench-reference-" + "k" * 64)
    monkeypatch.setitem(sys.modules, "distributed", None)  # not installed
    assert isinstance(cache._cluster_lock("k"), contextlib.nullcontext)


# ---------------------------------------------------------------- the progress bar
class _Bar:
    def __init__(self):
        self.closed = 0

    def close(self):
        self.closed += 1


@pytest.mark.parametrize("env, shown", [("1", True), (" 1 ", True), ("0", False), ("", False), (None, False)])
def test_a_computed_reference_shows_a_bar_only_when_asked(tmp_path, solver, monkeypatch, env, shown):
    bar, bars = _Bar(), []

    def update(*args):
        pass

    def reference_bar(scene, backend):
        bars.append((scene, backend))
        return bar, update
    monkeypatch.setattr(cache, "_reference_bar", reference_bar)
    if env is None:
        monkeypatch.delenv(cache.PROGRESS_ENV, raising=False)
    else:
        monkeypatch.setenv(cache.PROGRESS_ENV, env)
    cached_solve(SCENE, "ngsolve", cache=tmp_path)
    assert bars == ([(SCENE, "ngsolve")] if shown else [])
    assert solver.calls[0][2] is (update if shown else None) and bar.closed == int(shown)
    mine = object()
    cached_solve(SCENE, "skfem", "direct", progress=mine, cache=tmp_path)  # the caller's own progress wins
    assert solver.calls[1][2] is mine and len(bars) == int(shown)


def test_the_bar_is_closed_when_the_solve_raises(tmp_path, monkeypatch):
    bar = _Bar()
    monkeypatch.setattr(cache, "_reference_bar", lambda scene, backend: (bar, None))
    monkeypatch.setenv(cache.PROGRESS_ENV, "1")

    def solve(*args, **kwargs):
        raise RuntimeError("the solver broke")
    monkeypatch.setattr(cache, "solve", solve)
    with pytest.raises(RuntimeError, match="the solver broke"):
        cached_solve(SCENE, cache=tmp_path)
    assert bar.closed == 1 and not _folder(tmp_path).exists()


# ---------------------------------------------------------------- listing and clearing
def _store(tmp_path, solver, scenes):
    for scene, result in scenes:
        solver.result = result
        cached_solve(scene, cache=tmp_path)


def test_cache_ls_lists_each_entry_by_hand(tmp_path, solver):
    other = SCENE.at({"load_scale": 0.25})
    _store(tmp_path, solver, [(SCENE, _result()), (other, _result(variant=None, status="success", wall_s=2.0))])
    table = list_entries(tmp_path)
    assert list(table.columns) == COLUMNS
    rows = {r["key"]: r for r in table.to_dict("records")}
    a, b = (_folder(tmp_path, s) for s in (SCENE, other))
    assert rows[a.name[:16]] == {"key": a.name[:16], "case": "frame_2dof", "variant": "soft", "resolution": "ci",
                                 "backend": "line", "mu": '{"load_scale": 0.5}', "status": "stalled",
                                 "wall_s": 1.25, "bytes": sum(f.stat().st_size for f in a.iterdir()),
                                 "valid": True}
    assert pd.isna(rows[b.name[:16]]["variant"]) and rows[b.name[:16]]["status"] == "success"
    assert rows[b.name[:16]]["mu"] == '{"load_scale": 0.25}' and rows[b.name[:16]]["wall_s"] == 2.0
    (b / "table.parquet").write_bytes(b"x")  # damaged data behind a valid meta: listed, not valid
    assert list_entries(tmp_path).set_index("key")["valid"].to_dict() == {a.name[:16]: True, b.name[:16]: False}
    assert list(list_entries(tmp_path / "empty").columns) == COLUMNS and list_entries(tmp_path / "empty").empty


def test_an_entry_whose_meta_cannot_be_read_now_is_listed_invalid_and_cleared(tmp_path, solver, monkeypatch):
    _store(tmp_path, solver, [(SCENE, _result())])
    entry = _folder(tmp_path)
    size = sum(f.stat().st_size for f in entry.iterdir())

    def read_bytes(self, p):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(LocalRoot, "read_bytes", read_bytes)
    row, = list_entries(tmp_path).to_dict("records")
    assert row == {"key": entry.name[:16], "case": None, "variant": None, "resolution": None, "backend": None,
                   "mu": "{}", "status": None, "wall_s": None, "bytes": size, "valid": False}
    assert stray_items(tmp_path) == [] and clear(tmp_path) == 1 and not entry.exists()


def test_only_entries_are_listed_and_cleared_and_old_temporaries_go(tmp_path, solver, monkeypatch):
    _store(tmp_path, solver, [(SCENE, _result())])
    refs, entry = tmp_path / "references", _folder(tmp_path)
    (refs / ("e" * 64)).mkdir()  # named like a key, no meta
    (refs / "notes.txt").write_text("mine")
    os.symlink(entry, refs / ("d" * 64))  # a link to an entry is not one
    (refs / (entry.name + "0")).mkdir()  # 65 characters
    temporaries = {".0123456789abcdef.old": 3600.5, ".0123456789abcdef.now": 3600.0, ".fedcba9876543210.x": 0.0}
    for name in temporaries:
        (refs / name).mkdir()
    (refs / ".00000000000000ff.file").write_text("a file named like a temporary")
    ages = {**temporaries, ".00000000000000ff.file": 1e9}
    monkeypatch.setattr(LocalRoot, "age_s", lambda self, p: ages[Path(p).name])
    assert list_entries(tmp_path)["key"].tolist() == [entry.name[:16]]
    strays = ["e" * 64, "d" * 64, entry.name + "0", "notes.txt"]
    assert sorted(p.name for p in stray_items(tmp_path)) == sorted(strays)
    strays.append(".00000000000000ff.file")  # named like a temporary: not named a stray, not removed
    assert clear(tmp_path) == 1  # the entry; the temporary older than an hour; nothing else
    assert sorted(p.name for p in refs.iterdir()) == sorted(strays + [".0123456789abcdef.now",
                                                                      ".fedcba9876543210.x"])
    assert clear(tmp_path, min_age_s=0.0) == 0  # the temporaries older than 0 s
    assert sorted(p.name for p in refs.iterdir()) == sorted(strays + [".fedcba9876543210.x"])


def test_a_cache_that_cannot_be_listed_has_no_entries(tmp_path, solver, monkeypatch):
    _store(tmp_path, solver, [(SCENE, _result())])

    def listdir(self, p):
        raise PermissionError(13, "Permission denied")
    monkeypatch.setattr(LocalRoot, "listdir", listdir)
    assert list_entries(tmp_path).empty and stray_items(tmp_path) == [] and clear(tmp_path) == 0
    assert _folder(tmp_path).exists()
