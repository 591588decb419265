"""``tissuebench sweep``: plan -> resume -> execute -> store -> derived tables.

:func:`run_sweep` expands a :class:`~.spec.SweepSpec` into units, checks the output folder
before any work, takes the folder's lock, skips the units already stored under the same
key (``resume``), recomputes those whose key changed (code, scene, mesh file, versions,
protocol, a plugin method's code: said unit by unit, with what changed, :mod:`.resume_reasons`),
runs the rest on an executor, writes each unit as it finishes, and finally writes the derived
tables (Pareto front, validity radii, fidelity ladder) into ``_derived/``, with the figures
drawn by the ``figures`` callable the caller passes (the reports layer's
:func:`~tissuebench.reports.derived_figures.draw_derived`: the CLI passes it; this layer never
imports ``reports``). A unit that raises is a failed row, and the sweep goes on (a ``SystemExit``
or ``KeyboardInterrupt`` its method's code raises included: :mod:`~tissuebench.exits`). Ctrl-C
and SIGTERM stop after marking the manifest "interrupted" and releasing the lock, saying how to
resume.
"""
from __future__ import annotations

import os
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..exits import user_signals
from .executors import check_executor, execute
from ..reference.cache import PROGRESS_ENV
from ..reference.location import CACHE_ENV, cache_url, check_cache_url, probe_cache
from .metrics import TOLERANCES, pareto_front
from .results import ResultsStore, read_points, read_units
from .resume_reasons import stored_provenance, why_stale
from .sweep_manifest import SweepManifestError, read_sweep_manifest
from .spec import SweepSpec, expand_units
from .atomic_files import new_folder
from .atomic_folders import _writable, check_output_location, provenance

__all__ = ["SweepSummary", "run_sweep", "check_output_folder", "write_derived"]


@dataclass
class SweepSummary:
    out: Path
    planned: int
    computed: list = field(default_factory=list)
    skipped: list = field(default_factory=list)
    recomputed: list = field(default_factory=list)
    failed: list = field(default_factory=list)
    wall_s: float = 0.0
    # why the recomputed units were (resume_reasons.why_stale) -> how many
    why_recomputed: dict = field(default_factory=dict)
    # unit key -> failed steps, of the computed units that ran to their end with failed steps
    # (a step that failed or returned a non-finite state: protocol.drive); their unit_status is "ok"
    failed_steps: dict = field(default_factory=dict)


def check_output_folder(out: Path, resume: bool) -> None:
    """Refuse an unusable output location before any work (:func:`~.store.check_output_location`),
    and a folder that holds a sweep without ``resume``."""
    check_output_location(out, overwrite=True)
    out = Path(out)
    if out.is_dir() and not _writable(out):
        raise ValueError(f"--out = {out}: the folder is not writable")
    if out.is_dir() and any(out.glob("case=*")) and not resume:
        raise FileExistsError(f"results folder {out} holds a sweep; pass --resume to continue it, "
                              "or choose another --out")


def _plan(units, store, resume, log):
    done = store.finished() if resume else {}
    by_identity = {(c, m, o): k for k, (c, m, o) in done.items()}
    pending, skipped, stale = [], [], []
    for u in units:
        if u.key in done:
            skipped.append(u)
            continue
        old = by_identity.get(u.identity)
        if old is not None:
            why = why_stale(stored_provenance(store.root / store._rel(u.case.id, u.method, old)), u)
            stale.append((u, old, why))
            log(f"{u.case.id} {u.label}: stored result has another key ({why}): recomputed")
        pending.append(u)
    return pending, skipped, stale


def check_same_spec(out: Path, spec: SweepSpec, units, store: ResultsStore) -> None:
    """Refuse to resume into a folder holding units this spec does not plan (module docstring);
    a folder of the same spec (its ``_sweep.json`` has this spec's hash: another ``--cases``
    selection of it) is this spec's."""
    try:
        stored = read_sweep_manifest(out, missing_ok=True).get("spec_hash", "unknown (no _sweep.json)")
    except SweepManifestError as exc:
        stored = f"unknown ({exc})"
    if stored == spec.hash:
        return
    planned = {u.identity for u in units}
    foreign = [(k, ident) for k, ident in store.finished().items() if ident not in planned]
    if not foreign:
        return
    key, (case, method, options) = foreign[0]
    raise ValueError(f"--resume: results folder {out} holds {len(foreign)} units that spec {spec.name!r} (hash "
                     f"{spec.hash[:16]}) does not plan, e.g. {case} {method} {options}; they were written by the "
                     f"spec of hash {str(stored)[:16]}. Resume with that spec, or choose another --out")


def run_sweep(spec: SweepSpec, out, executor: str = "serial", workers: int | None = None,
              scheduler: str | None = None, resume: bool = False, progress: bool = True, log=print,
              figures=None, cache=None) -> SweepSummary:
    """Run a sweep into results folder ``out`` (module docstring); ``figures``: see :func:`write_derived`;
    ``cache``: the reference cache's folder or fsspec URL (default ``$TISSUEBENCH_CACHE``, see
    :mod:`.reference.location`), handed to every unit by the executor."""
    out = Path(out)
    check_executor(executor, workers, scheduler)
    if cache is not None:
        cache = probe_cache(check_cache_url(cache))
    elif scheduler is None:  # the environment's, refused before any work as --cache would be
        probe_cache(check_cache_url(cache_url(), CACHE_ENV), CACHE_ENV)
    else:  # a cluster's workers use each their own: only its form can be checked here
        check_cache_url(cache_url(), CACHE_ENV)
    if cache is None and scheduler is not None and progress:
        log("note: no --cache: each worker of the cluster computes references into its own cache "
            "($TISSUEBENCH_CACHE on the worker); give --cache a location every worker reaches (s3://..., a shared "
            "folder) to compute each one once")
    check_output_folder(out, resume)
    units = expand_units(spec)
    if not units:
        raise ValueError(f"spec {spec.name!r}: plans no unit (no method runs on the selected cases)")
    # SIGTERM (timeout, a batch system) stops the sweep as Ctrl-C does; a SystemExit or KeyboardInterrupt a
    # method's code raises fails its unit only (tissuebench.exits)
    with user_signals(terminate=True):
        t_start = time.perf_counter()
        store = ResultsStore(out)
        store.acquire()
        state = None  # the folder's manifest is this sweep's once written: then failed until it finishes
        # the reference runs a unit computes show their own bar (which one, load factor or time, ETA);
        # an environment variable, so that the worker processes of an executor see it too
        previous = os.environ.get(PROGRESS_ENV)
        if progress:
            os.environ[PROGRESS_ENV] = "1"
        try:
            store.clean_temporaries()
            if resume:
                check_same_spec(out, spec, units, store)
            pending, skipped, stale = _plan(units, store, resume, log if progress else (lambda *_: None))
            summary = SweepSummary(out, len(units), skipped=[u.key for u in skipped],
                                   recomputed=[u.key for u, _, _ in stale])
            for _, _, why in stale:
                summary.why_recomputed[why] = summary.why_recomputed.get(why, 0) + 1
            store.write_manifest(_manifest(spec, units, executor, "running", cache=cache))
            state = "failed"
            _execute(spec, pending, skipped, stale, store, summary, (executor, workers, scheduler, cache), progress)
            write_derived(out, spec.error_metric, figures)
            summary.wall_s = time.perf_counter() - t_start
            state = "finished"
            store.write_manifest(_manifest(spec, units, executor, state, summary, cache))
            return summary
        except KeyboardInterrupt:
            state = state and "interrupted"
            raise
        finally:
            if progress and previous is None:
                os.environ.pop(PROGRESS_ENV, None)
            elif progress:
                os.environ[PROGRESS_ENV] = previous
            if state in ("failed", "interrupted"):
                _mark(store, spec, units, executor, state, cache)
            store.release()


def _execute(spec, pending, skipped, stale, store, summary, where, progress):
    executor, workers, scheduler, cache = where
    total = len(pending) + len(skipped)
    bar = _bar(total, len(skipped), progress)
    stale_old = {u.key: old for u, old, _ in stale}
    try:
        for unit, outcome in execute(pending, executor, workers, scheduler, cache=cache):
            store.write_unit(outcome)
            if unit.key in stale_old:
                store.remove_unit(unit.case.id, unit.method, stale_old[unit.key])
            summary.computed.append(unit.key)
            if outcome.row.get("unit_status") != "ok":
                summary.failed.append(unit.key)
            elif (outcome.row.get("n_failed") or 0) > 0:  # an ok unit some of whose steps failed (NaN state)
                summary.failed_steps[unit.key] = int(outcome.row["n_failed"])
            if bar is not None:
                bar.update(1)
                bar.write(_line(len(summary.computed) + len(skipped), total, unit, outcome.row,
                                 spec.error_metric))
    finally:
        if bar is not None:
            bar.close()


def _mark(store, spec, units, executor, state, cache=None) -> None:
    """Best effort: record that the sweep stopped (the folder may have turned read-only)."""
    try:
        store.write_manifest(_manifest(spec, units, executor, state, cache=cache))
    except OSError:
        pass


def _manifest(spec, units, executor, state, summary=None, cache=None) -> dict:
    """``_sweep.json``; ``cache``: the ``--cache`` the sweep was given (``report`` and ``verify``
    on this folder read their references from it unless told otherwise), absent when none was."""
    data = provenance(spec_name=spec.name, spec_source=spec.source, spec_hash=spec.hash, spec_text=spec.text,
                      resolution=spec.resolution, error_metric=spec.error_metric, executor=executor, state=state,
                      cases=[c.as_dict() for c in spec.cases], not_applicable=list(spec.skipped),
                      units=[{"key": u.key, "case": u.case.id, "method": u.method, "label": u.label} for u in units])
    if cache is not None:
        data["cache"] = cache
    if summary is not None:
        data.update(computed=len(summary.computed), skipped=len(summary.skipped),
                    recomputed=len(summary.recomputed), failed=len(summary.failed), wall_s=summary.wall_s)
    return data


def _bar(total, initial, enabled):
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc="sweep", unit="unit")


def _line(done, total, unit, row, error_metric="max_rel_l2") -> str:
    head = f"[{done}/{total}] {unit.case.id} {unit.label}"
    if row.get("unit_status") != "ok":
        return f"{head}: FAILED: {row.get('message', '')}"
    error = row.get(error_metric, float("nan"))
    return (f"{head}: {error_metric} {error:.3g}, haptic {row['haptic_median_s'] * 1e6:.1f} us median / "
            f"{row['haptic_p99_s'] * 1e6:.1f} us p99, speed-up {row['speedup']:.3g}, steps "
            f"{row['n_ok']} ok {row['n_extrapolation']} extrapolated {row['n_beyond_validity']} beyond "
            f"{row['n_failed']} failed")


def paper_points(out: Path) -> pd.DataFrame:
    """The published points of the sweep's paper-resolution cases (``case.paper_points``):
    columns case, label, step_ms, error (empty when none)."""
    cases = read_sweep_manifest(out, missing_ok=True).get("cases", [])
    rows = [{"case": c["id"], **p} for c in cases if c.get("resolution") == "paper"
            for p in c.get("paper_points", [])]
    return pd.DataFrame(rows, columns=["case", "label", "step_ms", "error"])


def write_derived(out: Path, error_metric: str = "max_rel_l2", figures=None) -> Path | None:
    """``_derived/pareto.parquet``, ``radius.parquet``, ``ladder.parquet`` (``scaling.parquet`` when
    the sweep has a scaling group at 2 sizes or more) and, when ``figures`` is
    given, its figures, replaced atomically (a reader sees the old folder or the new one).

    ``figures(out, units, tables, folder, error_metric) -> list of paths`` draws into ``folder``
    (the ``_derived`` being written); ``tables`` maps ``pareto``, ``radius``, ``ladder`` (and
    ``scaling``) to the frames written."""
    units = read_units(out)
    if units.empty:
        return None
    from .ladder import ladder_table
    from .scaling import scaling_table

    cols = ["case", "method", "label", "options", "unit_key", "unit_status", error_metric, "haptic_median_s",
            "haptic_p99_s", "reconstruct_median_s", "reference_step_s", "speedup", "n_reduced"]
    pareto = pareto_front(units, error=error_metric)[cols + ["pareto"]].rename(columns={error_metric: "error"})
    pareto.insert(len(cols), "error_metric", error_metric)
    radius = units[["case", "method", "label", "options", "unit_key", "x_name"]
                   + [f"validity_{int(round(t * 100))}pct" for t in TOLERANCES]].copy()
    radius["validity_range"] = units["validity_range"] if "validity_range" in units else ""
    tables = {"pareto": pareto, "radius": radius, "ladder": ladder_table(units, read_points(out))}
    scaling = scaling_table(units, read_sweep_manifest(out, missing_ok=True).get("cases", []), error_metric)
    if not scaling.empty:  # a scaling_group of cases at >= 2 sizes (studies/scaling.py)
        tables["scaling"] = scaling
    final = out / "_derived"
    # the umask's mode, as every other folder of the store (mkdtemp's 0700 of earlier versions is not kept)
    tmp = new_folder(out, "._derived.")
    try:
        for name, table in tables.items():
            table.to_parquet(tmp / f"{name}.parquet", index=False)
        if figures is not None:
            figures(out, units, tables, tmp, error_metric)
        if final.exists():
            old = out / "._derived.old"
            shutil.rmtree(old, ignore_errors=True)
            final.rename(old)
            shutil.rmtree(old, ignore_errors=True)
        tmp.rename(final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final
