"""The regression gate: ``tissuebench check RESULTS [--baseline FILE] [--against REF] [--require R]``.

Three checks of a sweep's results folder, at least one asked for:

* **Errors, exactly.** With ``--against REF`` (a git ref; CI passes the previous commit, a
  user's CI the merge base) REF is resolved in the repository of the project under test
  (:mod:`tissuebench.gate.project`: ``project``, else the repository of the sweep's plugin
  methods, else the working directory's, else this tissuebench's; said in the output), its
  packages are exported at REF and REF's code runs the same sweep on this machine
  (:mod:`tissuebench.gate.ref`, its processes checked to import REF's copies), and
  every unit's error must equal REF's within ``max(error_rtol * error, error_atol)``
  (defaults 1e-3 and 1e-9), in either direction, unless the baseline file's entry for that
  unit changed in this commit (a declared change, noted). Same machine and packages make
  identical code give bit-identical errors, so nothing here depends on where the baseline
  was written. Without REF the errors are gated against the baseline file (:mod:`.baseline`)
  by the same rule, and the gate says so: no ``--against``, or a shallow clone whose cut history
  lacks REF (the one fallback). A REF git cannot resolve otherwise (a typo, no git checkout, no
  git) or whose code does not import is an error (exit 2), ``--baseline`` or not. REF's code, its
  sweep and the A/B's jobs live in a scratch folder (:mod:`tissuebench.gate.scratch`:
  its processes die with the check; the next check removes what a killed one left).
  A unit missing or failed, or with more flagged steps (failed, extrapolated, beyond
  validity, not reached), regresses too.
* **Latency, A/B in one run** (``--against REF``): every ok unit re-timed with REF's code and
  with this code, a worker process per side timed in turn on one core
  (:mod:`tissuebench.gate.latency`); a unit regresses when its HEAD/REF median ratio
  is judged ``slower`` against ``latency_tolerance`` (default 1.3) and its step grew by at
  least ``latency_floor_s`` (default 10 us; ``--latency-floor-s``; rule in
  :mod:`tissuebench.gate.stats`); a unit the floor held is said in the verdict line. An intended
  slowdown is declared like an error change, in the same commit: the unit's baseline entry gets
  ``latency_change`` (the factor its step grows by, > 1) and ``latency_change_reason``; while the
  commit adds or edits them (the file compared with the same file at REF) the A/B expects that
  factor (the slowdown to catch is ``latency_change * latency_tolerance``, the threshold
  ``latency_change * sqrt(latency_tolerance)``; a failure names both factors), and the declared
  change is noted with the measured ratio, its interval and the reason. The next commit, the
  entry unchanged against its REF, is gated at the normal tolerance again (the keys may stay).
  Without REF (no ``--against``, a shallow clone) latency is **not gated**: the baseline file's
  ratios (haptic median / calibration kernel) move 2-3x between runs of identical code for
  microsecond steps (a user's gate failed 5 of 9 runs of identical code at x1.3), so they are
  printed for information (``file_latency_tolerance``, ``latency_floor``), never a regression;
  a declared ``latency_change`` is shown, nothing else.
* **Absolute requirements** (``--require "rate>=500Hz, error<=2%"``, the report's grammar and
  p99 rule, :mod:`tissuebench.reports.recommend`): every case needs a unit that meets them.

Nothing passes vacuously: a baseline without units, results that share no unit with what
they are compared with, an A/B that compared no unit, or a project under test that holds none
of the sweep's methods (each would run the same code on both sides,
:mod:`tissuebench.gate.scope`) are errors (exit 2); a sweep whose units all failed is a
regression (exit 1). Every path the check writes (``--junit``, ``RESULTS/_gate/``) is checked
before any work (:func:`.io.check_outputs`).

The package, in the layers above the sweep harness it drives (:mod:`tissuebench.studies`) and the
report whose requirement grammar it reads, below the CLI: :mod:`.base` (what the gate finds:
:class:`Finding`, :class:`CheckResult`, :class:`ABSettings`), :mod:`.baseline` (the baseline file),
:mod:`.checks` (the rules, one function each), :mod:`.io` (the results it reads, the A/B's files,
JUnit); REF: :mod:`.project` (the project under test), :mod:`.layout` (where its packages lie),
:mod:`.sides` (the code each side runs), :mod:`.ref` (REF from git and its sweep), :mod:`.scope`
(which methods are the project's), :mod:`.scratch` (the scratch folder and child processes); the
A/B: :mod:`.latency` (the rounds), :mod:`.probe` (one worker process), :mod:`.stats` (the verdict).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import tomlkit

from ..reports.recommend import parse_requirement
from . import checks
from .base import ABSettings, CheckResult, Finding
from .baseline import DEFAULTS, BaselineError, load_baseline, unit_identity, update_baseline
from .io import GateOutputError, check_outputs, read_gate_results, write_ab_artifacts, write_junit
from .project import describe_head, export_project, find_project, head_code
from .ref import check_ref_text, file_at_ref, portable_spec_text, ref_import_error, resolve_ref, run_ref_sweep
from .scope import check_scope
from .scratch import ref_scratch

# the folder holding the tissuebench package this process runs: HEAD's side of every A/B
HEAD_ROOT = Path(__file__).resolve().parents[2]

__all__ = ["check", "baseline_rows", "ABSettings", "CheckResult", "Finding", "BaselineError", "GateOutputError",
           "check_outputs", "load_baseline", "update_baseline", "write_junit"]


def baseline_rows(results_dir) -> tuple[dict, list]:
    """``({identity: baseline unit values}, [(identity, why left out)])`` of a results folder for
    :func:`.baseline.update_baseline`: failed units and units without an error or a latency
    are left out, and said. A unit without a reference step has ``latency_per_reference = 0``."""
    rows, _ = read_gate_results(results_dir)
    kept, left = {}, []
    for k, r in rows.items():
        now = checks.unit_values(r)
        if r["unit_status"] != "ok":
            left.append((k, "failed"))
        elif math.isnan(now["error"]) or not math.isfinite(now["latency_per_calibration"]):
            left.append((k, "no error or no latency measured"))
        elif math.isinf(now["error"]):  # a baseline holds finite values only (baseline.py)
            left.append((k, "error inf (a step failed inside its range, or its reference is zero): nothing to gate "
                            "against"))
        else:
            if not math.isfinite(now["latency_per_reference"]):
                now["latency_per_reference"] = 0.0
            kept[k] = {"case": k[0], "method": k[1], "options": k[2], **now}
    return kept, left


def check(results_dir, baseline=None, against: str | None = None, require: str | None = None,
          ab: ABSettings | None = None, log=print, project=None, latency_floor_s: float | None = None) -> CheckResult:
    """Gate a results folder (module docstring). ``project``: a path inside the git repository of
    the code under test, REF is found there (default: :func:`~tissuebench.gate.project.find_project`);
    ``latency_floor_s`` [s]: the A/B's floor for every unit the baseline file does not give one.
    ValueError (exit 2) for bad input and for a gate that would compare nothing."""
    if baseline is None and against is None and require is None:
        raise ValueError("check: give --baseline FILE, --against REF or --require REQUIREMENT (or several)")
    if against is not None:
        check_ref_text(against)
    elif project is not None:
        raise ValueError(f"--project = {str(project)!r}: only with --against REF (the repository REF is found in)")
    floor = _floor(latency_floor_s)
    requirement = parse_requirement(require) if require is not None else None
    rows, metric = read_gate_results(results_dir)
    defaults, units = load_baseline(baseline) if baseline is not None else (dict(DEFAULTS), [])
    if floor is not None:
        defaults["latency_floor_s"] = floor
    out = CheckResult()
    ok_rows = {k: r for k, r in rows.items() if r["unit_status"] == "ok"}
    if not ok_rows:
        out.add(("*", "*", "*"), Finding("*", "*", "*", "unit_status", len(rows), 0,
                                         f"all {len(rows)} units of the sweep failed"))
    proj = None
    if against is not None:
        check_outputs(results_dir, ab=True)  # RESULTS/_gate/, written at the end: refused before REF's minutes
        proj = find_project([(r.get("method_source"), r.get("method_distribution")) for r in rows.values()],
                            HEAD_ROOT, project)
        out.project = f"{proj.repo} ({proj.how})"
        # a project that holds none of the methods would compare each with itself: refused before any work
        out.notes += check_scope([(r.get("method"), r.get("method_source"), r.get("method_distribution"),
                                   r.get("method_version")) for r in rows.values()], proj, against)
    # a REF git cannot resolve is an error (a typo must not pass on the file), save in a shallow clone
    sha, why = _resolve(proj, against) if against is not None else (None, "")
    if against is not None and sha is None:
        if not units:
            raise ValueError(f"--against {against}: {why}; and no --baseline to fall back to")
        out.notes.append(f"--against {against}: {why}: falling back to the baseline file {baseline}, as for "
                         "any shallow clone (fetch the history, e.g. git fetch --unshallow, to compare with REF)")
    if sha is not None:
        _with_ref(out, proj, sha, against, (results_dir, rows, ok_rows), units, defaults, baseline, ab or ABSettings(),
                  log)
    elif units:
        checks.errors_against_baseline(out, rows, units, defaults)
        checks.latency_from_file(out, rows, units, defaults, "" if against else "no --against: ")
    if requirement is not None:
        checks.requirement_met(out, rows, requirement, metric)
    return out


def _floor(value) -> float | None:
    """``--latency-floor-s``: None, or a finite number of seconds >= 0 (ValueError naming it)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"--latency-floor-s = {value!r}: expected seconds >= 0 (e.g. 0, or 1e-6 for a microsecond "
                         "step)")
    return float(value)


def _resolve(proj, against: str) -> tuple[str | None, str]:
    """REF's commit in the project's repository (:func:`~tissuebench.gate.ref.resolve_ref`),
    its errors saying how that repository was chosen."""
    try:
        return resolve_ref(proj.repo, against)
    except ValueError as exc:
        raise ValueError(f"{exc}; the project under test: {proj.how} (--project PATH for another)") from None


def _with_ref(out, proj, sha: str, against: str, results, units, defaults, baseline, settings, log) -> None:
    """REF's packages exported into a scratch folder (what each side runs said in ``out.sides``),
    checked to import, then the errors and the A/B against REF (:func:`_against_ref`)."""
    log(f"project under test: {out.project}")
    with ref_scratch(log) as tmp:
        ref_code, held = export_project(proj, sha, tmp / "code", HEAD_ROOT)
        out.sides = [f"REF  {against} = {sha[:12]} of {proj.repo}: {held}", f"HEAD {describe_head(proj, HEAD_ROOT)}"]
        for line in out.sides:
            log(line)
        broken = ref_import_error(ref_code)
        if broken:
            raise ValueError(f"--against {against}: REF's code ({sha[:12]}) {broken}; REF cannot run the sweep")
        _against_ref(out, *results, units, defaults, baseline, proj.repo, sha, against,
                     (ref_code, head_code(proj, HEAD_ROOT)), tmp, settings, log)


def _against_ref(out, results_dir, rows, ok_rows, units, defaults, baseline, repo, sha, against, sides, tmp,
                 settings, log) -> None:
    ref_code, head = sides
    manifest = json.loads((Path(results_dir) / "_sweep.json").read_text())
    name = f"{against} ({sha[:12]})"
    ran, why = run_ref_sweep(ref_code, portable_spec_text(manifest), manifest.get("resolution", "ci"),
                             sorted({k[0] for k in rows}), tmp / "ref-sweep", log)
    ref_rows = {}
    if ran and why:
        out.notes.append(f"errors: {why}")
    if ran:
        try:
            ref_rows, _ = read_gate_results(tmp / "ref-sweep")
        except ValueError as exc:
            ran, why = False, f"its results cannot be read here: {exc}"
    errors_declared, slowdowns = _declared(repo, sha, baseline, units)
    if ran:
        checks.errors_against_ref(out, rows, ref_rows, units, defaults, errors_declared, name)
    elif units:
        out.notes.append(f"errors: {name} could not run the sweep ({why}): compared with the baseline file")
        checks.errors_against_baseline(out, rows, units, defaults)
    else:
        raise ValueError(f"--against {against}: REF's sweep did not run ({why}) and there is no --baseline")
    if ok_rows:
        samples = checks.latency_ab(out, results_dir, ok_rows, units, defaults, ref_code, head, name, settings,
                                    log, workdir=tmp, declared=slowdowns)
        note = write_ab_artifacts(results_dir, samples, out.ab, against, sha)
        if note:
            out.notes.append(note)


def _declared(repo, sha: str, baseline, units: list) -> tuple[set, dict]:
    """What this change declares, the baseline file now against the same file at REF:
    ``(identities whose entry's error or flagged steps it adds or edits, {identity:
    (latency_change, reason)} of the entries whose slowdown declaration it adds or edits)``. A
    declaration unchanged against REF (made by an earlier commit) is not one of this change."""
    if baseline is None:
        return set(), {}
    text = file_at_ref(repo, sha, baseline)
    if text is None:  # a baseline outside the repository: no commit can declare a change
        return set(), {}
    old = {}
    try:
        for t in (tomlkit.parse(text).unwrap().get("unit", []) if text else []):
            old[unit_identity(t["case"], t["method"], t["options"])] = t
    except Exception:  # REF's file is damaged or of another format: every entry counts as edited
        old = {}

    def at_ref(u, keys):
        t = old.get(u["_identity"])
        return None if t is None else tuple(t.get(k) for k in keys)

    errors = {u["_identity"] for u in units if at_ref(u, ("error", "flagged_steps")) != (u["error"],
                                                                                           u["flagged_steps"])}
    keys = ("latency_change", "latency_change_reason")
    slowdowns = {u["_identity"]: (float(u[keys[0]]), u[keys[1]]) for u in units
                 if keys[0] in u and at_ref(u, keys) != (u[keys[0]], u[keys[1]])}
    return errors, slowdowns
