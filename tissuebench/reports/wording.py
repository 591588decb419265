"""The report's words for what a sweep stores as ids: error metrics, case entries, meshes, monitors.

A person reads the report: a section is titled by the scene and what was measured ("kidney:
along the load path, between the states it learnt from"), not by the case id a spec generated
("path"); an axis says "worst relative L2 error over the training range", the metric's id
(``max_rel_l2_in_envelope``) beside it in small print; a scene on a user's mesh file names the
file, not the catalogue's resolution; the monitors a model cannot output are named.
"""
from __future__ import annotations

import html
from pathlib import Path

import pandas as pd

__all__ = ["METRIC_WORDS", "metric_words", "case_title", "case_titles", "mesh_text", "monitors_note"]

#: the sweep's error metrics (``[sweep] error_metric``) in words
METRIC_WORDS = {
    "claimed_error": "worst error of the field over the range it claims, relative to the largest displacement there",
    "peak_rel_l2": "worst error of the field over the run, relative to its largest displacement",
    "max_abs_error": "largest nodal displacement error, in the scene's length unit",
    "max_rel_l2": "worst relative L2 error of the field over the evaluation points",
    "max_rel_l2_in_envelope": "worst relative L2 error of the field over the training range",
    "mean_rel_l2": "mean relative L2 error of the field over the evaluation points",
    "rmse_rel": "relative RMS error of the field over the evaluation",
    "max_monitor_rel_error": "worst relative error of a monitored output",
}


def metric_words(metric: str, markup: bool = False) -> str:
    """``metric`` in words; with ``markup`` (a plotly label: HTML escaped) its id below in small
    print. An unknown metric is its id."""
    words = METRIC_WORDS.get(metric, str(metric))
    if not markup:
        return words
    return html.escape(words) + (f"<br><sup>{html.escape(str(metric))}</sup>" if metric in METRIC_WORDS else "")


def _evaluation_words(training: dict, evaluation: dict) -> str:
    kind = evaluation.get("kind", training.get("kind"))
    if kind == "path":
        held = ", between the states it learnt from" if evaluation.get("held_out") else ""
        return "along the load path" + held + (", and past it" if evaluation.get("beyond") else "")
    if kind == "trajectory":
        if "load_scale" in evaluation:
            return f"in time, at {evaluation['load_scale']:g}x the load it learnt"
        return "in time" + (", after the horizon it learnt" if "from_time" in evaluation else "")
    return {"positions": "at load positions between the stored ones", "map": "at parameter points",
            "cut_lengths": "along the incision, cut length by cut length",
            "contact_nodes": "at contact nodes of the surface"}.get(kind, str(kind))


_TRAINING_WORDS = {"path": "learnt from the load path", "positions": "learnt from stored load positions",
                   "trajectory": "learnt from a time history", "operators": "built from its operators, no snapshots"}


def case_title(case: dict, scene_name: str) -> str:
    """``"kidney: along the load path, between the states it learnt from"``, ``"kidney: at contact
    nodes of the surface (built from its operators, no snapshots)"``: a case entry
    (``_sweep.json``'s ``cases``) in words, led by the scene's name."""
    training, evaluation = case.get("training", {}), case.get("evaluation", {})
    variant = f" [{case['variant']}]" if case.get("variant") else ""
    # what it learnt from, where the place it is measured does not say it already
    same = training.get("kind") == evaluation.get("kind", training.get("kind"))
    learnt = "" if same else _TRAINING_WORDS.get(training.get("kind"), "")
    return f"{scene_name}{variant}: {_evaluation_words(training, evaluation)}" + (f" ({learnt})" if learnt else "")


def case_titles(units: pd.DataFrame, manifest: dict, scenes: dict) -> dict:
    """``{case id: title}`` of every case of ``units``: its entry in the manifest in words, led by
    its scene's name (``scenes``: case id -> loaded scene or None; else the catalogue name or the
    scene file's stem); a case the manifest does not list keeps its id."""
    entries = {c.get("id"): c for c in manifest.get("cases", []) if isinstance(c, dict)}
    out = {}
    for case, grp in units.groupby("case", sort=False):
        scene = scenes.get(case)
        name = scene.name if scene is not None else Path(str(grp["case_name"].iloc[0])).stem
        out[case] = case_title(entries[case], name) if case in entries else str(case)
    return out


def mesh_text(scene) -> str:
    """``"mesh file kidney.msh"`` for a scene on a user's mesh file, ``"ci mesh"`` for a catalogue
    scene built at a resolution."""
    spec = getattr(scene, "mesh_spec", {}) or {}
    if spec.get("builder") == "file":
        path = spec.get("file") or spec.get("params", {}).get("path", "")
        return f"mesh file {Path(str(path)).name}"
    return f"{scene.resolution} mesh"


def monitors_note(scene, outputs: pd.DataFrame, keys) -> str:
    """Which of the scene's monitors the units of ``keys`` output beside the reference, and which
    none does (a reduced model outputs the monitors linear in the displacement: a point's
    displacement, not a reaction force or the largest displacement), "" without monitors."""
    names = [m["name"] for m in getattr(scene, "monitors", []) or []] if scene is not None else []
    if not names:
        return ""
    mine = outputs[outputs["unit_key"].isin(set(keys))] if len(outputs) and "unit_key" in outputs else outputs
    compared = [n for n in names if len(mine) and n in set(mine["monitor"])]
    missing = [n for n in names if n not in compared]
    if not compared:
        return (f"No unit outputs a monitor of the scene ({', '.join(missing)}): only the displacement field is "
                "compared with the reference.")
    text = f"Monitored outputs compared with the reference: {', '.join(compared)}."
    if missing:
        text += (f" The scene's other monitors ({', '.join(missing)}) have no output from any unit here (a reduced "
                 "model outputs only the monitors linear in the displacement): they are not compared.")
    return text
