"""The report's "Peers beside ours" section: each unit of a method that declares a counterpart
(:meth:`~tissuebench.rom.base.RomMethod.counterpart_for`: a library's adapter beside the shipped
method of its family) paired with a unit of that counterpart on the same case, from the same run.

The pairing reads the method classes only, never their names: a unit of method ``P`` whose class
declares ``(name, options)`` for the case's training kind is paired with the units of ``name`` on the
same case whose options hold the declared ones; among them, the one sharing the most equal values of
the options both take (``n_modes``, ``hyper`` ...), the first by label on a tie. A unit of another
package whose class cannot be loaded (not installed where the report is made) is paired by what its
build recorded (``model_info["counterpart"]``: :class:`~tissuebench.rom.base.RomMethod` records it),
else named, unpaired.

Per pair: the error (the sweep's error metric), the p99 haptic step and the offline build of both,
and the ratios ours / peer (< 1: ours is lower). The verdict: a side is *ahead* where it is at least
as accurate (the errors within :data:`SAME_ERROR`, relative) and at least as fast at the p99 (within a
factor :data:`SAME_TIME`), and strictly better in one, or equal in both and cheaper offline (the same
factor); else the pair is a *trade-off* (one more accurate, the other faster); a failed unit is said
so. The factor is wide on purpose: two units of the same online model (``romtools_ecsw`` and
``pod_galerkin hyper = "ecsw"`` step the same code on the same elements) measured 9.3 and 13.3 ms at
the p99 in one run on the shared 2-core machine (load 6.7): a p99 resting on a few samples beyond it
moves by tens of percent between units. Each row carries the machine's load while it was timed.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd

from ..rom import method_class
from .format import number, seconds

__all__ = ["peer_pairs", "peers_section", "verdict", "SAME_ERROR", "SAME_TIME"]

#: errors within this relative difference are the same error
SAME_ERROR = 0.01
#: p99 latencies (and offline times) within this factor of each other are the same time: one run's timing noise
SAME_TIME = 1.5

_COLUMNS = ["case", "peer", "ours", "peer_method", "ours_method", "peer_status", "ours_status", "peer_error",
            "ours_error", "error_ratio", "peer_p99_s", "ours_p99_s", "p99_ratio", "peer_offline_s", "ours_offline_s",
            "offline_ratio", "peer_load", "ours_load", "verdict"]


def _options(text) -> dict:
    try:
        value = json.loads(text) if isinstance(text, str) and text else {}
    except ValueError:
        return {}
    return value if isinstance(value, dict) else {}


def _training_kinds(manifest: dict) -> dict:
    return {c.get("id"): (c.get("training") or {}).get("kind") for c in (manifest or {}).get("cases", [])}


def _recorded(row):
    """``(name, options)`` the unit's build recorded (``model_info["counterpart"]``), or None."""
    try:
        info = json.loads(row.get("model_info") or "{}")
        name, options = info["counterpart"]
    except (ValueError, TypeError, KeyError, AttributeError):
        return None
    return (name, dict(options)) if isinstance(name, str) and isinstance(options, dict) else None


def _declared(row, kinds: dict):
    """``(name, options)`` the unit's method class pairs it with on its case (what its build recorded
    where the class cannot be loaded), None, or the error text."""
    source = row.get("method_source")
    plugin = isinstance(source, str) and bool(source)
    try:
        cls = method_class(source if plugin else row["method"])
    except (ValueError, TypeError) as exc:  # a method of another package not installed here
        recorded = _recorded(row)
        if recorded is not None:
            return recorded
        return f"its method could not be loaded ({exc})" if plugin else None
    try:
        return cls.counterpart_for(kinds.get(row["case"]))
    except ValueError as exc:
        return str(exc)


def _ratio(ours, peer) -> float:
    ours, peer = float(ours), float(peer)
    if not (math.isfinite(ours) and math.isfinite(peer)) or peer <= 0:
        return float("nan")
    return ours / peer


def _same(a, b, tol) -> bool:
    """Within ``tol`` relative to the larger (errors)."""
    return abs(a - b) <= tol * max(abs(a), abs(b)) or max(abs(a), abs(b)) < 1e-300


def _same_time(a, b) -> bool:
    """Within a factor :data:`SAME_TIME` of each other (times)."""
    return max(a, b) <= SAME_TIME * min(a, b) or max(a, b) < 1e-300


def verdict(peer: dict, ours: dict) -> str:
    """``"ours ahead"``, ``"peer ahead"``, ``"trade-off: ..."``, ``"same"`` or why none (module docstring)."""
    if peer["status"] != "ok" or ours["status"] != "ok":
        who = [w for w, u in (("peer", peer), ("ours", ours)) if u["status"] != "ok"]
        return f"{' and '.join(who)} failed"
    e_p, e_o, t_p, t_o = (float(x) for x in (peer["error"], ours["error"], peer["p99"], ours["p99"]))
    if not all(math.isfinite(x) for x in (e_p, e_o, t_p, t_o)):
        return "not measured"
    err = 0 if _same(e_p, e_o, SAME_ERROR) else (1 if e_o < e_p else -1)  # +1: ours better
    lat = 0 if _same_time(t_p, t_o) else (1 if t_o < t_p else -1)
    if err == 0 and lat == 0:
        o_p, o_o = float(peer["offline"]), float(ours["offline"])
        if math.isfinite(o_p) and math.isfinite(o_o) and not _same_time(o_p, o_o):
            return "ours ahead (the same error and step, cheaper offline)" if o_o < o_p else \
                "peer ahead (the same error and step, cheaper offline)"
        return "same"
    if err >= 0 and lat >= 0:
        return "ours ahead"
    if err <= 0 and lat <= 0:
        return "peer ahead"
    return "trade-off: ours more accurate, the peer faster" if err > 0 else \
        "trade-off: the peer more accurate, ours faster"


def peer_pairs(units: pd.DataFrame, manifest: dict, error_metric: str) -> tuple[pd.DataFrame, list]:
    """``(pairs, notes)``: one row per unit of a method with a counterpart (:data:`_COLUMNS`), and a
    note per unit that could not be paired (module docstring)."""
    kinds = _training_kinds(manifest)
    rows, notes = [], []
    units = units.reset_index(drop=True)
    for _, u in units.iterrows():
        declared = _declared(u, kinds)
        if declared is None:
            continue
        if isinstance(declared, str):
            notes.append(f"{u['case']}: {u['label']}: {declared}: not paired")
            continue
        name, wanted = declared
        same_case = units[(units["case"] == u["case"]) & (units["method"] == name)]
        mine = _options(u["options"])
        best, best_score = None, -1
        for _, c in same_case.sort_values("label").iterrows():
            theirs = _options(c["options"])
            if any(theirs.get(k) != v for k, v in wanted.items()):
                continue
            score = sum(1 for k in set(mine) & set(theirs) if mine[k] == theirs[k])
            if score > best_score:
                best, best_score = c, score
        if best is None:
            notes.append(f"{u['case']}: {u['label']}: no unit of its counterpart {name} "
                         f"{json.dumps(wanted, sort_keys=True) if wanted else ''} in this case: not paired".replace(
                             "  ", " "))
            continue

        def side(r):
            return {"status": r["unit_status"], "error": r[error_metric], "p99": r["haptic_p99_s"],
                    "offline": r["offline_s"]}
        p, o = side(u), side(best)
        rows.append({"case": u["case"], "peer": u["label"], "ours": best["label"], "peer_method": u["method"],
                     "ours_method": best["method"], "peer_status": p["status"], "ours_status": o["status"],
                     "peer_error": float(p["error"]), "ours_error": float(o["error"]),
                     "error_ratio": _ratio(o["error"], p["error"]), "peer_p99_s": float(p["p99"]),
                     "ours_p99_s": float(o["p99"]), "p99_ratio": _ratio(o["p99"], p["p99"]),
                     "peer_offline_s": float(p["offline"]), "ours_offline_s": float(o["offline"]),
                     "offline_ratio": _ratio(o["offline"], p["offline"]),
                     "peer_load": float(u.get("load_average", np.nan)),
                     "ours_load": float(best.get("load_average", np.nan)), "verdict": verdict(p, o)})
    return pd.DataFrame(rows, columns=_COLUMNS), notes


def _sentence(rows: pd.DataFrame) -> str:
    """``"3 pair(s): ours ahead 1, trade-off 2."``: the verdicts counted (without their reasons)."""
    kinds = rows["verdict"].str.split(r" \(|:", regex=True).str[0]
    return f"{len(rows)} pair(s): " + ", ".join(f"{k} {n}" for k, n in kinds.value_counts(sort=False).items()) + "."


def peers_section(data, Table, titles: dict | None = None) -> dict | None:
    """``{"cases": [{"case", "title", "sentence"}], "table", "notes", "tables"}`` of the report, or None
    when no unit's method declares a counterpart."""
    if data.units.empty:
        return None
    pairs, notes = peer_pairs(data.units, data.manifest, data.error_metric)
    if pairs.empty and not notes:
        return None
    rows = [[r.case, r.peer, r.ours, number(r.peer_error, 3), number(r.ours_error, 3), number(r.error_ratio, 3),
             seconds(r.peer_p99_s), seconds(r.ours_p99_s), number(r.p99_ratio, 3), seconds(r.peer_offline_s),
             seconds(r.ours_offline_s), number(r.offline_ratio, 3), f"{number(r.peer_load, 2)} / "
             f"{number(r.ours_load, 2)}", r.verdict] for r in pairs.itertuples()]
    table = Table("peers", ["case", "peer", "ours", "error, peer", "error, ours", "ours / peer", "p99, peer",
                            "p99, ours", "ours / peer", "offline, peer", "offline, ours", "ours / peer",
                            "load (peer / ours)", "verdict"], rows, pairs)
    cases = [{"case": c, "title": (titles or {}).get(c, c), "sentence": _sentence(pairs[pairs["case"] == c])}
             for c in dict.fromkeys(pairs["case"])]
    return {"cases": cases, "table": table, "notes": notes, "tables": [table]}
