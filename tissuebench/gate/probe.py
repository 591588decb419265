"""One worker process of an A/B latency comparison (``tissuebench check --against REF``).

The orchestrator (:mod:`.latency`) copies this file into a scratch folder (as ``ab_probe.py``) and
runs it as a script, once per side and round, with the code under test first on ``PYTHONPATH``
(a git worktree of REF, or the working tree of HEAD). So the *timing loop* is always this
file's (HEAD's), the same for both sides, while the *models* are built by the side's own
code: a protocol change can never show up as a latency change (asv's split between its
runner and the benchmarked commit).

Usage: ``python ab_probe.py JOB.json``, spoken to in JSON lines on stdin/stdout.
``JOB.json``::

    {"units": [{"uid": "u0", "case": {...}, "method": "anm_pod", "options": {...},
                "steps": 300, "warmup": 30, "blas_threads": 1}, ...],
     "seed": 0, "inject": {"u0": 1.3} (optional, power tests only),
     "packages": ["tissuebench", "podreg"] (the project's packages)}

The worker first builds every unit through the side's code and answers
``{"ready": true, "tissuebench": PATH, "units": {uid: {"status", "message"}}, "modules": {name:
PATH}}`` (a unit whose build raises is reported with its message; the others go on; ``modules``:
the file of every module of ``packages`` it imported). Then each command
``{"time": uid}`` times one block of ``steps`` haptic steps (``step`` + ``outputs`` back to
back, each timed with ``time.perf_counter``) and answers ``{"uid", "status", "message",
"block": [s, ...], "copies": bool}``; ``{"cpus": [0]}`` pins every thread of the worker to
those cores (answers ``{"cpus": n}``, the threads pinned); ``{"quit": true}`` or the end of
stdin ends it. Every block runs on a fresh deep copy of the model where the model can be
copied (new allocations: the memory layout of a model's arrays moves a microsecond step by
up to 1.6x on these machines, so one layout per process is not a sample of the code's speed).

The worker waits, idle, between commands: the orchestrator times the two sides' blocks in
turn (:mod:`.latency`), so a slow spell of the machine falls on both sides of a pair.
Whatever the side's code prints goes to stderr; stdout carries the protocol only.

``inject`` (power tests of the gate only) makes the named units slower by a calibrated
factor: a busy wait of ``(factor - 1)`` times the unit's own median step, measured at its
first block (on the core the blocks are timed on), after every step.
"""
from __future__ import annotations

import copy
import json
import os
import sys
import time
import traceback

from threadpoolctl import threadpool_limits


def _prepare_legacy(case, method, options, steps, seed):
    """The unit as tissuebench 0.1 (before ``latency_ab.prepare_unit``) builds it for its
    latency pass (``studies.units._measure``): ``(model, sequence, start)``."""
    # lazy: this runs in the child interpreter of the A/B reference, importing whichever
    # tissuebench that interpreter has (another version's), not the one of this module
    from tissuebench.rom import make_method
    from tissuebench.studies.evaluation import NEEDS_MODEL, build_evaluation  # lazy: the side's (above)
    from tissuebench.studies.protocol import _start, _timing_sequence  # lazy: the side's (above)
    from tissuebench.studies.training import build_training, case_scene  # lazy: the side's (above)

    scene = case_scene(case)
    training = build_training(case, scene)
    needs_model = (case.get("evaluation") or {}).get("kind") in NEEDS_MODEL
    evaluation = None if needs_model else build_evaluation(case, scene)
    model = make_method(method, **options).build(training)
    if needs_model:
        evaluation = build_evaluation(case, scene, model)
    if training.outputs:
        model.attach_outputs(training.outputs)
    history = training.history or (scene.history if evaluation.kind == "trajectory" else None)
    seq = _timing_sequence(model, evaluation, history, steps, seed)
    return model, seq, (lambda m: _start(m, evaluation, seq)), evaluation.kind == "trajectory"


def prepare(unit, seed):
    """``(model, sequence, start(model), stop_on_failure)`` through the side's own code."""
    args = (unit["case"], unit["method"], unit["options"], int(unit["steps"]), seed)
    prepare_unit = _side_prepare_unit()
    if prepare_unit is None:  # code from before the A/B gate
        return _prepare_legacy(*args)
    p = prepare_unit(*args)
    return p.model, p.sequence, p.start, p.stop_on_failure


#: where a side's tissuebench keeps ``prepare_unit``, newest first: the gate's package (issue 55),
#: then ``studies/latency_ab.py`` (REF from before it)
PREPARE_UNIT_MODULES = (("gate", "latency"), ("studies", "latency_ab"))


def _side_prepare_unit():
    """The side's ``prepare_unit``, from the first module of :data:`PREPARE_UNIT_MODULES` that the
    side's own tissuebench folder holds, or None. Looked up on disk, not by trying the imports in
    turn: an editable install's import hook serves a module REF's folder lacks from HEAD's work
    tree (``tissuebench.gate`` to a REF of before it), which would time HEAD's code as REF's."""
    import importlib

    import tissuebench  # lazy: the child interpreter's tissuebench (see _prepare_legacy)

    root = os.path.dirname(tissuebench.__file__)
    for parts in PREPARE_UNIT_MODULES:
        if os.path.isfile(os.path.join(root, *parts[:-1], parts[-1] + ".py")):
            return importlib.import_module(".".join(("tissuebench", *parts))).prepare_unit
    return None


def _spin(seconds):
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def time_block(model, seq, start, stop_on_failure, steps, warmup, extra=0.0):
    """Per-step wall times [s] of ``steps`` haptic steps after ``warmup`` untimed ones."""
    clock = time.perf_counter
    start(model)
    for mu in seq[:warmup]:
        model.outputs(model.step(mu))
    out = []
    while len(out) < steps:
        start(model)
        for mu in seq:
            t0 = clock()
            res = model.step(mu)
            model.outputs(res)
            if extra:
                _spin(extra)
            out.append(clock() - t0)
            if len(out) >= steps or (stop_on_failure and res.status == "failed"):
                break
        if stop_on_failure and res.status == "failed":
            break
    return out


def _median(values):
    s = sorted(values)
    n = len(s)
    return 0.5 * (s[(n - 1) // 2] + s[n // 2]) if n else 0.0


class _Unit:
    """One built unit of this worker: its model and what a block of its steps needs."""

    def __init__(self, unit, seed, factor):
        self.threads = unit.get("blas_threads") or None
        self.steps, self.warmup = int(unit["steps"]), int(unit["warmup"])
        with threadpool_limits(limits=self.threads, user_api="blas"):
            self.model, self.seq, self.start, self.stop = prepare(unit, seed)
            if not self.seq:
                raise ValueError("the unit's evaluation gives no step to time")
        self.factor, self.extra = float(factor or 1.0), None

    def _block(self, model, extra):
        return time_block(model, self.seq, self.start, self.stop, self.steps, self.warmup, extra)

    def block(self):
        """``(per-step times [s], timed on a copy)``: one block on a fresh deep copy of the model."""
        try:
            m, copied = copy.deepcopy(self.model), True
        except Exception:  # factorisations and solver handles of some models cannot be copied
            m, copied = self.model, False
        with threadpool_limits(limits=self.threads, user_api="blas"):
            if self.extra is None:
                # the injected slowdown (power tests) calibrated on the unit's own warm median, at the
                # first block: on the core the blocks are timed on, not the one the build ran on
                warm = min(_median(self._block(self.model, 0.0)) for _ in range(3)) if self.factor != 1.0 else 0.0
                self.extra = (self.factor - 1.0) * warm
            return self._block(m, self.extra), copied


def _failure(exc):
    msg = traceback.format_exception_only(type(exc), exc)[-1].strip()
    return {"status": "failed", "message": msg[:500]}


def serve(job, commands, reply):
    """Build every unit of ``job``, say so (``reply``), then answer ``commands`` (the protocol
    of the module docstring) until ``quit`` or their end."""
    ready, built = {"ready": True, "units": {}}, {}
    try:
        import tissuebench  # lazy: the child interpreter's tissuebench (see _prepare_legacy)
        ready["tissuebench"] = str(tissuebench.__file__)
    except Exception as exc:
        ready["error"] = f"cannot import tissuebench: {exc}"
    inject = job.get("inject") or {}
    for unit in job["units"]:
        try:
            built[unit["uid"]] = _Unit(unit, int(job.get("seed", 0)), inject.get(unit["uid"]))
            ready["units"][unit["uid"]] = {"status": "ok", "message": ""}
        except Exception as exc:  # one unit failing is data, the others go on
            ready["units"][unit["uid"]] = _failure(exc)
    # where every module of the project's packages came from: the orchestrator checks it is the side's code
    tops = set(job.get("packages") or ())
    ready["modules"] = {n: getattr(m, "__file__", None) for n, m in list(sys.modules.items())
                        if n.split(".")[0] in tops}
    reply(ready)
    for line in commands:
        cmd = json.loads(line)
        if cmd.get("quit"):
            break
        if "cpus" in cmd:
            reply({"cpus": _pin(cmd["cpus"])})
            continue
        uid = cmd["time"]
        try:
            times, copied = built[uid].block()
            reply({"uid": uid, "status": "ok", "message": "", "block": times, "copies": copied})
        except Exception as exc:  # a step that raises on a copy: the unit fails, the worker goes on
            reply({"uid": uid, **_failure(exc), "block": [], "copies": False})


def _pin(cpus):
    """Every thread of this process (BLAS's included) onto the cores ``cpus`` (Linux); the
    number of threads pinned (0 where the platform cannot)."""
    if not hasattr(os, "sched_setaffinity") or not os.path.isdir("/proc/self/task"):
        return 0
    n = 0
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(tid), set(cpus))
            n += 1
        except OSError:  # a thread that ended meanwhile
            pass
    return n


def main(argv):
    job = json.loads(open(argv[1]).read())
    # the protocol owns the original stdout; anything the side's code prints goes to stderr
    proto = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    sys.stdout = sys.stderr

    def reply(obj):
        proto.write(json.dumps(obj) + "\n")
        proto.flush()

    serve(job, sys.stdin, reply)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
