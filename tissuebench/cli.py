"""Command line of tissuebench.

``tissuebench cases``                       the catalogue (name, paper, analysis, sizes)
``tissuebench describe CASE``               what a run models and why
``tissuebench run CASE [--variant V] [--backend skfem|ngsolve] [--resolution ci|paper]
[--out DIR] [--force]``                     reference solve, stored in DIR
``tissuebench sweep SPEC.toml | --preset NAME | --list [--resolution] [--out DIR]
[--executor serial|processes|dask] [--workers N] [--scheduler ADDR] [--cache URL] [--resume] [--quiet]``
                                            any methods over any scenes, one results store
``tissuebench study anm_pod``               alias of ``sweep --preset anm_pod``
``tissuebench cache ls|clear [--cache URL]`` the reference-run cache
``tissuebench report RESULTS [--out report.html] [--require "rate>=500Hz, error<=2%"] [--case C]``
                                            self-contained HTML: which method for which scene
``tissuebench fit SCENE --require "rate>=1kHz, error<=2%" [--methods A,B] [--budget-references N]
[--budget-minutes M] [--out DIR]``           train to a requirement: references added where the
                                            models err most until a unit meets it (studies.fit)
``tissuebench check RESULTS [--baseline FILE] [--against REF] [--project PATH] [--junit OUT.xml]``
                                            regression gate: errors exactly, latency A/B
``tissuebench verify [RESULTS] [--resolution ci|paper] [--backend B] [--cases C,D]``
                                            external anchors (Cook, Land et al.); written to
                                            RESULTS/_anchors.parquet for the report; with
                                            RESULTS also every FE scene of the sweep on both
                                            backends (RESULTS/_backends.parquet)

The package's subcommand modules are imported inside the handlers below, not at the top: a
command loads only what it runs (``tissuebench --help`` and ``cache ls`` need no solver).

Exit codes: 0 success (a sweep that finished: its failed units are results, stored and counted
in its last line; ``--strict`` exits 1 on them), 1 ``run`` finished with a numerical failure
(stored) or the results could not be written (a full disk: nothing stored), 2 bad input
(including an output location that cannot be written, checked before any work or found read-only during it), 130
interrupted (Ctrl-C), 143 a sweep stopped by SIGTERM (``timeout``: resumable as after Ctrl-C).
A ``SystemExit`` or ``KeyboardInterrupt`` raised by a plugin method's code fails that plugin or
unit, never the command (:mod:`.exits`). Every error is one line naming the key, value or path,
never a traceback (``TISSUEBENCH_DEBUG=1`` shows the traceback of an unexpected error).
"""
from __future__ import annotations

import argparse
import errno
import os
import signal
import sys
import time
import warnings
from pathlib import Path

from .choices import BACKEND_NAMES, RESOLUTIONS


def _parser():
    p = argparse.ArgumentParser(prog="tissuebench", description="Verification and benchmarking of "
                                "reduced-order models of soft tissue.")
    sub = p.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="reference solve of a catalogue case")
    run.add_argument("case", help="case name (see `tissuebench cases`) or a scene file")
    run.add_argument("--variant", default=None, help="scene variant (default: the scene's default)")
    run.add_argument("--backend", default="skfem", choices=BACKEND_NAMES)
    run.add_argument("--resolution", default="ci", choices=RESOLUTIONS)
    run.add_argument("--out", type=Path, default=None, help="result folder (default: out/CASE[-VARIANT]-BACKEND-RES)")
    run.add_argument("--force", action="store_true", help="replace an existing result folder")
    run.add_argument("--linear-solver", default="auto",
                     choices=["auto", "direct", "cholesky", "amg-cg", "kept-factor-cg", "pardiso"],
                     help="linear solver of the Newton iterations (default auto: CG preconditioned by kept factors "
                          "from 50 000 dofs, MKL PARDISO's where it is installed, else NGSolve's LDL^T; NGSolve's "
                          "sparse LDL^T from 1000 dofs, SuperLU below; which to pick: docs/explanation/benchmarks.md)")
    run.add_argument("--quiet", action="store_true", help="no progress bar")
    cases = sub.add_parser("cases", help="list the catalogue")
    cases.add_argument("--no-mesh", action="store_true", help="do not build meshes to count nodes")
    cases.add_argument("--paper", action="store_true", help="also build the paper-resolution meshes (slow)")
    sweep = sub.add_parser("sweep", help="sweep methods x options over scenes into one results store")
    sweep.add_argument("spec", nargs="?", help="a sweep spec (TOML file)")
    sweep.add_argument("--preset", default=None, help="a shipped spec (see --list)")
    sweep.add_argument("--list", action="store_true", help="list the shipped presets")
    sweep.add_argument("--scene", default=None, help="a scene file: with --all-methods, write the spec of every "
                       "method that applies (held-out evaluation) beside the results folder and run it")
    sweep.add_argument("--all-methods", action="store_true", help="with --scene: every registered method that applies")
    sweep.add_argument("--variant", default=None, help="with --scene: the scene's variant")
    sweep.add_argument("--convergence", action="store_true", help="with --scene: also the reference's h/2 check "
                       "(the monitored quantities on the mesh refined once), written to OUT/_convergence.parquet")
    _sweep_options(sweep)
    study = sub.add_parser("study", help="alias: sweep --preset NAME")
    study.add_argument("name", help="preset name (anm_pod, interpolation, ...)")
    _sweep_options(study)
    cache = sub.add_parser("cache", help="the reference-run cache")
    cache.add_argument("action", choices=["ls", "clear"])
    _cache_option(cache)
    rep = sub.add_parser("report", help="self-contained HTML report of a results folder: which method for a scene")
    rep.add_argument("results", type=Path, help="a sweep's results folder")
    _cache_option(rep)
    rep.add_argument("--out", type=Path, default=None, help="HTML file (default: RESULTS/_report/report.html)")
    rep.add_argument("--require", default=None,
                     help='e.g. "rate>=500Hz, error<=2%%" (default: 1 kHz on the p99 haptic step, error <= 1 %%)')
    rep.add_argument("--case", default=None, help="only this case id (or catalogue case name)")
    rep.add_argument("--force", action="store_true",
                     help="replace an existing file that is not a report written by tissuebench")
    _check_parser(sub)
    _fit_parser(sub)
    ver = sub.add_parser("verify", help="our values against the external anchors (Cook, Land et al., analytic)")
    ver.add_argument("results", type=Path, nargs="?", default=None,
                     help="a sweep's results folder: the table goes to RESULTS/_anchors.parquet (the report shows it)")
    ver.add_argument("--resolution", default="ci", choices=RESOLUTIONS)
    _cache_option(ver)
    ver.add_argument("--backend", default="ngsolve", choices=BACKEND_NAMES)
    ver.add_argument("--cases", default=None, help="only these anchor cases (comma-separated)")
    ver.add_argument("--convergence", default=None, metavar="SCENE",
                     help="only the reference convergence check of SCENE (a scene file or case): its monitored "
                          "quantities at h and h/2 (with RESULTS: written to RESULTS/_convergence.parquet)")
    ver.add_argument("--variant", default=None, help="with --convergence: the scene's variant")
    ver.add_argument("--same-formulation", action="store_true",
                     help="with --convergence: keep the scene's element at h/2 even where it locks (default: a P1 "
                          "that locks is checked against average nodal pressure tetrahedra at h/2)")
    ver.add_argument("--memory-limit", type=float, default=None, metavar="GB",
                     help="with --convergence: the memory the h/2 run may take (default: the machine's available "
                          "memory); a refinement estimated above it is refused before any solve")
    ver.add_argument("--no-backends", action="store_true",
                     help="skip the backend agreement (with RESULTS: every FE scene of the sweep on both backends, "
                          "written to RESULTS/_backends.parquet)")
    ver.add_argument("--quiet", action="store_true",
                     help="no progress on stderr (the convergence check's meshes and load increments, the "
                          "anchors computed, the references solved for the backend agreement)")
    desc = sub.add_parser("describe", help="what a run of CASE models, and why")
    desc.add_argument("case")
    desc.add_argument("--variant", default=None)
    desc.add_argument("--resolution", default="ci", choices=RESOLUTIONS)
    scene = sub.add_parser("scene", help="check a scene file: what it models, counted, and scene.png")
    scene.add_argument("action", choices=["check"])
    scene.add_argument("case", help="a scene file (or a catalogue case name)")
    scene.add_argument("--variant", default=None)
    scene.add_argument("--resolution", default="ci", choices=RESOLUTIONS)
    scene.add_argument("--out", type=Path, default=None,
                       help="the picture, a .png file (default: scene.png in the working folder; '-' for none)")
    scene.add_argument("--force", action="store_true", help="replace an existing picture")
    methods = sub.add_parser("methods", help="every registered method (shipped and plugins, with their version); "
                             "with SCENE: does it apply, and why not")
    methods.add_argument("case", nargs="?", default=None, help="a scene file or a catalogue case name")
    methods.add_argument("--method", action="append", default=None, metavar="NAME",
                         help="only this method: a registry name or 'module:Class' of a method in another package "
                              "(repeat for several)")
    methods.add_argument("--variant", default=None)
    methods.add_argument("--resolution", default="ci", choices=RESOLUTIONS)
    return p


def _cache_option(p):
    p.add_argument("--cache", default=None,
                   help="the reference cache: a folder or the URL of a writable fsspec file system (s3://bucket/"
                        "cache; not zip, http, data ...; default $TISSUEBENCH_CACHE, else ~/.cache/tissuebench); on a "
                        "cluster, one every worker reaches")


def _sweep_options(p):
    p.add_argument("--resolution", default=None, choices=RESOLUTIONS,
                   help="mesh resolution of every case and the grid of the methods (default: the spec's, ci)")
    p.add_argument("--out", type=Path, default=None, help="results folder (default: out/sweep-NAME-RES)")
    p.add_argument("--executor", default="serial", help="serial (default) | processes | dask")
    p.add_argument("--workers", type=int, default=None, help="worker processes of --executor processes or a dask "
                   "LocalCluster (default 2; at most 4 per core; refused with serial and with --scheduler)")
    p.add_argument("--scheduler", default=None, help="address of a running dask scheduler, tcp://HOST:PORT")
    _cache_option(p)
    p.add_argument("--resume", action="store_true", help="continue the sweep stored in --out")
    p.add_argument("--cases", default=None, help="only these case ids of the spec (comma-separated)")
    p.add_argument("--quiet", action="store_true", help="no progress bar, no per-unit lines")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 when a unit of the sweep failed (computed now or kept from before; default: a failed "
                   "unit is a result, stored with its message and counted in the last line, and the finished sweep "
                   "exits 0)")
    p.add_argument("--max-units", type=int, default=None,
                   help="refuse a spec expanding to more units than this (default: studies.spec.MAX_UNITS)")


def _error(exc) -> int:
    print(f"tissuebench: error: {exc}", file=sys.stderr)
    return 2


# an output the user pointed at cannot be written there: bad input (exit 2); anything else
# (a full disk, an I/O error) is a failure to store results (exit 1)
_BAD_PATH = {errno.EACCES, errno.EPERM, errno.EROFS, errno.EISDIR, errno.ENOTDIR, errno.ENAMETOOLONG, errno.ELOOP,
             errno.ENOENT, errno.EEXIST, errno.ENOTEMPTY}


def _os_error(exc: OSError, doing: str = "") -> int:
    """One line naming the path of an OSError; 2 when the path is unusable, else 1."""
    where = exc.filename if exc.filename is not None else "?"
    if exc.filename2 is not None:
        where = f"{where} -> {exc.filename2}"
    reason = exc.strerror or type(exc).__name__
    print(f"tissuebench: error: {doing + ': ' if doing else ''}cannot use {where}: {reason}", file=sys.stderr)
    return 2 if exc.errno in _BAD_PATH else 1


def _id_list(text, option: str):
    """The comma-separated ids of ``option`` (None when not given); ValueError when it names none."""
    if text is None:
        return None
    ids = [c.strip() for c in text.split(",") if c.strip()]
    if not ids:
        raise ValueError(f"{option} = {text!r}: names no id (give comma-separated ids)")
    return ids


def _run(args) -> int:
    out, started = args.out, time.time()
    try:
        from .cases.scene import load
        from .studies.run import default_out
        from .studies.atomic_folders import check_output_location, clean_leftovers

        scene = load(args.case, resolution=args.resolution, variant=args.variant)
        out = args.out or default_out(scene, args.backend, args.resolution)
        clean_leftovers(out)  # what a killed run left beside it
        check_output_location(out, args.force)  # before any work (meshing included)
        return _run_scene(scene, args, out)
    except KeyboardInterrupt:
        manifest = Path(out) / "manifest.json" if out is not None else None
        if manifest is not None and manifest.is_file() and manifest.stat().st_mtime >= started - 1:
            print(f"tissuebench: interrupted after the results were written to {out}", file=sys.stderr)
        else:
            where = f" to {out}" if out is not None else ""
            print(f"tissuebench: interrupted; nothing was written{where} (a partial result is never kept). "
                  f"Run the command again to start over.", file=sys.stderr)
        return 130
    except OSError as exc:
        if isinstance(exc, (FileExistsError, FileNotFoundError)):
            raise
        print(f"tissuebench: error: cannot write the results to {out}: {exc}; nothing was written",
              file=sys.stderr)
        return 1


def _run_scene(scene, args, out) -> int:
    from .reports.run_files import write_result
    from .studies.describe import paper_comparison
    from .studies.run import run_case

    if scene.is_fe and scene.mesh_info.get("fallback"):
        print(f"tissuebench: note: {scene.mesh_info.get('reason', 'built-in fallback shape used')}",
              file=sys.stderr)
    result = run_case(scene, args.backend, args.resolution, args.variant, progress=not args.quiet,
                      linear_solver=args.linear_solver)
    write_result(result, scene, Path(out), args.force)
    t = result.table
    monitors = [m["name"] for m in scene.monitors if m["name"] in t]
    cols = [c for c in ("step", "load_factor", "time", "newton_iterations", "converged", "wall_s") if c in t]
    shown = t[cols + monitors]
    print((shown if len(shown) <= 25 else shown.iloc[:: max(1, len(shown) // 20)]).to_string(index=False))
    for row in paper_comparison(scene, t).itertuples():
        print(f"{row.monitor}: ours {row.ours:.4g}, paper {row.paper:.4g} (ratio {row.ratio:.3f}); {row.note}")
    if result.info.get("formulation"):  # which formulation, and why (a locking warning with its number)
        print(f"formulation: {result.info['formulation']} ({result.info.get('element')}): "
              f"{result.info.get('formulation_reason', '')}")
        if result.info.get("locking_warning"):
            print(result.info["locking_warning"], file=sys.stderr)
    print(f"{result.status}: {result.message}; results in {out}")
    return 0 if result.ok else 1


def _sweep(args, preset=None) -> int:
    from .reports.derived_figures import draw_derived
    from .studies.run import safe_name
    from .studies.spec import list_presets, load_spec
    from .studies.sweep import run_sweep

    if getattr(args, "list", False):
        for name, desc in list_presets():
            print(f"{name:16s} {desc}")
        return 0
    from .reference.location import check_cache_url
    from .studies.executors import check_executor

    check_executor(args.executor, args.workers, args.scheduler)  # the options first: before a spec is read
    if args.cache is not None:
        check_cache_url(args.cache)
    spec_arg, preset_arg = getattr(args, "spec", None), getattr(args, "preset", None)
    if getattr(args, "scene", None) is not None:
        if spec_arg or preset_arg:
            raise ValueError("sweep: give either --scene FILE --all-methods, or SPEC.toml, or --preset NAME")
        spec_arg, args.out = _scene_spec(args)
    elif getattr(args, "all_methods", False) or getattr(args, "variant", None) or getattr(args, "convergence", False):
        raise ValueError("sweep: --all-methods, --variant and --convergence go with --scene FILE")
    source = preset or preset_arg or spec_arg
    if source is None or (spec_arg and preset_arg):
        raise ValueError("sweep: give exactly one of SPEC.toml, --preset NAME, --scene FILE --all-methods or --list")
    spec = load_spec(source, resolution=args.resolution, only=_id_list(args.cases, "--cases"),
                     max_units=args.max_units)
    out = args.out or Path("out") / f"sweep-{safe_name(spec.name)}-{spec.resolution}"
    log = (lambda *_: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    for s in spec.skipped:  # before any reference is computed: one line per (case, method) pair
        log(f"skipped: {s['case']} {s['method']}{' ' + s['options'] if s['options'] else ''}: {s['why']}")
    if getattr(args, "scene", None) is not None:  # the yardstick every method is measured against, and why
        _say_formulation(args.scene, args.variant, spec.resolution)
    resume_hint = f"tissuebench sweep {source} --out {out} --resume"
    try:
        summary = run_sweep(spec, out, args.executor, args.workers, args.scheduler, args.resume,
                            progress=not args.quiet, log=log, figures=draw_derived, cache=args.cache)
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (exits.Terminated): the manifest says interrupted
        signum = getattr(exc, "signum", signal.SIGINT)
        said = "" if signum == signal.SIGINT else f" ({signal.Signals(signum).name})"
        print(f"tissuebench: interrupted{said}; finished units are stored in {out}. Resume with: {resume_hint}",
              file=sys.stderr)
        return 128 + signum
    except (FileExistsError, FileNotFoundError):
        raise
    except OSError as exc:  # the folder turned read-only, a full disk: the finished units are kept
        code = _os_error(exc, f"sweep into {out}")
        print(f"tissuebench: the units finished before are stored in {out}; once it is writable, resume with: "
              f"{resume_hint}", file=sys.stderr)
        return code
    _print_pareto(out)
    steps = sum(summary.failed_steps.values())  # ok units some of whose steps failed (a NaN state included)
    with_steps = (f"; {len(summary.failed_steps)} with failed steps ({steps} step{'s' if steps != 1 else ''})"
                  if summary.failed_steps else "")
    print(f"{summary.planned} units: {len(summary.computed)} computed ({len(summary.failed)} failed{with_steps}), "
          f"{len(summary.skipped)} kept from before, {len(summary.recomputed)} recomputed; results in {out}")
    for why, n in summary.why_recomputed.items():
        print(f"recomputed {n} unit{'s' if n != 1 else ''}: {why}")
    # a unit that failed (a method's exception, a plugin's sys.exit) or whose steps failed is a
    # measured result, stored with its message: the finished sweep exits 0, whichever code it was
    failed = _failed_units(out) if getattr(args, "strict", False) else 0
    if getattr(args, "convergence", False):
        failed |= _convergence(args.scene, args.variant, spec.resolution, "skfem", out, quiet=args.quiet)
    return failed


def _failed_units(out: Path) -> int:
    """``--strict``: 1 when a unit stored in ``out`` (computed now or kept from before) failed, saying
    how many on stderr; else 0. A unit that ran with failed steps is not a failed unit (its error
    says it: infinite where a step failed)."""
    from .studies.results import read_units

    units = read_units(out)
    bad = units[units["unit_status"] == "failed"]
    if len(bad):
        print(f"tissuebench: --strict: {len(bad)} of {len(units)} units failed", file=sys.stderr)
    return 1 if len(bad) else 0


def _say_formulation(case, variant, resolution) -> None:
    """One line: the formulation of the scene's reference and why; its locking warning beside."""
    from .cases.scene import load
    from .reference.formulation import formulation_of

    scene = load(case, resolution=resolution, variant=variant)
    if scene.is_fe:
        form = formulation_of(scene)
        print(f"reference formulation: {form.label}: {form.reason}", file=sys.stderr)
        if form.warning:
            print(form.warning, file=sys.stderr)


def _scene_spec(args):
    """``(spec path, results folder)`` of ``sweep --scene FILE --all-methods``: the spec written
    beside the folder (``<out>.toml``), the methods that do not apply said one line each."""
    from .cases.scene import load
    from .studies.run import safe_name
    from .studies.scene_spec import write_scene_spec
    from .studies.atomic_folders import check_output_location

    if not args.all_methods:
        raise ValueError("sweep --scene FILE: add --all-methods (every registered method that applies to the scene; "
                         "to choose methods, write a spec: docs, the sweep-spec format)")
    resolution = args.resolution or "ci"
    scene = load(args.scene, resolution=resolution, variant=args.variant)
    out = args.out or Path("out") / f"sweep-{safe_name(scene.name)}-{resolution}"
    check_output_location(out, overwrite=True)
    spec, left_out = write_scene_spec(args.scene, out, args.variant, resolution)
    if not args.quiet:
        for name, why in left_out:
            print(f"not applicable: {name}: {why}", file=sys.stderr)
        print(f"spec: {spec} (edit it and run it again with: tissuebench sweep {spec} --out FOLDER)", file=sys.stderr)
    return str(spec), out


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


def _report(args) -> int:
    from .reports.html import DEFAULT_NAME, verdict_lines, write_report
    from .reports.recommend import parse_requirement

    path = write_report(args.results, args.out or args.results / DEFAULT_NAME, args.require, args.case,
                        force=args.force)
    print(f"requirement {parse_requirement(args.require).text}:")
    for line in verdict_lines(args.results, args.require, args.case):  # the recommendation, one line per case
        print(f"  {line}")
    print(f"report: {path}")
    return 0


CHECK_HELP = """\
Errors are gated exactly: against REF's own run of the same sweep with --against REF, else
against the baseline file. Latency is gated by the A/B of --against REF only (REF's code and
this code timed in turn on one core): a unit is slower when its ratio's interval lies above
sqrt(latency_tolerance) and its step grew by at least latency_floor_s. The baseline file's
latency ratios (no --against, or a shallow clone) are printed for information, never gated:
they move 2-3x between runs of identical code for microsecond steps.

REF is found in the repository of the project under test: --project PATH, else the repository
of the sweep's plugin methods' package, else the working directory's (said in the output). Its
packages are exported at REF and come first on the path of REF's processes; tissuebench and
every other package are the same on both sides. A project that holds none of the sweep's
methods is refused (exit 2): each would be compared with itself.

latency_floor_s [s] (default 1e-5: 10 us, 1 % of a 1 kHz haptic step) is the least increase
of the step that counts as slower: a 1.5x slowdown of a 6 us step adds 3 us and passes it. For
a microsecond ROM give --latency-floor-s 0 (the ratio alone decides) or the least increase
that matters, e.g. 1e-6; a baseline file sets it in [defaults] or per [[unit]] (a unit's own
value wins over the command). A unit the floor held is said in the verdict line.

An intended slowdown is declared in the baseline file, in the commit that makes it: a unit's
entry gets latency_change = FACTOR (> 1) and latency_change_reason = "why". That commit's A/B
judges the unit against FACTOR (slower above FACTOR x sqrt(latency_tolerance)) and notes it; the
next commit, finding the entry unchanged at its REF, gates the unit as before."""


def _fit_parser(sub):
    fit = sub.add_parser("fit", help="train to a requirement: add references where the models err most until a unit "
                         "meets it, or show that none can within the budget")
    fit.add_argument("scene", help="a catalogue case or a scene file")
    fit.add_argument("--require", required=True, help='e.g. "rate>=1kHz, error<=2%%" (the error: the headline, on '
                     "references never used for training; the rate: the p99 step's)")
    fit.add_argument("--variant", default=None, help="the scene's variant")
    fit.add_argument("--resolution", default="ci", choices=RESOLUTIONS)
    fit.add_argument("--backend", default="skfem", choices=BACKEND_NAMES)
    fit.add_argument("--methods", default=None, help="only these method families (comma-separated; default: every "
                     "one that applies, `tissuebench methods SCENE`)")
    fit.add_argument("--budget-references", type=int, default=4, help="references the fit may add per family "
                     "(default 4)")
    fit.add_argument("--budget-minutes", type=float, default=60.0, help="wall minutes after which no round starts "
                     "(default 60; a resumed fit counts the time spent before)")
    fit.add_argument("--out", type=Path, default=None, help="the fit's folder (default out/fit-SCENE-RES); the same "
                     "command resumes a fit killed there")
    fit.add_argument("--executor", default="serial", help="serial (default) | processes | dask: where each round's "
                     "units (and the references they need) run")
    fit.add_argument("--workers", type=int, default=None, help="worker processes of --executor processes or dask")
    fit.add_argument("--scheduler", default=None, help="address of a running dask scheduler, tcp://HOST:PORT")
    _cache_option(fit)
    fit.add_argument("--quiet", action="store_true", help="no progress on stderr")


def _fit(args) -> int:
    """``tissuebench fit``: :mod:`.studies.fit`; exit 0 when a unit meets the requirement, 1 when none does."""
    from .reference.location import check_cache_url
    from .reports.fit_figure import draw_learning_curves
    from .reports.recommend import parse_requirement
    from .studies.executors import check_executor
    from .studies.fit import FitSettings, Target, run_fit
    from .studies.run import safe_name

    check_executor(args.executor, args.workers, args.scheduler)
    if args.cache is not None:
        check_cache_url(args.cache)
    requirement = parse_requirement(args.require)
    target = Target.of([(c.quantity, c.op, c.value) for c in requirement.clauses])
    if args.budget_references < 0:
        raise ValueError(f"--budget-references = {args.budget_references}: expected an integer >= 0")
    if not args.budget_minutes > 0 or args.budget_minutes == float("inf"):
        raise ValueError(f"--budget-minutes = {args.budget_minutes}: expected a finite number of minutes > 0")
    methods = _id_list(args.methods, "--methods")
    stem = Path(args.scene).stem if Path(args.scene).suffix == ".toml" else args.scene
    tag = safe_name(stem) + (f"-{safe_name(args.variant)}" if args.variant else "")
    out = args.out or Path("out") / f"fit-{tag}-{args.resolution}"
    settings = FitSettings(scene=args.scene, target=target, require=args.require, out=out, variant=args.variant,
                           resolution=args.resolution, backend=args.backend, methods=methods,
                           budget_references=args.budget_references, budget_minutes=args.budget_minutes,
                           executor=args.executor, workers=args.workers, scheduler=args.scheduler, cache=args.cache,
                           progress=not args.quiet)
    log = (lambda *_: None) if args.quiet else _progress_line
    try:
        m = run_fit(settings, log=log, figures=draw_learning_curves)
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: the manifest and the round's store are kept
        signum = getattr(exc, "signum", signal.SIGINT)
        print(f"tissuebench: fit interrupted; resume with the same command (its state is in {out / 'fit.json'})",
              file=sys.stderr)
        return 128 + signum
    answer = m.get("answer")
    if answer:
        p = answer["point"]
        print(f"fit: {p['label']} ({answer['family']}) meets {args.require}: error {100 * p['error']:.3g} % held out, "
              f"p99 {1e3 * p['p99_s']:.3g} ms, after {p['references']} added references; spec {answer['spec']} "
              f"({answer['why']})")
        dense = (m.get("dense") or {}).get(p["unit_key"])
        if dense:
            print(f"fit: dense check {100 * dense['error']:.3g} % at parameters neither the training nor the greedy "
                  "used")
    else:
        print(f"fit: no unit meets {args.require} ({m['state']})")
        for clause, pick in (m.get("best_per_clause") or {}).items():
            if pick:
                p = pick["point"]
                print(f"fit: best {'meeting the speed' if clause == 'error' else 'meeting the error'}: {p['label']}: "
                      f"error {100 * p['error']:.3g} %, p99 {1e3 * p['p99_s']:.3g} ms")
    for name, st in m["families"].items():
        print(f"fit: {name}: {st['status']}: {st['why']} ({st['refs_added']} references added; "
              f"{(st.get('heading') or {}).get('words', '')})")
    print(f"fit: report {out / 'fit.md'}, learning curves {out / 'learning_curves.png'}, manifest {out / 'fit.json'}")
    return 0 if answer else 1


def _check_parser(sub):
    chk = sub.add_parser("check", help="fail on a regression in error or latency (A/B against a git ref) or on a "
                                       "requirement no unit meets", description=CHECK_HELP,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    chk.add_argument("results", type=Path, help="a sweep's results folder")
    chk.add_argument("--baseline", type=Path, default=None, help="baseline TOML: errors gated exactly (e.g. "
                     "baselines/ci.toml) when there is no --against, and declared error changes and slowdowns "
                     "(latency_change) with it; its latency ratios are shown for information only")
    chk.add_argument("--against", default=None, metavar="REF", help="git ref (e.g. HEAD~1, the merge base) of the "
                     "project under test: REF's code runs the same sweep (errors) and every unit is re-timed with "
                     "REF's code and this code, their processes timed in turn on one core (A/B); in a shallow "
                     "clone that lacks REF, falls back to --baseline (any other REF git cannot resolve: exit 2)")
    chk.add_argument("--project", type=Path, default=None, metavar="PATH", help="with --against: a path in the git "
                     "repository of the code under test (default: the repository of the sweep's plugin methods, "
                     "else the working directory's)")
    chk.add_argument("--latency-floor-s", type=float, default=None, metavar="SECONDS", help="A/B: the least step "
                     "increase that counts as slower (default: the baseline's latency_floor_s, else 1e-5); 0 for a "
                     "microsecond ROM")
    chk.add_argument("--require", default=None, help='e.g. "rate>=500Hz, error<=2%%": every case needs a unit that '
                     "meets it (p99 rule of the report)")
    chk.add_argument("--update-baseline", action="store_true", help="rewrite the baseline from the results")
    chk.add_argument("--junit", type=Path, default=None, help="also write JUnit XML here")
    chk.add_argument("--ab-rounds", default="3,8", metavar="MIN,MAX",
                     help="A/B rounds: at least MIN, at most MAX (default 3,8)")
    chk.add_argument("--ab-blocks", type=int, default=3, help="timed blocks per unit and worker process (default 3)")
    chk.add_argument("--ab-budget", type=float, default=900.0, help="A/B time budget [s] (default 900), looked at "
                     "from round MIN on: MIN rounds always run (the interval resamples rounds)")


def _ab_settings(args):
    from .gate import ABSettings

    try:
        lo, hi = (int(x) for x in args.ab_rounds.split(","))
    except ValueError:
        raise ValueError(f"--ab-rounds = {args.ab_rounds!r}: expected MIN,MAX (two integers, e.g. 3,8)") from None
    if not 2 <= lo <= hi <= 100:
        raise ValueError(f"--ab-rounds = {args.ab_rounds!r}: need 2 <= MIN <= MAX <= 100")
    if not 1 <= args.ab_blocks <= 100:
        raise ValueError(f"--ab-blocks = {args.ab_blocks}: need 1..100")
    if not args.ab_budget > 0:
        raise ValueError(f"--ab-budget = {args.ab_budget}: need a positive number of seconds")
    return ABSettings(lo, hi, args.ab_blocks, args.ab_budget)


def _check(args) -> int:
    from .gate import GateOutputError, baseline_rows, check, check_outputs, update_baseline, write_junit

    # before REF's sweep and the A/B's minutes: a folder, a device, a FIFO, a loop of links, a missing folder
    check_outputs(args.results, junit=args.junit)
    if args.update_baseline:
        if args.baseline is None:
            raise ValueError("--update-baseline needs --baseline FILE")
        rows, left = baseline_rows(args.results)
        for key, why in left:
            print(f"note: {' '.join(key)} left out of the baseline: {why}")
        n = update_baseline(rows, args.baseline)
        print(f"baseline {args.baseline}: {n} units written from {args.results}")
        return 0
    result = check(args.results, args.baseline, args.against, args.require, _ab_settings(args),
                   log=lambda m: print(m, file=sys.stderr, flush=True), project=args.project,
                   latency_floor_s=args.latency_floor_s)
    _print_check(result, args)
    if args.junit:
        try:
            write_junit(result, args.junit)
        except GateOutputError as exc:
            return _error(exc)
    return 0 if result.ok else 1


def _print_check(result, args) -> None:
    if result.project:
        print(f"project under test: {result.project}")
    for line in result.sides:
        print(line)
    for note in result.notes:
        print(f"note: {note}")
    for key in result.new_units if args.baseline is not None else ():  # without a baseline, every unit is new
        print(f"note: {' '.join(key)} is not in the baseline" + (" and failed (--update-baseline leaves failed "
              "units out)" if key in result.new_failed else " (run --update-baseline to add it)"))
    for key, v in sorted(result.ab.items(), key=lambda kv: -kv[1].ratio):
        print(f"A/B {v.verdict:6s} {key[0]} {key[1]} {key[2]}: {v.text()}")
    errors = {"ref": f"errors against {args.against}", "baseline": f"errors against {args.baseline}",
              "none": "no error check"}[result.errors_against]
    latency = {"ab": f"latency A/B against {args.against}", "file": "latency not gated (no REF: the baseline's "
               "ratios noted for information)", "none": "no latency check"}[result.latency_mode]
    what = f"{errors}, {latency}" + (f", requirement {args.require!r}" if args.require else "")
    held = result.held_by_floor
    if held:
        floors = sorted({result.ab[k].floor_s for k in held})
        what += (f"; {len(held)} unit{'s' if len(held) > 1 else ''} slower by ratio but held by the latency floor "
                 f"({', '.join(f'{f * 1e6:g} us' for f in floors)}: {', '.join(k[1] for k in held)}; "
                 "--latency-floor-s 0 gates microsecond steps)")
    declared = result.declared_slowdowns  # this commit's latency_change: judged against it, noted
    if declared:
        what += (f"; {len(declared)} declared slowdown{'s' if len(declared) > 1 else ''} (" + ", ".join(
            f"{k[1]} x{result.ab[k].ratio:.3g}, declared x{result.ab[k].expected:g}" for k in declared) + ")")
    units = len([k for k in result.per_unit if k[1] != "*"])
    if result.ok:
        print(f"check: {units} units hold ({what})")
        return
    print(f"check: {len(result.regressions)} regressions in {units} units ({what}):")
    for f in result.regressions:
        print("  " + f.line())
    if any(f.metric in ("error", "flagged_steps") for f in result.regressions):
        print(_accept_hint(args))


def _accept_hint(args) -> str:
    """What to run to accept an intended change of errors: the baseline file written from these
    results and committed with the change (the gate then notes the entries the commit edits as
    declared, :mod:`.gate`)."""
    import shlex

    results = shlex.quote(str(args.results))
    if args.baseline is not None:
        base = shlex.quote(str(args.baseline))
        return (f"check: if the change is intended, record it in the baseline and commit that file with the change: "
                f"tissuebench check {results} --baseline {base} --update-baseline")
    return ("check: if the change is intended, record it in a baseline file of the repository, commit that file with "
            f"the change and pass it to this check (--baseline FILE): tissuebench check {results} --baseline FILE "
            "--update-baseline")


def _cache(args) -> int:
    from .reference.cache import cache_url, clear, list_entries, stray_items

    where = cache_url()
    stray = stray_items()
    if args.action == "clear":
        print(f"removed {clear()} reference runs from {where}")
    else:
        table = list_entries()
        print(f"{where}: {len(table)} reference runs")
        if len(table):
            print(table.to_string(index=False))
    if stray:
        names = ", ".join(str(p).rstrip("/").rsplit("/", 1)[-1] for p in stray[:10]) + (" ..." if len(stray) > 10
                                                                                      else "")
        print(f"note: {len(stray)} items in {where.rstrip('/')}/references are not cache entries (no valid "
              f"meta.json) and were left alone: {names}", file=sys.stderr)
    return 0


def _verify(args) -> int:
    from .reports.anchors import external_anchors
    from .studies.results import write_table

    if args.results is not None:
        from .studies.atomic_folders import check_output_location

        if not args.results.is_dir():
            raise FileNotFoundError(f"results: {args.results} is not a folder")
        check_output_location(args.results, overwrite=True)  # writable, before minutes of solves
    if args.convergence is not None:
        return _convergence(args.convergence, args.variant, args.resolution, args.backend, args.results,
                            quiet=args.quiet, same_formulation=args.same_formulation,
                            memory_limit=None if args.memory_limit is None else args.memory_limit * 1e9)

    def anchor_line(case, quantity):
        _progress_line(f"verify: anchor {case}: {quantity} ({args.backend}, {args.resolution})")
    table = external_anchors(args.resolution, args.backend, _id_list(args.cases, "--cases"),
                             progress=None if args.quiet else anchor_line)
    with _pd_display():
        print(table[["case", "quantity", "unit", "ours", "anchor", "low", "high", "verdict"]].to_string(index=False))
    if args.results is not None:
        write_table(table, args.results / "_anchors.parquet")
        print(f"verify: {len(table)} anchors written to {args.results / '_anchors.parquet'}")
    bad = table[(table["verdict"] != "in") & table["expected_in"]]
    for _, r in bad.iterrows():
        print(f"verify: {r['case']} {r['quantity']}: {r['ours']:.6g} outside [{r['low']:.6g}, {r['high']:.6g}] "
              f"({r['how']})", file=sys.stderr)
    disagree = 0
    if args.results is not None and not args.no_backends:
        if (args.results / "_sweep.json").is_file():
            disagree = _verify_backends(args.results, args.quiet)
        else:
            print(f"verify: {args.results} holds no sweep (_sweep.json): no scenes for the backend agreement")
    return 1 if len(bad) or disagree else 0


def _convergence(case, variant, resolution, backend, results, quiet=False, same_formulation=False,
                 memory_limit=None) -> int:
    """The h/2 check of a scene (:mod:`.reference.convergence`), printed and, with ``results``,
    written to ``results/_convergence.parquet`` (the report's verification section shows it).
    Unless ``quiet``, each mesh, load increment and mesh's end is a line on stderr as it happens
    (stdout keeps the table only: two meshes of an organ take hours). A refinement that would not
    fit in memory is refused before any solve: exit 1 with the estimate."""
    from .cases.scene import load
    from .reference.convergence import RefinementTooLarge, convergence_check
    from .studies.results import write_table

    if memory_limit is not None and not memory_limit > 0:
        raise ValueError(f"--memory-limit must be > 0 GB, got {memory_limit / 1e9:g}")
    scene = load(case, resolution=resolution, variant=variant)
    print(f"verify: {scene.name}: the reference at h and h/2 ({backend})", flush=True)
    try:
        table = convergence_check(scene, backend, log=None if quiet else _progress_line,
                                  same_formulation=same_formulation, memory_limit=memory_limit)
    except RefinementTooLarge as exc:
        print(f"verify: refused: {exc}", file=sys.stderr)
        return 1
    with _pd_display():
        print(table[["case", "quantity", "h", "h_half", "rel_diff", "dofs_h", "dofs_h_half", "status_h",
                     "status_h_half"]].to_string(index=False))
    print(f"verify: {table['how'].iloc[0] if len(table) else ''}")
    if results is not None:
        write_table(table, Path(results) / "_convergence.parquet")
        print(f"verify: convergence check written to {Path(results) / '_convergence.parquet'}")
    bad = table[(table["status_h"] != "success") | (table["status_h_half"] != "success")]
    return 1 if len(bad) else 0


def _progress_line(text: str) -> None:
    """A progress line of ``verify``: on stderr, at once (a log read while the check runs)."""
    print(text, file=sys.stderr, flush=True)


def _verify_backends(results, quiet=False) -> int:
    """Backend agreement of every scene of the sweep in ``results``; the number that disagree.
    Unless ``quiet``, each scene is a line on stderr and each reference not in the cache a bar
    naming it (as in a sweep: :data:`~.reference.cache.PROGRESS_ENV`)."""
    from .reference.backend_comparison import backend_agreement
    from .reference.cache import PROGRESS_ENV
    from .reports.backends import scenes_of_results
    from .studies.results import write_table

    previous = os.environ.get(PROGRESS_ENV)
    os.environ[PROGRESS_ENV] = "0" if quiet else "1"  # --quiet wins over a "1" exported by the user
    try:
        table = backend_agreement(scenes_of_results(results), progress=None if quiet else (
            lambda c: _progress_line(f"verify: {c} on both backends")))
    finally:  # the variable is the process's: as it was before
        if previous is None:
            os.environ.pop(PROGRESS_ENV, None)
        else:
            os.environ[PROGRESS_ENV] = previous
    with _pd_display():
        print(table[["case", "ndof", "field_rel_diff", "worst_monitor", "monitor_rel_diff", "verdict"]]
              .to_string(index=False))
    write_table(table, results / "_backends.parquet")
    print(f"verify: backend agreement of {len(table)} cases written to {results / '_backends.parquet'}")
    bad = table[table["verdict"].isin(["disagree", "failed"])]
    for _, r in bad.iterrows():
        print(f"verify: {r['case']}: the backends {r['verdict']}: {r['how']}", file=sys.stderr)
    return len(bad)


def _scene_check(args) -> int:
    from .cases.scene import load
    from .studies.scene_check import scene_summary, summary_lines

    scene = load(args.case, resolution=args.resolution, variant=args.variant)
    picture = None
    if scene.is_fe and str(args.out) != "-":  # never beside a catalogue scene: that is inside the package
        from .reports.scene_figure import picture_path

        picture = picture_path(args.out, args.force)  # before any work
    summary = scene_summary(scene)
    for line in summary_lines(summary, scene.units):
        print(line)
    if picture is not None:
        from .reports.scene_figure import draw_scene

        how = draw_scene(scene, summary, picture)
        print(f"picture: {picture.absolute()} ({how})")
    print(f"scene {scene.path}: valid")
    return 0


def _methods(args) -> int:
    from .cases.scene import load
    from .rom.plugins import FAILURES
    from .studies.applicability import method_rows, registry_rows

    if args.case is None:
        rows = registry_rows(args.method)
        width = max(len(r["method"]) for r in rows)
        for r in rows:
            print(f"  {r['method']:{width}s}  {r['kind']:10s}  learns from {', '.join(r['training_kinds'])}"
                  + (f"  [{r['origin']}]" if r["origin"] else ""))
        plugins = sum(bool(r["origin"]) for r in rows)
        print(f"{len(rows)} methods ({len(rows) - plugins} shipped, {plugins} from other packages); "
              "`tissuebench methods SCENE` says which apply to a scene")
    else:
        scene = load(args.case, resolution=args.resolution, variant=args.variant)
        rows = method_rows(scene, args.method)
        width = max(len(r["method"]) for r in rows)
        print(f"{scene.name}" + (f" [{scene.variant}]" if scene.variant else "") + f": {scene.analysis['type']}, "
              + (f"material {scene.material['name']}" if scene.material else f"{scene.model} model"))
        for r in rows:
            verdict = f"applies ({', '.join(r['learns_from'])} training)" if r["applies"] else "does not apply"
            print(f"  {r['method']:{width}s}  {verdict}" + (f": {r['why']}" if r["why"] else "")
                  + (f"  [{r['origin']}]" if r["origin"] else ""))
        n = sum(r["applies"] for r in rows)
        print(f"{n} of {len(rows)} methods apply")
    for name, (what, error) in sorted(FAILURES.items()):
        print(f"  plugin {name!r} of {what} could not be loaded: {error}")
    return 0


def _pd_display():
    import pandas as pd

    return pd.option_context("display.width", 200, "display.max_colwidth", 40)


def _dispatch(args) -> int:
    if args.command == "cases":
        from .studies.describe import catalogue_table

        print(catalogue_table(build_meshes=not args.no_mesh, paper=args.paper).to_string(index=False))
        return 0
    if args.command == "describe":
        from .studies.describe import describe

        print(describe(args.case, resolution=args.resolution, variant=args.variant))
        return 0
    if args.command == "scene":
        return _scene_check(args)
    if args.command == "methods":
        return _methods(args)
    if args.command == "sweep":
        return _sweep(args)
    if args.command == "study":
        return _sweep(args, preset=args.name)
    if args.command == "fit":
        return _fit(args)
    if args.command == "check":
        return _check(args)
    if args.command in ("cache", "report", "verify"):  # the reference cache they read: --cache
        from .reference.location import using_cache

        with using_cache(_cache_of(args)):
            return {"cache": _cache, "report": _report, "verify": _verify}[args.command](args)
    return _run(args)


def _cache_of(args):
    """The reference cache a command reads: its ``--cache``, else the one the sweep of its results
    folder was given (recorded in ``_sweep.json``), else None (``$TISSUEBENCH_CACHE`` or the default)."""
    if args.cache is not None or getattr(args, "results", None) is None:
        return args.cache
    from .studies.sweep_manifest import read_sweep_manifest

    recorded = read_sweep_manifest(args.results, missing_ok=True).get("cache")
    if recorded is not None:
        print(f"{args.command}: the reference cache the sweep used, {recorded} (--cache to read another)")
    return recorded


def _one_line_warning(message, category, filename, lineno, line=None) -> str:
    return f"tissuebench: warning: {message}\n"


def main(argv=None) -> int:
    from .studies.results import SweepLocked

    from .exits import user_signals

    args = _parser().parse_args(argv)
    formatwarning, warnings.formatwarning = warnings.formatwarning, _one_line_warning
    try:
        with user_signals():  # a plugin's import that raises KeyboardInterrupt fails that plugin, not the command
            return _dispatch(args)
    except (ValueError, TypeError, FileExistsError, FileNotFoundError, SweepLocked) as exc:
        return _error(exc)
    except KeyboardInterrupt:
        print("tissuebench: interrupted", file=sys.stderr)
        return 130
    except OSError as exc:
        return _os_error(exc, args.command)
    except Exception as exc:  # a defect of tissuebench, not of the input: one line, exit 1
        if os.environ.get("TISSUEBENCH_DEBUG", "").strip():
            raise
        print(f"tissuebench: internal error in `{args.command}`: {type(exc).__name__}: {exc} (a bug of tissuebench; "
              f"TISSUEBENCH_DEBUG=1 shows the traceback)", file=sys.stderr)
        return 1
    finally:
        warnings.formatwarning = formatwarning


if __name__ == "__main__":
    sys.exit(main())
