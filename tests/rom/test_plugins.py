"""Methods from other packages (issue 38): found by entry point (group ``tissuebench.methods``) or
by ``"module:Class"``, added to the one registry, refused on a name clash naming both, named with
their error when they fail to load (everything else still works), and listed with their
distribution and version."""
from __future__ import annotations

import json
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

import tissuebench
from _gate_spec import cornea_spec
from _plugin_dist import Installed, toy_source, write_dist
from tissuebench.cli import main
from tissuebench.rom import METHODS, make_method, method_class
from tissuebench.rom.plugins import FAILURES, PLUGINS, PluginWarning, origin, third_party
from tissuebench.gate.ref import _spec_for, code_env
from tissuebench.studies.spec import expand_units, load_spec


@pytest.fixture
def installed(tmp_path, monkeypatch):
    inst = Installed(tmp_path / "site", monkeypatch)
    yield inst
    inst.undo()


def _install(inst, dist="tb-toyplug", version="0.1.0", name="toy_plug", module="tb_toyplug", value=None,
             source=None):
    write_dist(inst.root, dist, version, {name: value or f"{module}:Toy"},
               {module: source if source is not None else toy_source(name)})


def test_an_entry_point_joins_the_registry_at_its_first_read_with_its_distribution(installed, capsys):
    _install(installed)
    assert "toy_plug" not in dict.keys(METHODS)  # nothing read yet: nothing imported
    assert "toy_plug" in METHODS
    cls = METHODS["toy_plug"]
    assert cls.__module__ == "tb_toyplug" and make_method("toy_plug", gain=2.0).gain == 2.0
    record = PLUGINS["toy_plug"]
    assert (record.distribution, record.version, record.source, record.how) == ("tb-toyplug", "0.1.0",
                                                                               "tb_toyplug:Toy", "entry point")
    assert origin("toy_plug") == "plugin tb-toyplug 0.1.0 (tb_toyplug:Toy)" and origin("nearest") == ""
    assert main(["methods"]) == 0
    out = capsys.readouterr().out
    assert "toy_plug" in out and "[plugin tb-toyplug 0.1.0 (tb_toyplug:Toy)]" in out
    shipped = sum(cls.__module__.split(".")[0] == "tissuebench" for cls in METHODS.values())
    # other plugin distributions installed in this environment (the peers of peers/) count too
    others = sum(1 for name in PLUGINS if name != "toy_plug")
    assert f"{shipped + 1 + others} methods ({shipped} shipped, {1 + others} from other packages)" in out
    assert shipped >= 17
    assert main(["methods", "cornea_pinch", "--method", "toy_plug"]) == 0
    assert "toy_plug  applies (path training)  [plugin tb-toyplug 0.1.0" in capsys.readouterr().out


def test_a_plugin_named_like_a_shipped_method_is_refused_naming_both(installed, capsys):
    _install(installed, dist="tb-clash", name="nearest", module="tb_clash")
    shipped = dict.get(METHODS, "nearest")
    with pytest.warns(PluginWarning) as caught:
        assert METHODS["nearest"] is shipped  # the shipped method stays
    message = str(caught[0].message)
    assert "tb-clash 0.1.0" in message and "tissuebench.rom.baselines.Nearest" in message, message
    assert "nearest" in FAILURES
    assert main(["methods"]) == 0
    assert "plugin 'nearest' of tb_clash:Toy (distribution tb-clash 0.1.0) could not be loaded" in \
        capsys.readouterr().out


def test_a_plugin_that_fails_to_import_is_named_with_its_error_and_the_rest_works(installed, capsys):
    _install(installed, dist="tb-broken", name="broken_plug", module="tb_broken",
             source="import numpy\nraise ImportError('needs torch, which is not installed')\n")
    _install(installed, dist="tb-fine", name="fine_plug", module="tb_fine")
    with pytest.warns(PluginWarning, match=r"'broken_plug' of tb_broken:Toy \(distribution tb-broken 0.1.0\) could "
                                           r"not be loaded: ImportError: needs torch"):
        names = sorted(METHODS)
    assert "fine_plug" in names and "broken_plug" not in names and "nearest" in names
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per process: no second warning
        assert "broken_plug" not in METHODS
    assert main(["methods", "cornea_pinch"]) == 0
    out = capsys.readouterr().out
    assert "plugin 'broken_plug' of tb_broken:Toy (distribution tb-broken 0.1.0) could not be loaded: ImportError: " \
           "needs torch" in out and "fine_plug" in out


def test_an_entry_point_named_otherwise_than_its_class_is_refused(installed):
    _install(installed, dist="tb-misnamed", name="other_name", module="tb_misnamed",
             source=toy_source("real_name"))
    with pytest.warns(PluginWarning, match="the entry point is named 'other_name' but Toy.name = 'real_name'"):
        assert "other_name" not in METHODS and "real_name" not in METHODS


def test_a_module_class_name_is_imported_and_registered_under_its_name(installed):
    (installed.root).mkdir(parents=True, exist_ok=True)
    (installed.root / "tb_direct.py").write_text(toy_source("direct_toy"))
    cls = method_class("tb_direct:Toy")
    assert cls.name == "direct_toy" and METHODS["direct_toy"] is cls
    assert PLUGINS["direct_toy"].how == "module:Class" and PLUGINS["direct_toy"].distribution is None
    assert make_method("tb_direct:Toy", gain=3.0).gain == 3.0
    provenance = third_party("direct_toy")
    assert provenance["source"] == "tb_direct:Toy" and len(provenance["code_hash"]) == 64
    assert third_party("nearest") == {}
    assert method_class("tissuebench.rom.baselines:Nearest") is METHODS["nearest"]  # a shipped class by its path


@pytest.mark.parametrize("source, message", [
    ("tb_nowhere_xyz:Toy", "cannot import 'tb_nowhere_xyz'"),
    ("tb_direct2:Nope", "has no attribute 'Nope'"),
    ("tb_direct2:np", "is not a named RomMethod subclass"),
    ("tb direct:Toy", "expected 'module:Class'"),
    ("tb_shadow:Toy", "clashes with the shipped method 'nearest' (tissuebench.rom.baselines.Nearest)"),
])
def test_a_bad_module_class_name_is_refused_naming_it(installed, source, message):
    installed.root.mkdir(parents=True, exist_ok=True)
    (installed.root / "tb_direct2.py").write_text(toy_source("direct_toy2"))
    (installed.root / "tb_shadow.py").write_text(toy_source("nearest"))
    with pytest.raises((ValueError, TypeError), match=f"method '{source}'|{message.split(' (')[0]}") as exc:
        method_class(source)
    assert message in str(exc.value) and ("tb_shadow" not in source or "tb_shadow:Toy" in str(exc.value))





def test_a_spec_names_a_method_by_module_class_and_its_units_carry_it(installed, tmp_path):
    installed.root.mkdir(parents=True, exist_ok=True)
    (installed.root / "tb_spec.py").write_text(toy_source("spec_toy"))
    spec = tmp_path / "s.toml"
    spec.write_text(cornea_spec("plug", ["tb_spec:Toy"]))
    units = expand_units(load_spec(spec))
    assert [(u.method, u.source) for u in units] == [("spec_toy", "tb_spec:Toy")]
    spec.write_text(cornea_spec("plug", ["tb_nowhere_xyz:Toy"]))
    with pytest.raises(ValueError, match=r"method\[0\].name: method 'tb_nowhere_xyz:Toy': cannot import"):
        load_spec(spec)


def test_refs_sweep_keeps_the_plugin_methods_refs_code_resolves(installed):
    """REF's code (here this checkout's, from a copy of its path) finds the installed plugin's entry
    point and a ``module:Class`` on PYTHONPATH; a name it cannot resolve is left out."""
    _install(installed)
    (installed.root / "tb_direct3.py").write_text(toy_source("direct_toy3"))
    text = "\n".join(f'[[method]]\nname = "{n}"' for n in ("toy_plug", "tb_direct3:Toy", "nearest", "tb_nope:X"))
    kept, dropped = _spec_for(Path(tissuebench.__file__).parents[1], text)
    assert dropped == {"tb_nope:X": "unknown to REF's code"} and "toy_plug" in kept and "tb_direct3:Toy" in kept


def test_a_copy_of_tissuebench_first_on_the_path_still_finds_the_installed_plugins(installed, tmp_path):
    """The A/B workers import REF's copy of tissuebench (first on PYTHONPATH): the user's
    installed distributions are still found there."""
    _install(installed)
    copy = tmp_path / "ref"
    copy.mkdir()
    (copy / "tissuebench").symlink_to(Path(tissuebench.__file__).parent)
    code = ("import json, tissuebench; from tissuebench.rom import METHODS; "
            "print(json.dumps([tissuebench.__file__, 'toy_plug' in METHODS]))")
    proc = subprocess.run([sys.executable, "-c", code], env=code_env(copy), capture_output=True, text=True,
                          cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    where, found = json.loads(proc.stdout.strip().splitlines()[-1])
    assert where.startswith(str(copy)) and found


def test_a_class_of_an_interactive_main_has_no_code_hash_and_no_error(monkeypatch):
    """``find_spec("__main__")`` raises where ``__main__`` has no spec (an interactive session): the
    provenance of a method defined there says no code hash instead of failing the sweep's plan."""
    import types

    from tissuebench.rom.plugins import _files_hash

    main_module = types.ModuleType("__main__")
    main_module.__spec__ = None
    monkeypatch.setitem(sys.modules, "__main__", main_module)
    assert _files_hash.__wrapped__("__main__") is None
