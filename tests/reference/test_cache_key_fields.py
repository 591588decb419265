"""Every field that makes two references differ changes the reference cache's key, and nothing
else does (issue 41): a property test over scene, variant, resolution, parameters, material,
analysis, mesh, backend, solver settings, package versions and code.

Two references may share an entry only when every field is equal; a field dropped from
:func:`tissuebench.reference.cache.reference_key` would let two different references share one.
And the entry behind a key reads back as the reference that was solved, field by field.
"""
from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
import shutil
import subprocess
from functools import lru_cache
from pathlib import Path
from unittest import mock

import numpy as np
import pandas as pd
import pytest

from hypothesis import given, settings, strategies as st

import tissuebench
from tissuebench.cases.scene import load
from tissuebench.reference import cache, provenance
from tissuebench.reference.cache import cached_solve, cached_table, list_entries, reference_key

SCENES = [("cube_tension_twist", "tension"), ("cube_tension_twist", "twist"), ("frame_2dof", None),
          ("heat1d_source", None)]
FIELDS = {
    "scene": st.sampled_from(range(len(SCENES))),
    "resolution": st.sampled_from(["ci", "paper"]),
    "backend": st.sampled_from(["skfem", "ngsolve"]),
    "linear_solver": st.sampled_from(["auto", "direct", "cholesky", "amg-cg"]),
    "material_scale": st.sampled_from([1.0, 1.5]),
    "load_steps": st.sampled_from([0, 1]),
    "mu": st.sampled_from([None, 0.5, 0.75]),
    "divisions": st.sampled_from([None, 4]),
    "numpy": st.sampled_from(["2.0.0", "2.0.1"]),
    "scikit-fem": st.sampled_from(["10.0.0", "11.0.0"]),
    "matplotlib": st.sampled_from(["3.9.0", "3.10.0"]),  # not a dependency of a reference: no effect
    "code": st.sampled_from(["a" * 64, "b" * 64]),
}
configs = st.fixed_dictionaries(FIELDS)


@lru_cache(maxsize=None)
def _scene(index, resolution):
    name, variant = SCENES[index]
    return load(name, resolution=resolution, variant=variant)


def _build(cfg):
    """The scene and the arguments of one configuration (``None`` where a field does not apply)."""
    scene = _scene(cfg["scene"], cfg["resolution"])
    if scene.material is not None and cfg["material_scale"] != 1.0:
        scene = dataclasses.replace(scene, material={k: v * cfg["material_scale"] if isinstance(v, float) else v
                                                     for k, v in scene.material.items()})
    if cfg["load_steps"] and "load_steps" in scene.analysis:
        scene = dataclasses.replace(scene, analysis={**scene.analysis,
                                                     "load_steps": scene.analysis["load_steps"] + cfg["load_steps"]})
    if cfg["mu"] is not None:
        scene = scene.at({"load_scale": cfg["mu"]})
    if cfg["divisions"] and scene.is_fe:
        scene = scene.with_mesh({"divisions": [cfg["divisions"], 2, 2]})
    return scene


def _key(cfg):
    versions = {"numpy": cfg["numpy"], "scipy": "1.0", "ngsolve": "6.2", "scikit-fem": cfg["scikit-fem"],
                "pyamg": "5.0", "matplotlib": cfg["matplotlib"]}
    calls = []

    def code_hash(*subpackages):
        calls.append(subpackages)
        return cfg["code"]

    with mock.patch.object(cache, "package_versions", lambda: versions), \
            mock.patch.object(cache, "code_hash", code_hash):
        key = cache.reference_key(_build(cfg), cfg["backend"], cfg["linear_solver"])
    assert calls == [("refsolvers", "cases", "reference")]  # the code that computes a reference, all of it
    return key


def _relevant(cfg):
    """What determines the reference: a line model has no backend, mesh or material of a solid."""
    scene = _build(cfg)
    return (scene.content_hash(), cfg["backend"] if scene.is_fe else "line", cfg["linear_solver"], cfg["numpy"],
            cfg["scikit-fem"], cfg["code"])


@settings(max_examples=150, deadline=None, derandomize=True)
@given(configs, configs)
def test_two_references_share_a_key_only_when_every_field_is_equal(a, b):
    assert (_key(a) == _key(b)) == (_relevant(a) == _relevant(b))


@settings(max_examples=40, deadline=None, derandomize=True)
@given(configs, st.sampled_from(sorted(set(FIELDS) - {"matplotlib"})))
def test_each_field_alone_changes_the_key_of_a_solid(cfg, field):
    cfg = {**cfg, "scene": 0}
    other = {**cfg, field: _other_value(field, cfg[field])}
    assert _key(cfg) != _key(other), field


def _other_value(field, value):
    domain = {"scene": [0, 1], "resolution": ["ci", "paper"], "backend": ["skfem", "ngsolve"],
              "linear_solver": ["auto", "direct"], "material_scale": [1.0, 1.5], "load_steps": [0, 1],
              "mu": [None, 0.5], "divisions": [None, 4], "numpy": ["2.0.0", "2.0.1"],
              "scikit-fem": ["10.0.0", "11.0.0"], "code": ["a" * 64, "b" * 64]}[field]
    return domain[1] if value == domain[0] else domain[0]


def test_the_key_is_a_sha256_of_the_documented_content():
    cfg = {"scene": 0, "resolution": "ci", "backend": "ngsolve", "linear_solver": "amg-cg", "material_scale": 1.0,
           "load_steps": 0, "mu": None, "divisions": None, "numpy": "2.0.0", "scikit-fem": "10.0.0",
           "matplotlib": "3.9.0", "code": "c" * 64}
    key = _key(cfg)
    assert len(key) == 64 and int(key, 16) >= 0
    assert _key(cfg) == key  # deterministic
    line = {**cfg, "scene": 2}
    assert _key(line) == _key({**line, "backend": "skfem"})  # a line model is not solved by a backend


# ---------------------------------------------------------------- provenance
def test_code_hash_is_over_the_sources_and_tomls_of_the_named_subpackages():
    root = Path(tissuebench.__file__).resolve().parent

    def expected(*subs):
        h = hashlib.sha256()
        for d in [root / s for s in subs] or [root]:
            for f in sorted(d.rglob("*")):
                if f.suffix in (".py", ".toml") and "__pycache__" not in f.parts:
                    h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes())
        return h.hexdigest()

    assert provenance.code_hash("reference") == expected("reference")
    assert provenance.code_hash("cases", "reference") == expected("cases", "reference")
    assert provenance.code_hash("cases") != provenance.code_hash("reference")
    assert provenance.code_hash.__wrapped__() == expected()


def test_package_versions_name_each_dependency_and_none_when_absent():
    real = importlib.metadata.version

    def version(pkg):
        if pkg == "pyamg":
            raise importlib.metadata.PackageNotFoundError(pkg)
        return real(pkg) if pkg != "numpy" else "9.9.9"

    with mock.patch.object(importlib.metadata, "version", version):
        got = provenance.package_versions.__wrapped__()
    assert list(got) == list(provenance._PACKAGES) and got["pyamg"] is None and got["numpy"] == "9.9.9"
    assert {"tissuebench", "numpy", "scipy", "ngsolve", "scikit-fem", "pyamg"} <= set(got)


def test_git_commit_inside_and_outside_a_repository():
    def run(args, cwd, **kw):
        assert args == ["git", "rev-parse", "HEAD"] and Path(cwd) == Path(tissuebench.__file__).resolve().parents[1]
        return subprocess.CompletedProcess(args, 0, stdout=" abc123\n", stderr="")

    with mock.patch.object(subprocess, "run", run):
        assert provenance.git_commit.__wrapped__() == "abc123"
    with mock.patch.object(subprocess, "run", lambda *a, **k: subprocess.CompletedProcess(a, 128, "", "no repo")):
        assert provenance.git_commit.__wrapped__() == "unknown"
    for exc in (OSError("no git"), subprocess.TimeoutExpired("git", 5)):
        with mock.patch.object(subprocess, "run", mock.Mock(side_effect=exc)):
            assert provenance.git_commit.__wrapped__() == "unknown"


# ---------------------------------------------------------------- the entry read back
@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    scene = load("frame_2dof").at({"load_scale": 0.5})
    first, hit = cached_solve(scene, cache=cache)
    assert hit is False
    again, hit = cached_solve(scene, cache=cache)
    assert hit is True
    return cache, scene, first, again


def test_every_field_reads_back_as_solved(solved):
    _, _, first, again = solved
    for f in dataclasses.fields(first):
        a, b = getattr(first, f.name), getattr(again, f.name)
        if f.name == "table":
            pd.testing.assert_frame_equal(b, a)
        elif isinstance(a, np.ndarray):
            assert b.dtype == a.dtype and b.shape == a.shape, f.name
            np.testing.assert_array_equal(b, a, err_msg=f.name)
        elif f.name == "plan":
            assert b == a and all(isinstance(r, tuple) for r in b.reasons), f.name
        elif f.name == "info":
            assert b == json.loads(json.dumps(a, default=str)), f.name
        else:
            assert b == a, f.name
    assert again.velocity is not None and again.problem is None  # a line model: no FE problem
    assert again.case == "frame_2dof" and again.components == first.components and again.wall_s == first.wall_s


def test_cached_table_is_the_table_and_none_without_an_entry(solved, tmp_path):
    cache, scene, first, _ = solved
    pd.testing.assert_frame_equal(cached_table(scene, cache=cache), first.table)
    assert cached_table(scene, cache=tmp_path) is None
    assert cached_table(scene, backend="skfem", linear_solver="direct", cache=cache) is None  # another key


def test_cached_table_of_a_damaged_table_is_none(solved, tmp_path):
    cache, scene, _, _ = solved
    copy = tmp_path / "c"
    shutil.copytree(cache, copy)
    entry = copy / "references" / reference_key(scene)
    (entry / "table.parquet").write_bytes(b"x" * (entry / "table.parquet").stat().st_size)
    assert cached_table(scene, cache=copy) is None


def test_cache_ls_row_by_hand(solved):
    cache, scene, first, _ = solved
    row = list_entries(cache).iloc[0]
    entry = cache / "references" / reference_key(scene)
    assert row["key"] == reference_key(scene)[:16] and row["case"] == "frame_2dof"
    assert row["variant"] == first.variant and row["resolution"] == "ci" and row["status"] == first.status
    assert row["backend"] == first.backend and json.loads(row["mu"]) == {"load_scale": 0.5}
    assert row["wall_s"] == first.wall_s and bool(row["valid"]) is True
    assert row["bytes"] == sum(f.stat().st_size for f in entry.iterdir())


def test_the_progress_bar_names_the_reference_being_computed(monkeypatch):
    calls = []
    monkeypatch.setattr(cache, "progress_bar", lambda *a, **k: calls.append((a, k)) or "bar")
    line = load("frame_2dof").at({"load_scale": 0.5})
    assert cache._reference_bar(line, "skfem") == "bar"
    solid = load("cube_tension_twist", variant="twist").at({"load_scale": 2})
    cache._reference_bar(solid, "ngsolve")
    plain = load("cube_tension_twist", variant="twist")
    cache._reference_bar(dataclasses.replace(plain, variant=None), "skfem")
    assert calls == [
        (("reference frame_2dof (load_scale=0.5) line", line.analysis["type"],
          line.units.get("time", "s")), {"leave": False}),
        (("reference cube_tension_twist [twist] (load_scale=2) ngsolve", "static", "s"), {"leave": False}),
        (("reference cube_tension_twist skfem", "static", "s"), {"leave": False})]
    cache._reference_bar(load("cube_tension_twist").at({"load_scale": 1 / 3}), "skfem")
    assert calls[-1][0][0] == "reference cube_tension_twist [tension] (load_scale=0.3333) skfem"


def test_the_key_ignores_the_order_of_a_table_and_the_type_of_a_number():
    cfg = {"scene": 0, "resolution": "ci", "backend": "skfem", "linear_solver": "auto", "material_scale": 1.0,
           "load_steps": 0, "mu": None, "divisions": None, "numpy": "2.0.0", "scikit-fem": "10.0.0",
           "matplotlib": "3.9.0", "code": "c" * 64}
    scene = _scene(0, "ci")
    reordered = dataclasses.replace(scene, material=dict(reversed(list(scene.material.items()))))
    with mock.patch.object(cache, "code_hash", lambda *a: "c" * 64):
        assert cache.reference_key(reordered) == cache.reference_key(scene)
        # a parameter given as a numpy number: the same reference as the float
        assert cache.reference_key(scene.at({"load_scale": np.float64(0.5)})) == \
            cache.reference_key(scene.at({"load_scale": 0.5}))
        # the defaults are the solver's: scikit-fem, automatic linear solver
        assert cache.reference_key(scene) == cache.reference_key(scene, "skfem", "auto")
    assert _key(cfg) != _key({**cfg, "backend": "skfem", "linear_solver": "direct"})
