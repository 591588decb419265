"""Mutation testing of the modules that compute the numbers users decide on (issue 41): ``tox -e mutation``.

Runs mutmut (configured in ``pyproject.toml``, ``[tool.mutmut]``) over one module at a time, in
the order below, and prints per module: mutants, killed (by a failing test, or by a timeout
or a crash), equivalent (listed with the reason in ``tools/mutation_equivalent.toml``: the
mutant cannot change any result), survived, not covered, and the wall time. Exit status 1
when a module's score (killed + equivalent over all its mutants) is below its target.

    python tools/mutation.py                 # every module
    python tools/mutation.py metrics gate    # the modules whose name starts with these
    python tools/mutation.py --scores        # the table of the last run, nothing re-run
    python tools/mutation.py --retest pod    # re-test only the mutants that were not killed (after new tests)

mutmut keeps its results in ``mutants/`` (git-ignored). A module's run re-tests all its mutants;
``--retest`` only those that survived; a change of the test selection in ``[tool.mutmut]``
makes mutmut forget every result (its stats map tests to functions).
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
import tomllib
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EQUIVALENT = ROOT / "tools" / "mutation_equivalent.toml"

#: (name, mutmut's glob of the module's mutant names, target score): 95 % for the metrics, the gate, the
#: cache key and the recommendation; 90 % for the materials, the integrators and POD (issue 41); the
#: third-party boundary and the ROM code of issue 50 after them
MODULES = [
    ("metrics", "tissuebench.studies.metrics.*", 0.95),
    ("timing", "tissuebench.studies.timing.*", 0.95),
    ("gate.stats", "tissuebench.gate.stats.*", 0.95),
    ("gate.checks", "tissuebench.gate.checks.*", 0.95),
    ("gate.baseline", "tissuebench.gate.baseline.*", 0.95),
    ("provenance", "tissuebench.reference.provenance.*", 0.95),
    ("cache", "tissuebench.reference.cache.*", 0.95),
    ("entry", "tissuebench.reference.entry.*", 0.95),
    ("recommend", "tissuebench.reports.recommend.*", 0.95),
    ("pod", "tissuebench.rom.pod.*", 0.90),
    ("materials", "tissuebench.refsolvers.materials.*", 0.90),
    # the integrators' update formulas first, then the machinery around them
    *[(f"dynamics.{m}", f"tissuebench.refsolvers.dynamics.{m}.*", 0.90)
      for m in ("implicit", "explicit", "step_newton", "system", "base", "driver", "result", "checks", "registry")],
    # issue 50: where tissuebench meets code and numbers it did not write (which reference, which plugin code a
    # key records, which parameters a step reads, the evaluation points of the claimed range): 95 %
    ("locking", "tissuebench.reference.locking.*", 0.95),
    ("formulation", "tissuebench.reference.formulation.*", 0.95),
    ("plugins", "tissuebench.rom.plugins.*", 0.95),
    ("reads", "tissuebench.rom.reads.*", 0.95),
    ("path_range", "tissuebench.studies.path_range.*", 0.95),
    # the POD-Galerkin kernels: 90 %
    *[(f"galerkin.{m}", f"tissuebench.rom.galerkin.{m}.*", 0.90)
      for m in ("kernel", "forces", "ecsw", "deim", "basis", "system", "model", "method")],
]

_KILLED = {1, 3}  # a test failed (3: pytest's internal error, raised by the mutant)
_DETECTED = {36, -24, 24, 152, 255, -11, -9}  # a timeout or a crash: detected too
_SURVIVED = 0
_NO_TESTS = {5, 33}


def results() -> dict:
    """``{mutant name: mutmut's exit code}`` of every mutant in ``mutants/``."""
    out = {}
    for meta in (ROOT / "mutants").rglob("*.meta"):
        out.update(json.loads(meta.read_text())["exit_code_by_key"])
    return out


def equivalent() -> dict:
    """``{mutant name: why it cannot change any result}``."""
    return tomllib.loads(EQUIVALENT.read_text()) if EQUIVALENT.is_file() else {}


def score(glob: str, codes: dict, equiv: dict) -> dict:
    pattern = re.compile(re.escape(glob[:-1]) + ".*")
    mine = {k: v for k, v in codes.items() if pattern.fullmatch(k)}
    count = Counter()
    survivors = []
    for name, code in sorted(mine.items()):
        if code in _KILLED:
            count["killed"] += 1
        elif code in _DETECTED:
            count["timeout"] += 1
        elif code == _SURVIVED and name in equiv:
            count["equivalent"] += 1
        elif code == _SURVIVED:
            count["survived"] += 1
            survivors.append(name)
        elif code in _NO_TESTS:
            count["no_tests"] += 1
            survivors.append(name)
        else:
            count["not_checked"] += 1
            survivors.append(name)
    count["total"] = len(mine)
    good = count["killed"] + count["timeout"] + count["equivalent"]
    count["score"] = good / len(mine) if mine else float("nan")
    return {"count": count, "survivors": survivors}


def run_module(names: list, children: int) -> float:
    """Run mutmut over the mutants ``names`` (names or globs); the wall time [s]."""
    t0 = time.monotonic()
    env = {**os.environ, "MPLBACKEND": "Agg", "PYVISTA_OFF_SCREEN": "true"}
    subprocess.run([sys.executable, "-m", "mutmut", "run", "--max-children", str(children), *names], cwd=ROOT,
                   env=env, check=False, stdout=subprocess.DEVNULL)
    return time.monotonic() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("modules", nargs="*", help="module names (prefixes) to run; all without any")
    ap.add_argument("--scores", action="store_true", help="print the scores of the last run only")
    ap.add_argument("--children", type=int, default=1, help="mutants tested at once (default 1)")
    ap.add_argument("--survivors", action="store_true", help="list each surviving mutant")
    ap.add_argument("--retest", action="store_true", help="re-test only the mutants not killed in the last run")
    args = ap.parse_args(argv)
    chosen = [m for m in MODULES if not args.modules or any(m[0].startswith(p) for p in args.modules)]
    if not chosen:
        ap.error(f"modules {args.modules}: none of {[m[0] for m in MODULES]}")
    walls = {}
    if not args.scores:
        codes, equiv = results(), equivalent()
        for name, glob, _ in chosen:
            if codes and not score(glob, codes, equiv)["count"]["total"]:
                print(f"{name}: no mutant (mutmut 3 leaves decorated functions alone)", flush=True)
                continue
            names = [m for m in score(glob, codes, equiv)["survivors"]] if args.retest else [glob]
            walls[name] = run_module(names, args.children) if names else 0.0
            print(f"{name}: {len(names) if args.retest else 'all'} mutants, {walls[name]:.0f} s", flush=True)
    codes, equiv = results(), equivalent()
    below = []
    print(f"{'module':20s} {'total':>6s} {'killed':>6s} {'timeout':>7s} {'equiv':>6s} {'survived':>8s} "
          f"{'no test':>7s} {'score':>6s} {'target':>6s} {'wall s':>7s}")
    for name, glob, target in chosen:
        s = score(glob, codes, equiv)
        c = s["count"]
        print(f"{name:20s} {c['total']:6d} {c['killed']:6d} {c['timeout']:7d} {c['equivalent']:6d} "
              f"{c['survived']:8d} {c['no_tests'] + c['not_checked']:7d} {c['score']:6.1%} {target:6.0%} "
              f"{walls.get(name, float('nan')):7.0f}")
        if args.survivors:
            for m in s["survivors"]:
                print(f"    survived: {m}")
        if c["total"] and not c["score"] >= target:  # no mutant: mutmut skips decorated functions
            below.append(name)
    if below:
        print(f"below target: {', '.join(below)} (mutmut show NAME; mutmut results)")
    return 1 if below else 0


if __name__ == "__main__":
    sys.exit(main())
