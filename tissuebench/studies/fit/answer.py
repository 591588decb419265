"""The answer of a fit: the cheapest unit that meets the requirement, its spec, and its checks.

When the greedy stops (:mod:`.loop`), every unit it measured is a point of a family's learning
curve. The answer is the **cheapest** unit that meets the requirement: the fewest references
added (the offline cost a user pays again for another organ), then the largest margin over the
requirement's clauses (the report's ranking of the units that meet it: a unit at 1.7 % of a 2 %
requirement is not preferred to one at 0.9 % because its step is 10 us faster). It comes with

* its spec (``OUT/answer.spec.toml``): one case, one method, one option set and the protocol,
  so that ``tissuebench sweep OUT/answer.spec.toml`` measures the same unit (the same key: checked
  here, :func:`reproduces`);
* the references it needed (the protocol's and the ones the fit added), the offline cost (the
  reference runs' solve time plus the model's build) and the fit's own wall time;
* the learning curve of every family (error against references added: ``OUT/learning_curves.png``
  and a table in ``OUT/fit.md``), the indicator's rank correlation with the true error;
* a **dense check** (``OUT/dense``, a sweep of its own) at parameters neither the training nor the
  greedy ever used (:meth:`~.axes.Axis.dense_evaluations`: the thirds of every training interval of
  a path, amplitudes at the thirds of a motion's range), of the answer and of every family's last
  lead: its error beside the held-out one.

When no unit meets the requirement: the best unit per clause (the most accurate that meets the
speed clauses, the fastest that meets the error), what the budget bought (each family's error
before and after the references it added) and where each curve is heading (the error's rate of
fall per reference over its last references, and how many more would reach the requirement at
that rate).
"""
from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

import numpy as np

from ...reference import cached_solve
from ..atomic_files import write_text
from ..case_entry import CaseEntry
from ..results import read_units
from ..spec import expand_units, load_spec
from ..sweep import run_sweep
from ..training import training_references
from ..units import options_text
from .specs import family_case, round_spec, toml_text

__all__ = ["finish", "cheapest", "heading", "report_text", "size_text"]


def _row(p: dict) -> dict:
    return {"unit_status": p["status"], "seen": p["seen"], "error": np.nan if p["error"] is None else p["error"],
            "haptic_p99_s": np.nan if p["p99_s"] is None else p["p99_s"]}


def _points(m: dict) -> list[tuple[str, dict]]:
    """Every measured unit of the fit: ``(family, curve point)`` (round 0's grid included)."""
    out = []
    for name, st in m["families"].items():
        seen = set()
        for p in st.get("grid_points", []) + st["curve"]:
            if p["unit_key"] not in seen:
                seen.add(p["unit_key"])
                out.append((name, p))
    return out


def margin(point: dict, target) -> float:
    """The smallest headroom of ``point`` over the clauses of ``target`` (> 1: met with room to
    spare), as the report ranks the units that meet a requirement
    (:mod:`tissuebench.reports.recommend`)."""
    row = _row(point)
    return min(c.headroom(row["error"], row["haptic_p99_s"]) for c in target.clauses)


def cheapest(m: dict, target) -> tuple[str, dict] | None:
    """``(family, point)`` of the cheapest unit meeting ``target`` (module docstring), or None."""
    meeting = [(n, p) for n, p in _points(m) if target.meets(_row(p))]
    if not meeting:
        return None
    return min(meeting, key=lambda np_: (np_[1]["references"], -margin(np_[1], target)))


def best_per_clause(m: dict, target) -> dict:
    """``{"error": (family, point) or None, "speed": ...}``: the most accurate unit meeting the speed
    clauses, and the fastest meeting the error clause."""
    pts = [(n, p) for n, p in _points(m) if p["status"] == "ok" and not p["seen"]]
    fast = [(n, p) for n, p in pts if target.meets_speed(_row(p)) and p["error"] is not None]
    accurate = [(n, p) for n, p in pts if target.meets_error(_row(p)) and p["p99_s"] is not None]
    return {"error": min(fast, key=lambda x: x[1]["error"]) if fast else None,
            "speed": min(accurate, key=lambda x: x[1]["p99_s"]) if accurate else None}


def size_text(point: dict) -> str:
    """A point's model size as written: the size option's value, and its refinement where it has one
    (``30, ecsw_tol 0.0025``)."""
    refined = point.get("refined") or {}
    return ", ".join([str(point.get("size"))] + [f"{k} {v:g}" for k, v in refined.items()])


def _action_text(p: dict) -> str:
    grew = f" ({p['grew']})" if p.get("grew") else ""
    return f"{p['action']}{grew}{' (dropped)' if p.get('dropped') else ''}"


def heading(curve: list, target_error: float | None) -> dict:
    """Where a learning curve is heading: over the points of its last size measured after added
    references (at least two), the error's fall per reference (a fitted log-linear rate) and the
    references that rate needs to reach ``target_error`` (None when flat or rising)."""
    pts = [p for p in curve if not p.get("dropped") and p["error"] is not None and p["status"] == "ok"]
    if len(pts) < 2:
        return {"rate": None, "more_references": None, "words": "one point: no trend yet"}
    size = size_text(pts[-1])
    same = [p for p in pts if size_text(p) == size]
    if len(same) < 2 or same[-1]["references"] == same[0]["references"]:
        return {"rate": None, "more_references": None, "words": "no reference added at the last size: no trend"}
    x = np.array([p["references"] for p in same], float)
    y = np.log(np.maximum([p["error"] for p in same], 1e-300))
    slope = float(np.polyfit(x, y, 1)[0])
    factor = math.exp(slope)
    out = {"rate": factor, "more_references": None}
    if slope >= -1e-3:
        out["words"] = f"flat: x{factor:.3g} per reference at size {size}"
        return out
    out["words"] = f"x{factor:.3g} per reference at size {size}"
    if target_error is not None and same[-1]["error"] > target_error:
        more = math.ceil((math.log(target_error) - y[-1]) / slope)
        out["more_references"] = more
        out["words"] += f": about {more} more references to reach {100 * target_error:.3g} %"
    return out


def _offline(fit, name, point) -> dict:
    """The references a unit trained on (the protocol's and the fit's) and their solve time."""
    runs = fit.m["families"][name]["runs"][:point["references"]]
    spec = round_spec(fit.plan, "offline", [(family_case(fit.plan, name, runs), fit.fams[name],
                                             [point["options"]])])
    entry = CaseEntry.from_dict({**spec["case"][0], "resolution": fit.plan.resolution})
    seconds, n = 0.0, 0
    for scene in training_references(entry):
        ref, _ = cached_solve(scene, fit.s.backend)
        seconds += float(ref.wall_s or 0.0)
        n += 1
    return {"training_references": n, "added_references": len(runs), "reference_solve_s": seconds,
            "build_s": point.get("offline_s"), "offline_s": seconds + float(point.get("offline_s") or 0.0)}


def _scene_name_for(fit, spec_path: Path) -> str:
    """The case name in a spec written at ``spec_path``: a catalogue name, or the scene file
    relative to the spec's folder (as ``sweep --scene`` writes it)."""
    name = fit.plan.name
    if not Path(name).is_absolute():
        return name
    try:
        return os.path.relpath(name, spec_path.parent.resolve())
    except ValueError:  # another drive (Windows)
        return name


def write_answer_spec(fit, name: str, point: dict) -> dict:
    """``OUT/answer.spec.toml`` of the answer unit, and whether it reproduces the unit (:func:`reproduces`)."""
    path = fit.out / "answer.spec.toml"
    runs = fit.m["families"][name]["runs"][:point["references"]]
    case = family_case(fit.plan, name, runs)
    case["name"] = _scene_name_for(fit, path)
    spec = round_spec(fit.plan, f"fit-{fit.plan.scene.name}-answer", [(case, fit.fams[name], [point["options"]])])
    write_text(path, toml_text(spec, f"The answer of `tissuebench fit` on {fit.plan.scene.name}: {point['label']}.\n"
                                     "Measure it again with `tissuebench sweep THIS_FILE --out FOLDER`."), "--out")
    return {"spec": str(path), **reproduces(fit, path, point)}


def reproduces(fit, spec_path: Path, point: dict) -> dict:
    """Whether the spec at ``spec_path`` plans the unit of ``point``: its key now against the key the
    round's own spec gives now (same code) and against the stored one (the code of the round)."""
    units = expand_units(load_spec(spec_path, resolution=fit.s.resolution))
    if len(units) != 1:
        return {"reproduces": False, "why": f"the spec plans {len(units)} units"}
    unit = units[0]
    round_ = next(r for r in fit.m["rounds"] if r["round"] == point["round"])
    again = [u for u in expand_units(load_spec(fit.out / round_["spec"], resolution=fit.s.resolution))
             if u.identity == unit.identity]
    same_now = bool(again) and again[0].key == unit.key
    out = {"unit_key": unit.key, "stored_key": point["unit_key"], "reproduces": same_now}
    if unit.key == point["unit_key"]:
        out["why"] = "the same unit key as the fit's measurement"
    elif same_now:
        out["why"] = ("the same case, method, options and protocol as the round's spec (the key differs from the "
                      "stored one by the code's hash: the code changed since the round)")
    else:
        out["why"] = "the spec plans another unit than the round's"
    return out


def dense_check(fit, chosen: list[tuple[str, dict]]) -> dict:
    """Run the dense check (module docstring) of ``chosen`` ``[(family, point)]`` in ``OUT/dense``;
    ``{family: {"error", "claimed", "ratio", "cases", "unit_keys"}}``."""
    if not chosen:
        return {}
    entries, ids = [], {}
    for name, point in chosen:
        axis = fit.axis_for(name)
        if axis is None:
            continue
        runs = fit.m["families"][name]["runs"][:point["references"]]
        tag = f"{name}-r{point['references']}"
        base = family_case(fit.plan, name, runs)
        for suffix, evaluation in axis.dense_evaluations(base):
            cid = f"{tag}-{suffix}"  # two units of one training share its case (round_spec lists it once)
            ids[cid] = name
            entries.append((family_case(fit.plan, name, runs, case_id=cid, evaluation=evaluation), fit.fams[name],
                            [point["options"]]))
    if not entries:
        return {}
    spec_path = fit.out / "dense.spec.toml"
    spec = round_spec(fit.plan, f"fit-{fit.plan.scene.name}-dense", entries)
    text = toml_text(spec, f"The dense check of `tissuebench fit` on {fit.plan.scene.name}: parameters neither the "
                           "training nor the greedy used.")
    folder = fit.out / "dense"
    if spec_path.exists() and spec_path.read_text(encoding="utf-8") != text:  # another answer: measured afresh
        shutil.rmtree(folder, ignore_errors=True)
    spec_path.write_text(text, encoding="utf-8")
    fit.log(f"fit: the dense check: {len(entries)} units at parameters neither the training nor the greedy used")
    run_sweep(load_spec(spec_path, resolution=fit.s.resolution), folder, fit.s.executor, fit.s.workers,
              fit.s.scheduler, resume=folder.exists() and any(folder.iterdir()), progress=fit.s.progress,
              log=fit.log if fit.s.progress else (lambda *_: None), cache=fit.s.cache)
    rows = read_units(folder)
    out = {}
    for name, point in chosen:
        if fit.axis_for(name) is None:
            continue
        tag = f"{name}-r{point['references']}-"
        mine = rows[rows["case"].str.startswith(tag) & (rows["options"] == options_text(point["options"]))]
        errors = mine[fit.plan.error_metric].astype(float) if fit.plan.error_metric in mine else mine.index
        ok = (mine["unit_status"] == "ok").all() if len(mine) else False
        worst = float(errors.max()) if len(mine) and ok else float("inf")
        out[point["unit_key"]] = {"family": name, "label": point["label"], "error": worst,
                                  "held_out_error": point["error"],
                                  "ratio": worst / point["error"] if point["error"] else None,
                                  "cases": sorted(mine["case"].tolist()), "unit_keys": mine["unit_key"].tolist(),
                                  "status": "ok" if ok else "failed"}
    return out


def finish(fit) -> dict:
    """Choose the answer, run the dense check, write the answer spec, the report and the figure;
    returns the manifest (its ``state``: ``met``, ``not_met`` or ``budget``)."""
    m, target = fit.m, fit.s.target
    found = cheapest(m, target)
    chosen = []
    if found:
        chosen.append(found)
    per_clause = best_per_clause(m, target)
    for st_name, st in m["families"].items():
        last = next((p for p in reversed(st["curve"]) if not p.get("dropped") and p["status"] == "ok"), None)
        if st["learns"] and last is not None and all(last["unit_key"] != p["unit_key"] for _, p in chosen):
            chosen.append((st_name, last))
    if not found:
        for pick in per_clause.values():
            if pick and all(pick[1]["unit_key"] != p["unit_key"] for _, p in chosen):
                chosen.append(pick)
    m["dense"] = dense_check(fit, chosen)
    for st in m["families"].values():
        st["heading"] = heading(st["curve"], target.error_clause().value if target.error_clause() else None)
    if found:
        name, point = found
        m["answer"] = {"family": name, "point": point, **_offline(fit, name, point),
                       **write_answer_spec(fit, name, point)}
        m["state"] = "met"
    else:
        m["answer"] = None
        m["best_per_clause"] = {k: (None if v is None else {"family": v[0], "point": v[1]})
                                for k, v in per_clause.items()}
        if m["state"] != "budget":
            m["state"] = "not_met"
    m["references_added"] = sum(st["refs_added"] for st in m["families"].values())
    m["machine_load"] = _load()
    fit.save()
    figure = None
    if getattr(fit, "figures", None) is not None:
        figure = fit.out / "learning_curves.png"
        fit.figures(m, figure)
    m["figure"] = str(figure.name) if figure is not None else None
    write_text(fit.out / "fit.md", report_text(m, target), "--out")
    fit.save()
    return m


def _load() -> dict:
    try:
        one, five, fifteen = os.getloadavg()
    except (AttributeError, OSError):
        one = five = fifteen = float("nan")
    return {"load_1min": one, "load_5min": five, "load_15min": fifteen, "cpus": os.cpu_count()}


def _pct(x) -> str:
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else (
        "inf" if x == math.inf else f"{100 * x:.3g} %")


def _ms(x) -> str:
    return "n/a" if x is None else f"{1e3 * x:.3g} ms"


def report_text(m: dict, target) -> str:
    """``OUT/fit.md``: the answer (or why none), the families' learning curves and checks."""
    s = m["settings"]
    lines = [f"# tissuebench fit: {m.get('scene_name', s['scene'])}", "",
             f"Requirement: `{s['require']}` ({target.text()}; the error is the headline `{m['error_metric']}` on "
             "references never used for training, the rate the p99 step's).", "",
             f"State: **{m['state']}** after {len(m['rounds'])} rounds, {m.get('references_added', 0)} references "
             f"added, {m['elapsed_s'] / 60:.1f} min (budget: {s['budget_references']} references per family, "
             f"{s['budget_minutes']:g} min). Machine load at the end: {m['machine_load']['load_1min']:.2f} "
             f"(1 min) on {m['machine_load']['cpus']} CPUs.", ""]
    a = m.get("answer")
    if a:
        p = a["point"]
        lines += ["## The answer", "",
                  f"**{p['label']}** ({a['family']}): error {_pct(p['error'])} held out, p99 {_ms(p['p99_s'])} "
                  f"(median {_ms(p['median_s'])}), after {p['references']} added references.", "",
                  f"- spec: `{Path(a['spec']).name}` ({a['why']}; unit key {a['unit_key'][:16]})",
                  f"- references: {a['training_references']} reference runs ({a['added_references']} added by the "
                  f"fit), solved in {a['reference_solve_s']:.1f} s; model build {a['build_s'] or 0:.2f} s: offline "
                  f"{a['offline_s']:.1f} s",
                  ]
        d = (m.get("dense") or {}).get(p["unit_key"])
        if d:
            lines.append(f"- dense check: {_pct(d['error'])} at parameters neither the training nor the greedy used "
                         f"({', '.join(d['cases'])}), {d['ratio']:.3g}x the held-out error" if d["ratio"] else
                         f"- dense check: {_pct(d['error'])}")
        lines.append("")
    else:
        lines += ["## No unit meets the requirement", ""]
        for clause, pick in (m.get("best_per_clause") or {}).items():
            what = "most accurate meeting the speed clauses" if clause == "error" else "fastest meeting the error"
            if pick is None:
                lines.append(f"- the {what}: none")
            else:
                p = pick["point"]
                lines.append(f"- the {what}: {p['label']} ({pick['family']}), error {_pct(p['error'])}, p99 "
                             f"{_ms(p['p99_s'])}, {p['references']} references added")
        lines.append("")
    lines += ["## Families", "", "| family | status | why | references added | error: protocol -> last | p99 last | "
              "rank correlation (indicator, true error) | heading |", "|---|---|---|---|---|---|---|---|"]
    for name, st in m["families"].items():
        curve = [p for p in st["curve"] if not p.get("dropped")]
        first, last = (curve[0], curve[-1]) if curve else ({}, {})
        rhos = [c["rho"] for c in st.get("checks", []) if c["rho"] is not None and not math.isnan(c["rho"])]
        rho = (f"{np.mean(rhos):.2f} (mean of {len(rhos)}; last {rhos[-1]:.2f})" if rhos else "n/a")
        lines.append(f"| {name} | {st['status']} | {st['why']} | {st['refs_added']} | {_pct(first.get('error'))} -> "
                     f"{_pct(last.get('error'))} | {_ms(last.get('p99_s'))} | {rho} | "
                     f"{(st.get('heading') or {}).get('words', '')} |")
    lines += ["", "## Learning curves", ""]
    if m.get("figure"):
        lines += [f"![learning curves]({m['figure']})", ""]
    lines += ["| family | round | references | size | error | p99 | action | added at (indicator) |",
              "|---|---|---|---|---|---|---|---|"]
    for name, st in m["families"].items():
        added = {a["round"]: a for a in st.get("added", [])}
        for p in st["curve"]:
            ad = added.get(p["round"])
            where = f"{st.get('axis')} {ad['value']:.6g} ({ad['indicator']:.3g})" if ad else ""
            lines.append(f"| {name} | {p['round']} | {p['references']} | {size_text(p)} | {_pct(p['error'])} | "
                         f"{_ms(p['p99_s'])} | {_action_text(p)} | {where} |")
    dense = m.get("dense") or {}
    if dense:
        lines += ["", "## Dense check", "", "| unit | held out | dense | ratio | cases |", "|---|---|---|---|---|"]
        for d in dense.values():
            ratio = f"{d['ratio']:.3g}" if d["ratio"] else "n/a"
            lines.append(f"| {d['label']} ({d['family']}) | {_pct(d['held_out_error'])} | {_pct(d['error'])} | "
                         f"{ratio} | {', '.join(d['cases'])} |")
    if m.get("not_fitted"):
        lines += ["", "Not fitted: " + "; ".join(f"{n} ({w})" for n, w in m["not_fitted"])]
    lines += ["", "Rounds: " + ", ".join(f"{r['round']} ({(r.get('wall_s') or 0) / 60:.1f} min)"
                                          for r in m["rounds"])]
    return "\n".join(lines) + "\n"
