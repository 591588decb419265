"""A results folder built by hand (no solver): units with chosen errors and latencies, their
evaluation points and a manifest, written through the store's own writer. Used by the
report tests; ``evil`` puts markup in every user-supplied string the store lets through."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tissuebench.studies.results import ResultsStore
from tissuebench.studies.units import UnitOutcome, options_text

EVIL = "<script>alert(1)</script>"
# (method, options, error max_rel_l2, haptic median [s], p99 [s]); reference step 10 ms
UNITS = [
    ("fast_rough", {"n_modes": 2}, 0.030, 20e-6, 60e-6),    # fast, 3 % error
    ("fast_rough", {"n_modes": 4}, 0.015, 40e-6, 1.5e-3),    # 1.5 %, p99 1.5 ms: 667 Hz on the p99
    ("accurate", {"n_modes": 9}, 0.004, 300e-6, 2.5e-3),     # 0.4 %, p99 2.5 ms: 400 Hz
    ("accurate", {"n_modes": 16}, 0.002, 900e-6, 4e-3),      # dominated in latency, best error
    ("slow", {}, 0.050, 2e-3, 3e-3),                         # dominated
]


def point_rows(error: float, n: int = 6, beyond_status: str = "extrapolation"):
    xs = np.linspace(1.0 / n, 1.0, n)
    rows = [{"point": k, "x": float(x), "group": np.nan, "mu": f"load_factor={x:.6g}", "status": "ok", "message": "",
             "rel_l2": float(error * x), "rel_max_displacement": float(error * x / 2), "has_reference": True}
            for k, x in enumerate(xs)]
    rows.append({"point": n, "x": 2.0, "group": np.nan, "mu": "load_factor=2", "status": beyond_status,
                 "message": "past the training envelope", "rel_l2": np.nan, "rel_max_displacement": np.nan,
                 "has_reference": False})
    return rows


def unit_row(case, method, options, error, median, p99, evil, info=None):
    label = f"{method} " + " ".join(f"{k}={v}" for k, v in sorted(options.items()))
    return {"unit_key": "", "case": case, "case_name": "cornea_pinch", "variant": "", "resolution": "ci",
            "backend": "skfem", "method": method, "kind": "path", "options": options_text(options),
            "label": label.strip(), "spec_name": EVIL if evil else "handmade", "spec_hash": "0" * 64,
            "scene_hash": "1" * 64, "unit_status": "ok", "message": "", "n_dof": 657, "n_reduced": 4,
            "n_training_snapshots": 5, "n_points": 7, "n_reference_points": 6, "n_ok": 6, "n_extrapolation": 1,
            "n_beyond_validity": 0, "n_failed": 0, "n_not_reached": 0, "max_rel_l2": error, "mean_rel_l2": error / 2,
            "max_rel_l2_in_envelope": error, "rmse_rel": error * 0.7, "max_monitor_rel_error": error,
            "x_name": "load_factor", "validity_1pct": min(1.0, 0.01 / error), "validity_5pct": min(1.0, 0.05 / error),
            "haptic_median_s": median, "haptic_p99_s": p99, "haptic_n": 200, "reconstruct_median_s": 1e-4,
            "reconstruct_p99_s": 2e-4, "reference_step_s": 10e-3, "speedup": 10e-3 / median, "calibration_s": 1e-3,
            "haptic_per_calibration": median / 1e-3, "floor_s": median / 4, "efficiency": 0.25,
            "floor_p99_s": median / 4 * 1.6,
            "blas": "openblas", "blas_threads": 1, "offline_s": 0.5,
            "build_peak_bytes": 2_000_000, "model_bytes": 10_000, "model_info": json.dumps(info or {}),
            "git_commit": "abc", "code_hash": "def", "tissuebench": "0.1.0", "numpy": "2", "scipy": "1",
            "machine": "test", "python": "3.11", "date": "2025-01-01T00:00:00+00:00"}


def build_store(root: Path, case: str = "cornea", evil: bool = False, failed_unit: bool = True,
                unflagged: bool = False) -> Path:
    """Write the :data:`UNITS` (plus a failed unit and an unflagged extrapolation when asked)."""
    store = ResultsStore(root)
    rows = []
    for i, (method, opts, err, med, p99) in enumerate(UNITS):
        opts = dict(opts)
        if evil and i == 0:
            opts["note"] = EVIL
        row = unit_row(case, method, opts, err, med, p99, evil)
        if i == 2:
            row["energy_drift"] = 0.002  # a long run's measured drift (studies/energy.py)
        row["unit_key"] = f"{case}-k{i:02d}"
        status = "ok" if (unflagged and i == 1) else "extrapolation"
        store.write_unit(UnitOutcome(row, point_rows(err, beyond_status=status)))
        rows.append(row)
    if failed_unit:
        row = unit_row(case, "broken", {}, np.nan, np.nan, np.nan, evil)
        row.update(unit_key=f"{case}-k99", unit_status="failed",
                   message="ValueError: " + (EVIL if evil else "boom"))
        store.write_unit(UnitOutcome(row))
    manifest = {"spec_name": EVIL if evil else "handmade", "spec_hash": "0" * 64, "error_metric": "max_rel_l2",
                "spec_text": '[sweep]\nname = "handmade"\ndescription = "' + (EVIL if evil else "by hand") + '"\n',
                "versions": {"numpy": "2"}, "git_commit": "abc", "machine": {"node": "test"},
                "date": "2025-01-01T00:00:00+00:00", "state": "finished"}
    store.write_manifest(manifest)
    return root


def rename_case(root: Path, old: str, new_folder_name: str) -> None:
    """Rename a case partition folder (e.g. to a URL-encoded name the store itself refuses), in
    the unit rows, the points and the outputs."""
    for base in (root, root / "_points", root / "_outputs"):
        (base / f"case={old}").rename(base / f"case={new_folder_name}")
