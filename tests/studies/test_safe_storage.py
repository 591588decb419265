"""Safe loading and corrupted files (issue 16): no pickle, eval or shell anywhere; a truncated
reference-cache entry or sweep unit file is detected and recomputed, never read as valid."""
from __future__ import annotations

import ast
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from tissuebench.cases.scene import load
from tissuebench.reference.cache import cached_solve, reference_key
from tissuebench.studies.results import ResultsStore
from tissuebench.studies.sweep import _plan

ROOT = Path(__file__).resolve().parents[2]
UNSAFE_MODULES = {"pickle", "cPickle", "_pickle", "dill", "joblib", "shelve", "marshal"}


def _sources():
    for folder in ("tissuebench", "tests", "examples"):
        yield from sorted((ROOT / folder).rglob("*.py"))


def _unsafe_calls(tree):
    """(line, what) of every unsafe construct in a module's syntax tree."""
    found = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names = [a.name for a in node.names] + ([node.module] if isinstance(node, ast.ImportFrom) else [])
            found += [(node.lineno, f"import {n}") for n in names if n and n.split(".")[0] in UNSAFE_MODULES]
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
        owner = f.value.id if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) else ""
        kw = {k.arg: k.value for k in node.keywords}
        if name in ("eval", "exec") and isinstance(f, ast.Name):
            found.append((node.lineno, name))
        if name in ("read_pickle", "to_pickle") or (owner == "os" and name in ("system", "popen")):
            found.append((node.lineno, f"{owner}.{name}"))
        if owner in ("np", "numpy") and name == "load":
            flag = kw.get("allow_pickle")
            if not (isinstance(flag, ast.Constant) and flag.value is False):
                found.append((node.lineno, "np.load without allow_pickle=False"))
        if owner == "yaml" and name == "load":
            found.append((node.lineno, "yaml.load"))
        shell = kw.get("shell")
        if shell is not None and not (isinstance(shell, ast.Constant) and shell.value is False):
            found.append((node.lineno, f"{name}(shell=...)"))
    return found


def test_no_pickle_eval_or_shell_anywhere():
    bad = [f"{p.relative_to(ROOT)}:{line}: {what}" for p in _sources()
           for line, what in _unsafe_calls(ast.parse(p.read_text(), str(p)))]
    assert bad == []


def test_the_checker_finds_what_it_looks_for():
    tree = ast.parse("import pickle\nnp.load(f)\nnp.load(f, allow_pickle=True)\neval('1')\n"
                     "subprocess.run(c, shell=True)\nos.system('ls')\nnp.load(f, allow_pickle=False)\n")
    assert [line for line, _ in _unsafe_calls(tree)] == [1, 2, 3, 4, 5, 6]


# ------------------------------------------------------------------------------ corrupted files
@pytest.mark.parametrize("damage", ["truncate fields.npz", "truncate table.parquet", "garble meta.json"])
def test_a_damaged_reference_cache_entry_is_recomputed_not_read(tmp_path, damage):
    scene = load("frame_2dof")
    first, hit = cached_solve(scene, cache=tmp_path)
    assert not hit
    entry = tmp_path / "references" / reference_key(scene)
    what, name = damage.split(" ")
    path = entry / name
    if what == "truncate":
        data = path.read_bytes()
        path.write_bytes(data[: len(data) // 2])
    else:
        path.write_text("{not json")
    with pytest.warns(UserWarning, match="corrupted"):
        again, hit = cached_solve(scene, cache=tmp_path)
    assert not hit
    np.testing.assert_array_equal(again.displacement, first.displacement)
    _, hit = cached_solve(scene, cache=tmp_path)
    assert hit  # the entry was written anew, valid


def _row(store_root: Path, key: str) -> Path:
    path = store_root / "case=c" / "method=m" / f"{key}.parquet"
    path.parent.mkdir(parents=True)
    pq.write_table(pa.table({"unit_key": [key], "options": ["{}"]}), path)
    return path


def test_a_truncated_sweep_unit_file_is_not_finished_and_is_recomputed(tmp_path):
    store = ResultsStore(tmp_path)
    path = _row(tmp_path, "k1")
    assert set(store.finished()) == {"k1"}
    unit = SimpleNamespace(key="k1", identity=("c", "m", "{}"), case={"id": "c"}, label="m")
    pending, skipped, _ = _plan([unit], store, True, lambda *_: None)
    assert skipped == [unit] and pending == []
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert store.finished() == {}
    pending, skipped, _ = _plan([unit], store, True, lambda *_: None)
    assert pending == [unit] and skipped == []


def test_a_unit_file_of_another_unit_is_not_taken_for_it(tmp_path):
    path = _row(tmp_path, "k1")
    path.rename(path.with_name("k2.parquet"))  # a file renamed by hand: its row names k1
    assert ResultsStore(tmp_path).finished() == {}

