"""The gate's A/B mode (``tissuebench check --against REF``): the statistics decide as sized, REF
is found or its absence said, the probe times what it should, and end to end an injected 2x
slowdown of one unit is flagged while its untouched neighbour holds."""
from __future__ import annotations

import json
import math
import os
import platform
import re
import subprocess
import sys
import time
import tomllib

import numpy as np
import pandas as pd
import pytest

from tissuebench.gate.io import write_ab_artifacts
from tissuebench.gate import probe as ab_probe, stats as ab_stats
from tissuebench.gate.ref import export_ref, file_at_ref, portable_spec_text, ref_import_error, resolve_ref
from tissuebench.gate.scratch import PREFIX, clean_stale_scratch, process_start
from tissuebench.gate.stats import ratio_interval, verdicts
from tissuebench.gate.latency import SAMPLE_COLUMNS


def _samples(rng, factor, rounds=3, blocks=3, steps=50, noise=0.03, slow_process=0.0, slow_block=0.0,
             median=20e-6):
    """Synthetic A/B samples: per process and per block a memory-layout mode 1.6x slower with
    probability ``slow_process`` / ``slow_block``, per block lognormal jitter ``noise``, per step
    heavy-tailed noise."""
    rows = []
    for side, f in (("ref", 1.0), ("head", factor)):
        for r in range(rounds):
            mode = 1.6 if rng.random() < slow_process else 1.0
            for b in range(blocks):
                block_mode = 1.6 if rng.random() < slow_block else 1.0
                level = median * f * mode * block_mode * np.exp(rng.normal(0, noise))
                steps_s = level * (1 + rng.exponential(0.05, steps))
                rows += [("u", side, r, b, k, s) for k, s in enumerate(steps_s)]
    return pd.DataFrame(rows, columns=SAMPLE_COLUMNS)


def test_the_interval_covers_the_true_ratio():
    rng = np.random.default_rng(1)
    for factor in (1.0, 1.3, 2.0):
        blocks = _samples(rng, factor).groupby(["side", "round", "block"])["haptic_s"].median().rename(
            "median_s").reset_index()
        ratio, lo, hi = ratio_interval(blocks[blocks.side == "ref"], blocks[blocks.side == "head"])
        assert lo <= factor * 1.01 and hi >= factor * 0.99 and abs(ratio / factor - 1) < 0.05


def _sequential(rng, factor, max_rounds=8, **noise):
    """The A/B's rounds as :func:`run_ab` runs them: 3, then one more while undecided."""
    frames = []
    for r in range(max_rounds):
        frames.append(_samples(rng, factor, rounds=1, **noise).assign(round=r))
        samples = pd.concat(frames, ignore_index=True)
        if r + 1 >= 3 and verdicts(samples, 1.3, final=False):
            break
    return verdicts(samples, 1.3)["u"]


@pytest.mark.parametrize("noise", [{}, pytest.param({"slow_block": 1 / 4}, marks=pytest.mark.slow),
                                   pytest.param({"slow_process": 1 / 6}, marks=pytest.mark.slow),
                                   pytest.param({"noise": 0.08}, marks=pytest.mark.slow)])
def test_a_1_3x_slowdown_is_flagged_and_no_change_is_not(noise, monkeypatch):
    """The decision rule's error rates on synthetic runs with this machine's noise (block jitter
    3 %; a memory layout 1.6x slower, measured for pod_interp in 2 of 8 copies and in 1 of 6
    processes; or 8 % jitter, a loaded machine): >= 95 % of 1.3x slowdowns flagged, <= 5 % of
    identical runs (the issue's 19 of 20 and 1 of 20). Measured with n = 200 and 4000
    resamples: 200 of 200 and 0 of 200 in every noise model, 3.0-4.1 rounds on average."""
    monkeypatch.setattr(ab_stats, "N_BOOT", 1000)  # the same rule, a coarser interval: faster
    rng = np.random.default_rng(7)
    n = 100
    flagged = {f: sum(_sequential(rng, f, **noise).regressed for _ in range(n)) for f in (1.0, 1.3)}
    assert flagged[1.3] >= 0.95 * n and flagged[1.0] <= 0.05 * n, flagged


def _blocks(ref, head):
    """Samples whose block medians are exactly ``ref`` / ``head`` (one block per round)."""
    rows = [("u", side, r, 0, k, v) for side, values in (("ref", ref), ("head", head))
            for r, v in enumerate(values) for k in range(3)]
    return pd.DataFrame(rows, columns=SAMPLE_COLUMNS)


def test_verdicts_name_faster_and_undecided_units():
    v = verdicts(_blocks([2.0, 2.0, 2.1], [1.0, 1.0, 1.05]), 1.3)["u"]
    assert v.verdict == "faster" and v.decided and not v.regressed and v.ratio == pytest.approx(0.5)
    straddles = _blocks([1.0, 1.0], [1.0, 1.3])  # the interval [1, 1.3] holds the threshold 1.14
    assert "u" not in verdicts(straddles, 1.3, final=False)  # the A/B would go on
    final = verdicts(straddles, 1.3)["u"]
    assert not final.decided and final.verdict == "holds" and "undecided" in final.text()
    assert verdicts(_blocks([1.0, 1.0, 1.0], [1.5, 1.5, 1.6]), 1.3)["u"].regressed


def test_an_undecided_unit_is_slower_only_when_its_interval_is_clear_of_faster():
    """CI's false alarms on identical code (estimate 1.35, interval [0.747, 1.683]): an estimate
    above the threshold is not enough; an interval whose lower end is above 1 / threshold is."""
    noisy = _blocks([1.0, 1.0, 1.0, 1.0], [0.75, 1.5, 1.5, 1.6])
    v = verdicts(noisy, 1.3)["u"]
    assert not v.decided and v.ratio > v.threshold and v.low < 1 / v.threshold and v.verdict == "holds"
    shifted = _blocks([1.0, 1.0, 1.0, 1.0], [1.0, 1.5, 1.5, 1.6])
    w = verdicts(shifted, 1.3)["u"]
    assert not w.decided and w.low > 1 / w.threshold and w.ratio > w.threshold and w.regressed


def test_a_slowdown_below_the_floor_holds_and_says_so():
    """A decided 1.5x slowdown of a 6 us step adds 3 us: below a 10 us floor it holds, named;
    with no floor, and for a 60 us step, it is slower."""
    small = _blocks([6e-6] * 3, [9e-6, 9e-6, 9.2e-6])
    v = verdicts(small, 1.3, floor_s=1e-5)["u"]
    assert v.decided and v.verdict == "holds" and not v.regressed and "below the floor: +3 us < 10 us" in v.text()
    assert verdicts(small, 1.3)["u"].regressed
    assert verdicts(small, 1.3, floor_s={"u": 2e-6})["u"].regressed
    large = _blocks([6e-5] * 3, [9e-5, 9e-5, 9.2e-5])
    assert verdicts(large, 1.3, floor_s=1e-5)["u"].regressed


def _git(cwd, *args):
    subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True)


@pytest.fixture
def two_commits(tmp_path):
    repo = tmp_path / "repo"
    (repo / "tissuebench").mkdir(parents=True)
    _git(repo, "init", "-q")
    _git(repo, "config", "user.email", "t@t")
    _git(repo, "config", "user.name", "t")
    for k in (1, 2):
        (repo / "tissuebench" / "__init__.py").write_text(f"VERSION = {k}\n")
        (repo / "base.toml").write_text(f"# baseline {k}\n")
        _git(repo, "add", ".")
        _git(repo, "commit", "-qm", f"c{k}")
    return repo


def test_ref_is_resolved_exported_and_its_absence_said(two_commits, tmp_path):
    sha, why = resolve_ref(two_commits, "HEAD~1")
    assert len(sha) == 40 and why == ""
    code = export_ref(two_commits, sha, tmp_path / "code")
    assert (code / "tissuebench" / "__init__.py").read_text() == "VERSION = 1\n"
    assert file_at_ref(two_commits, sha, two_commits / "base.toml") == "# baseline 1\n"
    assert file_at_ref(two_commits, sha, two_commits / "missing.toml") == ""
    assert file_at_ref(two_commits, sha, tmp_path / "outside.toml") is None
    shallow = tmp_path / "shallow"
    _git(tmp_path, "clone", "-q", "--depth", "1", f"file://{two_commits}", str(shallow))
    # the one fallback: a shallow clone whose history lacks REF
    assert resolve_ref(shallow, "HEAD~1") == (None, f"HEAD~1 is not in the history of {shallow}, a shallow clone")
    # anything else git cannot resolve is an error naming the ref and where it was looked for
    with pytest.raises(ValueError, match=f"--against = 'HEAD': {tmp_path} is not inside a git checkout"):
        resolve_ref(tmp_path, "HEAD")
    with pytest.raises(ValueError, match=f"--against = 'nope': not a commit of the repository {two_commits}"):
        resolve_ref(two_commits, "nope")
    # found by tests/studies/test_fuzz_surfaces.py: '^HEAD' verified as '^<sha>', then handed to git archive
    with pytest.raises(ValueError, match=r"--against = '\^HEAD': not a single commit \(git rev-parse gives '\^"):
        resolve_ref(two_commits, "^HEAD")
    for bad in ("--upload-pack=x", " -x", "", "a\x00b", "HEAD\n", "x" * 1025, None):
        with pytest.raises(ValueError, match=r"--against = .*: expected a git ref"):
            resolve_ref(two_commits, bad)


class _Model:
    """A model whose step costs ``cost`` seconds of busy work."""

    def __init__(self, cost):
        self.cost, self.steps = cost, 0

    def step(self, mu):
        self.steps += 1
        end = time.perf_counter() + self.cost
        while time.perf_counter() < end:
            pass
        return type("R", (), {"status": "ok"})()

    def outputs(self, res):
        return {}


def test_the_probe_times_the_asked_steps_and_injects_a_calibrated_slowdown():
    m = _Model(200e-6)
    seq = [{"x": 0.1 * i} for i in range(7)]
    plain = ab_probe.time_block(m, seq, lambda model: None, False, steps=40, warmup=5)
    assert len(plain) == 40 and m.steps == 45
    slowed = ab_probe.time_block(m, seq, lambda model: None, False, steps=40, warmup=5,
                                 extra=0.5 * float(np.median(plain)))
    assert 1.35 < np.median(slowed) / np.median(plain) < 1.8


@pytest.mark.slow
def test_an_injected_2x_slowdown_is_flagged_and_its_neighbour_holds(tmp_path):
    """End to end on the project's own git checkout: REF = HEAD's commit (the working tree is
    this code). anm_pod's step (about 6 us) made 5x slower on HEAD's side only, so it grows by more
    than the gate's 10 us floor: flagged; pod_interp: holds."""
    from tissuebench.gate import HEAD_ROOT, ABSettings, baseline_rows, check
    from tissuebench.studies.spec import load_spec
    from tissuebench.studies.sweep import run_sweep

    try:
        resolve_ref(HEAD_ROOT, "HEAD")
    except ValueError:
        pytest.skip("not run from a git checkout (the standalone copy): no REF to compare with")
    from _gate_spec import SPEC

    spec = tmp_path / "gate.toml"
    spec.write_text(SPEC)
    out = tmp_path / "res"
    run_sweep(load_spec(spec), out, progress=False)
    anm = next(k for k in baseline_rows(out)[0] if k[1] == "anm_pod")
    result = check(out, None, against="HEAD", ab=ABSettings(2, 4, 3, inject={anm: 5.0}), log=lambda m: None)
    assert result.latency_mode == "ab" and result.errors_against == "ref"
    slow = {f.method for f in result.regressions if f.metric == "latency_ab"}
    assert slow == {"anm_pod"}, [f.line() for f in result.regressions]
    by_method = {k[1]: v for k, v in result.ab.items()}
    # the ratio of a 6 us step over 2 rounds of 3 blocks, both sides timed in turn on one pinned core,
    # the busy wait calibrated on that core: measured 5.02-5.27 in 11 runs (3.08-7.22 when each side's
    # process ran whole, on its own core, calibrated while building). Fails on an injection lost (1x)
    # or doubled (25x).
    assert 4.0 < by_method["anm_pod"].ratio < 6.5 and by_method["pod_interp"].verdict == "holds"
    stored = pd.read_parquet(out / "_gate" / "ab_samples.parquet")
    assert set(stored["side"]) == {"ref", "head"} and (out / "_gate" / "ab_ratios.png").is_file()


# ------------------------------------------------------------------------ issue 37: one sample, the plot
def test_a_side_with_one_sample_has_no_interval_and_says_so():
    """One block median per side: the interval was printed [x, x] (resampling one number); now it
    is n/a and the unit is judged by its estimate alone. Two per side give an interval."""
    one = verdicts(_blocks([1.0], [1.5]), 1.3)["u"]
    assert math.isnan(one.low) and math.isnan(one.high) and not one.decided and one.regressed
    assert "interval n/a (one sample)" in one.text() and "[" not in one.text().split("(")[0]
    assert "judged by the estimate alone" in one.text()
    assert verdicts(_blocks([1.0], [1.05]), 1.3)["u"].verdict == "holds"
    two = verdicts(_blocks([1.0, 1.0], [1.5, 1.5]), 1.3)["u"]
    assert two.has_interval and two.low <= two.ratio <= two.high and "[1.500, 1.500]" in two.text()


def _verdict_rows(**fields):
    base = dict(uid="u", ratio=1.0, low=1.0, high=1.0, ref_median_s=1e-5, head_median_s=1e-5, rounds=2, blocks=1,
                threshold=1.14, verdict="holds", decided=True)
    return {("c", "m", "{}"): ab_stats.ABVerdict(**{**base, **fields})}


@pytest.mark.parametrize("fields", [
    # the bootstrap works in logs, the estimate does not: equal samples gave a lower end 1 ulp above the
    # estimate, and matplotlib refused the negative error bar ("'xerr' must not contain negative values")
    {"ratio": 1.0, "low": 1.0000000000000002, "high": 1.0000000000000002},
    {"ratio": 1.2, "low": 1.25, "high": 1.4},  # a percentile interval need not hold the estimate
    {"ratio": 1.5, "low": math.nan, "high": math.nan, "decided": False, "verdict": "slower"},  # one sample
])
def test_the_a_b_plot_draws_any_interval(tmp_path, fields):
    samples = _blocks([1.0, 1.0], [1.0, 1.0])
    assert write_ab_artifacts(tmp_path, samples, _verdict_rows(**fields), "HEAD", "0" * 40) == ""
    assert (tmp_path / "_gate" / "ab_ratios.png").stat().st_size > 0


def test_a_plot_that_fails_is_a_note_and_the_tables_are_kept(tmp_path, monkeypatch):
    from tissuebench.gate import io as gate_io

    def broken(*args):
        raise ValueError("'xerr' must not contain negative values")

    monkeypatch.setattr(gate_io, "_plot", broken)
    note = write_ab_artifacts(tmp_path, _blocks([1.0, 1.0], [1.0, 1.0]), _verdict_rows(), "HEAD", "0" * 40)
    assert "ab_ratios.png could not be drawn: ValueError: 'xerr' must not contain negative values" in note
    assert all((tmp_path / "_gate" / f"ab_{name}.parquet").is_file() for name in ("samples", "verdicts"))


# ------------------------------------------------------------------------ issue 37: REF's processes
def _package(root, files: dict):
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    return root


FAKE_REF = {"tissuebench/__init__.py": "", "tissuebench/cli.py": "", "tissuebench/rom/__init__.py": "METHODS = {}\n",
            "tissuebench/studies/__init__.py": "", "tissuebench/studies/sweep.py": ""}


def test_ref_processes_import_refs_code_even_from_a_checkouts_root(tmp_path, monkeypatch):
    """``python -m`` and ``-c`` put the working folder first on sys.path: run from a checkout's root
    (CI's case), REF's sweep imported HEAD's package there, and compared HEAD's errors with HEAD's."""
    ref = _package(tmp_path / "ref", FAKE_REF)
    decoy = _package(tmp_path / "checkout", {**FAKE_REF, "tissuebench/__init__.py": "DECOY = True\n"})
    monkeypatch.chdir(decoy)
    assert ref_import_error(ref) == ""
    # a module REF lacks is never taken from elsewhere (an editable install's hook supplies HEAD's)
    lacking = _package(tmp_path / "lacking", {k: v for k, v in FAKE_REF.items() if k != "tissuebench/cli.py"})
    why = ref_import_error(lacking)
    assert re.match(rf"is not what REF's processes import: tissuebench\.\w+ comes from .*, not from {lacking}", why) \
        or why.startswith("failed to import: ModuleNotFoundError: No module named 'tissuebench.cli'"), why
    broken = _package(tmp_path / "broken", {**FAKE_REF, "tissuebench/rom/__init__.py": "METHODS = {\n"})
    assert re.fullmatch(r"failed to import: SyntaxError: .*", ref_import_error(broken))


def test_stale_scratch_folders_are_removed_and_live_ones_kept(tmp_path):
    """What a SIGKILLed check left is removed by the next (its owner's pid gone, or reused by a
    process started at another time); a live check's folder, another host's, and a folder whose
    owner is unknown are kept."""
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    me = {"pid": os.getpid(), "start": process_start(os.getpid()), "host": platform.node()}
    owners = {"dead": {**me, "pid": dead.pid}, "reused": {**me, "start": "1"}, "live": me,
              "other_host": {**me, "pid": dead.pid, "host": me["host"] + "-x"}, "damaged": "{", "none": None}
    for name, owner in owners.items():
        folder = tmp_path / f"{PREFIX}{name}"
        folder.mkdir()
        if owner is not None:
            (folder / "owner.json").write_text(owner if isinstance(owner, str) else json.dumps(owner))
    (tmp_path / f"{PREFIX}a_file").write_text("")
    removed = clean_stale_scratch(tmp_path)
    assert sorted(p.name for p in removed) == [f"{PREFIX}dead", f"{PREFIX}reused"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        f"{PREFIX}{n}" for n in ("live", "other_host", "damaged", "none", "a_file"))


# ------------------------------------------------------------------------ issue 37: a scene-file store
def test_a_scene_file_case_reads_from_any_folder():
    """The spec of ``sweep --scene`` names its scene relative to the spec's folder; REF's sweep and
    the A/B load it from a scratch folder, where that path meant nothing ("unknown case")."""
    manifest = {"spec_text": '[[case]]\nname = "../kidney/scene.toml"\nid = "path"\n'
                             '[[case]]\nname = "../kidney/scene.toml"\nid = "operators"\n'
                             '[[case]]\nname = "cornea_pinch"\n',
                "cases": [{"id": "path", "name": "/data/kidney/scene.toml"}, {"id": "cornea_pinch",
                                                                                "name": "cornea_pinch"}]}
    doc = tomllib.loads(portable_spec_text(manifest))
    # the operators case (left out by --cases) is the same file: resolved too
    assert [c["name"] for c in doc["case"]] == ["/data/kidney/scene.toml"] * 2 + ["cornea_pinch"]
    plain = {"spec_text": '[[case]]\nname = "cornea_pinch"\n',
             "cases": [{"id": "cornea_pinch", "name": "cornea_pinch"}]}
    assert portable_spec_text(plain) == plain["spec_text"]
    # a damaged spec or manifest (read back from _sweep.json) is left to the spec loader to name
    for damaged in ({"spec_text": "[[case]\nx", "cases": []},
                    {"spec_text": '[[case]]\nname = "a.toml"\nid = [1]\n', "cases": [{"id": [1], "name": "/x"}]},
                    {"spec_text": '[[case]]\nname = "a.toml"\n', "cases": {"a": "/x/a.toml"}}):
        assert portable_spec_text(damaged) == damaged["spec_text"]


@pytest.mark.slow
def test_check_against_gates_a_scene_file_store(tmp_path, monkeypatch):
    """End to end: a store whose case is a user's scene file named relative to its spec (as
    ``sweep --scene`` writes it) is gated against REF (REF's sweep once failed with "unknown case
    '../scene.toml'", exit 2 even with --baseline)."""
    from _mesh_scene import scene_file, write_block
    from tissuebench.gate import HEAD_ROOT, ABSettings, check
    from tissuebench.studies.spec import load_spec
    from tissuebench.studies.sweep import run_sweep

    try:
        resolve_ref(HEAD_ROOT, "HEAD")
    except ValueError:
        pytest.skip("not run from a git checkout (the standalone copy): no REF to compare with")
    organ = tmp_path / "organ"
    organ.mkdir()
    write_block(organ)
    scene_file(organ)
    spec = tmp_path / "study" / "organ.spec.toml"
    spec.parent.mkdir()
    spec.write_text('[sweep]\nname = "organ"\n[protocol]\nlatency_steps = 50\nwarmup = 5\n'
                    '[[case]]\nname = "../organ/scene.toml"\nid = "path"\ntraining = { kind = "path", every = 2 }\n'
                    'evaluation = { kind = "path", held_out = true }\n[[method]]\nname = "pod_linear"\n'
                    'grid = { n_modes = [2] }\n')
    out = tmp_path / "study" / "organ"
    run_sweep(load_spec(spec), out, progress=False)
    monkeypatch.chdir(tmp_path)  # neither the spec's folder nor the scene's
    result = check(out, None, against="HEAD", ab=ABSettings(2, 2, 1), log=lambda m: None)
    assert result.errors_against == "ref" and result.latency_mode == "ab", result.notes
    assert result.compared == 1 and len(result.ab) == 1
