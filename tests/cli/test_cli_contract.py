"""The command line's contract on every subcommand (issue 26): ``--help`` works, one real call
works, and bad input exits 2 with one line naming the key, value or path, never a traceback.

Items: 1 (``study NAME``, the documented alias, always failed), 6 (``--cases ",,,"`` ran 0
units), 20 (``verify --cases ",,"`` gave a KeyError traceback), 14 (a results folder made
read-only mid-sweep gave OSError tracebacks).
"""
from __future__ import annotations

import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from _gate_spec import PATH, cornea_spec
from _report_store import build_store
from tissuebench.cli import _parser, main
from tissuebench.studies.sweep_manifest import read_sweep_manifest

ROOT = Path(__file__).resolve().parents[2]
SUBCOMMANDS = ["run", "cases", "sweep", "study", "cache", "report", "check", "verify", "describe", "scene", "methods",
               "fit"]

ONE = cornea_spec("one", ["nearest"], latency_steps=5, warmup=1, evaluation=PATH)


def cli(argv, capsys):
    """``(exit code, stderr)`` of ``tissuebench argv`` run in this process."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: usage and one error line, exit 2
        code = exc.code
    captured = capsys.readouterr()
    return code, captured.err


def test_every_subcommand_is_walked_here():
    actions = [a for a in _parser()._actions if a.dest == "command"]
    assert sorted(actions[0].choices) == sorted(SUBCOMMANDS)


@pytest.mark.parametrize("command", SUBCOMMANDS)
def test_help_of_every_subcommand(command, capsys):
    code, _ = cli([command, "--help"], capsys)
    assert code == 0


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("cli")
    (d / "garbage.toml").write_text("this is = = not toml\n")
    (d / "binary.toml").write_bytes(b"\xff\xfe\x00\x01")
    (d / "afile").write_text("x")
    (d / "empty").mkdir()
    (d / "spec.toml").write_text(ONE)
    build_store(d / "store")
    (d / "baseline.toml").write_text("[defaults]\nerror_rtol = 0.25\n[[unit]]\ncase = 1\n")
    return d


# every entry: argv (with {d} the fixture folder) and a word the error line must contain
BAD = [
    (["run", "nope"], "unknown case 'nope'"),
    (["run", "{d}/garbage.toml"], "garbage.toml"),
    (["run", "{d}/binary.toml"], "binary.toml"),
    (["run", "{d}/empty"], "empty"),
    (["run", "heat1d_source", "--out", "{d}/afile"], "afile"),
    (["run", "heat1d_source", "--out", "a\0b"], "NUL"),
    (["run", "heat1d_source", "--variant", "nope"], "nope"),
    (["run", "heat1d_source", "--backend", "nope"], "invalid choice"),
    (["cases", "--bogus"], "unrecognized arguments"),
    (["describe", "nope"], "unknown case 'nope'"),
    (["describe", "{d}/garbage.toml"], "garbage.toml"),
    (["describe", "cornea_pinch", "--variant", "nope"], "nope"),
    (["sweep"], "give exactly one of"),
    (["sweep", "{d}/nope.toml"], "nope.toml"),
    (["sweep", "{d}/garbage.toml"], "garbage.toml"),
    (["sweep", "{d}/binary.toml"], "binary.toml"),
    (["sweep", "{d}/spec.toml", "--cases", ",,,"], "--cases = ',,,'"),
    (["sweep", "{d}/spec.toml", "--cases", "nope"], "--cases = 'nope'"),
    (["sweep", "{d}/spec.toml", "--workers", "0"], "workers = 0"),
    (["sweep", "{d}/spec.toml", "--executor", "threads"], "executor = 'threads'"),
    (["sweep", "{d}/spec.toml", "--out", "{d}/afile"], "afile"),
    (["sweep", "{d}/spec.toml", "--max-units", "0"], "--max-units = 0"),
    (["sweep", "{d}/spec.toml", "--preset", "ci"], "give exactly one of"),
    (["sweep", "--preset", "nope"], "nope"),
    (["study", "nope"], "nope"),
    (["study", "ci", "--cases", ",,"], "--cases = ',,'"),
    (["study", "ci", "--cases", "nope"], "--cases = 'nope'"),
    (["study", "ci", "--executor", "nope"], "executor = 'nope'"),
    (["cache", "nope"], "invalid choice"),
    (["report", "{d}/nope"], "nope"),
    (["report", "{d}/afile"], "afile"),
    (["report", "{d}/empty"], "holds no unit rows"),
    (["report", "{d}/store", "--require", "rate>5 parsecs"], "require = 'rate>5 parsecs'"),
    (["report", "{d}/store", "--out", "{d}"], "is a folder"),
    (["report", "{d}/store", "--out", "{d}/afile/r.html"], "afile"),
    (["report", "{d}/store", "--case", "nope"], "case = 'nope'"),
    (["check", "{d}/nope", "--baseline", "{d}/baseline.toml"], "error:"),  # the baseline is read first
    (["check", "{d}/store", "--baseline", "{d}/nope.toml"], "nope.toml"),
    (["check", "{d}/store", "--baseline", "{d}/garbage.toml"], "garbage.toml"),
    (["verify", "--cases", ",,"], "--cases = ',,'"),
    (["verify", "--cases", "nope"], "nope"),
    (["verify", "{d}/nope"], "nope"),
    (["verify", "--resolution", "fine"], "invalid choice"),
    (["scene", "check", "nope"], "unknown case 'nope'"),
    (["scene", "check", "{d}/garbage.toml"], "garbage.toml"),
    (["scene", "nope", "cornea_pinch"], "invalid choice"),
    (["methods", "nope"], "unknown case 'nope'"),
    (["methods", "{d}/binary.toml"], "binary.toml"),
    (["methods", "--method", "nope"], "unknown ROM method 'nope'"),
    (["methods", "--method", "tb_nowhere_xyz:Cls"], "cannot import 'tb_nowhere_xyz'"),
    (["methods", "cornea_pinch", "--method", "tissuebench.rom:Applies"], "not a named RomMethod subclass"),
    (["sweep", "--scene", "{d}/garbage.toml", "--all-methods"], "garbage.toml"),
    (["sweep", "--scene", "cornea_pinch"], "--all-methods"),
    (["sweep", "--all-methods"], "go with --scene"),
    (["sweep", "{d}/spec.toml", "--scene", "cornea_pinch", "--all-methods"], "give either --scene"),
    (["fit", "nope", "--require", "error<=2%"], "unknown case 'nope'"),
    (["fit", "{d}/garbage.toml", "--require", "error<=2%"], "garbage.toml"),
    (["fit", "cornea_pinch"], "--require"),
    (["fit", "cornea_pinch", "--require", "rate>5 parsecs"], "require = 'rate>5 parsecs'"),
    (["fit", "cornea_pinch", "--require", "error<=2%", "--methods", "nope"], "--methods = 'nope'"),
    (["fit", "cornea_pinch", "--require", "error<=2%", "--budget-minutes", "-1"], "--budget-minutes = -1"),
    (["fit", "cornea_pinch", "--require", "error<=2%", "--out", "{d}/afile/x"], "afile"),
]


@pytest.mark.parametrize("argv, word", BAD, ids=[" ".join(a) for a, _ in BAD])
def test_bad_input_exits_2_with_one_line_and_no_traceback(files, capsys, argv, word):
    argv = [a.replace("{d}", str(files)) for a in argv]
    code, err = cli(argv, capsys)
    assert code == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert lines and "error:" in lines[-1] and word in lines[-1], err
    if not lines[-1].startswith("tissuebench") or "usage" not in err:  # ours, not argparse's usage + line
        assert len(lines) == 1, err


def test_one_real_call_of_every_subcommand(files, tmp_path, capsys, monkeypatch):
    """Item 1: ``study NAME`` failed on every call (AttributeError: no attribute 'spec')."""
    monkeypatch.chdir(tmp_path)
    assert cli(["cases", "--no-mesh"], capsys)[0] == 0
    assert cli(["describe", "cornea_pinch"], capsys)[0] == 0
    assert cli(["methods", "cornea_pinch"], capsys)[0] == 0
    assert cli(["scene", "check", "cornea_pinch", "--out", "-"], capsys)[0] == 0
    assert cli(["run", "heat1d_source", "--quiet"], capsys)[0] == 0
    assert cli(["sweep", "--list"], capsys)[0] == 0
    assert cli(["sweep", str(files / "spec.toml"), "--quiet", "--out", str(tmp_path / "s")], capsys)[0] == 0
    assert cli(["study", "direct_frame_2dof", "--quiet"], capsys)[0] == 0
    assert (tmp_path / "out" / "sweep-direct_frame_2dof-ci" / "_sweep.json").is_file()
    assert cli(["cache", "ls"], capsys)[0] == 0
    assert cli(["report", str(tmp_path / "s")], capsys)[0] == 0
    baseline = tmp_path / "b.toml"
    assert cli(["check", str(tmp_path / "s"), "--baseline", str(baseline), "--update-baseline"], capsys)[0] == 0
    assert cli(["check", str(tmp_path / "s"), "--baseline", str(baseline)], capsys)[0] == 0
    assert cli(["verify", "--cases", "cube_tension_twist", "--backend", "skfem"], capsys)[0] == 0


def test_an_unexpected_error_is_one_line_exit_1(monkeypatch, capsys):
    import tissuebench.studies.describe as describe

    monkeypatch.setattr(describe, "describe", lambda *a, **k: {}["boom"])
    code, err = cli(["describe", "cornea_pinch"], capsys)
    assert code == 1 and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert "internal error in `describe`: KeyError: 'boom'" in err
    monkeypatch.setenv("TISSUEBENCH_DEBUG", "1")
    with pytest.raises(KeyError):
        main(["describe", "cornea_pinch"])


# ------------------------------------------------------------------------ 14: unwritable outputs
needs_permissions = pytest.mark.skipif(os.geteuid() == 0, reason="root ignores file permissions")


def _read_only(path: Path):
    for p in [path, *path.rglob("*")]:
        if p.is_dir():
            p.chmod(stat.S_IRUSR | stat.S_IXUSR)


def _writable(path: Path):
    for p in [path, *path.rglob("*")]:
        if p.is_dir():
            p.chmod(stat.S_IRWXU)


def test_14_a_results_folder_that_turns_read_only_mid_sweep_exits_2_naming_it(files, tmp_path, capsys,
                                                                               monkeypatch):
    """The unit writer raises PermissionError (as a read-only folder does, also as root): one line
    naming the path, exit 2, the lock released where it can be, the manifest says failed; resume works."""
    from tissuebench.studies import results

    out = tmp_path / "ro"
    real = results._write_table
    calls = []

    def refuse(table, path):
        calls.append(path)
        if len(calls) > 4:  # the first unit is written, the second is refused
            raise PermissionError(13, "Permission denied", str(path))
        real(table, path)

    spec = tmp_path / "two.toml"
    spec.write_text(ONE + '[[method]]\nname = "pod_interp"\n')
    monkeypatch.setattr(results, "_write_table", refuse)
    code, err = cli(["sweep", str(spec), "--out", str(out), "--quiet"], capsys)
    assert code == 2 and "Traceback" not in err
    assert f"cannot use {out}" in err and "Permission denied" in err and "resume with" in err
    assert len(list(out.glob("case=*/method=*/*.parquet"))) == 1
    monkeypatch.setattr(results, "_write_table", real)
    assert read_sweep_manifest(out)["state"] == "failed"
    assert not (out / ".lock").exists()
    code, err = cli(["sweep", str(spec), "--out", str(out), "--quiet", "--resume"], capsys)
    assert code == 0 and len(list(out.glob("case=*/method=*/*.parquet"))) == 2


@needs_permissions
def test_14_a_really_read_only_folder_is_refused_before_work_and_mid_sweep(files, tmp_path, capsys):
    out = tmp_path / "ro"
    assert cli(["sweep", str(files / "spec.toml"), "--out", str(out), "--quiet"], capsys)[0] == 0
    _read_only(out)
    try:
        code, err = cli(["sweep", str(files / "spec.toml"), "--out", str(out), "--quiet", "--resume"], capsys)
        assert code == 2 and "Traceback" not in err and str(out) in err
        code, err = cli(["report", str(out)], capsys)  # the default page goes inside: not writable
        assert code == 2 and "Traceback" not in err
    finally:
        _writable(out)


def test_14_release_of_a_lock_in_a_read_only_folder_warns_not_raises(tmp_path, monkeypatch):
    from tissuebench.studies.results import ResultsStore

    store = ResultsStore(tmp_path / "s")
    store.acquire()

    def refuse(self, missing_ok=False):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "unlink", refuse)
    with pytest.warns(UserWarning, match="could not remove the lock"):
        store.release()


def test_14_a_subprocess_sees_the_same_one_line(tmp_path):
    """The installed entry point (not only main()): a bad spec is one line on stderr, exit 2."""
    spec = tmp_path / "bad.toml"
    spec.write_text(ONE.replace("latency_steps = 5", "latency_steps = 1000000000"))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-m", "tissuebench.cli", "sweep", str(spec)], capture_output=True,
                          text=True, env=env, cwd=tmp_path, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().splitlines() == [
        "tissuebench: error: protocol.latency_steps = 1000000000: expected an integer from 1 to 100000 (the maximum "
        "LIMITS['latency_steps'] of tissuebench.studies.limits)"]
