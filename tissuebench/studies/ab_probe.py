"""One worker process of an A/B latency comparison (``tissuebench check --against REF``).

The orchestrator (:mod:`.latency_ab`) copies this file into a scratch folder and runs it
as a script, once per side and round, with the code under test first on ``PYTHONPATH``
(a git worktree of REF, or the working tree of HEAD). So the *timing loop* is always this
file's (HEAD's), the same for both sides, while the *models* are built by the side's own
code: a protocol change can never show up as a latency change (asv's split between its
runner and the benchmarked commit).

Usage: ``python ab_probe.py JOB.json RESULT.json``. ``JOB.json``::

    {"units": [{"uid": "u0", "case": {...}, "method": "anm_pod", "options": {...},
                "steps": 300, "warmup": 30, "blas_threads": 1}, ...],
     "blocks": 4, "seed": 0, "inject": {"u0": 1.3} (optional, power tests only)}

Per unit it builds the model once through the side's code, then times ``blocks`` blocks
of ``steps`` haptic steps (``step`` + ``outputs`` back to back, each timed with
``time.perf_counter``), every block on a fresh deep copy of the model where the model can
be copied (new allocations: the memory layout of a model's arrays moves a microsecond
step by up to 1.6x on these machines, so one layout per process is not a sample of the
code's speed). ``RESULT.json`` holds, per unit, the status, the per-step samples [s] of
every block and whether the blocks ran on copies. A unit whose build or step raises is
reported with its message; the other units go on.

``inject`` (power tests of the gate only) makes the named units slower by a calibrated
factor: a busy wait of ``(factor - 1)`` times the unit's own median step, measured first,
after every step.
"""
from __future__ import annotations

import copy
import json
import sys
import time
import traceback


def _prepare_legacy(case, method, options, steps, seed):
    """The unit as tissuebench 0.1 (before ``latency_ab.prepare_unit``) builds it for its
    latency pass (``studies.units._measure``): ``(model, sequence, start)``."""
    # lazy: this runs in the child interpreter of the A/B reference, importing whichever
    # tissuebench that interpreter has (another version's), not the one of this module
    from tissuebench.rom import make_method
    from tissuebench.studies.evaluation import NEEDS_MODEL, build_evaluation
    from tissuebench.studies.protocol import _start, _timing_sequence
    from tissuebench.studies.training import build_training, case_scene

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
    try:
        from tissuebench.studies.latency_ab import prepare_unit
    except ImportError:  # code from before the A/B gate
        return _prepare_legacy(*args)
    p = prepare_unit(*args)
    return p.model, p.sequence, p.start, p.stop_on_failure


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


def measure(unit, blocks, seed, factor=None):
    """``{"status", "message", "blocks": [[s, ...], ...], "copies": bool}`` of one unit."""
    model, seq, start, stop = prepare(unit, seed)
    if not seq:
        raise ValueError("the unit's evaluation gives no step to time")
    steps, warmup = int(unit["steps"]), int(unit["warmup"])
    extra = 0.0
    if factor:  # calibrate the injected slowdown on the unit's own median (power tests), warm
        warm = min(_median(time_block(model, seq, start, stop, steps, warmup)) for _ in range(3))
        extra = (float(factor) - 1.0) * warm
    out, copies = [], True
    for _ in range(blocks):
        try:
            m = copy.deepcopy(model)
        except Exception:  # factorisations and solver handles of some models cannot be copied
            m, copies = model, False
        out.append(time_block(m, seq, start, stop, steps, warmup, extra))
    return {"status": "ok", "message": "", "blocks": out, "copies": copies}


def main(argv):
    job = json.loads(open(argv[1]).read())
    limits = None
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        threadpool_limits = None
    result = {"units": {}}
    try:
        import tissuebench  # lazy: the child interpreter's tissuebench (see _prepare_legacy)
        result["tissuebench"] = str(tissuebench.__file__)
    except Exception as exc:
        result["error"] = f"cannot import tissuebench: {exc}"
    inject = job.get("inject") or {}
    for unit in job["units"]:
        threads = unit.get("blas_threads") or None
        try:
            if threadpool_limits is not None:
                limits = threadpool_limits(limits=threads, user_api="blas")
            result["units"][unit["uid"]] = measure(unit, int(job.get("blocks", 1)), int(job.get("seed", 0)),
                                                  inject.get(unit["uid"]))
        except Exception as exc:  # one unit failing is data, the others go on
            msg = traceback.format_exception_only(type(exc), exc)[-1].strip()
            result["units"][unit["uid"]] = {"status": "failed", "message": msg[:500], "blocks": [], "copies": False}
        finally:
            if limits is not None:
                limits.unregister()
    with open(argv[2] + ".tmp", "w") as fh:
        json.dump(result, fh)
    import os

    os.replace(argv[2] + ".tmp", argv[2])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
