"""Studies run from the command line: ``tissuebench study NAME``.

A study is split into units (one case, one part); each finished unit is written at once
(atomically) into ``<out>.partial/`` under a hash of its configuration, so an
interrupted study resumes without redoing finished units; the final folder is then
assembled atomically and the partial folder removed.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd

from .store import atomic_directory, hash_json, provenance, write_json_atomic

__all__ = ["STUDIES", "run_study", "ANM_POD_SETTINGS"]

# the sweep of the issue (paper) and the one CI runs (ci)
ANM_POD_SETTINGS = {
    "paper": {"cases": ["cornea_pinch", "liver_palpation"], "modes": list(range(1, 16)),
              "orders": list(range(1, 11)), "n_lattice": 7, "latency_steps": 2000},
    "ci": {"cases": ["cornea_pinch", "liver_palpation"], "modes": [1, 2, 3, 4, 6, 9],
           "orders": [1, 2, 3, 4, 6, 8, 10], "n_lattice": 4, "latency_steps": 1000},
}


def _unit(partial: Path, name: str, config: dict, compute):
    """Tables of unit ``name``: loaded from ``partial`` when a finished unit with the same
    configuration is there, else computed (``compute() -> {part: rows}``) and stored. A
    unit counts as finished only once its marker is written, after all its tables."""
    stem = partial / f"{name}-{hash_json(config)[:16]}"
    marker = stem.with_suffix(".done")
    if marker.exists():
        parts = marker.read_text().split()
        return {k: pd.read_parquet(f"{stem}.{k}.parquet") for k in parts}, True
    tables = {k: pd.DataFrame(v) for k, v in compute().items()}
    for k, df in tables.items():
        tmp = Path(f"{stem}.{k}.tmp")
        df.to_parquet(tmp, index=False)
        tmp.replace(f"{stem}.{k}.parquet")
    marker.write_text(" ".join(tables))
    return tables, False


def _anm_pod(out: Path, resolution: str, settings: dict, progress_factory):
    from .anm_pod import sweep_case
    from .anm_pod_interp import interpolation_rows

    partial = out.with_name(out.name + ".partial")
    partial.mkdir(parents=True, exist_ok=True)
    rows, curves, interp, resumed = [], [], [], []
    for case in settings["cases"]:
        cfg = {"case": case, "resolution": resolution, "modes": settings["modes"], "orders": settings["orders"],
               "latency_steps": settings["latency_steps"]}
        bar = progress_factory(f"{case}: sweep", len(settings["modes"]) * len(settings["orders"]))

        def compute_sweep():
            r, c, _ = sweep_case(case, settings["modes"], settings["orders"], resolution,
                                 latency_steps=settings["latency_steps"], progress=bar)
            return {"rows": r, "curves": c}
        t, was = _unit(partial, f"{case}-sweep", cfg, compute_sweep)
        rows.append(t["rows"])
        curves.append(t["curves"])
        resumed += [f"{case}-sweep"] if was else []
        icfg = {"case": case, "resolution": resolution, "n_lattice": settings["n_lattice"]}
        ibar = progress_factory(f"{case}: interpolation", 3 * settings["n_lattice"] - 2)
        t, was = _unit(partial, f"{case}-interp", icfg,
                       lambda: {"rows": interpolation_rows(case, settings["n_lattice"], resolution=resolution,
                                                           progress=ibar)})
        interp.append(t["rows"])
        resumed += [f"{case}-interp"] if was else []
    return pd.concat(rows), pd.concat(curves), pd.concat(interp), partial, resumed


def run_study(name: str, out: Path, resolution: str = "ci", overwrite: bool = False, progress: bool = True):
    """Run study ``name`` into ``out`` (see the module docstring); returns the main table."""
    if name not in STUDIES:
        raise ValueError(f"unknown study {name!r}; valid: {sorted(STUDIES)}")
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"output folder {out} exists; pass overwrite (--force) to replace it")
    settings = ANM_POD_SETTINGS[resolution]
    table, curves, interp, partial, resumed = STUDIES[name](out, resolution, settings, _bars(progress))
    prov = provenance(study=name, resolution=resolution, settings=settings, resumed_units=resumed)
    for key in ("git_commit", "date"):
        table[key] = prov[key]
    table["machine"] = prov["machine"]["node"]
    table["numpy"] = prov["versions"]["numpy"]
    from ..reports.study_plots import plot_anm_pod

    with atomic_directory(out, overwrite) as tmp:
        table.to_parquet(tmp / "study.parquet", index=False)
        curves.to_parquet(tmp / "curves.parquet", index=False)
        interp.to_parquet(tmp / "interpolation.parquet", index=False)
        plot_anm_pod(table, curves, interp, tmp)
        write_json_atomic(tmp / "manifest.json", prov)
    shutil.rmtree(partial, ignore_errors=True)
    return table, curves, interp


def _bars(enabled):
    def factory(label, total):
        if not enabled:
            return None
        from tqdm import tqdm

        bar = tqdm(total=total, desc=label, leave=False)
        return lambda: bar.update(1)
    return factory


STUDIES = {"anm_pod": _anm_pod}
