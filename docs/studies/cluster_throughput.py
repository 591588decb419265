"""Throughput of the dask executor: the same 12-unit sweep on 1, 2, ... dask workers (issue 30).

    python docs/studies/cluster_throughput.py [--workers 1,2] [--repeats 3] [--warm]

The sweep is ``cluster_throughput.toml`` beside this file (the 12 units of the kill soak,
tests/studies/test_cluster_soak.py: the ci cube bar pulled 30 %, POD family and the practitioner
baselines). Per worker count a LocalCluster of that many single-threaded worker processes is
started and its workers import tissuebench before the clock starts (``startup_s`` is reported
apart); then the sweep runs on it into a fresh results folder with a fresh reference cache
(the cube's reference is computed once, as a task: part of the wall time; ``--warm`` fills one
cache first and reuses it, so only the units are timed). Prints one row per run, the median
wall time per worker count, the speed-up against 1 worker, and the machine load (``uptime``)
before and after: state it beside the figure. The units' own wall times, added up, tell a
busy machine from a sweep that does not spread: with 2 workers running side by side they add up
to about 2x the wall time even when a loaded core makes each unit slower.
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

from distributed import Client, LocalCluster

from tissuebench.studies.results import read_units
from tissuebench.studies.spec import load_spec
from tissuebench.studies.sweep import run_sweep

SPEC = Path(__file__).with_name("cluster_throughput.toml")


def _uptime() -> str:
    return subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()


def _import_tissuebench() -> int:
    import tissuebench.studies.units  # noqa: F401 - the import a first unit would otherwise pay

    return os.getpid()


def one_run(spec, n_workers: int, cache: str | None) -> dict:
    """Start ``n_workers`` workers, then time the sweep on them."""
    t0 = time.perf_counter()
    with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster, Client(cluster) as client:
        client.run(_import_tissuebench)
        startup = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as tmp:
            t1 = time.perf_counter()
            summary = run_sweep(spec, Path(tmp) / "out", executor="dask", scheduler=cluster.scheduler_address,
                                progress=False, cache=cache or str(Path(tmp) / "cache"))
            wall = time.perf_counter() - t1
            busy = float(read_units(Path(tmp) / "out")["unit_wall_s"].sum())
    if summary.failed or len(summary.computed) != summary.planned:
        raise RuntimeError(f"{len(summary.failed)} units failed, {len(summary.computed)} of {summary.planned} ran")
    return {"workers": n_workers, "units": summary.planned, "wall_s": wall, "startup_s": startup, "unit_s": busy}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--workers", default="1,2", help="worker counts, comma-separated (default 1,2)")
    ap.add_argument("--repeats", type=int, default=3, help="runs per worker count, alternating (default 3)")
    ap.add_argument("--warm", action="store_true", help="one reference cache for every run, filled first")
    args = ap.parse_args(argv)
    counts = [int(w) for w in args.workers.split(",")]
    spec = load_spec(SPEC)
    print("load before:", _uptime())
    cache = None
    if args.warm:
        cache = tempfile.mkdtemp(prefix="tb-throughput-cache-")
        run_sweep(spec, Path(cache) / "warmup", progress=False, cache=cache)
    rows = []
    for r in range(args.repeats):  # alternating, so that a change of load hits every count alike
        for n in counts if r % 2 == 0 else counts[::-1]:
            rows.append(one_run(spec, n, cache))
            print(f"run {r + 1}: {n} workers: {rows[-1]['units']} units in {rows[-1]['wall_s']:.2f} s "
                  f"(cluster start {rows[-1]['startup_s']:.2f} s; the units' own wall times add up to "
                  f"{rows[-1]['unit_s']:.2f} s)", flush=True)
    print("load after: ", _uptime())
    base = statistics.median(x["wall_s"] for x in rows if x["workers"] == counts[0])
    print(f"\n{'workers':>7} {'median wall (s)':>16} {'speed-up':>9}  (vs {counts[0]} worker(s), "
          f"{'warm' if args.warm else 'fresh'} reference cache)")
    for n in counts:
        med = statistics.median(x["wall_s"] for x in rows if x["workers"] == n)
        print(f"{n:>7} {med:>16.2f} {base / med:>9.2f}")


if __name__ == "__main__":
    main()
