"""Row schemas of the results store, declared once: the store, the report and the gate use them.

``UNIT_COLUMNS`` is one row per unit (the Parquet dataset ``pandas.read_parquet(DIR)``
reads; ``case`` and ``method`` come from the partition folders ``case=<id>/method=<name>``);
``POINT_COLUMNS`` one row per evaluation point (``DIR/_points``); ``OUTPUT_COLUMNS`` one row
per (point, monitored output) (``DIR/_outputs``); ``LATENCY_COLUMNS`` one row per timed haptic
step (``DIR/_latency``: the samples behind a unit's median and p99). Every file of a dataset is written with
exactly its schema, so the datasets read back with one set of columns and types.
"""
from __future__ import annotations

import re

import numpy as np
import pandas as pd
import pyarrow as pa

__all__ = ["UNIT_COLUMNS", "POINT_COLUMNS", "OUTPUT_COLUMNS", "LATENCY_COLUMNS", "PARTITIONS", "arrow_schema",
           "conform"]

#: a file or folder name the store writes (case ids, method names, unit keys): no path separator
SAFE_NAME = re.compile(r"[A-Za-z0-9_.-]+")

PARTITIONS = ("case", "method")

_F, _I, _S, _B = pa.float64(), pa.int64(), pa.string(), pa.bool_()

UNIT_COLUMNS = {
    # identity
    "unit_key": _S, "case_name": _S, "variant": _S, "resolution": _S, "backend": _S, "kind": _S,
    "options": _S, "label": _S, "spec_name": _S, "spec_hash": _S, "scene_hash": _S,
    # outcome, and what the reference did at the evaluation (status, message, energy growth ratio)
    "unit_status": _S, "message": _S, "reference_status": _S, "reference_message": _S,
    "reference_energy_growth": _F,
    # long-run energy drift over the constant-load window of a trajectory (studies/energy.py)
    "energy_drift": _F, "energy_spread": _F, "energy_window_start": _F, "energy_message": _S,
    "reference_energy_drift": _F, "reference_energy_spread": _F,
    # sizes
    "n_dof": _I, "n_reduced": _I, "n_training_snapshots": _I, "n_points": _I, "n_reference_points": _I,
    # step statuses
    "n_ok": _I, "n_extrapolation": _I, "n_beyond_validity": _I, "n_failed": _I, "n_not_reached": _I,
    # errors (relative; inf where a step failed against a reference)
    "max_rel_l2": _F, "mean_rel_l2": _F, "max_rel_l2_in_envelope": _F, "rmse_rel": _F, "max_monitor_rel_error": _F,
    # what a user feels of a motion (studies/metrics.py): the worst step's error over the run's peak
    # displacement, and the largest nodal error in the scene's length unit (length_unit)
    "peak_rel_l2": _F, "max_abs_error": _F, "length_unit": _S,
    # the headline (issue 52): the worst error over the claimed range (metrics.claimed_range) over its
    # largest reference displacement; NaN in a store written before it (its validity radii read rel_l2)
    "claimed_error": _F,
    "x_name": _S, "validity_1pct": _F, "validity_5pct": _F,
    # what the validity radii read (studies/metrics.claimed_range): "training" (a path's training
    # range: no point past its top, none the model flags), "extrapolation" (asked: every point),
    # "" (a kind without a training range along its abscissa, or a store written before issue 44)
    "validity_range": _S,
    # the abscissa in the scene's units: x = 1 is x_scale x_unit (load factor 1: the net force, in N ...);
    # reference_limit: where the reference continued past the path stopped converging (evaluation beyond)
    "x_scale": _F, "x_unit": _S, "reference_limit": _F, "n_beyond_reference": _I,
    # evaluation points whose reference coincides with a training snapshot (the model has seen
    # the answer: studies/metrics.seen_points); seen: every reference point was (nothing held
    # out), and the report never recommends such a unit
    "n_seen": _I, "seen": _B,
    # latency [s] and the same-process references
    "haptic_median_s": _F, "haptic_p99_s": _F, "haptic_n": _I, "reconstruct_median_s": _F, "reconstruct_p99_s": _F,
    "reference_step_s": _F, "speedup": _F, "calibration_s": _F, "haptic_per_calibration": _F,
    # the arithmetic floor of the step (OnlineModel.floor_ops, median, timed beside it) and
    # efficiency = floor_s / haptic_median_s (1: nothing but the arithmetic); the floor's p99:
    # floor_p99_s / floor_s is the machine's own tail on the same arithmetic in the same run
    "floor_s": _F, "efficiency": _F, "floor_p99_s": _F,
    "blas": _S, "blas_threads": _I,
    # the machine's load when the unit was timed: the 1-minute load average (os.getloadavg, the
    # unit's own process included) and the CPUs the process may run on (NaN / -1: not recorded)
    "load_average": _F, "n_cpus": _I,
    # offline
    "offline_s": _F, "build_peak_bytes": _I, "model_bytes": _I, "model_info": _S, "unit_wall_s": _F,
    # provenance
    "git_commit": _S, "code_hash": _S, "tissuebench": _S, "numpy": _S, "scipy": _S, "machine": _S, "python": _S,
    "date": _S,
    # a method from another package (rom/plugins.py; "" for a shipped one): its "module:Class",
    # installed distribution and version, and the hash of its package's .py files
    "method_source": _S, "method_distribution": _S, "method_version": _S, "method_code_hash": _S,
}
#: the unit columns that differ between two runs of the same unit: timings and their ratios, memory,
#: dates, the machine, its threads and its load; every other column repeats exactly (errors, counts,
#: statuses, keys)
RUN_DEPENDENT_COLUMNS = frozenset({
    "haptic_median_s", "haptic_p99_s", "reconstruct_median_s", "reconstruct_p99_s", "reference_step_s", "speedup",
    "calibration_s", "haptic_per_calibration", "floor_s", "efficiency", "floor_p99_s", "offline_s", "build_peak_bytes",
    "date", "model_info", "machine", "blas_threads", "unit_wall_s", "load_average", "n_cpus"})
POINT_COLUMNS = {"unit_key": _S, "point": _I, "x": _F, "group": _F, "mu": _S, "status": _S, "message": _S,
                 "rel_l2": _F, "rel_max_displacement": _F, "has_reference": _B,
                 # issue 52: the error over the largest reference of the claimed range (the validity
                 # radius reads it) and the largest nodal error in the scene's length unit
                 "peak_rel": _F, "abs_error": _F,
                 # the reference field equals a training snapshot (the model was trained on it)
                 "seen": _B,
                 # past the training path's top (evaluation.beyond; the continued reference where
                 # it converged): in the validity radius, not in the unit's error columns
                 "beyond": _B,
                 # trajectory points in the constant-load window: E / scale of the model and the
                 # reference (studies/energy.py), NaN elsewhere
                 "energy_rel": _F, "reference_energy_rel": _F}
OUTPUT_COLUMNS = {"unit_key": _S, "point": _I, "x": _F, "monitor": _S, "reference": _F, "rom": _F, "rel_error": _F}
# x: the evaluation abscissa of the timed parameter (protocol._abscissae), NaN when it has none
# floor_s: the model's floor timed right after that step; reconstruct_s: NaN but at the display's frames
LATENCY_COLUMNS = {"unit_key": _S, "sample": _I, "x": _F, "haptic_s": _F, "floor_s": _F, "reconstruct_s": _F}


# what each column holds: the store's reference in the documentation is generated from the schemas
# above and these words (a column without its words fails the docs' test)
UNIT_COLUMNS_DOC = {
    "unit_key": "the unit's key: a hash of its case, scene, method, options, protocol and code",
    "case_name": "the scene (catalogue name or file)", "variant": "the scene's variant", "resolution": "ci or paper",
    "backend": "the reference's backend", "kind": "the model kind: map, path or trajectory",
    "options": "the method's options (JSON)", "label": "method and options, for plots",
    "spec_name": "the sweep's name", "spec_hash": "the spec's hash", "scene_hash": "the scene's content hash",
    "unit_status": "ok or failed", "message": "why a unit failed",
    "reference_status": "what the full model did at the evaluation", "reference_message": "its message",
    "reference_energy_growth": "the reference's energy growth ratio (dynamics)",
    "energy_drift": "the model's long-run energy drift over the final constant-load window (relative; < 0 "
                    "dissipates)", "energy_spread": "the model's energy spread over that window",
    "energy_window_start": "where that window starts", "energy_message": "why the drift is undefined, where it is",
    "reference_energy_drift": "the reference's drift over the window",
    "reference_energy_spread": "the reference's spread over the window",
    "n_dof": "dofs of the full model", "n_reduced": "size of the reduced state",
    "n_training_snapshots": "snapshots learnt from", "n_points": "evaluation points",
    "n_reference_points": "evaluation points with a reference",
    "n_ok": "steps ok", "n_extrapolation": "steps flagged outside the training envelope",
    "n_beyond_validity": "steps flagged past the model's validity radius", "n_failed": "failed steps",
    "n_not_reached": "points the model did not reach",
    "max_rel_l2": "largest relative l2 error of the field (inf where a step failed against a reference)",
    "mean_rel_l2": "mean relative l2 error", "max_rel_l2_in_envelope": "largest relative l2 error inside the "
    "training envelope", "rmse_rel": "sqrt(sum ||u_rom - u_ref||^2 / sum ||u_ref||^2)",
    "max_monitor_rel_error": "largest relative error of a monitored output",
    "x_name": "the evaluation abscissa: load factor, distance to the nearest stored position, time",
    "validity_1pct": "the largest x up to which every peak-normalised error (`peak_rel`) of the claimed range is "
                     "within 1 % (state-relative `rel_l2` in a store written before issue 52)",
    "validity_5pct": "the same within 5 %", "x_scale": "what x = 1 is in the scene's units",
    "x_unit": "that unit", "reference_limit": "where the reference continued past the path stopped converging",
    "validity_range": "the points the validity radius reads: `training` (a path: the training range only), "
                      "`extrapolation` (the evaluation asked `extrapolation = true`: past it too) or empty (every "
                      "point: a distance, a time)",
    "peak_rel_l2": "the worst step's l2 error over the run's peak displacement (inf where every reference is zero)",
    "claimed_error": "the headline error: the worst l2 error over the claimed range (the training range of a path, "
                     "with its held-out states, quarter points and near rest; every point of a motion) over the "
                     "largest reference l2 norm of that range (NaN: a store written before issue 52)",
    "max_abs_error": "the largest nodal displacement error, in `length_unit`",
    "length_unit": "the scene's length unit (`[units] length`) of the absolute error columns",
    "n_beyond_reference": "points past the path's top with a reference",
    "n_seen": "evaluation points whose reference is a training snapshot",
    "seen": "every evaluation point was seen in training (never recommended)",
    "haptic_median_s": "median haptic step (`step` + `outputs`) [s]", "haptic_p99_s": "its 99th percentile [s]",
    "haptic_n": "timed haptic steps", "reconstruct_median_s": "median full-field reconstruction [s]",
    "reconstruct_p99_s": "its 99th percentile [s]", "reference_step_s": "the full model's step, same process [s]",
    "speedup": "reference_step_s / haptic_median_s", "calibration_s": "the 256x256 matmul kernel, same process [s]",
    "haptic_per_calibration": "haptic_median_s / calibration_s (to compare machines)",
    "floor_s": "the step's arithmetic floor (`OnlineModel.floor_ops`) [s]",
    "efficiency": "floor_s / haptic_median_s (1: nothing but the arithmetic)",
    "floor_p99_s": "the floor's 99th percentile [s] (floor_p99_s / floor_s: the machine's tail on the same arithmetic, "
                   "same run)",
    "blas": "the BLAS library", "blas_threads": "its threads while the unit ran",
    "load_average": "the machine's 1-minute load average when the unit was timed (its own process included)",
    "n_cpus": "the CPUs the unit's process could run on",
    "offline_s": "the offline build [s]", "build_peak_bytes": "tracemalloc peak of the build",
    "model_bytes": "the online model's size", "model_info": "what the model reports of itself (JSON)",
    "unit_wall_s": "the whole unit [s]",
    "git_commit": "the commit of the code", "code_hash": "a hash of the package's code",
    "method_source": "a plugin method's module:Class ('' for a shipped one)",
    "method_distribution": "the plugin's installed distribution", "method_version": "its version",
    "method_code_hash": "a hash of the plugin package's .py files",
    "tissuebench": "version", "numpy": "version", "scipy": "version", "machine": "the machine",
    "python": "version", "date": "when the unit ran",
}
POINT_COLUMNS_DOC = {
    "unit_key": "the unit", "point": "its index", "x": "the evaluation abscissa",
    "group": "the group (a stored position, a run)", "mu": "the model's parameters (JSON)",
    "status": "the step's status: ok, extrapolation, beyond_validity, failed", "message": "why",
    "rel_l2": "relative l2 error of the field", "rel_max_displacement": "relative error of the largest displacement",
    "peak_rel": "l2 error of the field over the largest reference l2 norm of the claimed range (the validity "
                "radius reads it)", "abs_error": "the largest nodal displacement error, in the scene's length unit",
    "has_reference": "a reference exists at this point", "seen": "the reference equals a training snapshot",
    "beyond": "past the training path's top", "energy_rel": "the model's energy / scale in the constant-load window",
    "reference_energy_rel": "the reference's",
}
OUTPUT_COLUMNS_DOC = {"unit_key": "the unit", "point": "the evaluation point", "x": "its abscissa",
                      "monitor": "the monitored output", "reference": "the reference's value", "rom": "the model's",
                      "rel_error": "relative error"}
LATENCY_COLUMNS_DOC = {"unit_key": "the unit", "sample": "the timed step's index",
                       "x": "the evaluation abscissa of the timed parameter (NaN without one)",
                       "haptic_s": "the haptic step [s]", "floor_s": "the floor timed right after it [s]",
                       "reconstruct_s": "the reconstruction, at the display's frames only (NaN elsewhere) [s]"}


def arrow_schema(columns: dict) -> pa.Schema:
    return pa.schema([(k, t) for k, t in columns.items()])


_FILL = {_F: np.nan, _I: -1, _S: "", _B: False}


def conform(rows, columns: dict) -> pa.Table:
    """A pyarrow table of ``rows`` (list of dicts) with exactly ``columns`` (missing values filled:
    NaN, -1, "" or False; extra keys are an error, so nothing is silently dropped)."""
    df = pd.DataFrame(list(rows))
    extra = sorted(set(df.columns) - set(columns) - set(PARTITIONS))
    if extra:
        raise ValueError(f"row keys not in the store schema: {extra}")
    data = {}
    for name, typ in columns.items():
        col = df[name] if name in df else pd.Series([_FILL[typ]] * len(df), dtype=object)
        col = col.where(col.notna(), _FILL[typ]) if typ != _F else col
        if typ == _F:
            col = pd.to_numeric(col, errors="coerce").astype(float)
        elif typ == _I:
            col = col.astype("int64")
        elif typ == _B:
            col = col.astype(bool)
        else:
            col = col.astype(str)
        data[name] = pa.array(col.to_numpy(), type=typ)
    return pa.table(data, schema=arrow_schema(columns))
