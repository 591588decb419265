"""Command line of tissuebench.

``tissuebench cases``                       the catalogue (name, paper, analysis, sizes)
``tissuebench describe CASE``               what a run models and why
``tissuebench study anm_pod [--resolution ci|paper] [--out DIR]``   ANM-POD study
``tissuebench run CASE [--variant V] [--backend skfem|ngsolve] [--resolution ci|paper]
[--out DIR] [--force]``                     reference solve, stored in DIR

Exit codes: 0 success, 1 the run finished with a numerical failure (stored), 2 bad input.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def _parser():
    p = argparse.ArgumentParser(prog="tissuebench", description="Verification and benchmarking of "
                                "reduced-order models of soft tissue.")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="reference solve of a catalogue case")
    run.add_argument("case", help="case name (see `tissuebench cases`) or a scene file")
    run.add_argument("--variant", default=None, help="scene variant (default: the scene's default)")
    run.add_argument("--backend", default="skfem", choices=["skfem", "ngsolve"])
    run.add_argument("--resolution", default="ci", choices=["ci", "paper"])
    run.add_argument("--out", type=Path, default=None, help="result folder (default: out/CASE[-VARIANT]-BACKEND-RES)")
    run.add_argument("--force", action="store_true", help="replace an existing result folder")
    run.add_argument("--linear-solver", default="direct", choices=["direct", "amg-cg"])
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    cases = sub.add_parser("cases", help="list the catalogue")
    cases.add_argument("--no-mesh", action="store_true", help="do not build meshes to count nodes")
    cases.add_argument("--paper", action="store_true", help="also build the paper-resolution meshes (slow)")
    study = sub.add_parser("study", help="run a study (anm_pod)")
    study.add_argument("name", help="study name: anm_pod")
    study.add_argument("--resolution", default="ci", choices=["ci", "paper"],
                       help="ci: small sweep on the ci meshes; paper: the full sweep (modes 1-15, orders 1-10)")
    study.add_argument("--out", type=Path, default=None, help="result folder (default: out/study-NAME-RES)")
    study.add_argument("--force", action="store_true", help="replace an existing result folder")
    study.add_argument("--quiet", action="store_true", help="no progress bars")
    desc = sub.add_parser("describe", help="what a run of CASE models, and why")
    desc.add_argument("case")
    desc.add_argument("--variant", default=None)
    desc.add_argument("--resolution", default="ci", choices=["ci", "paper"])
    return p


def _error(exc) -> int:
    print(f"tissuebench: error: {exc}", file=sys.stderr)
    return 2


def _run(args) -> int:
    from .cases.scene import load
    from .studies.run import run_case

    scene = load(args.case, resolution=args.resolution, variant=args.variant)
    if scene.is_fe and scene.mesh_info.get("fallback"):
        print(f"tissuebench: note: {scene.mesh_info.get('reason', 'built-in fallback shape used')}",
              file=sys.stderr)
    tag = scene.name + (f"-{scene.variant}" if scene.variant else "")
    out = args.out or Path("out") / f"{tag}-{args.backend}-{args.resolution}"
    result = run_case(scene, args.backend, args.resolution, args.variant, out, args.force,
                      progress=not args.quiet, linear_solver=args.linear_solver)
    t = result.table
    monitors = [m["name"] for m in scene.monitors if m["name"] in t]
    cols = [c for c in ("step", "load_factor", "time", "newton_iterations", "converged", "wall_s") if c in t]
    shown = t[cols + monitors]
    print((shown if len(shown) <= 25 else shown.iloc[:: max(1, len(shown) // 20)]).to_string(index=False))
    from .studies.describe import paper_comparison

    for row in paper_comparison(scene, t).itertuples():
        print(f"{row.monitor}: ours {row.ours:.4g}, paper {row.paper:.4g} (ratio {row.ratio:.3f}); {row.note}")
    print(f"{result.status}: {result.message}; results in {out}")
    return 0 if result.ok else 1


def _study(args) -> int:
    from .studies.study import run_study

    out = args.out or Path("out") / f"study-{args.name}-{args.resolution}"
    table, _, interp = run_study(args.name, out, args.resolution, args.force, progress=not args.quiet)
    cols = ["case", "modes", "order", "max_rel_l2", "validity_1pct", "validity_5pct", "step_median_s",
            "step_p99_s", "step_recon_median_s", "reference_step_s", "speedup_per_step", "newton_radius"]
    print(table[cols].to_string(index=False))
    if len(interp):
        print(interp.groupby(["case", "method", "align"])[["projection_error", "rom_error"]]
              .agg(["mean", "max"]).to_string())
    print(f"results in {out}")
    return 0


def main(argv=None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "cases":
            from .studies.describe import catalogue_table

            print(catalogue_table(build_meshes=not args.no_mesh, paper=args.paper).to_string(index=False))
            return 0
        if args.command == "describe":
            from .studies.describe import describe

            print(describe(args.case, resolution=args.resolution, variant=args.variant))
            return 0
        if args.command == "study":
            return _study(args)
        return _run(args)
    except (ValueError, TypeError, FileExistsError, FileNotFoundError) as exc:
        return _error(exc)


if __name__ == "__main__":
    sys.exit(main())
