"""Power of the gate on a user's own repository (issue 39), measured, not assumed:

* ``test_gate_power_of_a_plugins_microsecond_step``: the example's package
  (examples/bring_your_own_method, ``pod_polyreg``: a 5-6 us step) in a git repository of its
  own; each run is the gate's A/B of two of its units, REF's side the package exported at the
  commit by the project machinery (:mod:`tissuebench.gate.project`), HEAD's the work tree,
  with a calibrated 1.3x slowdown injected on HEAD's side into one unit (a busy wait of 0.3x the
  unit's warm median after every step) and the other untouched; the floor set to 0 (the
  statistic decides alone). Issue: the 1.3x unit flagged in >= 19 of 20 runs, the untouched one
  in <= 1 of 20.
* ``test_identical_code_through_the_ci_recipe``: the documented user CI path, ``ci/gate.sh``
  (the example's ``spec.toml``, 16 units, ``--latency-floor-s 0``), run on a commit that changes
  a comment only; a false alarm is a run that exits otherwise than 0. Issue: <= 1 in 20.

Both skip unless ``TISSUEBENCH_GATE_POWER_RUNS`` is set (minutes per run)::

    TISSUEBENCH_GATE_POWER_RUNS=20 pytest -n 0 -m "slow or not slow" -s \\
        tests/benchmarks/test_bench_gate_power_plugin.py          # tox -e gate-power-plugin

The counts, verdicts and wall times are printed and written to ``$TISSUEBENCH_GATE_POWER_OUT``
(JSON, a key per test) when set.
"""
from __future__ import annotations

import json
import os
import subprocess
import time
from pathlib import Path

import pytest

from tissuebench.gate import HEAD_ROOT
from tissuebench.gate.project import export_project, find_project, head_code
from tissuebench.gate.stats import decided_units, verdicts
from tissuebench.gate.latency import ab_units, run_ab
from tissuebench.studies.results import read_units
from tissuebench.studies.spec import load_spec
from tissuebench.studies.sweep import run_sweep

from _gate_repo import commit, example_repo
from _gate_spec import HELD_OUT, cornea_spec
from _plugin_dist import on_path
from _venv import chained_venv, tissuebench_command

SPEC = cornea_spec("plugin-power", [("podreg.method:PodPolyReg",
                                     "list = [{ n_modes = 4, degree = 3 }, { n_modes = 2, degree = 2 }]")],
                   latency_steps=300, warmup=30, evaluation=HELD_OUT, sweep='resolution = "ci"')
INJECTED = '{"degree":3,"n_modes":4}'


def _runs() -> int:
    if "TISSUEBENCH_GATE_POWER_RUNS" not in os.environ:
        pytest.skip("the plugin gate's power runs with TISSUEBENCH_GATE_POWER_RUNS=N (tox -e gate-power-plugin)")
    return int(os.environ["TISSUEBENCH_GATE_POWER_RUNS"])


def _report(key: str, report: dict) -> None:
    print(json.dumps({key: report}, indent=1))
    out = os.environ.get("TISSUEBENCH_GATE_POWER_OUT")
    if out:
        old = json.loads(Path(out).read_text()) if Path(out).is_file() else {}
        Path(out).write_text(json.dumps({**old, key: report}, indent=1))


def _user_repo(root: Path) -> tuple[Path, str]:
    return example_repo(root, {"power_spec.toml": SPEC})


@pytest.mark.benchmark
def test_gate_power_of_a_plugins_microsecond_step(tmp_path, monkeypatch):
    runs = _runs()
    repo, sha = _user_repo(tmp_path)
    # the package importable here and in every process the A/B starts (HEAD's copy, as an install would)
    on_path(monkeypatch, repo / "src")
    monkeypatch.chdir(repo)
    out = tmp_path / "res"
    run_sweep(load_spec(repo / "power_spec.toml"), out, progress=False)
    rows = read_units(out)
    assert (rows["unit_status"] == "ok").all() and len(rows) == 2
    project = find_project(zip(rows["method_source"], rows["method_distribution"]), HEAD_ROOT)
    assert project.repo == repo.resolve() and [p.name for p in project.packages] == ["podreg"]
    ref, held = export_project(project, sha, tmp_path / "ref", HEAD_ROOT)
    units = ab_units(out, rows)
    options = dict(zip(rows["unit_key"], rows["options"]))
    inject = {u.uid: 1.3 for u in units if options[u.uid] == INJECTED}
    flagged = {o: 0 for o in options.values()}
    ratios = {o: [] for o in options.values()}
    walls, rounds = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        samples, failures = run_ab(units, ref, head_code(project, HEAD_ROOT), decided_units(1.3), inject=inject,
                                   log=lambda m: None)
        walls.append(round(time.perf_counter() - t0, 1))
        assert not failures, failures
        for uid, v in verdicts(samples, 1.3, floor_s=0.0).items():
            flagged[options[uid]] += v.regressed
            ratios[options[uid]].append(round(v.ratio, 3))
            rounds.append(v.rounds)
    report = {"runs": runs, "ref": held, "flagged": flagged, "injected_1.3x": INJECTED, "ratios": ratios,
              "wall_s_per_run": walls, "mean_rounds": sum(rounds) / len(rounds), "load": os.getloadavg()}
    _report("plugin_power", report)
    assert flagged[INJECTED] >= 0.95 * runs, report
    assert all(n <= max(0.05 * runs, 1) for o, n in flagged.items() if o != INJECTED), report


@pytest.mark.benchmark
def test_identical_code_through_the_ci_recipe(tmp_path):
    runs = _runs()
    repo, _ = _user_repo(tmp_path)
    method = repo / "src" / "podreg" / "method.py"
    text = method.read_text()
    step = "    def step(self, mu) -> StepResult:\n"
    assert text.count(step) == 1
    commit(repo, {"src/podreg/method.py": text.replace(step, step + "        # the reduced coordinates first\n")},
           "comment")
    python = chained_venv(tmp_path / "venv")
    tissuebench_command(python)
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-build-isolation", "--no-deps", "-e", "."],
                   cwd=repo, check=True, capture_output=True)
    env = {**os.environ, "PATH": f"{python.parent}{os.pathsep}{os.environ['PATH']}", "MPLBACKEND": "Agg",
           "PYTHONPATH": ""}
    exits, walls, slower = [], [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        proc = subprocess.run(["bash", "ci/gate.sh", "HEAD~1"], cwd=repo, capture_output=True, text=True, env=env)
        walls.append(round(time.perf_counter() - t0))
        exits.append(proc.returncode)
        slower += [line for line in proc.stdout.splitlines() if line.startswith("A/B slower")]
        if proc.returncode not in (0, 1):
            pytest.fail(f"the gate exited {proc.returncode}: {proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    units = len(read_units(repo / "out" / "tissuebench-gate"))
    report = {"runs": runs, "units_per_run": units, "false_alarms": sum(e != 0 for e in exits), "exits": exits,
              "slower_lines": slower, "wall_s_per_run": walls, "load": os.getloadavg()}
    _report("ci_recipe_identical", report)
    assert report["false_alarms"] <= max(0.05 * runs, 1), report
