"""Command line: ``tissuebench run CASE [--backend] [--resolution] [--out] [--force]``."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _parser():
    p = argparse.ArgumentParser(prog="tissuebench", description=__doc__)
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="reference solve of a built-in case")
    run.add_argument("case", help="case name (built-in: bar_tension)")
    run.add_argument("--backend", default="skfem", choices=["skfem", "ngsolve"])
    run.add_argument("--resolution", default="ci", choices=["ci", "paper"])
    run.add_argument("--out", type=Path, default=None, help="result folder (default: out/CASE-BACKEND-RESOLUTION)")
    run.add_argument("--force", action="store_true", help="replace an existing result folder")
    run.add_argument("--increments", type=int, default=3, help="initial number of load increments")
    sub.add_parser("cases", help="list the built-in cases")
    return p


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    from .studies.run import CASES, run_case

    if args.command == "cases":
        for name in sorted(CASES):
            print(name)
        return 0
    out = args.out or Path("out") / f"{args.case}-{args.backend}-{args.resolution}"
    try:
        table, result = run_case(args.case, args.backend, args.resolution, out, args.force, args.increments)
    except (ValueError, FileExistsError) as exc:
        print(f"tissuebench: error: {exc}", file=sys.stderr)
        return 2
    cols = [c for c in ("step", "load_factor", "newton_iterations", "wall_s", "nominal_stress_kPa", "volume_ratio")
            if c in table]
    print(table[cols].to_string(index=False))
    print(f"{result.status}: {result.message}; results in {out}")
    return 0 if result.success else 1


if __name__ == "__main__":
    sys.exit(main())
