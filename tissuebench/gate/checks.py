"""The gate's checks, each adding findings to a :class:`.base.CheckResult` (rules in
:mod:`tissuebench.gate`)."""
from __future__ import annotations

import math

import pandas as pd

from ..reports.recommend import rank_units
from .base import Finding
from .baseline import DEFAULTS, unit_identity
from .latency import ab_units, run_ab
from .stats import decided_units, verdicts

__all__ = ["unit_values", "tolerances", "errors_against_baseline", "errors_against_ref", "latency_from_file",
           "latency_ab", "requirement_met"]

_FLAGGED = ("n_failed", "n_extrapolation", "n_beyond_validity", "n_not_reached")


def unit_values(row) -> dict:
    """The gated values of a stored unit row (the keys of a baseline unit)."""
    ref = row["reference_step_s"]
    return {"error": float(row["error"]), "latency_per_calibration": float(row["haptic_per_calibration"]),
            "latency_per_reference": float(row["haptic_median_s"] / ref) if ref > 0 else math.nan,
            "flagged_steps": int(sum(int(row[c]) for c in _FLAGGED))}


def tolerances(unit: dict | None, defaults: dict) -> dict:
    return {k: (unit or {}).get(k, defaults[k]) for k in DEFAULTS}


def _error_changed(was: float, now: float, tol: dict) -> bool:
    if was == now or (math.isinf(was) and math.isinf(now)):
        return False
    if math.isinf(was) or math.isinf(now):  # inf - x is inf, within a tolerance of inf * rtol: said, not held
        return True
    return not abs(now - was) <= max(tol["error_rtol"] * abs(was), tol["error_atol"])


def _value_findings(out, key, was: dict, now: dict, tol: dict, against: str, declared: bool) -> None:
    """Error and flagged-step findings of one ok unit against ``was`` (REF's or the baseline's)."""
    if _error_changed(was["error"], now["error"], tol):
        if declared:
            out.declare(key, f"error {was['error']:.6g} -> {now['error']:.6g}, declared by the baseline update of this "
                             "commit")
        else:
            out.add(key, Finding(*key, "error", was["error"], now["error"],
                                 f"changed against {against} by more than {tol['error_rtol']:g} relative / "
                                 f"{tol['error_atol']:g}: if intended, update the baseline in the same commit "
                                 "(check --update-baseline)"))
    if now["flagged_steps"] > was["flagged_steps"] and not declared:
        out.add(key, Finding(*key, "flagged_steps", was["flagged_steps"], now["flagged_steps"],
                             f"failed/extrapolated/beyond-validity steps may not grow ({against})"))
    out.add(key)


def errors_against_baseline(out, rows: dict, units: list, defaults: dict) -> None:
    """Every baseline unit against the results: missing, failed, error changed, more flagged steps."""
    out.errors_against = "baseline"
    for u in units:
        key, row = u["_identity"], rows.get(u["_identity"])
        if row is None:
            out.add(key, Finding(*key, "unit", 1.0, math.nan, "missing from the results"))
            continue
        out.compared += 1
        if row["unit_status"] != "ok":
            out.add(key, Finding(*key, "unit_status", 1.0, math.nan, f"failed: {str(row['message'])[:120]}"))
            continue
        _value_findings(out, key, u, unit_values(row), tolerances(u, defaults), "the baseline", False)
    if not out.compared:
        raise ValueError("check: no unit of the baseline is in the results (0 compared): wrong results folder or "
                         "baseline?")
    _new_units(out, rows, {u["_identity"] for u in units})


def _new_units(out, rows: dict, known: set) -> None:
    out.new_units = sorted(k for k in rows if k not in known)
    out.new_failed = {k for k in out.new_units if rows[k]["unit_status"] != "ok"}


def errors_against_ref(out, rows: dict, ref_rows: dict, units: list, defaults: dict, declared: set,
                       against: str) -> None:
    """Every unit of the results against REF's result of the same unit on this machine; units
    REF could not run fall back to the baseline file (or are new, and said so)."""
    out.errors_against = "ref"
    by_id = {u["_identity"]: u for u in units}
    for key, row in rows.items():
        ref, base = ref_rows.get(key), by_id.get(key)
        tol = tolerances(base, defaults)
        ref_ok = ref is not None and ref["unit_status"] == "ok"
        if row["unit_status"] != "ok":
            if ref_ok or base is not None:
                out.compared += 1
                out.add(key, Finding(*key, "unit_status", 1.0, math.nan, f"failed: {str(row['message'])[:120]}"))
            else:
                out.notes.append(f"{' '.join(key)}: fails here and on {against} (not a regression)")
            continue
        if ref_ok:
            out.compared += 1
            _value_findings(out, key, unit_values(ref), unit_values(row), tol, against, key in declared)
        elif base is not None:
            out.compared += 1
            why = "has no such unit" if ref is None else "failed on it"
            out.notes.append(f"{' '.join(key)}: {against} {why}: compared with the baseline file")
            _value_findings(out, key, base, unit_values(row), tol, "the baseline", False)
    for key in by_id:
        if key not in rows:
            out.add(key, Finding(*key, "unit", 1.0, math.nan, "in the baseline, missing from the results"))
    if not out.compared:
        raise ValueError(f"check: no unit could be compared with {against} or the baseline (0 compared)")
    _new_units(out, rows, set(by_id))


def latency_from_file(out, rows: dict, units: list, defaults: dict, why: str) -> None:
    """File mode (no REF), for information only: the haptic median per calibration against the
    baseline's, times ``file_latency_tolerance``, the baseline first raised to ``latency_floor``
    calibrations. Never a regression: these ratios move 2-3x between runs of identical code for
    microsecond steps (a gate of a 5-8 us step at x1.3 failed 5 of 9 runs of identical code);
    latency is gated by the A/B (``--against REF``)."""
    out.latency_mode = "file"
    above, seen = [], 0
    for u in units:
        key, row = u["_identity"], rows.get(u["_identity"])
        if row is None or row["unit_status"] != "ok":
            continue
        seen += 1
        tol = tolerances(u, defaults)
        base = u["latency_per_calibration"]
        limit = max(base, tol["latency_floor"]) * tol["file_latency_tolerance"]
        now = unit_values(row)["latency_per_calibration"]
        if not now <= limit:
            above.append(f"{' '.join(key)}: {base:.4g} -> {now:.4g} (limit {limit:.4g})")
        if "latency_change" in u:  # shown, nothing else: only the A/B of the commit that declares it uses it
            out.notes.append(f"{' '.join(key)}: the baseline declares latency_change = {u['latency_change']:g} "
                             f"({u['latency_change_reason']}): used only by the A/B (--against REF) of the commit "
                             "that adds or edits it")
    shown = "; ".join(above[:5]) + (f"; {len(above) - 5} more" if len(above) > 5 else "")
    out.notes.append(f"{why}latency not gated (the A/B of --against REF gates it): the baseline file's ratios "
                     "(haptic median / calibration kernel) move 2-3x between runs of identical code for microsecond "
                     f"steps. For information: {len(above)} of {seen} units above x"
                     f"{defaults['file_latency_tolerance']:g} of the file's ratio" + (f" ({shown})" if above else ""))


def latency_ab(out, results_dir, ok_rows: dict, units: list, defaults: dict, ref_root, head_root, against: str,
               settings, log, workdir=None, declared: dict | None = None) -> pd.DataFrame:
    """Every ok unit re-timed A/B (:mod:`tissuebench.gate.latency`); returns the samples.
    ``workdir``: the folder its scratch files go in (default: the temporary folder);
    ``declared``: ``{identity: (latency_change, reason)}``, the slowdowns this commit declares
    (:func:`tissuebench.gate._declared`): those units are judged against ``latency_change``
    times their tolerance (:func:`.stats.verdicts`' ``expected``) and noted."""
    declared = declared or {}
    table = pd.DataFrame([{**r, "case": k[0], "method": k[1], "options": k[2]} for k, r in ok_rows.items()])
    ab = ab_units(results_dir, table, workdir)
    by_uid = {u.uid: k for u, k in zip(ab, ok_rows)}
    base = {u["_identity"]: u for u in units}
    unit_tol = {uid: tolerances(base.get(k), defaults) for uid, k in by_uid.items()}
    tol = {uid: t["latency_tolerance"] for uid, t in unit_tol.items()}
    floor = {uid: t["latency_floor_s"] for uid, t in unit_tol.items()}
    expected = {uid: declared[k][0] for uid, k in by_uid.items() if k in declared}
    inject = {uid: f for uid, k in by_uid.items() for ik, f in (settings.inject or {}).items()
              if unit_identity(*ik) == k}
    log(f"A/B latency: {len(ab)} units, {against} against this code, {settings.min_rounds}-{settings.max_rounds} "
        f"rounds of {settings.blocks} blocks")
    samples, failures = run_ab(ab, ref_root, head_root, decided_units(tol, expected), settings.min_rounds,
                               settings.max_rounds, settings.blocks, settings.budget_s, inject=inject or None, log=log,
                               workdir=workdir)
    out.latency_mode = "ab"
    for uid, v in verdicts(samples, tol, floor_s=floor, expected=expected).items():
        key = by_uid[uid]
        out.ab[key] = v
        if key in declared:
            _declared_slowdown(out, key, v, declared[key], tol[uid], against)
            continue
        out.add(key, Finding(*key, "latency_ab", 1.0, v.ratio, f"{v.verdict}: {v.text()}") if v.regressed else None)
    for uid, sides in failures.items():
        key = by_uid[uid]
        if "head" in sides:
            out.add(key, Finding(*key, "latency_ab", math.nan, math.nan, f"fails under A/B: {sides['head'][:120]}"))
        else:
            out.notes.append(f"{' '.join(key)}: latency not compared: {against}'s code cannot run it "
                             f"({sides['ref'][:120]})")
    if not out.ab:
        raise ValueError(f"--against {against}: the A/B compared no unit ({against}'s code could run none of them)")
    return samples.assign(case=samples["uid"].map(lambda u: by_uid[u][0]),
                          method=samples["uid"].map(lambda u: by_uid[u][1]),
                          options=samples["uid"].map(lambda u: by_uid[u][2]))


def _declared_slowdown(out, key, v, declaration: tuple, tolerance: float, against: str) -> None:
    """A unit whose slowdown this commit declares: noted with the measured ratio, its interval and
    the reason when it holds; a regression naming the declared and the measured factor when it is
    slower than declared (beyond ``latency_change * latency_tolerance``, :func:`.stats.verdicts`)."""
    factor, reason = declaration
    measured = f"HEAD/REF {v.ratio:.3f} " + (f"[{v.low:.3f}, {v.high:.3f}]" if v.has_interval else
                                              "(interval n/a, one sample)")
    if v.regressed:
        out.add(key, Finding(*key, "latency_ab", factor, v.ratio,
                             f"slower than declared: measured {measured} against {against}, declared latency_change "
                             f"= {factor:g} ({reason}) x latency_tolerance {tolerance:g}: {v.text()}"))
        return
    out.add(key)
    out.declare(key, f"latency {measured} against {against}, declared latency_change = {factor:g} by the baseline "
                     f"update of this commit: {reason}")


def requirement_met(out, rows: dict, requirement, metric: str) -> None:
    """Every case needs a unit that meets ``requirement`` (the report's p99 rule)."""
    table = pd.DataFrame([{**r, "case": k[0], "method": k[1], "options": k[2]} for k, r in rows.items()])
    for case, units in table.groupby("case", sort=True):
        best = rank_units(units, requirement, metric).iloc[0]
        key = (case, "*", "*")
        if bool(best["meets"]):
            out.notes.append(f"{case}: {best['label']} meets {requirement.text!r} (margin {best['margin']:.3g})")
            out.add(key)
        else:
            out.add(key, Finding(case, "*", "*", "requirement", math.nan, float(best["margin"]),
                                 f"no unit meets {requirement.text!r}; closest {best['label']}: {best['misses']}"))
