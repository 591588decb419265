"""What the mean-dilatation correction adds to Q1's assembly (issue 54, item 1): medians side by side.

Times ``internal_force``, ``tangent`` and ``internal_force_and_tangent`` of the plain Q1 backend and
of :class:`~tissuebench.refsolvers.mean_dilatation.MeanDilatationBackend` wrapping the same backend
object, on a catalogue scene at one resolution, at a deformed state (a few percent of strain, so
SVK's nonlinear terms are live), in one process, interleaved (Q1, wrapped, Q1, ...) so that a
load change on the machine affects both columns alike. Also times the correction alone (its cell
forces scattered; its cell tangents added into Q1's matrix). For a before/after, run it with
``PYTHONPATH`` on an export of the older package (``git archive <commit> tissuebench | tar -x -C DIR``).

    python tools/bench_mean_dilatation.py                       # cornea_pinch at ci, skfem and ngsolve
    python tools/bench_mean_dilatation.py --resolution paper --repeat 15
    python tools/bench_mean_dilatation.py --backend skfem --case cornea_cut

Prints one row per operator: the medians (ms) of Q1 and of the wrapped backend, and the median of
their paired ratios; then the correction alone beside Q1's own force and tangent (the ratio is then
the correction's share of Q1's assembly).
"""
from __future__ import annotations

import argparse
import statistics
import time
from functools import partial

import numpy as np


def _sample_ms(fn, number):
    t0 = time.perf_counter()
    for _ in range(number):
        fn()
    return (time.perf_counter() - t0) / number * 1e3


def _paired_ms(f_q1, f_other, repeat, number):
    """Medians (ms) of ``repeat`` samples of each callable (a sample is the mean of ``number`` calls),
    the samples taken in turn (one of each, then again), and the median of the samples' ratios
    ``other / q1``: a change of the machine's load between pairs cancels in it."""
    f_q1(), f_other()  # warm-up (patterns, compiled forms, caches)
    a, b = [], []
    for _ in range(repeat):
        a.append(_sample_ms(f_q1, number))
        b.append(_sample_ms(f_other, number))
    return statistics.median(a), statistics.median(b), statistics.median(y / x for x, y in zip(a, b))


def bench(case="cornea_pinch", resolution="ci", backend="skfem", repeat=31, number=None, seed=0):
    """Rows ``(operator, q1_ms, other_ms, ratio)`` of ``case`` at ``resolution`` on ``backend``: the
    operators of Q1 and of the wrapped backend, then the correction alone (its cell forces scattered,
    its cell tangents added into Q1's matrix) beside Q1's force and tangent."""
    from tissuebench.cases.scene import load
    from tissuebench.refsolvers.backends import make_backend
    from tissuebench.refsolvers.mean_dilatation import MeanDilatationBackend

    pb = load(case, resolution).to_problem()
    q1 = make_backend(backend, pb)
    md = MeanDilatationBackend(pb, q1)
    h = float(np.ptp(pb.mesh.points, axis=0).max()) / pb.mesh.n_cells ** (1 / 3)  # a cell's size
    u = 0.02 * h * np.random.default_rng(seed).normal(size=pb.ndof)  # strains of a few percent
    number = number or (20 if pb.mesh.n_cells < 2000 else 1)
    K = q1.tangent(u)
    pairs = [("internal_force", q1.internal_force, md.internal_force),
             ("tangent", q1.tangent, md.tangent),
             ("internal_force_and_tangent", q1.internal_force_and_tangent, md.internal_force_and_tangent)]
    rows = [(name, *_paired_ms(partial(f_q1, u), partial(f_md, u), repeat, number)) for name, f_q1, f_md in pairs]
    f_alone = lambda: md._scatter(md.cell_correction(u)[1])  # noqa: E731
    k_alone = lambda: md._add(K, md.cell_correction(u, tangent=True)[2])  # noqa: E731
    rows.append(("correction alone (f)", *_paired_ms(partial(q1.internal_force, u), f_alone, repeat, number)))
    rows.append(("correction alone (K)", *_paired_ms(partial(q1.tangent, u), k_alone, repeat, number)))
    return pb, rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="cornea_pinch")
    ap.add_argument("--resolution", default="ci", choices=("ci", "paper"))
    ap.add_argument("--backend", action="append", choices=("skfem", "ngsolve"),
                    help="repeatable; default both (ngsolve skipped when it is not installed)")
    ap.add_argument("--repeat", type=int, default=31)
    ap.add_argument("--number", type=int, default=None, help="calls per sample (default 20 at ci, 1 above 2000 cells)")
    args = ap.parse_args(argv)
    for backend in args.backend or ("skfem", "ngsolve"):
        try:
            pb, rows = bench(args.case, args.resolution, backend, args.repeat, args.number)
        except ImportError as exc:
            print(f"{backend}: skipped ({exc})")
            continue
        print(f"{args.case} at {args.resolution}, {backend}: {pb.mesh.n_cells} cells, {pb.ndof} dofs; "
              f"medians in ms ({args.repeat} samples)")
        print(f"  {'operator':28s} {'Q1':>9s} {'mean dil.':>9s} {'ratio':>6s}   (correction alone: beside Q1's own)")
        for name, a, b, r in rows:
            print(f"  {name:28s} {a:9.3f} {b:9.3f} {r:6.2f}")

if __name__ == "__main__":
    main()
