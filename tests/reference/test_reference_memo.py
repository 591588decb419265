"""The reference layer's one in-process memo (``tissuebench.reference.memo``, issue 29: one
cache object instead of five module dictionaries): bounded per purpose, oldest first out, a
failed computation keeps nothing, and the layer's users share it."""
from __future__ import annotations

import pytest

from tissuebench.cases.scene import load
from tissuebench.reference import MEMO, cached_dynamics_system, reference_step_seconds, solve
from tissuebench.reference.memo import Memo


def test_a_bounded_purpose_keeps_its_newest_entries_and_computes_once():
    memo, calls = Memo({"two": 2, "all": None}), []

    def compute(k):
        calls.append(k)
        return k * 10
    assert [memo.get("two", k, lambda k=k: compute(k)) for k in (1, 2, 1, 3)] == [10, 20, 10, 30]
    assert calls == [1, 2, 3]  # 1 asked twice, computed once
    assert ("two", 1) not in memo and ("two", 2) in memo and ("two", 3) in memo  # the oldest inserted went
    for k in range(5):
        memo.get("all", k, lambda k=k: k)
    assert memo.sizes() == {"two": 2, "all": 5}
    memo.clear("two")
    assert memo.sizes() == {"two": 0, "all": 5}
    memo.clear()
    assert memo.sizes() == {"two": 0, "all": 0}


def test_a_failed_computation_keeps_nothing_and_bad_purposes_are_named():
    memo = Memo({"x": 1})

    def boom():
        raise RuntimeError("solver failed")
    with pytest.raises(RuntimeError):
        memo.get("x", "k", boom)
    assert ("x", "k") not in memo and memo.get("x", "k", lambda: 1) == 1
    with pytest.raises(ValueError, match="purpose = 'y'"):
        memo.get("y", "k", lambda: 1)
    with pytest.raises(ValueError, match="bound of 'z' = 0"):
        Memo({"z": 0})


def test_the_layer_memo_holds_the_reference_step_and_the_last_two_systems():
    MEMO.clear()
    scene = load("frame_2dof")
    ref = solve(scene)
    first = reference_step_seconds(ref, scene, "skfem", 3)
    assert first > 0 and reference_step_seconds(ref, scene, "skfem", 3) == first  # measured once per process
    assert MEMO.sizes()["reference_step"] == 1
    systems = [cached_dynamics_system(scene.at({"load_scale": s}) if s else scene) for s in (0, 2.0, 3.0)]
    assert systems[0] is not systems[1] and cached_dynamics_system(scene.at({"load_scale": 3.0})) is systems[2]
    assert MEMO.sizes()["dynamics_system"] == 2  # the last two scenes' systems, the first dropped
    MEMO.clear()
    assert not any(MEMO.sizes().values())
