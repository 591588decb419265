"""The one timed loop every method goes through, and the reference timed beside it.

For every unit, in one process, one unit at a time, with the BLAS thread count limited
(1 by default, recorded):

1. **Evaluation pass** (untimed): the model is driven through the evaluation set in its
   order (``start`` then ``step`` per point; trajectories from the initial state at the
   reference's dt), its outputs and reconstructed fields collected.
2. **Latency pass**: after ``warmup`` untimed steps, at least ``steps`` haptic steps
   (``step`` + ``outputs`` back to back, as a haptic loop runs them) are timed one by one
   with ``time.perf_counter`` (a map model at seeded random parameters, a path model along
   its path, a trajectory model through its time steps, restarted untimed when a pass
   ends): 2000 by default, so that 20 samples lie beyond the p99 (:func:`~.timing.p99_tail`).
   A model too slow for them within ``budget_s`` seconds of timing (a full solve per step)
   stops there, after at least one step: the row's ``haptic_n`` says how many were timed and
   the report how many samples its p99 rests on. The full field is reconstructed, and timed
   apart, only at the display's rate: once every ``ceil(1 kHz / 60 Hz) = 17`` steps (a
   display draws at ~60 Hz while the haptic loop runs at 1 kHz), so the caches a step sees
   are those of a haptic loop, not those left by a full-size reconstruction after every step. Right after each step the
   model's **floor** (:meth:`~tissuebench.rom.OnlineModel.floor_ops`: the arithmetic its
   step cannot avoid) is timed too, so ``efficiency = floor / haptic median`` compares
   the two under the same load. Median and 99th percentile. A map model is timed at fresh
   parameters drawn uniformly over the evaluation's range (never at parameters it may
   have cached).
3. **Reference step**: the full model's own step (one Newton increment from a converged
   state, one back-substitution for a linear static scene, one time step of the
   reference integrator) timed ``reference_samples`` times in the same process, so every
   row has a speed-up ratio that survives a noisy machine.
4. **Calibration kernel**: a 256 x 256 dense matmul timed in the same process, so a
   reader can scale latencies to another CPU.
"""
from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

import numpy as np
from threadpoolctl import threadpool_info

from ..reference.step_timing import reference_step_seconds as step_seconds
from ..rom.base import StepResult
from .timing import TAIL_STEPS, latency_stats

__all__ = ["Driven", "drive", "NON_FINITE", "non_finite_note", "time_latency", "calibration_seconds",
           "reference_step_seconds", "blas_info", "HAPTIC_HZ", "DISPLAY_HZ", "DISPLAY_EVERY"]


@dataclass
class Driven:
    """A model driven through an evaluation set: one entry per evaluation point."""

    results: list
    fields: list  # reconstructed full field or None (failed step / no reconstruction)
    outputs: list
    # trajectory: step index -> full field of the stored steps in the energy window and their
    # neighbours (the central-difference velocity of :mod:`.energy`)
    neighbours: dict = field(default_factory=dict)


def _trajectory_mus(evaluation, history):
    dt, t_end = evaluation.dt, evaluation.info["t_end"]
    t0 = evaluation.points[0].mu["time"]
    n = int(np.ceil((t_end - t0) / dt - 1e-9))
    return [{"time": t0 + k * dt, "load_factor": float(history(t0 + k * dt))} for k in range(1, n + 1)]


#: the start of the message of a step recorded as failed for a NaN or inf (:func:`drive`)
NON_FINITE = "the step returned a non-finite state"


def non_finite_note(driven: Driven) -> str:
    """The unit's note on its steps that returned a non-finite state (``""``: none): how many,
    and the first one's message."""
    bad = [r for r in driven.results if r is not None and r.status == "failed" and r.message.startswith(NON_FINITE)]
    if not bad:
        return ""
    steps = sum(r is not None for r in driven.results)
    return f"{len(bad)} of {steps} evaluation steps failed: {bad[0].message}"


def _non_finite(what: str, values) -> str:
    """``""`` when every number of ``values`` is finite, else what is not (``"q has 3 NaN"``); a
    value that is no array of numbers (None: nothing asked) is left to the code that reads it."""
    if values is None:
        return ""
    try:
        a = np.asarray(values, dtype=complex if np.iscomplexobj(values) else float)
    except (TypeError, ValueError):
        return ""
    nan, inf = int(np.isnan(a).sum()), int(np.isinf(a).sum())
    if not nan and not inf:
        return ""
    return f"{what} has " + " and ".join(f"{n} {kind}" for n, kind in ((nan, "NaN"), (inf, "inf")) if n)


def _finite_or_failed(res, field=None, outputs=None):
    """``res``, or when its state ``q``, its reconstructed ``field`` or its ``outputs`` hold a NaN or
    an inf, a failed step saying which (whatever the status the model gave: a NaN is no
    extrapolation). One place for every method, shipped or plugin: a step that returned no number
    is never an "ok" step with an infinite error."""
    if res.q is None:
        return res
    bad = [b for b in (_non_finite("q", res.q), _non_finite("the reconstructed field", field),
                       *(_non_finite(f"output {k!r}", [v]) for k, v in (outputs or {}).items())) if b]
    if not bad:
        return res
    said = f"; the model said {res.status}: {res.message}" if res.status != "ok" else ""
    return StepResult(None, "failed", f"{NON_FINITE} ({', '.join(bad)}){said}",
                      info=res.info, mu=res.mu)


def drive(model, evaluation, history=None) -> Driven:
    """Evaluation pass (module docstring, 1). A step whose state, field or outputs are not finite
    is recorded as failed (:func:`_finite_or_failed`): counted with the unit's failed steps."""
    results, fields, outputs = [], [], []

    def record(res):
        res = _finite_or_failed(res)
        out = model.outputs(res)
        field = model.reconstruct(res) if res.q is not None else None
        checked = _finite_or_failed(res, field, out)
        if checked is not res:  # the field or an output is not finite: nothing of the step is kept
            res, field, out = checked, None, {k: float("nan") for k in out}
        results.append(res)
        outputs.append(out)
        fields.append(field)
        return res

    if evaluation.kind == "trajectory":
        p0 = evaluation.points[0]
        model.start(p0.mu, evaluation.state0, evaluation.dt)
        wanted = {round(p.mu["time"] / evaluation.dt) for p in evaluation.points[1:]}
        energy = evaluation.reference_energy
        in_window = set() if energy is None else {k for k in wanted if k * evaluation.dt >= energy.window_start - 1e-9}
        around = {k + d for k in in_window for d in (-1, 0, 1)}
        neighbours = {}
        results.append(None), fields.append(evaluation.state0["u"]), outputs.append({})  # the initial state
        for mu in _trajectory_mus(evaluation, history):
            res = model.step(mu)
            if res.mu is None:
                res.mu = mu
            k = round(mu["time"] / evaluation.dt)
            if k in wanted:
                res = record(res)
            else:
                res = _finite_or_failed(res)  # a NaN between the stored steps ends the trajectory too
            if k in around and res.q is not None:
                u = fields[-1] if k in wanted else model.reconstruct(res)
                checked = res if k in wanted else _finite_or_failed(res, u)
                if checked is res:
                    neighbours[k] = u
                res = checked
            if res.status == "failed":
                if k not in wanted:  # between stored steps: the next stored point carries it
                    record(res)
                break
        missing = len(evaluation.points) - len(results)
        results += [None] * missing
        fields += [None] * missing
        outputs += [{}] * missing
        return Driven(results, fields, outputs, neighbours)
    model.start(evaluation.points[0].mu if evaluation.points else None)
    for p in evaluation.points:
        res = model.step(p.mu)
        if res.mu is None:
            res.mu = dict(p.mu)
        record(res)
    return Driven(results, fields, outputs)


def _timing_sequence(model, evaluation, history, n, seed):
    if evaluation.timing_mus:
        return list(evaluation.timing_mus)
    if evaluation.kind == "trajectory":
        return _trajectory_mus(evaluation, history)
    mus = [p.mu for p in evaluation.points]
    if model.kind == "map":
        # fresh parameters every step, uniform over the evaluation's range of each one (a tool
        # moves continuously: a model must not be timed on parameters it has cached); integer
        # parameters (node ids) are drawn from the evaluation's own points instead
        rng = np.random.default_rng(seed)
        keys = sorted(mus[0])
        if any(isinstance(m[k], (int, np.integer)) and not isinstance(m[k], bool) for m in mus for k in keys):
            return [mus[i] for i in rng.integers(0, len(mus), size=max(n, 1))]
        lo = {k: min(m[k] for m in mus) for k in keys}
        hi = {k: max(m[k] for m in mus) for k in keys}
        return [{k: float(rng.uniform(lo[k], hi[k])) for k in keys} for _ in range(max(n, 1))]
    return mus


def _start(model, evaluation, seq):
    if evaluation.kind == "trajectory":
        model.start(evaluation.points[0].mu, evaluation.state0, evaluation.dt)
    else:
        model.start(seq[0])


def _abscissae(evaluation, seq) -> list:
    """The evaluation abscissa of every timed parameter: the ``x`` of the evaluation point with
    the same ``mu`` (a scalpel's cut length, a held-out position's distance), else the
    parameter named ``x_name`` (a trajectory's time, a map's random draw), else NaN."""
    at_point = {repr(sorted(p.mu.items())): p.x for p in evaluation.points}
    return [float(at_point.get(repr(sorted(mu.items())), mu.get(evaluation.x_name, np.nan))) for mu in seq]


#: the rate a haptic loop runs at [Hz] and the rate a display asks for a full field [Hz]: the
#: latency pass reconstructs once every ceil(HAPTIC_HZ / DISPLAY_HZ) = 17 steps
HAPTIC_HZ, DISPLAY_HZ = 1000.0, 60.0
DISPLAY_EVERY = int(np.ceil(HAPTIC_HZ / DISPLAY_HZ))


def time_latency(model, evaluation, history=None, steps: int = TAIL_STEPS, warmup: int = 20, seed: int = 0,
                 clock=time.perf_counter, display_every: int = DISPLAY_EVERY, budget_s: float | None = None) -> dict:
    """Latency pass (module docstring, 2).

    Returns ``{"haptic": LatencyStats, "reconstruct": LatencyStats | None, "floor": LatencyStats,
    "samples": rows}``, ``rows`` one dict per timed step in timing order: ``sample``, ``x`` (its
    abscissa, see :func:`_abscissae`), ``haptic_s``, ``floor_s`` (the model's floor,
    :meth:`~tissuebench.rom.OnlineModel.floor_ops`, timed right after that step) and
    ``reconstruct_s`` [s] (NaN where nothing was reconstructed: the display asks for a field
    every ``display_every``-th step only): the distribution per cut length or load factor
    (pgd-cutting Fig. 8). ``clock`` returns seconds (injectable, for testing the protocol with
    exact durations). ``budget_s``: the timing stops once this many seconds (by ``clock``) have
    passed since the first timed step, even short of ``steps`` (None: no budget)."""
    if int(display_every) < 1:
        raise ValueError(f"time_latency: display_every must be >= 1, got {display_every!r}")
    seq = _timing_sequence(model, evaluation, history, steps, seed)
    if not seq:
        raise ValueError("time_latency: an empty evaluation set cannot be timed")
    floor = model.floor_ops()
    if not callable(floor):
        raise TypeError(f"{type(model).__name__}.floor_ops() returned {type(floor).__name__}, not a callable")
    xs = _abscissae(evaluation, seq)
    _start(model, evaluation, seq)
    for i, mu in enumerate(seq[:warmup]):
        res = model.step(mu)
        model.outputs(res)
        floor()
        if res.q is not None and i % display_every == 0:
            model.reconstruct(res)
    haptic, floors, recon, samples = [], [], [], []
    began = clock()
    spent = False
    while len(haptic) < steps and not spent:
        _start(model, evaluation, seq)
        for mu, x in zip(seq, xs):
            if haptic and budget_s is not None and clock() - began >= budget_s:
                spent = True  # a slow model: fewer steps, said by haptic_n and the report
                break
            # the haptic loop: step + outputs back to back, one clock pair per step
            t0 = clock()
            res = model.step(mu)
            model.outputs(res)
            t1 = clock()
            floor()
            t2 = clock()
            haptic.append(t1 - t0)
            floors.append(t2 - t1)
            r = np.nan
            if res.q is not None and len(samples) % display_every == 0:  # the display's frame
                if res.mu is None:
                    res.mu = mu
                t3 = clock()
                model.reconstruct(res)
                r = clock() - t3
                recon.append(r)
            samples.append({"sample": len(samples), "x": x, "haptic_s": t1 - t0, "floor_s": t2 - t1,
                            "reconstruct_s": r})
            if res.status == "failed" and evaluation.kind == "trajectory":
                break
        if not haptic:
            break
    return {"haptic": latency_stats(haptic), "reconstruct": latency_stats(recon) if recon else None,
            "floor": latency_stats(floors), "samples": samples}


def calibration_seconds(n: int = 256, repeats: int = 30, seed: int = 0) -> float:
    """Median time [s] of one ``n x n`` dense matmul (the machine's calibration kernel)."""
    rng = np.random.default_rng(seed)
    A, B = rng.standard_normal((n, n)), rng.standard_normal((n, n))
    A @ B
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        A @ B
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


@functools.lru_cache(maxsize=1)
def _numpy_blas_api() -> str | None:
    """threadpoolctl's name (``internal_api``) of the BLAS NumPy was built with, None if not known."""
    try:
        name = str(np.show_config(mode="dicts")["Build Dependencies"]["blas"]["name"]).lower()
    except Exception:  # noqa: BLE001 -- an older or unusual NumPy build: every BLAS counts
        return None
    return next((api for api in ("openblas", "mkl", "blis", "flexiblas") if api in name), None)


def blas_info() -> dict:
    """The BLAS NumPy calls (the methods' steps) and its thread count, as threadpoolctl reports it.
    Another BLAS loaded in the process is not it: MKL comes in with PARDISO's factorisations of a
    large reference (:mod:`tissuebench.refsolvers.pardiso`), so counting it would make the row depend
    on what else the process solved before."""
    info = [i for i in threadpool_info() if i.get("user_api") == "blas"]
    api = _numpy_blas_api()
    info = [i for i in info if i["internal_api"] == api] or info
    return {"blas": ",".join(sorted({i["internal_api"] for i in info})) or "unknown",
            "blas_threads": max((i["num_threads"] for i in info), default=0)}


def reference_step_seconds(evaluation, backend: str = "skfem", samples: int = 3) -> float:
    """Median wall time [s] of the reference's own step (module docstring, 3; measured by
    :func:`tissuebench.reference.step_timing.reference_step_seconds`, once per process and
    scene), the evaluation's own when it timed it; NaN when the evaluation has no reference
    run to step from."""
    if evaluation.reference_step_s is not None:
        return float(evaluation.reference_step_s)
    ctx = evaluation.reference_steps
    if not ctx:
        return float("nan")
    return step_seconds(ctx["ref"], ctx["scene"], backend, samples)
