"""``tissuebench report``: one self-contained HTML file answering "which method for this scene".

:func:`write_report` reads a results folder (``tissuebench sweep``) and writes

* ``OUT.html``: works offline, opened from disk: plotly.js is inlined
  (:func:`plotly.offline.get_plotlyjs`), the figures' data embedded as JSON;
* ``OUT_data/``: the data of every plot and table as CSV, linked from the page.

Per case: the accuracy-versus-latency Pareto front, error versus load factor / distance /
time with the validity radii, the recommendation for the requirement, the extremes table
with pass/fail, offline cost and memory; per scene: the paper's figures beside ours; then
the verification anchors, the calibration kernel and the provenance.

Every user-supplied string is escaped: the template is rendered with jinja2 autoescape on,
figure data are embedded with the ``tojson`` filter (``<``, ``>``, ``&`` and ``'`` become
``\\u003c`` ...; ``</script>`` in a string cannot end the script block), and strings inside
figures are HTML-escaped for plotly's own label markup.
"""
from __future__ import annotations

import datetime as _dt
import math
import os
import re
import shutil
from pathlib import Path

import jinja2
import numpy as np
import pandas as pd

from ..reference.provenance import git_commit, package_versions
from ..studies.atomic_files import new_folder, output_file, write_text
from .extremes import extremes_table
from .format import seconds
from .ladder import ladder_section, versus_baselines
from .scaling import scaling_section
from .paper import paper_rows
from .peers import peers_section
from .plotly_figures import error_figure, pareto_figure
from .recommend import LATENCY_STATISTIC, parse_requirement
from .report_data import load_results
from .report_sections import (Table, anchors_table, backends_table, calibration, convergence_table,
                              extremes_table_view, offline_table, one_line, paper_table, provenance_rows,
                              radius_table, ranking_table, recommendation, scene_info, scene_of)
from .wording import case_titles, mesh_text, metric_words, monitors_note

__all__ = ["write_report", "verdict_lines", "report_titles", "TEMPLATES", "DEFAULT_NAME"]

TEMPLATES = Path(__file__).resolve().parent / "templates"
DEFAULT_NAME = Path("_report") / "report.html"  # inside a results folder (a '_' folder is not part of the dataset)
_MARKER = ".tissuebench-report"  # in the data folder: a later report may replace the folder


def _file_part(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]", "_", str(text))[:80] or "_"


def _case_units(data, case):
    units = data.units[data.units["case"] == case].copy()
    flags = data.pareto.set_index("unit_key")["pareto"] if "pareto" in data.pareto else pd.Series(dtype=bool)
    units["pareto"] = units["unit_key"].map(flags).fillna(False).astype(bool)
    units["error"] = units[data.error_metric].astype(float)
    return units.reset_index(drop=True)


def _case_section(data, case, index, requirement, figures, tables, title):
    units = _case_units(data, case)
    scene, scene_error = scene_of(units)
    part = f"{index:02d}_{_file_part(case)}"
    pareto, pareto_data = pareto_figure(title, units, data.error_metric, requirement)
    err, err_data = error_figure(title, units, data.points)
    figures[f"pareto-{index}"], figures[f"error-{index}"] = pareto, err
    tables += [Table(f"pareto_{part}", [], [], pareto_data), Table(f"error_{part}", [], [], err_data)]
    rec = recommendation(units, requirement, data.error_metric, data.points)
    ext = extremes_table(units, data.points, {case: scene_info(scene)})
    section = {"case": case, "title": title, "index": index, "scene": scene, "scene_error": scene_error,
               "mesh": mesh_text(scene) if scene is not None else "",
               "monitors": monitors_note(scene, data.outputs, units["unit_key"]),
               "n_units": len(units), "n_plotted": len(pareto_data),
               "n_failed": int((units["unit_status"] != "ok").sum()),
               "pareto_csv": f"pareto_{part}.csv", "error_csv": f"error_{part}.csv", "recommendation": rec,
               "versus": versus_baselines(rec["ranked"]),
               "ranking": ranking_table(f"ranking_{part}", rec["ranked"]),
               "extremes": extremes_table_view(f"extremes_{part}", ext),
               "offline": offline_table(f"offline_{part}", units), "radius": radius_table(f"radius_{part}", units),
               "reference_step": units["reference_step_s"].median(),
               "failed_units": units[units["unit_status"] != "ok"]}
    tables += [section[k] for k in ("ranking", "extremes", "offline", "radius")]
    return section


def report_titles(data) -> dict:
    """``{case id: title}`` of a results folder's cases (:func:`~.wording.case_titles`)."""
    scenes = {c: scene_of(data.units[data.units["case"] == c])[0] for c in data.cases}
    return case_titles(data.units, data.manifest, scenes)


def verdict_lines(results_dir, require: str | None = None, case: str | None = None) -> list[str]:
    """One line per case of a results folder: its title and the recommendation's verdict for
    ``require`` (the unit that meets it with the largest margin, or the closest and what it
    misses by): what ``tissuebench report`` prints beside the page's path."""
    requirement = parse_requirement(require)
    data = load_results(results_dir, case)
    titles = report_titles(data)
    return [f"{titles[c]}: "
            f"{one_line(recommendation(_case_units(data, c), requirement, data.error_metric, data.points))}"
            for c in data.cases]


def _paper_sections(data, tables):
    """One section per scene (catalogue case, variant, resolution), over every case id of it."""
    out = []
    for i, ((name, variant, res), units) in enumerate(data.units.groupby(["case_name", "variant", "resolution"],
                                                                         sort=False)):
        scene, error = scene_of(units)
        title = f"{name}" + (f" [{variant}]" if variant else "") + f" ({res})"
        if scene is None or not scene.paper:
            out.append({"title": title, "error": error or "the catalogue has no [paper] table", "table": None})
            continue
        rows = paper_rows(scene, units, data.outputs, data.error_metric)
        table = paper_table(f"paper_{i:02d}_{_file_part(title)}", rows)
        tables.append(table)
        out.append({"title": title, "source": scene.case.get("paper", ""), "error": "", "table": table})
    return out


def _environment() -> jinja2.Environment:
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(TEMPLATES), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters["seconds"] = seconds
    return env


def _plotly_js() -> str:
    from plotly.offline import get_plotlyjs

    js = get_plotlyjs()
    if "</script" in js.lower():  # would end the inline script block early
        raise RuntimeError("plotly.js contains '</script': cannot be inlined")
    return js


def _jsonable(obj):
    """Figures with NaN/inf replaced by None (JSON has neither)."""
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, (np.integer, np.bool_)):
        return obj.item()
    return obj


# the folders of a results store that hold data read back (the datasets, the derived tables):
# a report there would be read as data, or overwrite it
_STORE_DATA = ("_points", "_outputs", "_latency", "_derived")
_REPORT_SUFFIXES = (".html", ".htm")


def _check_out(out_html: Path, results_dir, force: bool = False) -> Path:
    """Refuse, before any work, an output that would damage a store or another file: a name
    that is not ``.html``, a place inside a store's data (its datasets, ``_derived``, a
    ``case=`` partition, directly in a store), an existing file that no report wrote (unless
    ``force``), a folder, a device, a FIFO, a loop of links, an unwritable place. Returns the
    file to write: ``out_html``, or the end of its links (written through)."""
    text = str(out_html)
    if "\0" in text:
        raise ValueError(f"out_html = {text!r}: contains a NUL byte")
    if out_html.is_dir():
        raise ValueError(f"out_html = {text!r}: is a folder; give a file name like report.html")
    out_html = output_file(out_html, "out_html =")  # before _is_report opens it (a FIFO would block)
    if out_html.suffix.lower() not in _REPORT_SUFFIXES:
        raise ValueError(f"out_html = {text!r}: a report is an HTML file; give a name ending in .html")
    for root in {Path(results_dir), *_stores_above(out_html)}:
        rel = _relative(out_html, root)
        if rel is None:
            continue
        folders = rel.parts[:-1]
        if not folders or folders[0] in _STORE_DATA or not folders[0].startswith(("_", ".")) or any(
                p.startswith(("case=", "method=")) for p in folders):
            # pandas/pyarrow would read the page and its CSVs as part of the results, or replace its tables
            raise ValueError(f"out_html = {text!r}: inside the results folder only under a folder starting with "
                             f"'_' of its own (e.g. {str(root / DEFAULT_NAME)!r}), never in "
                             f"{', '.join(_STORE_DATA)} or a case= partition of {str(root)!r}: the store would "
                             "stop reading")
    if out_html.exists() and not force and not _is_report(out_html):
        raise ValueError(f"out_html = {text!r}: exists and is not a report written by tissuebench; choose another "
                         "name, or pass --force to replace it")
    parent = next((p for p in [out_html.parent, *out_html.parent.parents] if p.exists()), Path("."))
    if not parent.is_dir():
        raise ValueError(f"out_html = {text!r}: {str(parent)!r} is not a folder")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"out_html = {text!r}: the folder {str(parent)!r} is not writable")
    return out_html


def _stores_above(path: Path) -> list:
    """The results folders (holding ``_sweep.json``) among the folders above ``path``."""
    try:
        above = path.absolute().parents
        return [p for p in above if (p / "_sweep.json").is_file()]
    except OSError:
        return []


def _is_report(path: Path) -> bool:
    """Was ``path`` written by a report: its data folder carries the marker, or its title says so."""
    if (path.with_name(f"{path.stem}_data") / _MARKER).is_file():
        return True
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    return head.startswith(b"<!DOCTYPE html>") and b"<title>tissuebench report" in head


def _relative(path: Path, root: Path):
    try:
        return path.resolve().relative_to(root.resolve())
    except ValueError:
        return None


def _data_folder(out_html: Path) -> Path:
    """``<stem>_data`` beside the page; an existing folder is replaced only if a report wrote it."""
    folder = out_html.with_name(f"{out_html.stem}_data")
    if folder.exists() and not (folder / _MARKER).is_file():
        raise ValueError(f"out_html = {str(out_html)!r}: its data folder {str(folder)!r} exists and was not written "
                         "by a report; move it or choose another file name")
    return folder


def _write(out_html: Path, page: str, tables: list) -> None:
    """The data folder then the page, each through a temporary name (no half-written report)."""
    folder = _data_folder(out_html)
    out_html.parent.mkdir(parents=True, exist_ok=True)
    tmp = new_folder(out_html.parent, f".{folder.name}.", like=folder)
    try:
        for t in tables:
            t["data"].to_csv(tmp / t["csv"], index=False)
        (tmp / _MARKER).write_text(f"written by tissuebench report for {out_html.name}\n")
        if folder.exists():
            shutil.rmtree(folder)
        tmp.rename(folder)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    write_text(out_html, page, "out_html =")


def write_report(results_dir, out_html, require: str | None = None, case: str | None = None,
                 force: bool = False) -> Path:
    """Write the HTML report of a results folder (module docstring); returns the HTML path.

    Parameters
    ----------
    results_dir : path
        A folder written by ``tissuebench sweep``.
    out_html : path
        The HTML file (``.html``); its data go to ``<stem>_data/`` beside it (both replaced).
        Inside a results folder only under a ``_`` folder of its own, e.g.
        ``RESULTS/_report/report.html`` (:data:`DEFAULT_NAME`), never in the store's data
        (``_points``, ``_outputs``, ``_latency``, ``_derived``, ``case=`` partitions). An existing
        file is replaced only when a report wrote it, or with ``force``.
    require : str, optional
        ``"rate>=500Hz, error<=2%"`` (see :mod:`.recommend`); default 1 kHz and 1 %.
    case : str, optional
        Only this case id (or the case ids of this catalogue case name).
    force : bool
        Replace an existing file that no report wrote (never one inside a store's data).
    """
    requirement = parse_requirement(require)
    out_html = _check_out(Path(out_html), results_dir, force)
    _data_folder(out_html)
    data = load_results(results_dir, case)
    figures, tables = {}, []
    titles = report_titles(data)
    sections = [_case_section(data, c, i, requirement, figures, tables, titles[c]) for i, c in enumerate(data.cases)]
    papers = _paper_sections(data, tables)
    anchors = anchors_table("anchors", data.anchors) if data.anchors is not None else None
    if anchors is not None:
        tables.append(anchors)
    backends = backends_table("backends", data.backends) if data.backends is not None else None
    if backends is not None:
        tables.append(backends)
    convergence = convergence_table("convergence", data.convergence) if data.convergence is not None else None
    if convergence is not None:
        tables.append(convergence)
    ladder = ladder_section(data, Table, titles)
    tables += ladder["tables"] if ladder else []
    scaling = scaling_section(data, Table)  # cost versus size (studies/scaling.py)
    tables += scaling["tables"] if scaling else []
    peers = peers_section(data, Table, titles)  # a library's adapter beside the shipped method of its family
    tables += peers["tables"] if peers else []
    tables.append(Table("units", [], [], data.units))
    context = {"title": f"tissuebench report: {data.manifest.get('spec_name', data.root.name)}",
               "data_folder": f"{out_html.stem}_data", "requirement": requirement, "require_text": requirement.text,
               "error_metric": data.error_metric, "error_words": metric_words(data.error_metric),
               "latency_statistic": LATENCY_STATISTIC, "sections": sections,
               "papers": papers, "ladder": ladder, "scaling": scaling, "peers": peers, "anchors": anchors,
               "backends": backends,
               "convergence": convergence, "convergence_how": _convergence_how(data.convergence),
               "calibration": calibration(data.units),
               "provenance": provenance_rows(data.manifest, data.units),
               "spec_text": data.manifest.get("spec_text", ""),
               "description": _description(data.manifest), "notes": data.notes, "results_dir": str(data.root),
               "generated": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
               "generator": f"tissuebench {package_versions().get('tissuebench')} ({git_commit()[:12]})",
               "figures": _jsonable(figures), "plotly_js": _plotly_js()}
    page = _environment().get_template("report.html.j2").render(**context)
    _write(out_html, page, tables)
    return out_html


def _convergence_how(conv) -> str:
    """What the convergence check solved (its ``how`` column, the formulation and why)."""
    if conv is None or "how" not in conv or not len(conv):
        return ""
    return "; ".join(dict.fromkeys(str(h) for h in conv["how"]))


def _description(manifest: dict) -> str:
    import tomllib

    try:
        return str(tomllib.loads(manifest.get("spec_text", "")).get("sweep", {}).get("description", ""))
    except (tomllib.TOMLDecodeError, TypeError, AttributeError):
        return ""
