"""The A/B's worker processes (:func:`tissuebench.gate.latency.run_ab` and
:mod:`tissuebench.gate.probe`), run on two stand-in packages whose step is a busy wait:
the sides' blocks are timed in turn on one pinned core, a slower side is measured as such,
and a unit or a worker that fails is reported, not lost."""
from __future__ import annotations

import os
import textwrap

import pytest

from tissuebench.gate.latency import ABUnit, run_ab

FAKE = '''
import copy, os, sys, time

SIDE, COST = {side!r}, {cost!r}


class _Res:
    status = "ok"


class Model:
    def __init__(self, case, uid):
        self.case, self.uid = case, uid

    def step(self, mu):
        if SIDE in self.case.get("die", ()):
            print("dying on purpose", file=sys.stderr, flush=True)
            os._exit(3)
        end = time.perf_counter() + COST
        while time.perf_counter() < end:
            pass
        return _Res()

    def outputs(self, res):
        return {{}}

    def __deepcopy__(self, memo):  # one per timed block: the log of who timed when, and where
        with open(self.case["log"], "a") as fh:
            fh.write(f"{{SIDE}} {{self.uid}} {{sorted(os.sched_getaffinity(0))}}\\n")
        return Model(self.case, self.uid)


class PreparedUnit:
    def __init__(self, model, sequence):
        self.model, self.sequence, self.stop_on_failure = model, sequence, False
        self.start = lambda m: None


def prepare_unit(case, method, options, steps, seed):
    print("the side's code prints while it builds", flush=True)  # must not break the protocol
    if SIDE in case.get("fail_build", ()):
        raise ValueError(f"{{SIDE}} cannot build {{method}}")
    return PreparedUnit(Model(case, method), [{{"x": 0.0}}] * 5)
'''


def _package(root, side, cost):
    pkg = root / "tissuebench" / "studies"
    pkg.mkdir(parents=True)
    (root / "tissuebench" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "latency_ab.py").write_text(textwrap.dedent(FAKE.format(side=side, cost=cost)))
    return root


@pytest.fixture
def sides(tmp_path):
    return _package(tmp_path / "ref", "ref", 100e-6), _package(tmp_path / "head", "head", 200e-6)


def _unit(name, log, **case):
    return ABUnit(name, {"log": str(log), **case}, name, {}, steps=30, warmup=3, blas_threads=1)


def test_blocks_are_timed_in_turn_on_one_pinned_core_and_the_slower_side_shows(sides, tmp_path):
    log = tmp_path / "blocks.log"
    units = [_unit("a", log), _unit("b", log)]
    samples, failures = run_ab(units, *sides, decide=lambda s: set(), min_rounds=2, max_rounds=2, blocks=3,
                               log=lambda m: None)
    assert failures == {}
    assert len(samples) == 2 * 2 * 2 * 3 * 30  # units x sides x rounds x blocks x steps
    level = samples.groupby("side")["haptic_s"].median()
    assert 1.6 < level["head"] / level["ref"] < 2.5, level
    lines = [ln.split(" ", 2) for ln in log.read_text().splitlines()]
    # per round, per unit: blocks A B, B A, A B; the next round starts with the other side
    order = [side for side, _, _ in lines]
    abbaab = ["ref", "head", "head", "ref", "ref", "head"]
    assert order == abbaab * 2 + abbaab[::-1] * 2
    assert [uid for _, uid, _ in lines] == ["a"] * 6 + ["b"] * 6 + ["a"] * 6 + ["b"] * 6
    cpus = sorted(os.sched_getaffinity(0))
    first, second = {c for _, _, c in lines[:12]}, {c for _, _, c in lines[12:]}
    assert first == {str([cpus[0]])} and second == {str([cpus[1 % len(cpus)]])}


def test_a_unit_one_side_cannot_build_is_a_failure_and_the_others_go_on(sides, tmp_path):
    log = tmp_path / "blocks.log"
    units = [_unit("a", log, fail_build=["ref"]), _unit("b", log)]
    samples, failures = run_ab(units, *sides, decide=lambda s: set(), min_rounds=2, max_rounds=2, blocks=2,
                               log=lambda m: None)
    assert failures == {"a": {"ref": "ValueError: ref cannot build a"}}
    assert set(samples["uid"]) == {"b"} and set(samples["side"]) == {"ref", "head"}


def test_a_worker_that_dies_fails_the_a_b_naming_its_side_code_and_last_words(sides, tmp_path):
    units = [_unit("a", tmp_path / "blocks.log", die=["head"])]
    with pytest.raises(RuntimeError, match=r"A/B head worker of round 1 exited 3: .*dying on purpose"):
        run_ab(units, *sides, decide=lambda s: set(), min_rounds=2, max_rounds=2, blocks=1, log=lambda m: None)


def test_the_budget_never_cuts_the_a_b_below_min_rounds(sides, tmp_path):
    """``check --ab-budget 5 --ab-blocks 1`` stopped after round 1 (the budget was spent while the
    first workers built): one block median per side, printed as an interval [x, x], and a plot
    that crashed the check. The budget is looked at from round ``min_rounds`` on."""
    log = tmp_path / "blocks.log"
    samples, failures = run_ab([_unit("a", log)], *sides, decide=lambda s: set(), min_rounds=2, max_rounds=4,
                               blocks=1, budget_s=1e-9, log=lambda m: None, workdir=tmp_path)
    assert failures == {} and sorted(samples["round"].unique()) == [0, 1]  # 2 rounds: not 1, not 4
    assert not list(tmp_path.glob("tissuebench-ab.*"))  # its scratch folder, under workdir, removed
