"""Backend agreement of a sweep's scenes: which scenes a sweep ran, for ``tissuebench verify``.

:func:`scenes_of_results` reads the case entries of a sweep's ``_sweep.json`` back as scenes;
:func:`~tissuebench.reference.backend_comparison.backend_agreement` (the reference layer)
solves each finite-element scene with both backends and compares them, one row per scene
with a verdict against :data:`~tissuebench.reference.backend_comparison.RTOL`; the report's
Verification section shows the table (:mod:`.report_sections`).
"""
from __future__ import annotations

from ..studies.sweep_manifest import SweepManifestError, read_sweep_manifest
from ..studies.case_entry import CaseEntry
from ..studies.training import case_scene

__all__ = ["scenes_of_results"]


def scenes_of_results(results) -> list:
    """``[(case id, scene)]`` of the case entries a sweep ran (``cases`` of its ``_sweep.json``)."""

    meta = read_sweep_manifest(results)
    if "cases" not in meta:
        raise ValueError(f"{results}/_sweep.json has no 'cases' (written by an older tissuebench): rerun the sweep "
                         "with --resume to record them")
    out = []
    for i, c in enumerate(meta["cases"]):
        missing = [k for k in ("name", "resolution", "backend") if k not in c]
        if missing:
            raise SweepManifestError(f"{results}/_sweep.json: cases[{i}].{missing[0]}: missing")
        try:
            out.append((c["id"], case_scene(CaseEntry.from_dict(c))))
        except (ValueError, TypeError) as exc:
            raise SweepManifestError(f"{results}/_sweep.json: cases[{i}]: {exc}") from None
    return out
