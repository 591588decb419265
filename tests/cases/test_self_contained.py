"""The project stands alone: what runs and tests need ships inside the package.

CI (``.ci/run``) runs the tests selected by ``-k "liver or data_dir or self_contained"``
a second time from a copy of the clone in an empty temporary folder, with
``TISSUEBENCH_EXPECT_ROOT`` naming that copy.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

import tissuebench
from tissuebench.cases import load
from tissuebench.cases.io import DATA_ENV

ROOT = Path(__file__).resolve().parents[2]


def test_self_contained_package_is_the_one_under_test():
    expected = os.environ.get("TISSUEBENCH_EXPECT_ROOT")
    if expected is None:
        pytest.skip("not the standalone CI pass (TISSUEBENCH_EXPECT_ROOT unset): nothing to compare")
    assert Path(tissuebench.__file__).resolve().is_relative_to(Path(expected).resolve())
    assert not (Path(expected).resolve().parent / "shared").exists()


def test_self_contained_no_source_reads_outside_the_clone():
    pattern = re.compile(r"\.\./shared|[\"']shared[\"']\s*/|parents\[\d\]\s*/\s*[\"']shared")
    offenders = [str(p.relative_to(ROOT)) for p in (ROOT / "tissuebench").rglob("*.py")
                 if pattern.search(p.read_text())]
    assert offenders == []


def test_self_contained_liver_scene_uses_the_shipped_mesh(monkeypatch):
    monkeypatch.delenv(DATA_ENV, raising=False)
    info = load("liver_palpation").mesh_info
    assert info["fallback"] is False
    assert Path(info["source"]).resolve().is_relative_to(Path(tissuebench.__file__).resolve().parent)
