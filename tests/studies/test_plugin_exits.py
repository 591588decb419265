"""Plugin code that exits cannot break a sweep (issue 50, item 1).

A ``SystemExit`` (a ``sys.exit`` left in a plugin) or a ``KeyboardInterrupt`` raised by a plugin's
code passes an ``except Exception``: at import it ended ``tissuebench methods`` and every sweep
(exit 5, no output), in a step it ended the sweep in the serial and the processes executors
alike. Raised by the code, they now fail that plugin (a line of ``tissuebench methods``) or that
unit (its row names the exception) and the rest goes on; a real Ctrl-C is still the user's
(:mod:`tissuebench.exits`: tested here on both sides, and on a running sweep in
test_sweep_signals.py). The plugins are installed distributions (tests/_plugin_dist.py)."""
from __future__ import annotations

import signal
import sys
import threading

import pytest

from _gate_spec import HELD_OUT, cornea_spec
from _plugin_dist import Installed, toy_source, write_dist
from tissuebench.cli import main
from tissuebench.exits import Terminated, exit_text, raised_by_code, user_signals
from tissuebench.rom.plugins import FAILURES, load_source, origin
from tissuebench.rom.registry import METHODS
from tissuebench.studies.executors import execute
from tissuebench.studies.results import read_units
from tissuebench.studies.spec import expand_units, load_spec
from tissuebench.studies.units import UnitOutcome
from tissuebench.studies.sweep_manifest import read_sweep_manifest

IMPORT_EXITS = {"sys.exit(5)": ("import sys\nsys.exit(5)\n", "SystemExit(5) raised by its code"),
                "KeyboardInterrupt": ("raise KeyboardInterrupt\n", "KeyboardInterrupt() raised by its code")}
_STEP = "        mu = check_parameters(mu,"


def _step_plugin(name: str, first_line: str) -> str:
    """The toy plugin (tests/_plugin_dist.py) whose step starts with ``first_line``."""
    source = toy_source(name)
    assert source.count(_STEP) == 1
    return source.replace(_STEP, f"        {first_line}\n{_STEP}")


def _spec(tmp_path, *methods) -> str:
    path = tmp_path / "spec.toml"
    # a shipped method beside the plugins: "nearest", fast on the cornea's path
    path.write_text(cornea_spec("plugin-exits", [*methods, "nearest"], evaluation=HELD_OUT))
    return str(path)


@pytest.fixture(autouse=True)
def no_derived_figures(monkeypatch):
    """The derived figures (seconds of matplotlib per sweep) are not what this file tests."""
    import tissuebench.reports.derived_figures as figures

    monkeypatch.setattr(figures, "draw_derived", lambda *args, **kwargs: [])


@pytest.fixture
def site(tmp_path, monkeypatch):
    inst = Installed(tmp_path / "site", monkeypatch)
    yield inst
    inst.undo()


# ---------------------------------------------------------------- raised by the code, or sent by the user
@pytest.fixture(autouse=True)
def python_sigint():
    """Each test starts from Python's own SIGINT handler, whatever a test before it in the same worker
    process left (a SIGINT raised at the system default ends the worker: CI saw it once), and the
    disposition it found is put back after."""
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)



def test_a_system_exit_is_always_the_codes_a_keyboard_interrupt_only_without_a_signal():
    assert raised_by_code(SystemExit(7)) and raised_by_code(SystemExit())
    assert not raised_by_code(ValueError("x"))
    # no recorder (a library call outside the CLI and a sweep): cannot be told, so the user's
    assert not raised_by_code(KeyboardInterrupt())
    with user_signals():
        assert raised_by_code(KeyboardInterrupt())  # recorded no signal: the code raised it
        with pytest.raises(KeyboardInterrupt) as real:
            signal.raise_signal(signal.SIGINT)  # what Ctrl-C delivers
        assert not isinstance(real.value, Terminated) and not raised_by_code(real.value)
        assert not raised_by_code(KeyboardInterrupt())  # once the user interrupted, every one is his
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored
    with user_signals():  # a fresh record
        assert raised_by_code(KeyboardInterrupt())


def test_a_keyboard_interrupt_in_another_thread_is_the_codes():
    """Python delivers signals to the main thread only (a dask worker runs its units in threads)."""
    seen = []
    thread = threading.Thread(target=lambda: seen.append(raised_by_code(KeyboardInterrupt())))
    thread.start()
    thread.join()
    assert seen == [True]


def test_sigterm_is_an_interrupt_while_watched_and_the_default_after():
    with user_signals(terminate=True):
        with pytest.raises(Terminated) as got:
            signal.raise_signal(signal.SIGTERM)
        assert isinstance(got.value, KeyboardInterrupt) and got.value.signum == 15
        assert not raised_by_code(got.value)
    assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    with user_signals():  # not asked: SIGTERM keeps its default
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL


def test_an_ignored_sigint_is_left_ignored_and_every_keyboard_interrupt_is_the_codes():
    """A run started with SIGINT ignored (a background job of a script) keeps it so; no signal can
    raise KeyboardInterrupt there, so one that comes was raised by the code."""
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with user_signals():
            assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
            assert raised_by_code(KeyboardInterrupt())
        assert not raised_by_code(KeyboardInterrupt())  # nothing watches any more
    finally:
        signal.signal(signal.SIGINT, previous)


def test_another_python_handler_is_wrapped_recorded_then_called():
    """An embedding application's SIGINT handler still runs; the signal is recorded first."""
    calls = []

    def theirs(signum, frame):
        calls.append(signum)
        raise KeyboardInterrupt("theirs")

    previous = signal.signal(signal.SIGINT, theirs)
    try:
        with user_signals():
            assert raised_by_code(KeyboardInterrupt())
            with pytest.raises(KeyboardInterrupt, match="theirs") as real:
                signal.raise_signal(signal.SIGINT)
            assert calls == [signal.SIGINT] and not raised_by_code(real.value)
        assert signal.getsignal(signal.SIGINT) is theirs
    finally:
        signal.signal(signal.SIGINT, previous)


def test_exit_text_names_the_exception_as_written():
    assert exit_text(SystemExit(7)) == "SystemExit(7) raised by the method's code"
    assert exit_text(KeyboardInterrupt(), "its code") == "KeyboardInterrupt() raised by its code"
    assert len(exit_text(SystemExit("x" * 500))) < 160


# ---------------------------------------------------------------- at import


@pytest.mark.parametrize("how", list(IMPORT_EXITS))
def test_an_entry_point_whose_import_exits_fails_that_plugin_only(site, tmp_path, capsys, how):
    body, said = IMPORT_EXITS[how]
    write_dist(site.root, "tb-bad", "0.1", {"bad_import": "badimp:Toy"}, {"badimp": body})
    with pytest.warns(UserWarning, match="bad_import"):
        assert main(["methods"]) == 0  # was: exit 5 (130) with no output
    out = capsys.readouterr().out
    # other distributions of this environment (the peers of peers/), counted as the listing counts them:
    # the registered methods with an origin (PLUGINS may keep a record of a test's plugin since removed)
    loaded = sum(1 for name in METHODS if name != "bad_import" and origin(name))
    assert f" shipped, {loaded} from other packages)" in out  # the listing, then the plugin's line
    assert f"plugin 'bad_import' of badimp:Toy (distribution tb-bad 0.1) could not be loaded: {said}" in out
    assert FAILURES["bad_import"][1] == said


@pytest.mark.parametrize("how", list(IMPORT_EXITS))
def test_a_sweep_of_shipped_methods_runs_beside_a_plugin_whose_import_exits(site, tmp_path, capsys, how):
    write_dist(site.root, "tb-bad", "0.1", {"bad_import": "badimp:Toy"}, {"badimp": IMPORT_EXITS[how][0]})
    with pytest.warns(UserWarning, match="bad_import"):
        assert main(["sweep", _spec(tmp_path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert "1 units: 1 computed (0 failed)" in capsys.readouterr().out
    assert read_units(tmp_path / "out")["unit_status"].tolist() == ["ok"]


def test_a_module_class_name_whose_import_exits_is_refused_naming_it(site):
    write_dist(site.root, "tb-bad", "0.1", {}, {"exitmod": "import sys\nsys.exit(3)\n",
                                                "kbimod": "raise KeyboardInterrupt\n"})
    with user_signals():
        with pytest.raises(ValueError, match=r"method 'exitmod:Toy': importing 'exitmod' failed: SystemExit\(3\) "
                                             "raised by its code"):
            load_source("exitmod:Toy")
        with pytest.raises(ValueError, match=r"importing 'kbimod' failed: KeyboardInterrupt\(\) raised by its code"):
            load_source("kbimod:Toy")
    with pytest.raises(ValueError, match=r"SystemExit\(3\)"):  # SystemExit: the code's, recorder or not
        load_source("exitmod:Toy")
    with pytest.raises(KeyboardInterrupt):  # no recorder: it cannot be told from Ctrl-C, which is never swallowed
        load_source("kbimod:Toy")


# ---------------------------------------------------------------- in a unit


@pytest.fixture
def step_plugins(site):
    """toy_exit: its step calls sys.exit(7); toy_nan: its step returns a NaN state; toy_kbi: its step
    raises KeyboardInterrupt (no signal sent)."""
    nan = toy_source("toy_nan").replace("np.array([self.gain * lam]), mu=mu)\n", "np.array([np.nan]), mu=mu)\n")
    assert nan != toy_source("toy_nan")
    write_dist(site.root, "tb-steps", "0.1", {"toy_exit": "toyexit:Toy", "toy_nan": "toynan:Toy",
                                              "toy_kbi": "toykbi:Toy"},
               {"toyexit": _step_plugin("toy_exit", "raise SystemExit(7)"), "toynan": nan,
                "toykbi": _step_plugin("toy_kbi", "raise KeyboardInterrupt")})
    return site


def _check_units(out):
    units = read_units(out).set_index("method")
    assert units.loc["nearest", "unit_status"] == "ok" and units.loc["nearest", "n_failed"] == 0
    assert units.loc["toy_exit", "unit_status"] == "failed"
    assert units.loc["toy_exit", "message"].startswith("SystemExit(7) raised by the method's code (in ")
    assert units.loc["toy_kbi", "unit_status"] == "failed"
    assert units.loc["toy_kbi", "message"].startswith("KeyboardInterrupt() raised by the method's code (in ")
    nan = units.loc["toy_nan"]  # a unit whose steps failed: as one whose Newton failed (status ok, steps failed)
    assert (nan["n_ok"], nan["n_failed"], nan["max_rel_l2"]) == (0, nan["n_points"], float("inf"))
    assert nan["message"].startswith(f"{nan['n_points']} of {nan['n_points']} evaluation steps failed: the step "
                                     "returned a non-finite state (q has 1 NaN)")
    assert read_sweep_manifest(out)["state"] == "finished" and not (out / ".lock").exists()


@pytest.mark.parametrize("executor", ["serial", "processes"])
def test_units_whose_code_exits_or_returns_nan_fail_and_the_sweep_goes_on(step_plugins, tmp_path, capsys, executor):
    """Was: the sweep ended at toy_exit's step (exit 7), the shipped unit after it never computed,
    and toy_nan stored as ok (19 ok steps, error inf, "0 failed")."""
    spec, out = _spec(tmp_path, "toy_exit", "toy_nan", "toy_kbi"), tmp_path / "out"
    extra = ["--executor", "processes", "--workers", "2"] if executor == "processes" else []
    # exit 0: the sweep finished, the plugins' failures are results stored with their messages (the
    # CLI's exit codes); not 7, not 130, and not 1: a broken plugin fails its units, not the sweep
    assert main(["sweep", spec, "--out", str(out), "--quiet", *extra]) == 0
    said = capsys.readouterr().out
    assert "4 units: 4 computed (2 failed; 1 with failed steps (" in said
    _check_units(out)
    # --resume afterwards: every unit is stored (the failed ones too), nothing runs again; --strict
    # exits 1 on the failed units kept from before, naming how many
    assert main(["sweep", spec, "--out", str(out), "--quiet", "--resume", *extra]) == 0
    assert "4 units: 0 computed (0 failed), 4 kept from before" in capsys.readouterr().out
    assert main(["sweep", spec, "--out", str(out), "--quiet", "--resume", "--strict", *extra]) == 1
    assert "--strict: 2 of 4 units failed" in capsys.readouterr().err
    _check_units(out)


def test_strict_exits_0_when_no_unit_failed(tmp_path, capsys):
    """The other side of --strict's rule: a sweep whose units are all ok exits 0 with it."""
    spec, out = _spec(tmp_path, "pod_interp"), tmp_path / "out"
    assert main(["sweep", spec, "--out", str(out), "--quiet", "--strict"]) == 0
    assert "--strict" not in capsys.readouterr().err


def exits_for_nearest(unit) -> UnitOutcome:
    """A unit function (module level: a spawned worker imports it) that calls sys.exit(9) for the
    nearest unit, outside run_unit's own guard, and returns an ok row for any other."""
    if unit.method == "nearest":
        sys.exit(9)
    return UnitOutcome({"unit_key": unit.key, "unit_status": "ok", "message": ""})


@pytest.mark.parametrize("executor", ["serial", "processes"])
def test_an_exit_outside_run_unit_fails_its_unit_and_the_worker_runs_the_next(tmp_path, executor):
    """The executors' own guard (executors._in_cache): one worker (processes) runs both units, so
    the second one ran on the worker the first one's SystemExit came from."""
    units = expand_units(load_spec(_spec(tmp_path, "pod_interp")))
    assert sorted(u.method for u in units) == ["nearest", "pod_interp"]
    done = {u.method: o.row for u, o in execute(units, executor, 1 if executor == "processes" else None,
                                                run=exits_for_nearest)}
    assert done["pod_interp"]["unit_status"] == "ok"
    assert done["nearest"]["unit_status"] == "failed"
    assert done["nearest"]["message"] == "SystemExit(9) raised by the code running this unit; the sweep went on"
