"""The import paths of names that moved in issue 55 (the gate's package, the circles untied) work
for one release, each read warning DeprecationWarning with both paths, and give the very object
of the new path; a name that did not move is still a missing attribute there."""
from __future__ import annotations

import importlib
import warnings

import pytest

from test_layers import ROOT, _old_paths

#: old module -> new module (every name moved) or {name: new module}
MOVED = {
    "tissuebench.reports.gate": "tissuebench.gate",
    "tissuebench.reports.gate.baseline": "tissuebench.gate.baseline",
    "tissuebench.reports.gate.checks": "tissuebench.gate.checks",
    "tissuebench.reports.gate.io": "tissuebench.gate.io",
    "tissuebench.reports.gate.result": "tissuebench.gate.base",
    "tissuebench.studies.ab_code": "tissuebench.gate.sides",
    "tissuebench.studies.ab_layout": "tissuebench.gate.layout",
    "tissuebench.studies.ab_probe": "tissuebench.gate.probe",
    "tissuebench.studies.ab_project": "tissuebench.gate.project",
    "tissuebench.studies.ab_ref": "tissuebench.gate.ref",
    "tissuebench.studies.ab_scope": "tissuebench.gate.scope",
    "tissuebench.studies.ab_stats": "tissuebench.gate.stats",
    "tissuebench.studies.latency_ab": "tissuebench.gate.latency",
    "tissuebench.studies.ref_scratch": "tissuebench.gate.scratch",
    "tissuebench.rom.registry": {name: "tissuebench.rom.base"
                                 for name in ("register", "method_class", "make_method", "check_method_class")},
    "tissuebench.rom.separated": {"pgd_solve": "tissuebench.rom.separated_solver"},
    "tissuebench.refsolvers.backends.ngsolve_backend": {
        "TET_TO_NG": "tissuebench.refsolvers.backends.ngsolve_mesh",
        "simplex_rule_to_ng": "tissuebench.refsolvers.backends.ngsolve_mesh"},
}


def _names(new: str) -> list:
    """The public names of module ``new``: its ``__all__``, else what it defines."""
    module = importlib.import_module(new)
    if hasattr(module, "__all__"):
        return list(module.__all__)
    return sorted(n for n, v in vars(module).items() if not n.startswith("_") and getattr(v, "__module__", "") == new)


def _moves():
    for old, new in MOVED.items():
        pairs = new.items() if isinstance(new, dict) else [(name, new) for name in _names(new)]
        yield from ((old, name, module) for name, module in pairs)


def test_every_old_path_is_one_of_these():
    """The list above is the package's: an old path added or dropped is said here."""
    assert _old_paths(ROOT) == MOVED


@pytest.mark.parametrize("old, name, new", list(_moves()), ids=lambda v: v if isinstance(v, str) else None)
def test_an_old_path_gives_the_new_object_and_warns_naming_both(old, name, new):
    if new in ("tissuebench.refsolvers.backends.ngsolve_mesh",):
        pytest.importorskip("ngsolve")
    module = importlib.import_module(old)
    with pytest.warns(DeprecationWarning, match=rf"^{old}\.{name} moved to {new}\.{name}: import it from there"):
        value = getattr(module, name)
    assert value is getattr(importlib.import_module(new), name)


def test_the_from_import_form_warns_and_works():
    from tissuebench.gate import check as new
    from tissuebench.gate.stats import verdicts as new_verdicts

    with pytest.warns(DeprecationWarning, match=r"tissuebench.reports.gate.check moved to tissuebench.gate.check"):
        from tissuebench.reports.gate import check
    with pytest.warns(DeprecationWarning, match=r"tissuebench.studies.ab_stats.verdicts moved"):
        from tissuebench.studies.ab_stats import verdicts
    assert check is new and verdicts is new_verdicts


def test_a_name_that_did_not_move_is_missing_there_without_a_warning():
    """The other side of the boundary: only the names that moved are forwarded."""
    registry = importlib.import_module("tissuebench.rom.registry")
    stats = importlib.import_module("tissuebench.studies.ab_stats")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no DeprecationWarning on the way to the AttributeError
        with pytest.raises(AttributeError, match="module 'tissuebench.rom.registry' has no attribute 'load_source'"):
            registry.load_source  # noqa: B018  (plugins.load_source never lived here)
        with pytest.raises(AttributeError, match=r"'tissuebench.studies.ab_stats' has no attribute 'nothing' \(its "
                                                 r"names moved to 'tissuebench.gate.stats'\)"):
            stats.nothing  # noqa: B018
        with pytest.raises(AttributeError):
            stats.__wrapped__  # noqa: B018  (a dunder is the old module's own: inspect and pickle probe them)
        assert registry.METHODS is importlib.import_module("tissuebench.rom.base").METHODS  # stayed: no warning


PROBE_SIDE = """
import importlib.util, json, sys
spec = importlib.util.spec_from_file_location("ab_probe", sys.argv[1])
probe = importlib.util.module_from_spec(spec)
spec.loader.exec_module(probe)
found = probe._side_prepare_unit()
elsewhere = sorted(n for n, m in sys.modules.items() if n.split(".")[0] == "tissuebench"
                   and not (getattr(m, "__file__", None) or sys.argv[2]).startswith(sys.argv[2]))
print(json.dumps([None if found is None else [found.__module__, sys.modules[found.__module__].__file__], elsewhere]))
"""


@pytest.mark.parametrize("layout, expected", [
    ({"studies/latency_ab.py": "def prepare_unit(*a):\n    pass\n"}, "tissuebench.studies.latency_ab"),
    ({"studies/latency_ab.py": "raise ImportError('the old path: not read')\n",
      "gate/latency.py": "def prepare_unit(*a):\n    pass\n"}, "tissuebench.gate.latency"),
    ({}, None),
], ids=["ref-before-the-move", "after-the-move", "before-the-a-b"])
def test_the_probe_takes_prepare_unit_from_the_sides_own_folder(tmp_path, layout, expected):
    """A/B workers of a REF from before the move (REF = the previous commit, as CI runs it) find
    ``prepare_unit`` at its old path in REF's folder, although this environment's editable install
    would serve ``tissuebench.gate`` from HEAD's work tree to any tissuebench (timing HEAD's code
    as REF's, or refusing the side); the newest layout wins where the side has both."""
    import subprocess
    import sys
    from pathlib import Path

    import tissuebench.gate.probe as probe

    side = tmp_path / "side"
    (side / "tissuebench").mkdir(parents=True)
    (side / "tissuebench" / "__init__.py").write_text("")
    for rel, text in layout.items():
        (side / "tissuebench" / rel).parent.mkdir(exist_ok=True)
        (side / "tissuebench" / rel).parent.joinpath("__init__.py").touch()
        (side / "tissuebench" / rel).write_text(text)
    out = subprocess.run([sys.executable, "-c", PROBE_SIDE, probe.__file__, str(side)], env={"PYTHONPATH": str(side)},
                         cwd=tmp_path, capture_output=True, text=True, check=True, timeout=120)
    found, elsewhere = __import__("json").loads(out.stdout)
    assert elsewhere == []  # no module of HEAD's tissuebench in the side's process
    if expected is None:
        assert found is None
    else:
        assert found == [expected, str(side / "tissuebench" / Path(*expected.split(".")[1:])) + ".py"]


def test_the_registry_loads_a_module_class_name_through_the_loader_armed_below_the_plugins():
    """The registry imports neither the method contract nor the plugins (issue 55): tissuebench.rom
    arms it with the plugins' loader, which ``method_class("module:Class")`` reaches through it; an
    unarmed registry says so instead of importing one."""
    from tissuebench.rom import METHODS, method_class, plugins
    from tissuebench.rom.baselines import Nearest
    from tissuebench.rom.registry import MethodRegistry

    assert METHODS._source_loader is plugins.load_source
    assert method_class("tissuebench.rom.baselines:Nearest") is Nearest
    with pytest.raises(RuntimeError, match=r"method 'x:Y': no loader of 'module:Class' names is armed"):
        MethodRegistry().load_source("x:Y")
    armed = MethodRegistry()
    armed.arm_sources(lambda source: (source, "loaded"))
    assert armed.load_source("x:Y") == ("x:Y", "loaded")
