"""A/B latency in one run: the units of a sweep re-timed with REF's code and HEAD's code.

``tissuebench check RESULTS --against REF`` uses this instead of comparing latency ratios
across runs (microsecond medians move 2-3x between identical runs on a shared machine:
no tolerance survives that, a measurement design does). asv's ``continuous`` and pyperf's
worker processes are the models:

* REF's package is exported from git (:func:`.ab_ref.export_ref`) into a scratch folder;
  HEAD is the package this process runs (the working tree, uncommitted changes included).
  Both use the same installed dependencies.
* Rounds alternate the sides, A B then B A (so a linear drift of the machine cancels):
  each round starts one worker process per side (:mod:`.ab_probe`, always HEAD's timing
  loop) that builds every still-undecided unit with its side's code and times ``blocks``
  blocks of haptic steps, each block on a fresh copy of the model (memory layout is part
  of the noise to sample: see :mod:`.ab_probe`).
* After ``min_rounds`` rounds, every unit whose confidence interval of the HEAD/REF
  median ratio lies clear of the decision threshold is decided (:mod:`.ab_stats`) and
  leaves the later rounds; the rest run until ``max_rounds`` or the time budget.

Every per-step sample is kept (:func:`run_ab` returns them; the gate writes them to
``RESULTS/_gate/ab_samples.parquet``).
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import pandas as pd

from ..rom import make_method
from .ab_ref import code_env
from .case_entry import CaseEntry
from .evaluation import NEEDS_MODEL, build_evaluation
from .protocol import _start, _timing_sequence
from .spec import expand_units, load_spec
from .training import build_training, case_scene

__all__ = ["PreparedUnit", "prepare_unit", "ABUnit", "ab_units", "run_ab", "SAMPLE_COLUMNS"]

SAMPLE_COLUMNS = ["uid", "side", "round", "block", "sample", "haptic_s"]


@dataclass
class PreparedUnit:
    """A built model and the haptic sequence the protocol times it on (:mod:`.protocol`)."""

    model: object
    sequence: list
    start: object  # start(model): restart ``model`` at the beginning of ``sequence``
    stop_on_failure: bool  # a trajectory cannot go on past a failed step


def prepare_unit(case: CaseEntry | dict, method: str, options: dict, steps: int, seed: int = 0) -> PreparedUnit:
    """Build the unit's model and its timing sequence as the sweep does (:func:`.units.run_unit`).

    The stable entry point the A/B probe calls into the code under test: keep its signature
    (the probe falls back to the 0.1 internals for code from before it). ``case``: the entry or
    its dict form (:meth:`~.case_entry.CaseEntry.as_dict`: what the probe's JSON job carries)."""
    case = case if isinstance(case, CaseEntry) else CaseEntry.from_dict(case)
    scene = case_scene(case)
    training = build_training(case, scene)
    needs_model = case.evaluation_kind in NEEDS_MODEL
    evaluation = None if needs_model else build_evaluation(case, scene)
    model = make_method(method, **options).build(training)
    if needs_model:
        evaluation = build_evaluation(case, scene, model)
    if training.outputs:
        model.attach_outputs(training.outputs)
    history = training.history or (scene.history if evaluation.kind == "trajectory" else None)
    seq = _timing_sequence(model, evaluation, history, steps, seed)
    return PreparedUnit(model, seq, lambda m: _start(m, evaluation, seq), evaluation.kind == "trajectory")


@dataclass(frozen=True)
class ABUnit:
    """One unit to re-time: its identity in the store and what the probe needs to build it."""

    uid: str
    case: dict  # the entry's dict form (CaseEntry.as_dict): the probe hands it to either side's code
    method: str
    options: dict
    steps: int
    warmup: int
    blas_threads: int


def ab_units(results_dir, rows: pd.DataFrame) -> list[ABUnit]:
    """The :class:`ABUnit` of every row of ``rows`` (units of the store in ``results_dir``):
    the case entries and protocols come from the sweep's own spec (``_sweep.json``), expanded
    again; ``uid`` is the stored ``unit_key``."""
    manifest = json.loads((Path(results_dir) / "_sweep.json").read_text())
    with tempfile.TemporaryDirectory(prefix="tissuebench-spec.") as tmp:
        path = Path(tmp) / f"{manifest.get('spec_name', 'sweep')}.toml"
        path.write_text(manifest["spec_text"])
        spec = load_spec(path, resolution=manifest.get("resolution"))
    by_identity = {u.identity: u for u in expand_units(spec)}
    out = []
    for _, row in rows.iterrows():
        u = by_identity.get((row["case"], row["method"], row["options"]))
        if u is None:
            raise ValueError(f"{results_dir}: unit {row['case']} {row['label']} is not in the sweep's spec "
                             f"(_sweep.json spec_text): the store and its spec disagree")
        p = u.protocol
        out.append(ABUnit(row["unit_key"], u.case.as_dict(), u.method, u.options, int(p["latency_steps"]),
                          int(p["warmup"]), int(p.get("blas_threads") or 0)))
    return out


def _probe(root: Path, units: list[ABUnit], blocks: int, seed: int, scratch: Path, tag: str,
           inject: dict | None) -> dict:
    """One worker process with ``root`` first on the path; its result dict (``ab_probe``)."""
    job, result = scratch / f"{tag}.job.json", scratch / f"{tag}.result.json"
    job.write_text(json.dumps({"units": [asdict(u) for u in units], "blocks": blocks, "seed": seed,
                               "inject": inject or {}}, default=str))
    proc = subprocess.run([sys.executable, str(scratch / "ab_probe.py"), str(job), str(result)], env=code_env(root),
                          capture_output=True, text=True)
    if proc.returncode != 0 or not result.is_file():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
        return {"error": f"worker exited {proc.returncode}: {' | '.join(tail)}", "units": {}}
    out = json.loads(result.read_text())
    loaded = out.get("tissuebench")
    if not loaded or Path(loaded).resolve().parents[1] != root.resolve():
        return {"error": f"worker imported tissuebench from {out.get('tissuebench')}, not {root}", "units": {}}
    return out


def run_ab(units: list[ABUnit], ref_root: Path, head_root: Path, decide, min_rounds: int = 3,
           max_rounds: int = 8, blocks: int = 3, budget_s: float = 900.0, seed: int = 0,
           inject: dict | None = None, log=print) -> tuple[pd.DataFrame, dict]:
    """Alternate REF (side ``"ref"``) and HEAD (``"head"``) worker processes (module docstring).

    ``decide(samples) -> set of decided uids`` is called after each round from ``min_rounds``
    on. ``inject`` maps uids to a slowdown factor applied on the HEAD side (power tests).
    Returns ``(samples, failures)``: the per-step samples (:data:`SAMPLE_COLUMNS`) and, per
    uid, ``{side: message}`` for units that failed on a side."""
    if min_rounds < 2 or max_rounds < min_rounds or blocks < 1:
        raise ValueError(f"A/B rounds: need 2 <= min_rounds ({min_rounds}) <= max_rounds ({max_rounds}), "
                         f"blocks ({blocks}) >= 1")
    roots = {"ref": Path(ref_root), "head": Path(head_root)}
    frames, failures, active = [], {}, list(units)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="tissuebench-ab.") as tmp:
        scratch = Path(tmp)
        shutil.copy(Path(__file__).with_name("ab_probe.py"), scratch / "ab_probe.py")
        for r in range(max_rounds):
            sides = ("ref", "head") if r % 2 == 0 else ("head", "ref")
            spent = {}
            for side in sides:
                ts = time.perf_counter()
                out = _probe(roots[side], active, blocks, seed + r, scratch, f"{side}{r}",
                             inject if side == "head" else None)
                spent[side] = time.perf_counter() - ts
                if "error" in out and not out["units"]:
                    raise RuntimeError(f"A/B {side} worker failed in round {r + 1}: {out['error']}")
                frames.append(_samples(out, side, r, failures))
            samples = pd.concat(frames, ignore_index=True)
            decided = decide(samples) if r + 1 >= min_rounds else set()
            active = [u for u in active if u.uid not in decided and u.uid not in failures]
            log(f"A/B round {r + 1}/{max_rounds}: REF {spent['ref']:.0f} s, HEAD {spent['head']:.0f} s; "
                f"{len(units) - len(active)} of {len(units)} units decided")
            if not active or time.perf_counter() - t0 > budget_s:
                break
    return samples, failures


def _samples(out: dict, side: str, rnd: int, failures: dict) -> pd.DataFrame:
    rows = {c: [] for c in SAMPLE_COLUMNS}
    for uid, res in out["units"].items():
        if res.get("status") != "ok":
            failures.setdefault(uid, {})[side] = res.get("message", "")
            continue
        for b, block in enumerate(res["blocks"]):
            n = len(block)
            rows["uid"] += [uid] * n
            rows["side"] += [side] * n
            rows["round"] += [rnd] * n
            rows["block"] += [b] * n
            rows["sample"] += list(range(n))
            rows["haptic_s"] += [float(x) for x in block]
    return pd.DataFrame(rows, columns=SAMPLE_COLUMNS)
