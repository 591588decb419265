"""What the gate reads and writes: a results folder's units (validated), the A/B artifacts
(``RESULTS/_gate/``) and the JUnit file.

``RESULTS/_gate/ab_samples.parquet`` holds every timed step of the A/B (uid, side, round,
block, sample, haptic_s, plus case, method, options); ``ab_verdicts.parquet`` one row per
unit (ratio, interval, medians, verdict) and ``ab_ratios.png`` plots the ratios with their
intervals beside the threshold. All written atomically, and every path checked before any
work (:func:`check_outputs`): a gate must not run REF's sweep and the A/B for minutes and then
find that it cannot write what it found.
"""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd

from ..studies.atomic_files import OutputPathError, output_file, replacing
from ..studies.results import read_units, write_table
from ..studies.sweep_manifest import read_sweep_manifest

__all__ = ["GateOutputError", "AB_FILES", "check_outputs", "read_gate_results", "write_ab_artifacts", "write_junit"]


class GateOutputError(OSError):
    """A gate output (JUnit, baseline) that cannot be written (the message names the path)."""


#: the A/B's files, in ``RESULTS/_gate/``
AB_FILES = ("ab_samples.parquet", "ab_verdicts.parquet", "ab_ratios.png")


def check_outputs(results_dir, junit=None, ab: bool = False) -> None:
    """Refuse, before any work, an output the check would fail to write at its end
    (:class:`~tissuebench.studies.atomic_files.OutputPathError`, naming the argument and the path):
    ``junit`` (``--junit``) that is a folder, a device, a FIFO, a loop of links, under a file, in
    an unwritable folder or in a folder that does not exist (a new folder is not made for it);
    with ``ab``, the A/B's files in ``RESULTS/_gate/`` (:data:`AB_FILES`): ``_gate`` that is not
    a folder, a file of it that is not a regular file, an unwritable folder."""
    if junit is not None:
        target = output_file(junit, "--junit")
        if not target.parent.is_dir():
            raise OutputPathError(f"--junit {junit}: the folder {target.parent} does not exist (create it first, "
                                  f"e.g. mkdir -p {target.parent})")
    if ab:
        folder = Path(results_dir) / "_gate"
        try:
            for name in AB_FILES:
                output_file(folder / name, "results")
        except OutputPathError as exc:
            raise OutputPathError(f"{exc} (the A/B's samples, verdicts and plot are written to {folder}/ at the "
                                  "end of the check)") from None


def read_gate_results(results_dir) -> tuple[dict, str]:
    """``({(case, method, canonical options): unit row}, error metric)`` of a results folder,
    ``error`` set to the sweep's metric. ValueError naming the folder or file when there are
    no units, the manifest is damaged (:func:`~tissuebench.studies.sweep_manifest.read_sweep_manifest`),
    a file in the store is not one the store wrote (refused, not skipped: a gate must not pass
    on what it could not read), or a unit appears twice."""
    root = Path(results_dir)
    if not root.is_dir():
        raise ValueError(f"results {root}: not a folder")
    metric = read_sweep_manifest(root, missing_ok=True)["error_metric"]
    units = read_units(root, foreign="raise")
    if units.empty:
        raise ValueError(f"results {root}: no sweep results (no case=*/method=*/*.parquet)")
    units["error"] = units[metric].astype(float)
    rows = {}
    for _, r in units.iterrows():
        try:
            opts = json.dumps(json.loads(r["options"]), sort_keys=True, separators=(",", ":"))
        except (TypeError, ValueError):
            raise ValueError(f"results {root}: unit {r['case']}/{r['method']}: options {r['options']!r} "
                             "is not JSON") from None
        key = (str(r["case"]), str(r["method"]), opts)
        if key in rows:
            raise ValueError(f"results {root}: unit {' '.join(key)} is stored twice")
        rows[key] = r
    return rows, metric


def write_ab_artifacts(results_dir, samples: pd.DataFrame, verdicts: dict, against: str, sha: str) -> str:
    """Write ``RESULTS/_gate/`` (module docstring); returns a note ('' when all was written)."""
    folder = Path(results_dir) / "_gate"
    table = pd.DataFrame([{"case": k[0], "method": k[1], "options": k[2], "uid": v.uid, "ratio": v.ratio,
                           "low": v.low, "high": v.high, "threshold": v.threshold, "ref_median_s": v.ref_median_s,
                           "head_median_s": v.head_median_s, "rounds": v.rounds, "blocks": v.blocks,
                           "verdict": v.verdict, "decided": v.decided, "floor_s": v.floor_s,
                           "held_by_floor": v.held_by_floor, "expected": v.expected, "against": against,
                           "ref_commit": sha}
                          for k, v in verdicts.items()])
    try:
        folder.mkdir(exist_ok=True)
        write_table(samples, folder / AB_FILES[0])
        write_table(table, folder / AB_FILES[1])
    except OSError as exc:
        return f"the A/B samples could not be written to {folder}: {exc.strerror or exc}"
    try:
        _plot(table, folder / AB_FILES[2], against)
    except Exception as exc:  # noqa: BLE001 - a picture must never cost the verdict (it is computed and kept)
        return f"the A/B plot {folder / AB_FILES[2]} could not be drawn: {type(exc).__name__}: {exc}"
    return ""


def _plot(table: pd.DataFrame, path: Path, against: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = table.sort_values("ratio").reset_index(drop=True)
    fig, ax = plt.subplots(figsize=(8, 0.28 * len(t) + 1.5))
    y = range(len(t))
    colors = ["tab:red" if v == "slower" else "tab:green" if v == "faster" else "tab:blue" for v in t["verdict"]]
    # each interval drawn from its ends (a bootstrap interval need not hold the point estimate; an
    # interval of one sample is NaN: no line)
    ax.hlines(list(y), t["low"], t["high"], color="0.6")
    ax.scatter(t["ratio"], y, c=colors, zorder=3, s=18)
    ax.axvline(1.0, color="0.3", lw=0.8)
    for thr in sorted(set(t["threshold"])):
        ax.axvline(thr, color="tab:red", ls="--", lw=0.8)
    ax.set_yticks(list(y), [f"{c} {m} {o[:40]}" for c, m, o in zip(t["case"], t["method"], t["options"])],
                  fontsize=6)
    ax.set_xscale("log")
    ax.set_xlabel(f"median haptic step, this code / {against} (95 % interval; dashed: decision threshold)")
    fig.tight_layout()
    with replacing(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def write_junit(result, path) -> None:
    """One test case per unit checked (a failure per finding; the changes this commit declared
    for it, ``result.declared``, as its ``system-out``), and with REF the project and each
    side as properties (``project``, ``ref``, ``head``); atomic
    (:func:`~tissuebench.studies.atomic_files.replacing`). GateOutputError naming the path when
    it cannot be written, OutputPathError (a ValueError) when it is not a regular file."""
    cases = result.per_unit
    suite = ET.Element("testsuite", name="tissuebench.check", tests=str(len(cases) + len(result.new_units)),
                       failures=str(sum(1 for f in cases.values() if f)))
    said = ([("project", result.project)] if result.project else []) + [(line.split(" ", 1)[0].lower(), line.split(
        " ", 1)[1].strip()) for line in result.sides]
    if said:  # with REF: the repository, and what each side ran (commit, package versions)
        props = ET.SubElement(suite, "properties")
        for name, value in said:
            ET.SubElement(props, "property", name=name, value=value)
    for (case, method, options), found in cases.items():
        tc = ET.SubElement(suite, "testcase", classname=f"{case}.{method}", name=options)
        for f in found:
            ET.SubElement(tc, "failure", message=f"{f.metric} regressed", type="regression").text = f.line()
        if result.declared.get((case, method, options)):
            ET.SubElement(tc, "system-out").text = "\n".join(f"declared: {t}" for t in
                                                             result.declared[(case, method, options)])
    for case, method, options in result.new_units:
        if (case, method, options) not in cases:
            ET.SubElement(suite, "testcase", classname=f"{case}.{method}", name=options).append(
                ET.Element("system-out"))
    path = Path(path)
    if path.is_dir():
        raise GateOutputError(f"--junit {path}: is a folder")
    try:
        with replacing(path, "--junit") as tmp:  # a device, a FIFO refused (OutputPathError); a link written through
            ET.ElementTree(suite).write(tmp, encoding="utf-8", xml_declaration=True)
    except OSError as exc:
        raise GateOutputError(f"--junit {path}: cannot be written: {exc.strerror or exc}") from None

