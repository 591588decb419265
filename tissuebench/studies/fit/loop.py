"""The greedy of ``tissuebench fit``: add references where the models err most until one meets the requirement.

Round 0 is the scene's own training protocol (:mod:`.specs`: the generated spec's primary case,
every family with its option grid). From it each family keeps a **lead** option set: the most
accurate among those meeting the speed clauses of the requirement (rate or latency on the p99
step). Every later round is one sweep (:func:`~tissuebench.studies.sweep.run_sweep`, on the
executor asked) of the families still going, one unit each, after one decision per family:

* **add**: the lead model, built on the family's training (the unit's own, from the round's
  spec), is evaluated at every candidate (:mod:`.candidates`) by the cheap indicator
  (:mod:`.indicator`: the full model's residual at the reduced state, one assembly and no solve);
  a run is added at the worst candidate (:meth:`.axes.Axis.run`), the family's case gains it and
  its units are measured again. The indicator's ranking is checked against the true errors the
  unit measured at the evaluation's points (Spearman's rho, recorded per round).
* **grow**: when the last :data:`PATIENCE` references each lowered the error by less than
  :data:`MIN_GAIN` (more training no longer helps), the model grows along each of its two axes, both
  measured in the same round: its size (``n_modes`` ..., :data:`.specs.SIZE_KEYS`) takes its next
  value (:func:`next_size`), and, where the method declares one for the lead's options
  (:attr:`~tissuebench.rom.base.RomMethod.refinements`: ECSW's ``ecsw_tol`` halved, more elements
  in the cubature), the model is refined at its size (:func:`next_refinement`). The more accurate of
  the two that meets the speed clauses becomes the lead; an axis whose model fails or misses the
  speed clauses is not tried again, and when both do the family goes on at its size.
* **stop**: the lead meets the requirement (``met``); neither a reference nor a larger model
  lowered the error by :data:`MIN_GAIN`; no candidate or budget is left; no option set meets the
  speed clauses (more training does not make a model faster); a practitioner baseline learns
  nothing from references (measured once).

The **stopping rule** (:class:`.target.Target`) reads the headline error of the evaluation,
which holds only references **never used for training** (the candidates avoid every point it
measures), and the p99 of the protocol's timed steps. The fit stops when a family meets the
requirement (the fewest references any family needed: the others are not trained further), when
every family has stopped, or when ``budget_minutes`` has passed (checked before each round).
Everything is decided from stored rows and recorded in the manifest (:mod:`.manifest`) before the
next round starts: a killed fit resumes where it stopped.
"""
from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ...exits import EXIT_TYPES, raised_by_code
from ...rom import make_method
from ..results import read_points, read_units
from ..spec import load_spec
from ..sweep import run_sweep
from ..training import build_training, case_scene
from .answer import finish
from .growth import GROWTH, MAX_GROWTH, MAX_REFINEMENTS, next_refinement, next_size, refinements_kept
from .rules import MIN_GAIN, PATIENCE, _as_row, _pct, decide, load_factor, speed_ok
from .axes import axis_of
from .manifest import check_settings, new_manifest, read_manifest, write_manifest
from .specs import family_case, round_spec, scene_plan, toml_text
from .target import Target

__all__ = ["FitSettings", "run_fit", "next_size", "decide", "speed_ok", "load_factor", "MIN_GAIN", "PATIENCE", "GROWTH",
           "MAX_GROWTH", "MAX_REFINEMENTS", "next_refinement"]



@dataclass
class FitSettings:
    """What ``tissuebench fit`` was asked.

    Attributes
    ----------
    scene : str
        A catalogue case or a scene file.
    target : Target
        The requirement as numbers (:class:`.target.Target`); ``require`` is its text, as given.
    out : Path
        The fit's folder: ``fit.json``, ``fit.md``, ``learning_curves.png``, ``answer.spec.toml``,
        ``rounds/``, ``dense/``; a fit found there with the same settings is resumed.
    variant, resolution, backend : str
        The scene's variant (None: its default), mesh resolution and the references' backend.
    methods : list of str or None
        Only these method families (None: every one that applies).
    budget_references : int
        References the fit may add per family.
    budget_minutes : float
        Wall minutes after which no round starts (a resumed fit counts the time spent before).
    executor, workers, scheduler, cache
        Where each round's units run (:mod:`~tissuebench.studies.executors`) and the reference cache.
    progress : bool
        Progress on stderr (rounds, candidates, the references being solved).
    """

    scene: str
    target: Target
    require: str
    out: Path
    variant: str | None = None
    resolution: str = "ci"
    backend: str = "skfem"
    methods: list | None = None
    budget_references: int = 4
    budget_minutes: float = 60.0
    executor: str = "serial"
    workers: int | None = None
    scheduler: str | None = None
    cache: str | None = None
    progress: bool = True
    extra: dict = field(default_factory=dict)

    def key(self) -> dict:
        return {"scene": str(self.scene), "variant": self.variant, "resolution": self.resolution,
                "backend": self.backend, "require": self.require,
                "methods": sorted(self.methods) if self.methods else None,
                "budget_references": self.budget_references, "budget_minutes": self.budget_minutes}


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def _error_rows(rows: pd.DataFrame, metric: str) -> pd.DataFrame:
    rows = rows.copy()
    rows["error"] = rows[metric].astype(float) if metric in rows else np.nan
    return rows


def _point(row, round_, fam_state, action) -> dict:
    opts = _options(row)
    size_key, refine_key = fam_state["size_key"], fam_state.get("refine_key")
    return {"round": round_, "references": fam_state["refs_added"], "size": opts.get(size_key) if size_key else None,
            "refined": {refine_key: opts[refine_key]} if refine_key and refine_key in opts else None,
            "options": opts, "unit_key": row["unit_key"], "label": row["label"], "status": row["unit_status"],
            "error": _num(row.get("error")), "claimed_error": _num(row.get("claimed_error")),
            "peak_rel_l2": _num(row.get("peak_rel_l2")), "max_rel_l2": _num(row.get("max_rel_l2")),
            "p99_s": _num(row.get("haptic_p99_s")), "median_s": _num(row.get("haptic_median_s")),
            "offline_s": _num(row.get("offline_s")), "load_average": _num(row.get("load_average")),
            "n_cpus": _num(row.get("n_cpus")), "seen": bool(row.get("seen", False)),
            "message": str(row.get("message", ""))[:300], "action": action}


def _num(x) -> float | None:
    try:
        v = float(x)
    except (TypeError, ValueError):
        return None
    return None if math.isnan(v) else v


class _Fit:
    def __init__(self, settings: FitSettings, log):
        self.s = settings
        self.log = log
        self.out = Path(settings.out)
        self.plan = scene_plan(settings.scene, settings.variant, settings.resolution, settings.methods)
        self.axes = {kind: axis_of(self.plan, settings.backend, kind) for kind in self.plan.base_cases}
        self.fams = {f.id: f for f in self.plan.families}
        self.t0 = time.perf_counter()
        m = read_manifest(self.out)
        if m is None:
            m = new_manifest(settings.key())
            m["families"] = {f.id: {"status": "active", "why": "", "size_key": f.size_key, "learns": f.learns,
                                    "method": f.name, "case_kind": f.case_kind,
                                    "axis": self.axes[f.case_kind].name if self.axes[f.case_kind] else None,
                                      "lead": None, "runs": [], "refs_added": 0, "last_action": "start",
                                      "next": None, "curve": [], "checks": [], "added": [], "grew_to": []}
                             for f in self.plan.families}
            m["scene_name"] = self.plan.scene.name
            m["analysis"] = self.plan.analysis
            m["error_metric"] = self.plan.error_metric
            m["not_fitted"] = [list(x) for x in self.plan.not_fitted]
            m["target"] = [[c.quantity, c.op, c.value] for c in settings.target.clauses]
        else:
            check_settings(m, settings.key(), self.out)
            m["settings"].update(budget_references=settings.budget_references,
                                 budget_minutes=settings.budget_minutes)
            m["state"] = "running"
            self.log(f"fit: resuming {self.out} ({len(m['rounds'])} rounds begun, {m['elapsed_s'] / 60:.1f} min spent)")
        self.m = m
        self.base_elapsed = float(m.get("elapsed_s", 0.0))

    # --------------------------------------------------------------- bookkeeping
    def elapsed(self) -> float:
        return self.base_elapsed + time.perf_counter() - self.t0

    def save(self) -> None:
        self.m["elapsed_s"] = self.elapsed()
        write_manifest(self.out, self.m)

    # --------------------------------------------------------------- rounds
    def entries(self, k: int) -> list:
        out = []
        for name, st in self.m["families"].items():
            fam = self.fams[name]
            if k == 0:
                out.append((family_case(self.plan, name, []), fam, None))
            elif st["status"] == "active" and st["next"] is not None:
                sets = [a["options"] for a in st["next"].get("alternatives", [])] or [st["next"]["options"]]
                out.append((family_case(self.plan, name, st["next"]["runs"]), fam, sets))
        return out

    def run(self) -> dict:
        self.out.mkdir(parents=True, exist_ok=True)
        (self.out / "rounds").mkdir(exist_ok=True)
        self.save()
        while True:
            rounds = self.m["rounds"]
            if rounds and rounds[-1]["status"] == "running":
                r = rounds[-1]
                self.log(f"fit: round {r['round']}: resuming its sweep ({r['folder']})")
            else:
                k = len(rounds)
                entries = self.entries(k)
                if not entries:
                    break
                if k > 0 and self.elapsed() > 60.0 * self.s.budget_minutes:
                    for st in self.m["families"].values():
                        if st["status"] == "active":
                            st.update(status="stopped", why=f"the budget of {self.s.budget_minutes:g} minutes is spent")
                    self.m["state"] = "budget"
                    break
                r = self.start_round(k, entries)
            self.run_round(r)
            self.measure_round(r)
            if any(st["status"] == "met" for st in self.m["families"].values()):
                for st in self.m["families"].values():
                    if st["status"] == "active":
                        st.update(status="stopped", why="another family met the requirement with as many references")
                break
        return finish(self)

    def start_round(self, k: int, entries: list) -> dict:
        spec = round_spec(self.plan, f"fit-{self.plan.scene.name}-round{k}", entries)
        path = self.out / "rounds" / f"round-{k}.spec.toml"
        what = "the scene's training protocol" if k == 0 else "the families still training"
        path.write_text(toml_text(spec, f"Round {k} of `tissuebench fit` on {self.plan.scene.name}: {what}.\n"
                                        "Run it again with `tissuebench sweep THIS_FILE --out FOLDER`."),
                        encoding="utf-8")
        r = {"round": k, "spec": str(path.relative_to(self.out)), "folder": f"rounds/round-{k}",
             "families": [fam.id for _, fam, _ in entries], "status": "running", "wall_s": None,
             "started_s": self.elapsed()}
        self.m["rounds"].append(r)
        self.save()
        return r

    def run_round(self, r: dict) -> None:
        k = r["round"]
        fams = ", ".join(r["families"])
        news = [f"{n} {st['next']['value_text']}" for n, st in self.m["families"].items()
                if n in r["families"] and st.get("next") and st["next"].get("value_text")]
        self.log(f"fit: round {k}: sweeping {fams}" + (f"; references solved for: {'; '.join(news)}" if news else ""))
        spec = load_spec(self.out / r["spec"], resolution=self.s.resolution)
        folder = self.out / r["folder"]
        resume = folder.exists() and any(folder.iterdir())
        t0 = time.perf_counter()
        run_sweep(spec, folder, self.s.executor, self.s.workers, self.s.scheduler, resume=resume,
                  progress=self.s.progress, log=self.log if self.s.progress else (lambda *_: None), cache=self.s.cache)
        r["sweep_wall_s"] = time.perf_counter() - t0
        self.save()  # the time the sweep took counts in the budget, whatever happens next

    def measure_round(self, r: dict) -> None:
        """Record each family's measurement of round ``r``; then, unless one meets the requirement
        (the others stop: it needed as few references), decide each family's next step."""
        folder = self.out / r["folder"]
        rows = _error_rows(read_units(folder), self.plan.error_metric)
        spec = load_spec(self.out / r["spec"], resolution=self.s.resolution)
        entries = {c.id: c for c in spec.cases}
        pending = []
        for name in r["families"]:
            st = self.m["families"][name]
            if st["status"] == "active":
                step = self.record(r["round"], name, st, rows[rows["case"] == name])
                if step is not None:
                    pending.append((name, st, *step))
        met = [name for name, st in self.m["families"].items() if st["status"] == "met"]
        for name, st, point, dropped in pending:
            if st["status"] != "active":
                continue
            if met:
                st.update(status="stopped", next=None, why=f"{met[0]} met the requirement with as few references")
                continue
            self.next_step(r["round"], name, st, point, entries[name], force_after_drop=dropped)
        r["status"] = "done"
        r["wall_s"] = self.elapsed() - r.get("started_s", self.elapsed())
        self.save()

    def record(self, k, name, st, fam_rows):
        """Add round ``k``'s measurement of family ``name`` to its curve; ``(point, dropped)`` when a
        next step is to be decided, None when the family is done (met, a baseline, nothing ran)."""
        fam, target = self.fams[name], self.s.target
        if fam_rows.empty:
            st.update(status="stopped", why="no unit of the family ran", next=None)
            return None
        action = st["next"]["action"] if st.get("next") else "start"
        st["last_action"] = action
        if k == 0:
            lead = _lead(fam_rows, target)
            st["grid_points"] = [_point(row, k, st, "grid") for _, row in fam_rows.iterrows()]
        elif action == "grow":
            point = self.choose_growth(k, name, st, fam_rows)
            if point is None:  # every larger or refined model failed or missed the speed clauses
                st["last_action"] = "add"
                return next(p for p in reversed(st["curve"]) if not p.get("dropped")), True
        else:
            lead = fam_rows.iloc[0]
        if action != "grow" or k == 0:
            point = _point(lead, k, st, action)
        st["curve"].append(point)
        st["lead"] = point["options"]
        self.log(f"fit: round {k}: {name}: {point['label']} {_said(point)}")
        if target.meets(_as_row(point)):
            st.update(status="met", why="meets " + target.text(), next=None)
            return None
        if not fam.learns:
            st.update(status="stopped", next=None,
                      why="a practitioner baseline: it learns nothing from references (measured once)")
            return None
        return point, False

    def choose_growth(self, k, name, st, fam_rows):
        """The point of the growth round ``k`` of family ``name`` that becomes its lead: among its
        alternatives (a larger size, a refinement), the most accurate that meets the speed clauses;
        an axis whose model fails or misses them is closed (module docstring). None when none is kept
        (each tried one is added to the curve, dropped)."""
        target = self.s.target
        alternatives = st["next"].get("alternatives") or [{"options": st["next"]["options"],
                                                            "option": st["size_key"], "value": None}]
        tried, kept = [], []
        for alt in alternatives:
            rows = [row for _, row in fam_rows.iterrows() if _options(row) == alt["options"]]
            if not rows:
                continue
            point = {**_point(rows[0], k, st, "grow"), "grew": alt["option"]}
            good = point["status"] == "ok" and speed_ok(target, point)
            tried.append({"option": alt["option"], "value": alt["value"], "error": point["error"],
                          "p99_s": point["p99_s"], "status": point["status"], "kept": False})
            if good:
                kept.append((point, tried[-1]))
                continue
            st["refine_done" if alt["option"] == st.get("refine_key") else "ladder_done"] = True
            self.log(f"fit: round {k}: {name}: {point['label']} {_said(point)}: dropped ({alt['option']} stays)")
            st["curve"].append({**point, "dropped": True})
        if st.get("grew_to"):
            st["grew_to"][-1]["tried"] = tried
        if not kept:
            return None
        point, record = min(kept, key=lambda pr: pr[0]["error"] if pr[0]["error"] is not None else math.inf)
        record["kept"] = True
        for other, _ in kept:
            if other is not point:
                st["curve"].append({**other, "dropped": True, "why": "the other growth was more accurate"})
        return point

    def next_step(self, k, name, st, point, entry, force_after_drop=False) -> None:
        """Decide family ``name``'s next step after ``point`` and record it (module docstring). A
        family whose lead failed, or whose lead model cannot be rebuilt or stepped for the indicator
        (the method raises), stops saying why; the fit goes on with the others."""
        if point["status"] != "ok":
            st.update(status="stopped", next=None, why=f"its unit failed: {point['message'][:200]}")
            self.log(f"fit: round {k}: {name}: stop: {st['why']}")
            return
        try:
            self._next_step(k, name, st, point, entry, force_after_drop)
        except (Exception, *EXIT_TYPES) as exc:  # noqa: BLE001 - a method's failure stops its family, never the fit
            if not isinstance(exc, Exception) and not raised_by_code(exc):
                raise  # the user's Ctrl-C or SIGTERM: the fit stops, resumably (tissuebench.exits)
            st.update(status="stopped", next=None, why=f"the indicator could not be computed on its lead model: "
                                                       f"{type(exc).__name__}: {str(exc)[:200]}")
            self.log(f"fit: round {k}: {name}: stop: {st['why']}")

    def _next_step(self, k, name, st, point, entry, force_after_drop) -> None:
        fam, target = self.fams[name], self.s.target
        size = point["options"].get(fam.size_key) if fam.size_key else None
        grow_to = None if st.get("ladder_done") else next_size(fam, size)
        refine = None if st.get("refine_done") or not fam.learns else next_refinement(
            fam.name, point["options"], refinements_kept(st["curve"], st.get("refine_key")))
        model = training = None
        candidates = np.zeros(0)
        axis = self.axis_for(name)
        if axis is not None:
            trained_case = family_case(self.plan, name, st["runs"])
            model, training = self.lead_model(entry, fam.name, point["options"])
            pts = self.unit_points(point["round"], point["unit_key"])
            measured = axis.measured(trained_case, pts)
            candidates = axis.candidates(axis.trained(trained_case, training), measured)
            if not pts.empty and not force_after_drop:
                rho, n = axis.point_check(model, training, trained_case, pts)
                st["checks"].append({"round": k, "rho": rho, "pairs": n, "size": size})
                self.log(f"fit: round {k}: {name}: the indicator's rank correlation with the true error: "
                         f"{rho:.3g} over {n} points")
        if force_after_drop:
            action, why = ("add", "a reference at the worst candidate") if (
                st["refs_added"] < self.s.budget_references and len(candidates)) else (
                "stop", "a larger model misses the requirement's speed or fails, and no reference is left to add")
        else:
            action, why = decide(st, point, target, self.s.budget_references, bool(len(candidates)),
                                 grow_to is not None or refine is not None)
        if action == "met":
            st.update(status="met", why=why, next=None)
        elif action == "stop":
            st.update(status="stopped", why=why, next=None)
        elif action == "grow":
            alternatives = []
            if grow_to is not None:
                alternatives.append({"options": {**point["options"], fam.size_key: grow_to}, "option": fam.size_key,
                                     "value": grow_to})
            if refine is not None:
                st["refine_key"] = refine[0]
                alternatives.append({"options": {**point["options"], refine[0]: refine[1]}, "option": refine[0],
                                     "value": refine[1]})
            st["grew_to"].append({"round": k, "size": grow_to, "refinement": list(refine) if refine else None})
            st["next"] = {"action": "grow", "options": alternatives[0]["options"], "alternatives": alternatives,
                          "runs": list(st["runs"]), "why": why, "value_text": ""}
            self.log(f"fit: round {k}: {name}: grow: " + " and ".join(f"{a['option']} {a['value']:g}"
                                                                      for a in alternatives))
        else:
            self.log(f"fit: round {k}: {name}: indicator at {len(candidates)} candidate {axis.name}s")
            ind = axis.indicators(model, training, candidates)
            worst = int(np.argmax(np.where(np.isnan(ind), -np.inf, ind)))
            value = float(candidates[worst])
            order = np.argsort(-np.nan_to_num(ind, nan=-np.inf))[:3]
            st["added"].append({"round": k, "value": value, "indicator": float(ind[worst]),
                                "candidates": int(len(candidates)),
                                "top": [[float(candidates[i]), float(ind[i])] for i in order]})
            runs = list(st["runs"]) + [axis.run(value)]
            st["runs"] = runs
            st["refs_added"] += 1
            text = f"{axis.name} {value:.6g}"
            st["next"] = {"action": "add", "options": dict(point["options"]), "runs": runs, "why": why,
                          "value_text": text}
            self.log(f"fit: round {k}: {name}: worst candidate {text} (indicator {ind[worst]:.3g}): a reference "
                     f"is added there ({st['refs_added']} of {self.s.budget_references})")
        if action in ("met", "stop"):
            self.log(f"fit: round {k}: {name}: {action}: {why}")

    def axis_for(self, family_id: str):
        """The axis the family ``family_id`` adds references along (None: it has none)."""
        return self.axes[self.fams[family_id].case_kind]

    def lead_model(self, entry, method, options):
        """The lead's model rebuilt on the unit's own training (the round spec's case entry)."""
        scene = case_scene(entry)
        training = build_training(entry, scene)
        return make_method(method, **options).build(training), training

    def unit_points(self, k, unit_key) -> pd.DataFrame:
        points = read_points(self.out / self.m["rounds"][k]["folder"])
        return points[points["unit_key"] == unit_key] if not points.empty else points


def _options(row) -> dict:
    return json.loads(row["options"]) if isinstance(row.get("options"), str) else {}


def _said(p: dict) -> str:
    if p["status"] != "ok":
        return f"failed: {p['message'][:160]}"
    return (f"error {_pct(p['error'])}, p99 {p['p99_s'] * 1e3:.3g} ms" if p["p99_s"] is not None
            else f"error {_pct(p['error'])}")


def _lead(rows: pd.DataFrame, target: Target):
    """The family's lead among its round-0 units: the most accurate that meets the speed clauses
    as timed, else the most accurate that meets them with its p99 divided by the machine's load
    (:func:`speed_ok`), else the fastest usable, else the first."""
    usable = rows[(rows["unit_status"] == "ok") & ~rows.get("seen", pd.Series(False, index=rows.index)).fillna(False)
                  .astype(bool)]
    timed = [_point(r, 0, {"size_key": "", "refs_added": 0}, "") for _, r in usable.iterrows()]
    for ok in (lambda p: target.meets_speed(_as_row(p)), lambda p: speed_ok(target, p)):
        fast = usable[[ok(p) for p in timed]] if not usable.empty else usable
        if not fast.empty:
            return fast.sort_values(["error", "haptic_p99_s"], na_position="last").iloc[0]
    if not usable.empty:
        return usable.sort_values("haptic_p99_s", na_position="last").iloc[0]
    return rows.iloc[0]


def run_fit(settings: FitSettings, log=_stderr, figures=None) -> dict:
    """Train to a requirement (module docstring); returns the manifest (``answer``, ``dense``,
    each family's learning curve). ``figures(manifest, path)`` draws the learning curves into
    ``path`` (a PNG; :mod:`tissuebench.reports.fit_figure`)."""
    fit = _Fit(settings, log)
    fit.figures = figures
    return fit.run()
