"""A/B latency in one run: the units of a sweep re-timed with REF's code and HEAD's code.

``tissuebench check RESULTS --against REF`` uses this instead of comparing latency ratios
across runs (microsecond medians move 2-3x between identical runs on a shared machine:
no tolerance survives that, a measurement design does). asv's ``continuous`` and pyperf's
worker processes are the models:

* REF's packages of the project under test are exported from git (:mod:`.project`) into
  a scratch folder; HEAD is the code this process runs (the working tree, uncommitted changes
  included). Both use the same installed dependencies; each worker reports where it imported
  the project's packages from, and a unit whose package came from the other side's copy (an
  import hook, a package REF lacks) is not timed there (:mod:`.sides`).
* Each round starts one worker process per side (:mod:`.probe`, always HEAD's timing
  loop); the two build every still-undecided unit with their side's code at the same time
  (no timing runs then). Then, unit by unit, their ``blocks`` blocks of haptic steps are
  timed *in turn*, A B then B A (asv's ``--interleave-rounds`` carried down to blocks): one
  worker times while the other waits idle, each block on a fresh copy of the model (memory
  layout is part of the noise to sample: see :mod:`.probe`).
  Why in turn: the machine has slow spells of seconds to tens of seconds (1.4-2.4x on a
  microsecond step, then back). Timed one whole process per side after the other, a spell
  fell on one side only: CI flagged identical code (d8efd16 against its parent, which
  differ in a test file) as 1.47x slower, [1.214, 2.014], because HEAD's 3 processes of
  one unit all met a spell. Identical code timed that way here (``check --against HEAD
  --ab-rounds 8,8``, 16 processes): 39 of 40 units had a process 1.3-2.4x above the unit's
  median, in 116 of the 400 unit-processes of rounds 1-5 and 13 of the 240 of rounds 6-8.
  A block lasts milliseconds to a second, so a spell covers both blocks of a pair.
* For the timing both workers of a round are pinned, every thread, to the *same* core
  (the next core the next round; as many cores as the protocol's ``blas_threads`` ask). On
  this 2-core machine the core a process ran on moved a step 1.3-1.8x for the whole
  process, in either direction: timed in turn, each on the core the scheduler gave it, the
  two sides of one round still differed by more than 1.2x in 73 of 320 unit-rounds of
  identical code (per-round HEAD/REF spread, sd of the log ratio 0.169). Pinned: 8 of 320,
  sd 0.023, worst 1.34 (was 1.8); all 40 units decided in 8 rounds (32 before). Both
  measured with ``check --against HEAD --ab-rounds 8,8`` on the ci preset.
* After ``min_rounds`` rounds, every unit whose confidence interval of the HEAD/REF
  median ratio lies clear of the decision threshold is decided (:mod:`.stats`) and
  leaves the later rounds; the rest run until ``max_rounds`` or the time budget, which
  is looked at only from ``min_rounds`` on (the interval needs rounds to resample).

Every per-step sample is kept (:func:`run_ab` returns them; the gate writes them to
``RESULTS/_gate/ab_samples.parquet``).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import pandas as pd

from ..rom import make_method
from ..rom.plugins import PLUGINS
from ..studies.case_entry import CaseEntry
from ..studies.evaluation import NEEDS_MODEL, build_evaluation
from ..studies.protocol import _start, _timing_sequence
from ..studies.spec import expand_units, load_spec
from ..studies.training import build_training, case_scene
from .ref import portable_spec_text
from .scratch import child_options
from .sides import Code, as_code, code_env, foreign

__all__ = ["PreparedUnit", "prepare_unit", "ABUnit", "ab_units", "run_ab", "SAMPLE_COLUMNS"]

SAMPLE_COLUMNS = ["uid", "side", "round", "block", "sample", "haptic_s"]


@dataclass
class PreparedUnit:
    """A built model and the haptic sequence the protocol times it on (:mod:`.protocol`)."""

    model: object
    sequence: list
    start: object  # start(model): restart ``model`` at the beginning of ``sequence``
    stop_on_failure: bool  # a trajectory cannot go on past a failed step


def prepare_unit(case: CaseEntry | dict, method: str, options: dict, steps: int, seed: int = 0) -> PreparedUnit:
    """Build the unit's model and its timing sequence as the sweep does (:func:`.units.run_unit`).

    The stable entry point the A/B probe calls into the code under test: keep its signature
    (the probe falls back to the 0.1 internals for code from before it). ``case``: the entry or
    its dict form (:meth:`~.case_entry.CaseEntry.as_dict`: what the probe's JSON job carries)."""
    case = case if isinstance(case, CaseEntry) else CaseEntry.from_dict(case)
    scene = case_scene(case)
    training = build_training(case, scene)
    needs_model = case.evaluation_kind in NEEDS_MODEL
    evaluation = None if needs_model else build_evaluation(case, scene)
    model = make_method(method, **options).build(training)
    if needs_model:
        evaluation = build_evaluation(case, scene, model)
    if training.outputs:
        model.attach_outputs(training.outputs)
    history = training.history or (scene.history if evaluation.kind == "trajectory" else None)
    seq = _timing_sequence(model, evaluation, history, steps, seed)
    return PreparedUnit(model, seq, lambda m: _start(m, evaluation, seq), evaluation.kind == "trajectory")


@dataclass(frozen=True)
class ABUnit:
    """One unit to re-time: its identity in the store and what the probe needs to build it."""

    uid: str
    case: dict  # the entry's dict form (CaseEntry.as_dict): the probe hands it to either side's code
    method: str  # a registry name, or "module:Class" of a method from another package
    options: dict
    steps: int
    warmup: int
    blas_threads: int
    package: str = "tissuebench"  # the top-level package of the method's class


def _method_of(name: str, source: str) -> tuple[str, str]:
    """``(what a worker builds, its top-level package)`` of a unit's method: a plugin loaded by
    its entry point goes by its name, which each side's registry resolves through its own
    entry points (the class may have moved between the two versions); one named by
    "module:Class" by that; a shipped method by its name."""
    if not source:
        return name, "tissuebench"
    plugin = PLUGINS.get(name)
    by_name = plugin is not None and plugin.how == "entry point" and plugin.source == source
    return (name if by_name else source), source.split(":")[0].split(".")[0]


def ab_units(results_dir, rows: pd.DataFrame, workdir=None) -> list[ABUnit]:
    """The :class:`ABUnit` of every row of ``rows`` (units of the store in ``results_dir``):
    the case entries and protocols come from the sweep's own spec (``_sweep.json``), expanded
    again (loaded from a scratch folder under ``workdir``, its scene files by absolute path:
    :func:`.ref.portable_spec_text`); ``uid`` is the stored ``unit_key``."""
    manifest = json.loads((Path(results_dir) / "_sweep.json").read_text())
    with tempfile.TemporaryDirectory(prefix="tissuebench-spec.", dir=workdir) as tmp:
        path = Path(tmp) / f"{manifest.get('spec_name', 'sweep')}.toml"
        path.write_text(portable_spec_text(manifest))
        spec = load_spec(path, resolution=manifest.get("resolution"))
    by_identity = {u.identity: u for u in expand_units(spec)}
    out = []
    for _, row in rows.iterrows():
        u = by_identity.get((row["case"], row["method"], row["options"]))
        if u is None:
            raise ValueError(f"{results_dir}: unit {row['case']} {row['label']} is not in the sweep's spec "
                             f"(_sweep.json spec_text): the store and its spec disagree")
        p = u.protocol
        method, package = _method_of(u.method, u.source)
        out.append(ABUnit(row["unit_key"], u.case.as_dict(), method, u.options, int(p["latency_steps"]),
                          int(p["warmup"]), int(p.get("blas_threads") or 0), package))
    return out


class _Worker:
    """One side's worker process of a round (:mod:`.probe`), the side's code (:class:`~.sides.Code`)
    first on its path."""

    def __init__(self, side: str, code: Code, units: list[ABUnit], seed: int, scratch: Path, rnd: int,
                 inject: dict | None):
        self.side, self.code, tag = side, code, f"{side}{rnd}"
        self.name = f"A/B {side} worker of round {rnd + 1}"
        self.elsewhere: dict = {}  # package -> why this worker's copy of it is not the side's code
        job, self.err_path = scratch / f"{tag}.job.json", scratch / f"{tag}.stderr.txt"
        job.write_text(json.dumps({"units": [asdict(u) for u in units], "seed": seed, "inject": inject or {},
                                   "packages": sorted(code.packages)}, default=str))
        self._err = open(self.err_path, "w")  # a file, not a pipe: a chatty side cannot block on it
        self.proc = subprocess.Popen([sys.executable, str(scratch / "ab_probe.py"), str(job)], env=code_env(code),
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._err, text=True,
                                     **child_options())

    def _read(self) -> dict:
        line = self.proc.stdout.readline()
        if not line:
            self.proc.wait()
            tail = self.err_path.read_text(errors="replace").strip().splitlines()[-3:]
            raise RuntimeError(f"{self.name} exited {self.proc.returncode}: {' | '.join(tail)}")
        return json.loads(line)

    def ready(self) -> dict:
        """The worker's build report, once every unit is built; checked to run the side's code:
        RuntimeError when its tissuebench is another's; the packages of the project it imported
        from elsewhere are kept in ``elsewhere`` (their units cannot be timed on this side)."""
        out = self._read()
        loaded = out.get("tissuebench")
        files = {**(out.get("modules") or {}), "tissuebench": loaded}
        self.elsewhere = foreign(files, self.code) if loaded else {}
        if out.get("error") or not loaded or "tissuebench" in self.elsewhere:
            raise RuntimeError(f"{self.name}: {out.get('error') or ''} imported tissuebench from {loaded}, "
                               f"not {self.code.folder('tissuebench')}")
        return out

    def pin(self, cores: list[int]) -> None:
        """Every thread of the worker onto ``cores``."""
        self.proc.stdin.write(json.dumps({"cpus": cores}) + "\n")
        self.proc.stdin.flush()
        self._read()

    def time(self, uid: str) -> dict:
        """One block of the unit's steps (the worker's answer)."""
        self.proc.stdin.write(json.dumps({"time": uid}) + "\n")
        self.proc.stdin.flush()
        return self._read()

    def close(self) -> None:
        try:
            if self.proc.poll() is None:
                self.proc.stdin.write(json.dumps({"quit": True}) + "\n")
                self.proc.stdin.close()
            self.proc.wait(timeout=60)
        except (OSError, subprocess.TimeoutExpired):
            self.proc.kill()
            self.proc.wait()
        finally:
            self._err.close()


def _cores(active: list[ABUnit], rnd: int) -> list[int]:
    """The cores both workers of round ``rnd`` time on: as many as the units' BLAS threads ask
    (0, no limit: every core), the first of them moving by one core each round; [] where the
    platform cannot pin."""
    if not hasattr(os, "sched_getaffinity"):
        return []
    cpus = sorted(os.sched_getaffinity(0))
    want = max((u.blas_threads for u in active), default=1)
    k = len(cpus) if want <= 0 else min(want, len(cpus))
    return [cpus[(rnd + i) % len(cpus)] for i in range(k)]


def _round(workers: dict, active: list[ABUnit], blocks: int, rnd: int, failures: dict) -> pd.DataFrame:
    """Both workers built (concurrently) and pinned to the same core(s); then per unit its blocks in
    turn, A B then B A, each worker idle while the other times (module docstring)."""
    rows = {c: [] for c in SAMPLE_COLUMNS}
    for side, w in workers.items():
        for uid, res in w.ready()["units"].items():
            if res["status"] != "ok":
                failures.setdefault(uid, {})[side] = res.get("message", "")
        for u in active:
            if u.package in w.elsewhere:
                failures.setdefault(u.uid, {})[side] = f"not the {side} side's code: {w.elsewhere[u.package]}"
    cores = _cores(active, rnd)
    for w in workers.values():
        if cores:
            w.pin(cores)
    for u in active:
        for b in range(blocks):
            if u.uid in failures:
                break
            for side in (("ref", "head") if (rnd + b) % 2 == 0 else ("head", "ref")):
                res = workers[side].time(u.uid)
                if res["status"] != "ok":
                    failures.setdefault(u.uid, {})[side] = res.get("message", "")
                    break
                n = len(res["block"])
                rows["uid"] += [u.uid] * n
                rows["side"] += [side] * n
                rows["round"] += [rnd] * n
                rows["block"] += [b] * n
                rows["sample"] += list(range(n))
                rows["haptic_s"] += [float(x) for x in res["block"]]
    return pd.DataFrame(rows, columns=SAMPLE_COLUMNS)


def run_ab(units: list[ABUnit], ref_root: Code | Path, head_root: Code | Path, decide, min_rounds: int = 3,
           max_rounds: int = 8, blocks: int = 3, budget_s: float = 900.0, seed: int = 0,
           inject: dict | None = None, log=print, workdir=None) -> tuple[pd.DataFrame, dict]:
    """Rounds of one REF (side ``"ref"``) and one HEAD (``"head"``) worker process, their blocks
    timed in turn (module docstring). ``ref_root``, ``head_root``: each side's code
    (:class:`~.sides.Code`, or a folder holding that side's tissuebench package); a unit whose
    method's package a side's worker imported from elsewhere than that side's code fails there.

    ``decide(samples) -> set of decided uids`` is called after each round from ``min_rounds``
    on. ``min_rounds`` rounds always run: the time budget ``budget_s`` [s] ends the A/B only
    after them (the interval resamples rounds, worker processes: one round has no spread
    between processes to resample, and with one block it is a single number per side).
    ``inject`` maps uids to a slowdown factor applied on the HEAD side (power tests).
    ``workdir``: the folder the worker's scratch files go in (default: the temporary folder).
    Returns ``(samples, failures)``: the per-step samples (:data:`SAMPLE_COLUMNS`) and, per
    uid, ``{side: message}`` for units that failed on a side."""
    if min_rounds < 2 or max_rounds < min_rounds or blocks < 1:
        raise ValueError(f"A/B rounds: need 2 <= min_rounds ({min_rounds}) <= max_rounds ({max_rounds}), "
                         f"blocks ({blocks}) >= 1")
    roots = {"ref": as_code(ref_root), "head": as_code(head_root)}
    frames, failures, active = [], {}, list(units)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tissuebench-ab.", dir=workdir) as tmp:
        scratch = Path(tmp)
        shutil.copy(Path(__file__).with_name("probe.py"), scratch / "ab_probe.py")
        for r in range(max_rounds):
            ts = time.perf_counter()
            workers = {side: _Worker(side, roots[side], active, seed + r, scratch, r,
                                     inject if side == "head" else None) for side in ("ref", "head")}
            try:
                frames.append(_round(workers, active, blocks, r, failures))
            finally:
                for w in workers.values():
                    w.close()
            samples = pd.concat(frames, ignore_index=True)
            decided = decide(samples) if r + 1 >= min_rounds else set()
            active = [u for u in active if u.uid not in decided and u.uid not in failures]
            log(f"A/B round {r + 1}/{max_rounds}: {time.perf_counter() - ts:.0f} s; "
                f"{len(units) - len(active)} of {len(units)} units decided")
            if not active or (r + 1 >= min_rounds and time.perf_counter() - t0 > budget_s):
                break
    return samples, failures


