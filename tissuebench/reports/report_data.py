"""What a report reads from a results folder, read once: unit rows, points, outputs, the derived
tables, the manifest and the optional anchors table.

Nothing here writes or computes anything expensive: a missing derived table is recomputed
from the unit rows (:func:`~tissuebench.studies.metrics.pareto_front`), a missing manifest
gives the error metric ``max_rel_l2`` and empty provenance, both said in ``notes``. A damaged
manifest is refused (:func:`~tissuebench.studies.sweep_manifest.read_sweep_manifest`); files that are
not part of the store (a foreign Parquet file ...) are ignored and named in ``notes``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from ..studies.metrics import pareto_front
from ..studies.results import read_outputs, read_points, read_units
from ..studies.sweep_manifest import read_sweep_manifest

__all__ = ["ReportData", "load_results", "ANCHOR_COLUMNS"]

ANCHOR_COLUMNS = ["case", "quantity", "ours", "anchor", "low", "high", "source", "verdict"]


@dataclass
class ReportData:
    """The contents of one results folder, restricted to the selected cases."""

    root: Path
    units: pd.DataFrame
    points: pd.DataFrame
    outputs: pd.DataFrame
    pareto: pd.DataFrame
    radius: pd.DataFrame
    manifest: dict
    error_metric: str
    anchors: pd.DataFrame | None
    notes: list = field(default_factory=list)
    backends: pd.DataFrame | None = None  # _backends.parquet of `tissuebench verify RESULTS`
    convergence: pd.DataFrame | None = None  # _convergence.parquet: the reference at h and h/2

    @property
    def cases(self) -> list:
        """Case ids (the store's ``case`` partition) in the order of first appearance."""
        return list(dict.fromkeys(self.units["case"]))


def _manifest(root: Path, notes: list) -> dict:
    manifest = read_sweep_manifest(root, missing_ok=True)
    if not manifest:
        notes.append("_sweep.json is missing: no spec text or sweep provenance (rows carry their own)")
    return manifest


def _foreign_notes(foreign: list, notes: list) -> None:
    for path, why in foreign[:10]:
        notes.append(f"{path}: not a file of this results store ({why}): ignored")
    if len(foreign) > 10:
        notes.append(f"{len(foreign) - 10} more files that are not part of the store were ignored")


def _select(df: pd.DataFrame, keys) -> pd.DataFrame:
    if df.empty or "unit_key" not in df:
        return df
    return df[df["unit_key"].isin(keys)].reset_index(drop=True)


def _select_cases(units: pd.DataFrame, case: str | None) -> pd.DataFrame:
    if case is None:
        return units
    hit = units[(units["case"] == case) | (units["case_name"] == case)]
    if hit.empty:
        valid = sorted(set(units["case"]) | set(units["case_name"]))
        raise ValueError(f"case = {case!r}: not in the results; valid: {valid}")
    return hit


def load_results(results_dir, case: str | None = None) -> ReportData:
    """Read a results folder (see :mod:`tissuebench.studies.results`) for a report.

    Parameters
    ----------
    results_dir : path
        A folder written by ``tissuebench sweep``.
    case : str, optional
        Only this case id (or every case id of this catalogue case name).
    """
    root = Path(results_dir)
    if not root.is_dir():
        raise ValueError(f"results_dir = {str(root)!r}: not a folder")
    foreign: list = []
    units = read_units(root, foreign)
    if units.empty:
        raise ValueError(f"results_dir = {str(root)!r}: holds no unit rows (case=*/method=*/*.parquet); "
                         "run `tissuebench sweep SPEC --out RESULTS_DIR` first")
    notes: list = []
    manifest = _manifest(root, notes)
    metric = manifest.get("error_metric", "max_rel_l2")
    for s in manifest.get("not_applicable", []):  # left out before any work (studies.applicability)
        notes.append(f"not applicable, not run: {s.get('method', '?')} on {s.get('case', '?')}"
                     + (f" ({s['options']})" if s.get("options") else "") + f": {s.get('why', '')}")
    units = _select_cases(units, case).reset_index(drop=True)
    keys = set(units["unit_key"])
    pareto = _derived(root, "pareto.parquet", notes)
    if pareto is not None and (not keys <= set(pareto["unit_key"])
                               or set(pareto.get("error_metric", pd.Series([metric]))) != {metric}):
        notes.append("_derived/pareto.parquet does not cover every unit or has another error metric (stale): "
                     "recomputed from the rows")
        pareto = None
    if pareto is None:
        pareto = pareto_front(units, error=metric).rename(columns={metric: "error"})
    radius = _derived(root, "radius.parquet", notes)
    if radius is None:
        radius = units[["case", "method", "label", "options", "unit_key", "x_name", "validity_1pct",
                        "validity_5pct"]].copy()
    anchors = _anchors(root, notes)
    if anchors is not None and case is not None:
        names = set(units["case"]) | set(units["case_name"])
        anchors = anchors[anchors["case"].astype(str).isin(names)].reset_index(drop=True)
    backends = _backends(root, notes)
    if backends is not None and case is not None:
        backends = backends[backends["case"].astype(str).isin(set(units["case"]))].reset_index(drop=True)
    points, outputs = read_points(root, foreign), read_outputs(root, foreign)
    _foreign_notes(foreign, notes)
    path = root / "_convergence.parquet"
    convergence = _side_table(path, notes, ("case", "quantity", "h", "h_half", "rel_diff")) if path.is_file() else None
    return ReportData(root, units, _select(points, keys), _select(outputs, keys),
                      _select(pareto, keys), _select(radius, keys), manifest, metric, anchors, notes, backends,
                      convergence)


_DERIVED_COLUMNS = {"pareto.parquet": ["case", "method", "label", "options", "unit_key", "pareto", "error",
                                        "error_metric"],
                    "radius.parquet": ["case", "method", "label", "options", "unit_key", "x_name", "validity_1pct",
                                       "validity_5pct"]}


def _side_table(path: Path, notes: list, required=()) -> pd.DataFrame | None:
    """A Parquet side table, or None with a note naming it when unreadable or lacking ``required``."""
    try:
        df = pd.read_parquet(path)
    except Exception as exc:  # noqa: BLE001 - pyarrow raises several types for a damaged file
        notes.append(f"{path}: not a readable Parquet table ({type(exc).__name__}): ignored")
        return None
    missing = [c for c in required if c not in df]
    if missing:
        notes.append(f"{path}: lacks the columns {missing}: ignored")
        return None
    return df


def _derived(root: Path, name: str, notes: list) -> pd.DataFrame | None:
    path = root / "_derived" / name
    if not path.is_file():
        notes.append(f"_derived/{name} is missing: recomputed from the unit rows")
        return None
    df = _side_table(path, notes, _DERIVED_COLUMNS[name])
    if df is not None and name == "pareto.parquet" and df["pareto"].dtype != bool:
        notes.append(f"{path}: its column 'pareto' is not boolean: recomputed from the unit rows")
        return None
    return df


def _backends(root: Path, notes: list) -> pd.DataFrame | None:
    path = root / "_backends.parquet"
    return _side_table(path, notes, ("case", "verdict")) if path.is_file() else None


def _anchors(root: Path, notes: list) -> pd.DataFrame | None:
    path = root / "_anchors.parquet"
    if not path.is_file():
        return None
    df = _side_table(path, notes, ("case",))
    if df is None:
        return None
    missing = [c for c in ANCHOR_COLUMNS if c not in df]
    if missing:
        notes.append(f"_anchors.parquet lacks the columns {missing}: shown as '-'")
        for c in missing:
            df[c] = None
    return df[ANCHOR_COLUMNS + [c for c in df.columns if c not in ANCHOR_COLUMNS]]
