"""Work units of a sweep: plain data (picklable, no closures) and the function that runs one.

A unit is (case entry, method, options) plus the measurement protocol. Its ``key`` is the
SHA-256 of everything that changes its result: the case entry, the scene's content hash
(mesh files included), the method and options, the protocol, the source hash of the code
and the package versions, and for a method from another package its distribution, version and
code hash (:func:`~tissuebench.rom.plugins.third_party`). :func:`run_unit` runs in whatever
process an executor picks and returns plain rows; it never raises for a failure of the method (the unit's row says
``unit_status = "failed"`` with the message), so a sweep goes on: a ``SystemExit`` or ``KeyboardInterrupt``
the method's code raises included (``"SystemExit(7) raised by the method's code"``); a real Ctrl-C or
SIGTERM is told from those (:mod:`~tissuebench.exits`) and stops the sweep.
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import platform
import time
import tracemalloc
import traceback
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from ..exits import EXIT_TYPES, exit_text, raised_by_code
from ..rom import make_method, method_class
from ..rom.plugins import third_party
from .applicability import evaluation_why_not, why_not
from .case_entry import CaseEntry
from .energy import EnergyDrift, model_drift
from .evaluation import NEEDS_MODEL, build_evaluation, evaluation_references
from .metrics import output_rows, point_rows, seen_points, summarise_points
from .protocol import (_timing_sequence, blas_info, calibration_seconds, drive, non_finite_note,
                       reference_step_seconds, time_latency)
from .timing import TAIL_STEPS
from ..reference.provenance import code_hash, git_commit, package_versions
from ..reference import cached_dynamics_system, reference_key
from .training import build_training, case_scene, training_references

__all__ = ["WorkUnit", "UnitOutcome", "unit_key", "options_text", "run_unit", "failed_outcome", "unit_references",
           "unit_method", "machine_load", "DEFAULT_PROTOCOL"]

#: 2000 timed steps: 20 samples beyond the p99 (studies/timing.p99_tail); a model slower than
#: latency_budget_s seconds for them is timed on fewer (its haptic_n)
DEFAULT_PROTOCOL = {"latency_steps": TAIL_STEPS, "latency_budget_s": 60, "warmup": 20, "blas_threads": 1,
                    "reference_samples": 3, "seed": 0}
# what each protocol key means (the spec-format reference of the documentation)
PROTOCOL_DOC = {"latency_steps": "timed haptic steps per unit (2000 by default: 20 samples beyond the p99)",
                "latency_budget_s": "seconds the timed steps may take; a slower model is timed on fewer "
                                    "(its haptic_n says how many)",
                "warmup": "untimed steps before them",
                "blas_threads": "BLAS threads while a unit runs (threadpoolctl; 0: leave as is)",
                "reference_samples": "reference steps timed in the same process",
                "seed": "the seed of the random parameters a map model is timed at"}


def options_text(options: dict) -> str:
    """Canonical JSON of an option set (sorted keys): the same options give the same text."""
    return json.dumps(options, sort_keys=True, separators=(",", ":"))


def unit_key(case: CaseEntry, scene_hash: str, method: str, options: dict, protocol: dict) -> str:
    """SHA-256 identifying a unit's result (module docstring); the case entry enters in its dict
    form (:meth:`~.case_entry.CaseEntry.as_dict`)."""
    content = {"case": case.as_dict(), "scene": scene_hash, "method": method, "options": options, "protocol": protocol,
               "code": code_hash(), "versions": package_versions()}
    plugin = third_party(method)
    if plugin:  # a method from another package: its own version and code (a shipped method's key is unchanged)
        content["plugin"] = plugin
    return hashlib.sha256(json.dumps(content, sort_keys=True, default=str).encode()).hexdigest()


@dataclass(frozen=True)
class WorkUnit:
    """One (case entry, method, options) of a sweep, with its protocol and key."""

    case: CaseEntry
    method: str
    options: dict
    protocol: dict
    spec: dict
    key: str
    parent_options: dict | None = None  # nested options at their group maximum: built once, sliced
    # "module:Class" of a method from another package (rom.plugins.source_of): a worker process
    # imports it from there; "" for a shipped method
    source: str = ""

    @property
    def label(self) -> str:
        opts = " ".join(f"{k}={v}" for k, v in sorted(self.options.items()))
        return f"{self.method} {opts}".strip()

    @property
    def identity(self) -> tuple:
        """What the unit measures, whatever the code version: (case id, method, options)."""
        return self.case.id, self.method, options_text(self.options)


@dataclass
class UnitOutcome:
    row: dict
    points: list = field(default_factory=list)
    outputs: list = field(default_factory=list)
    latency: list = field(default_factory=list)  # one dict per timed haptic step (LATENCY_COLUMNS)


def _nbytes(obj, seen=None, depth=0) -> int:
    """Bytes of the numpy arrays an online model holds (not its backend or problem)."""
    seen = set() if seen is None else seen
    if id(obj) in seen or depth > 4:
        return 0
    seen.add(id(obj))
    if isinstance(obj, np.ndarray):
        return int(obj.nbytes)
    if isinstance(obj, dict):
        return sum(_nbytes(v, seen, depth + 1) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(_nbytes(v, seen, depth + 1) for v in obj)
    if hasattr(obj, "__dict__") and type(obj).__module__.startswith("tissuebench.rom"):
        return sum(_nbytes(v, seen, depth + 1) for k, v in vars(obj).items() if k not in ("backend", "problem"))
    return 0


def unit_method(unit: WorkUnit) -> type:
    """The unit's method class: imported from its ``source`` when it has one (a worker process
    that has not met the class yet), else by its registry name (ValueError when neither works)."""
    return method_class(unit.source or unit.method)


def _base_row(unit: WorkUnit) -> dict:
    c = unit.case
    try:
        kind = unit_method(unit).kind
    except (ValueError, TypeError):  # the unit's run stores why the method cannot be loaded
        kind = ""
    return {"unit_key": unit.key, "case": c.id, "case_name": c.name, "variant": c.variant or "",
            "resolution": c.resolution, "backend": c.backend, "method": unit.method,
            "kind": kind, "options": options_text(unit.options), "label": unit.label,
            "spec_name": unit.spec["name"], "spec_hash": unit.spec["hash"], **_plugin_row(unit)}


def _plugin_row(unit: WorkUnit) -> dict:
    """The store's record of a method from another package (:func:`~tissuebench.rom.plugins.third_party`):
    its class path, distribution, version and code hash ({} for a shipped method)."""
    try:
        p = third_party(unit.source or unit.method)
    except (ValueError, TypeError):
        return {}
    return {f"method_{k}": v for k, v in p.items() if v is not None}


def _provenance_row() -> dict:
    v = package_versions()
    return {"git_commit": git_commit(), "code_hash": code_hash(), "tissuebench": v.get("tissuebench"),
            "numpy": v.get("numpy"), "scipy": v.get("scipy"), "machine": platform.node(),
            "python": platform.python_version(),
            "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")}


def run_unit(unit: WorkUnit) -> UnitOutcome:
    """Build, drive, time and measure one unit (see :mod:`.protocol`); failures become a row."""
    row = {**_base_row(unit), **_provenance_row()}
    threads = unit.protocol.get("blas_threads") or None
    t0 = time.perf_counter()
    try:
        with threadpool_limits(limits=threads, user_api="blas"):
            row.update(_measure(unit, row))
            row.update(unit_status="ok", message="; ".join(row.pop("_notes")), unit_wall_s=time.perf_counter() - t0)
            return UnitOutcome(row, row.pop("_points"), row.pop("_outputs"), row.pop("_latency"))
    except (Exception, *EXIT_TYPES) as exc:  # a method that raises is a stored result, not the end of the sweep
        if not isinstance(exc, Exception) and not raised_by_code(exc):
            raise  # the user's Ctrl-C (or SIGTERM): the sweep stops, resumably (tissuebench.exits)
        tb = (traceback.format_exception_only(type(exc), exc)[-1].strip() if isinstance(exc, Exception)
              else exit_text(exc))  # SystemExit(7): the method's sys.exit fails its unit only
        for side in ("_points", "_outputs", "_latency", "_notes"):
            row.pop(side, None)
        row.update(unit_status="failed", message=f"{tb} (in {_where(exc)})", unit_wall_s=time.perf_counter() - t0)
        return UnitOutcome(row)


def failed_outcome(unit: WorkUnit, message: str, wall_s: float = float("nan")) -> UnitOutcome:
    """The stored row of a unit that could not run to its end outside :func:`run_unit` (its
    worker process died): ``unit_status = "failed"`` with ``message``."""
    row = {**_base_row(unit), **_provenance_row()}
    row.update(unit_status="failed", message=message, unit_wall_s=wall_s)
    return UnitOutcome(row)


def unit_references(unit: WorkUnit) -> dict:
    """``{reference key: scene}`` of the reference runs ``unit`` reads on its case's backend, as
    its training and evaluation kinds declare them (:func:`~.training.training_references`,
    :func:`~.evaluation.evaluation_references`); nothing solved. A case entry whose scene does not
    load declares none: the unit's own run stores the error."""
    try:
        scene = case_scene(unit.case)
        scenes = training_references(unit.case, scene) + evaluation_references(unit.case, scene)
        return {reference_key(s, unit.case.backend): s for s in scenes}
    except Exception:  # noqa: BLE001 - reported by the unit's run, which meets the same error
        return {}


def _where(exc) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    return f"{frames[-1].filename.split('tissuebench/')[-1]}:{frames[-1].lineno}" if frames else "?"


def _measure(unit: WorkUnit, row: dict) -> dict:
    p = unit.protocol
    unit_method(unit)  # a method from another package: imported here, or the unit fails saying why
    scene = case_scene(unit.case)
    # checked at spec load; again here, so that a unit built another way never returns a model's
    # training answer at a parameter it does not read as an ok result
    refusal = why_not(unit.method, scene, unit.case.training_kind, unit.options) or evaluation_why_not(
        unit.method, unit.case, scene)
    if refusal:
        raise ValueError(f"{unit.method} does not apply to case {unit.case.id!r}: {refusal}")
    training = build_training(unit.case, scene)
    needs_model = unit.case.evaluation_kind in NEEDS_MODEL
    evaluation = None if needs_model else build_evaluation(unit.case, scene)
    model, offline, peak = _build(unit, training)
    if needs_model:
        evaluation = build_evaluation(unit.case, scene, model)
    if training.outputs:
        model.attach_outputs(training.outputs)
    history = evaluation.history or training.history or (scene.history if evaluation.kind == "trajectory" else None)
    driven = drive(model, evaluation, history)
    energy, histories = _energy_drift(evaluation, driven, unit.case.backend)
    points = pd.DataFrame(point_rows(evaluation, driven, seen_points(evaluation, training.snapshots))).assign(
        **histories)
    outputs = pd.DataFrame(output_rows(evaluation, driven), columns=["point", "x", "monitor", "reference", "rom",
                                                                       "rel_error"])
    lat = time_latency(model, evaluation, history, int(p["latency_steps"]), int(p["warmup"]), int(p["seed"]),
                       budget_s=p.get("latency_budget_s"))
    load = machine_load()  # right after the timed steps: the load they ran under (the report states it)
    notes, label = _asked_versus_done(unit, model, evaluation, history, training.info)
    notes += [n for n in (non_finite_note(driven),) if n]  # NaN steps: failed steps, said on the unit's row too
    h = lat["haptic"]
    if h.n < int(p["latency_steps"]):  # the budget ran out before the steps asked (a slow step)
        notes.append(f"latency_budget_s = {p.get('latency_budget_s'):g} s reached: {h.n} of {p['latency_steps']} "
                     f"steps timed, the p99 rests on {h.tail} samples beyond it")
    ref_step = reference_step_seconds(evaluation, unit.case.backend, int(p["reference_samples"]))
    calib = calibration_seconds()
    r = lat["reconstruct"]
    n_dof = len(evaluation.points[0].reference) if evaluation.points and evaluation.points[0].reference is not None \
        else int(getattr(model, "ndof", 0))
    return {**summarise_points(points, outputs, evaluation, driven.fields),
            "n_dof": n_dof, "n_reduced": int(model.n_reduced), "n_training_snapshots":
                0 if training.snapshots is None else int(training.snapshots.shape[1]),
            "haptic_median_s": h.median, "haptic_p99_s": h.p99, "haptic_n": h.n,
            "reconstruct_median_s": r.median if r else np.nan, "reconstruct_p99_s": r.p99 if r else np.nan,
            "reference_step_s": ref_step, "speedup": ref_step / h.median if h.median > 0 else np.nan,
            "calibration_s": calib, "haptic_per_calibration": h.median / calib, **blas_info(), **load,
            "floor_s": lat["floor"].median, "efficiency": lat["floor"].median / h.median,
            "floor_p99_s": lat["floor"].p99,
            "offline_s": offline, "build_peak_bytes": int(peak), "model_bytes": _nbytes(model),
            "scene_hash": scene.content_hash(), "kind": model.kind,  # the built model's (a baseline's varies)
            "length_unit": (getattr(scene, "units", None) or {}).get("length", ""),
            **{k: evaluation.info.get(k) for k in ("reference_status", "reference_message",
                                                     "reference_energy_growth", "reference_limit", "x_scale",
                                                     "x_unit")}, **energy,
            "model_info": json.dumps(_jsonable(getattr(model, "info", {}))), "label": label,
            "_points": points.to_dict("records"), "_outputs": outputs.to_dict("records"), "_latency": lat["samples"],
            "_notes": notes + _blas_note(unit)}


def machine_load() -> dict:
    """``{"load_average", "n_cpus"}``: the 1-minute load average (the unit's own process included:
    about 1 on an otherwise idle machine) and the CPUs this process may run on; NaN where the
    system has no load average (Windows)."""
    try:
        load = float(os.getloadavg()[0])
    except (AttributeError, OSError):
        load = float("nan")
    cpus = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or -1)
    return {"load_average": load, "n_cpus": int(cpus)}


def _asked_versus_done(unit: WorkUnit, model, evaluation, history, training_info=None) -> tuple[list, str]:
    """What the unit asked for and did not get, said (notes for the row's message) rather than
    capped silently: fewer modes than ``n_modes`` (the training set spans fewer; the label says
    ``(N built)``), a ``warmup`` longer than the timing sequence (one pass of it is run)."""
    notes, label = [], unit.label
    retried = (training_info or {}).get("retried_positions")
    if retried:
        notes.append("stored positions solved again with more load steps (Newton stalled): " + ", ".join(
            f"{s:g} ({n} steps)" for s, n in retried.items()))
    asked, built = unit.options.get("n_modes"), int(model.n_reduced)
    if isinstance(asked, int) and not isinstance(asked, bool) and built < asked:
        notes.append(f"n_modes = {asked} asked, the built model has {built} reduced coordinates (what the training "
                     "set spans, or the method's own stop: see model_info)")
        label = f"{label} ({built} built)"
    warmup = int(unit.protocol.get("warmup", 0))
    if warmup:
        n = len(_timing_sequence(model, evaluation, history, int(unit.protocol["latency_steps"]),
                                 int(unit.protocol["seed"])))
        if warmup > n:
            notes.append(f"warmup = {warmup} asked, {n} untimed steps run (one pass of the {n}-step timing sequence)")
    return notes, label


def _blas_note(unit: WorkUnit) -> list:
    """A note when the BLAS ran another number of threads than ``blas_threads`` asked (the
    library caps it at what it was built or started with)."""
    asked = int(unit.protocol.get("blas_threads") or 0)
    ran = blas_info()["blas_threads"]
    return [f"blas_threads = {asked} asked, the BLAS ran {ran}"] if asked and ran and ran != asked else []


def _energy_drift(evaluation, driven, backend) -> tuple[dict, dict]:
    """The long-run energy drift columns of a trajectory unit, the model's and the reference's
    (:mod:`.energy`), NaN elsewhere; and the point columns of their histories (``energy_rel``,
    ``reference_energy_rel``: ``E / scale`` at the evaluation points in the window, else NaN)."""
    ref = evaluation.reference_energy
    if ref is None:
        why = "no constant-load window" if evaluation.kind == "trajectory" else ""
        return {**EnergyDrift(message=why).row(), "reference_energy_drift": np.nan,
                "reference_energy_spread": np.nan}, {}
    system = cached_dynamics_system(evaluation.reference_steps["scene"], backend)
    drift = model_drift(system, evaluation.dt, ref.window_start, evaluation.info["t_end"], driven.neighbours, ref.scale)
    failed = [r.mu["time"] for r in driven.results if r is not None and r.status == "failed" and r.mu]
    if failed and np.isfinite(drift.drift):  # a blow-up inside the window: its steps before the failure fit no drift
        drift = EnergyDrift(float("inf"), float("inf"), ref.window_start, ref.scale,
                            f"the model failed at t = {min(failed):.6g} (in or before the window)",
                            drift.times, drift.history)
    steps = [round(p.mu["time"] / evaluation.dt) for p in evaluation.points]
    model_at, ref_at = drift.at_steps(evaluation.dt), ref.at_steps(evaluation.dt)
    histories = {"energy_rel": [model_at.get(k, np.nan) for k in steps],
                 "reference_energy_rel": [ref_at.get(k, np.nan) for k in steps]}
    return {**drift.row(), "reference_energy_drift": ref.drift, "reference_energy_spread": ref.spread}, histories


_PARENTS: OrderedDict = OrderedDict()  # per process: nested parents (model, build seconds, peak bytes)


def _timed_build(method, options, training):
    tracemalloc.start()
    t0 = time.perf_counter()
    model = make_method(method, **options).build(training)
    seconds = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return model, seconds, peak


def _build(unit: WorkUnit, training):
    """``(model, offline seconds, peak bytes)``. A unit whose nested options (``RomMethod.nested``,
    e.g. n_modes and order of ANM-POD) are below its group's maximum is sliced from the group's
    model built once per process (``variant``: leading POD modes, sliced tensors; the same model
    as a fresh build); its offline time is then the parent's build plus the slicing."""
    parent_opts = unit.parent_options
    if not parent_opts or parent_opts == unit.options:
        return _timed_build(unit.method, unit.options, training)
    key = (unit.case.id, training.info.get("scene_hash"), unit.method, options_text(parent_opts))
    if key not in _PARENTS:
        _PARENTS[key] = _timed_build(unit.method, parent_opts, training)
        while len(_PARENTS) > 2:
            _PARENTS.popitem(last=False)
    parent, seconds, peak = _PARENTS[key]
    t0 = time.perf_counter()
    model = parent.variant(**unit.options)  # OnlineModel.variant: None where the model cannot be sliced
    if model is None:
        return _timed_build(unit.method, unit.options, training)
    model.info = {**getattr(model, "info", {}), "sliced_from": parent_opts}
    return model, seconds + time.perf_counter() - t0, peak


def _jsonable(obj, depth=0):
    """Scalars, strings and small lists of a model's info dict (arrays and objects summarised)."""
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, (str, int, float, bool)) or obj is None:
        return obj
    if depth > 3:  # a container nested deeper is named, not stored
        return str(type(obj).__name__)
    if isinstance(obj, dict):
        return {str(k): _jsonable(v, depth + 1) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v, depth + 1) for v in obj[:50]]
    if isinstance(obj, np.ndarray):
        return obj.tolist() if obj.size <= 50 else f"array{obj.shape}"
    return type(obj).__name__
