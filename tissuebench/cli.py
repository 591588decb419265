"""Command line of tissuebench.

``tissuebench cases``                       the catalogue (name, paper, analysis, sizes)
``tissuebench describe CASE``               what a run models and why
``tissuebench run CASE [--variant V] [--backend skfem|ngsolve] [--resolution ci|paper]
[--out DIR] [--force]``                     reference solve, stored in DIR
``tissuebench sweep SPEC.toml | --preset NAME | --list [--resolution] [--out DIR]
[--executor serial|processes|dask] [--workers N] [--scheduler ADDR] [--resume] [--quiet]``
                                            any methods over any scenes, one results store
``tissuebench study anm_pod``               alias of ``sweep --preset anm_pod``
``tissuebench cache ls|clear``              the reference-run cache
``tissuebench check RESULTS --baseline FILE [--update-baseline] [--junit OUT.xml]``
                                            regression gate on error and latency ratios

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
    sweep = sub.add_parser("sweep", help="sweep methods x options over scenes into one results store")
    sweep.add_argument("spec", nargs="?", help="a sweep spec (TOML file)")
    sweep.add_argument("--preset", default=None, help="a shipped spec (see --list)")
    sweep.add_argument("--list", action="store_true", help="list the shipped presets")
    _sweep_options(sweep)
    study = sub.add_parser("study", help="alias: sweep --preset NAME")
    study.add_argument("name", help="preset name (anm_pod, interpolation, ...)")
    _sweep_options(study)
    cache = sub.add_parser("cache", help="the reference-run cache")
    cache.add_argument("action", choices=["ls", "clear"])
    chk = sub.add_parser("check", help="fail on a regression in error or latency against a baseline")
    chk.add_argument("results", type=Path, help="a sweep's results folder")
    chk.add_argument("--baseline", type=Path, required=True, help="baseline TOML (e.g. baselines/ci.toml)")
    chk.add_argument("--update-baseline", action="store_true", help="rewrite the baseline from the results")
    chk.add_argument("--junit", type=Path, default=None, help="also write JUnit XML here")
    desc = sub.add_parser("describe", help="what a run of CASE models, and why")
    desc.add_argument("case")
    desc.add_argument("--variant", default=None)
    desc.add_argument("--resolution", default="ci", choices=["ci", "paper"])
    return p


def _sweep_options(p):
    p.add_argument("--resolution", default=None, choices=["ci", "paper"],
                   help="mesh resolution of every case and the grid of the methods (default: the spec's, ci)")
    p.add_argument("--out", type=Path, default=None, help="results folder (default: out/sweep-NAME-RES)")
    p.add_argument("--executor", default="serial", help="serial (default) | processes | dask")
    p.add_argument("--workers", type=int, default=None, help="worker processes (processes, dask LocalCluster)")
    p.add_argument("--scheduler", default=None, help="address of a running dask scheduler (tcp://host:port)")
    p.add_argument("--resume", action="store_true", help="continue the sweep stored in --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no per-unit lines")


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


def _sweep(args, preset=None) -> int:
    from .studies.spec import list_presets, load_spec
    from .studies.sweep import run_sweep

    if getattr(args, "list", False):
        for name, desc in list_presets():
            print(f"{name:16s} {desc}")
        return 0
    source = preset or args.preset or args.spec
    if source is None or (args.spec and args.preset):
        raise ValueError("sweep: give exactly one of SPEC.toml, --preset NAME or --list")
    spec = load_spec(source, resolution=args.resolution)
    out = args.out or Path("out") / f"sweep-{spec.name}-{spec.resolution}"
    log = (lambda *_: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    try:
        summary = run_sweep(spec, out, args.executor, args.workers, args.scheduler, args.resume,
                            progress=not args.quiet, log=log)
    except KeyboardInterrupt:
        print(f"tissuebench: interrupted; finished units are stored in {out}. Resume with: "
              f"tissuebench sweep {source} --out {out} --resume", file=sys.stderr)
        return 130
    _print_pareto(out)
    print(f"{summary.planned} units: {len(summary.computed)} computed ({len(summary.failed)} failed), "
          f"{len(summary.skipped)} kept from before, {len(summary.recomputed)} recomputed; results in {out}")
    return 1 if summary.failed else 0


def _print_pareto(out) -> None:
    import pandas as pd

    path = Path(out) / "_derived" / "pareto.parquet"
    if not path.is_file():
        return
    t = pd.read_parquet(path)
    front = t[t["pareto"]].sort_values(["case", "haptic_median_s"])
    cols = ["case", "label", "error", "haptic_median_s", "haptic_p99_s", "speedup"]
    with pd.option_context("display.width", 200, "display.max_colwidth", 60):
        print(f"Pareto front ({t['error_metric'].iloc[0]} vs haptic median):")
        print(front[cols].to_string(index=False))


def _check(args) -> int:
    from .reports.check import check, update_baseline, write_junit

    if args.update_baseline:
        n = update_baseline(args.results, args.baseline)
        print(f"baseline {args.baseline}: {n} units written from {args.results}")
        return 0
    result = check(args.results, args.baseline)
    if args.junit:
        write_junit(result, args.junit)
    for key in result.new_units:
        print(f"note: {' '.join(key)} is not in the baseline (run --update-baseline to add it)")
    if result.ok:
        print(f"check: {result.checked} units hold against {args.baseline}")
        return 0
    print(f"check: {len(result.regressions)} regressions in {result.checked} units against {args.baseline}:")
    for f in result.regressions:
        print("  " + f.line())
    return 1


def _cache(args) -> int:
    from .studies.reference.cache import cache_dir, clear, list_entries

    if args.action == "clear":
        print(f"removed {clear()} reference runs from {cache_dir()}")
        return 0
    table = list_entries()
    print(f"{cache_dir()}: {len(table)} reference runs")
    if len(table):
        print(table.to_string(index=False))
    return 0


def main(argv=None) -> int:
    from .studies.results import SweepLocked

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
        if args.command == "sweep":
            return _sweep(args)
        if args.command == "study":
            return _sweep(args, preset=args.name)
        if args.command == "cache":
            return _cache(args)
        if args.command == "check":
            return _check(args)
        return _run(args)
    except (ValueError, TypeError, FileExistsError, FileNotFoundError, SweepLocked) as exc:
        return _error(exc)


if __name__ == "__main__":
    sys.exit(main())
