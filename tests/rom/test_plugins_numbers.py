"""What the registry records of a plugin method, field by field (issue 50, item 10: the mutation
testing of rom/plugins.py): which classes are tissuebench's, where a plugin comes from (its
distribution or none), the ``module:Class`` a fresh process imports, what the unit key records of
its code, the listing's origin, the messages of a clash or a bad name, and the entry points read
once each, also from an importlib that gives them no ``dist``. Entry points are replaced by
plain objects here; the real discovery is tests/rom/test_plugins.py's."""
from __future__ import annotations

import importlib.metadata
import sys
import types
import warnings

import pytest

from tissuebench.rom import METHODS, RomMethod, plugins
from tissuebench.rom.base import Applies
from tissuebench.rom.baselines import Nearest
from tissuebench.rom.plugins import FAILURES, PLUGINS, Plugin


def _method(name, module="tb_numbers_pkg.sub", qualname=None):
    """A registrable method class named ``name`` whose class lives in ``module``."""
    cls = type(qualname or "Tool", (RomMethod,), {
        "name": name, "kind": "map", "training_kinds": ("path",), "applies": Applies(),
        "build": lambda self, training: None, "__module__": module})
    if qualname:
        cls.__qualname__ = qualname
    return cls


@pytest.fixture
def clean():
    """Every registry entry, plugin record and failure a test adds is removed after it."""
    len(METHODS)  # the installed plugins loaded first: they stay
    before = set(dict.keys(METHODS))
    yield
    for name in set(dict.keys(METHODS)) - before:
        dict.pop(METHODS, name)
        PLUGINS.pop(name, None)
    FAILURES.clear()


def test_describe_and_is_shipped():
    assert Plugin("a", "pkg.mod:A", "tb-a", "1.2", "entry point").describe() == "pkg.mod:A (distribution tb-a 1.2)"
    assert Plugin("a", "mod:A", None, None, "module:Class").describe() == "mod:A (no installed distribution)"
    assert plugins.is_shipped(Nearest)  # tissuebench.rom.baselines
    assert not plugins.is_shipped(_method("x", "tissuebench_extra.rom"))
    assert not plugins.is_shipped(_method("x", "pkg.tissuebench"))


def test_add_registers_once_and_names_both_sides_of_a_clash(clean):
    first = _method("tb_numbers_a")
    plugin = Plugin("tb_numbers_a", "tb_numbers_pkg.sub:Tool", "tb-pkg", "1.0", "entry point")
    plugins._add(first, plugin)
    assert METHODS["tb_numbers_a"] is first and PLUGINS["tb_numbers_a"] is plugin
    plugins._add(first, Plugin("tb_numbers_a", "other:Tool", None, None, "module:Class"))  # met again: kept
    assert PLUGINS["tb_numbers_a"] is plugin
    other = _method("tb_numbers_a", "tb_numbers_other")
    with pytest.raises(ValueError) as err:
        plugins._add(other, Plugin("tb_numbers_a", "tb_numbers_other:Tool", None, None, "module:Class"))
    assert str(err.value) == (
        "plugin method 'tb_numbers_a' of tb_numbers_other:Tool (no installed distribution) clashes with the plugin "
        "method 'tb_numbers_a' of tb_numbers_pkg.sub:Tool (distribution tb-pkg 1.0); give the plugin's method "
        "another name (its class's name and its entry point)")
    with pytest.raises(ValueError, match=r"clashes with the shipped method 'nearest' "
                                         r"\(tissuebench\.rom\.baselines\.Nearest\); give"):
        plugins._add(_method("nearest"), plugin)


def test_a_class_registered_in_this_process_clashes_as_a_method_and_is_recorded_when_added(clean):
    local = _method("tb_numbers_b", "tb_numbers_local")
    dict.__setitem__(METHODS, "tb_numbers_b", local)  # as @register does, no plugin record
    with pytest.raises(ValueError, match=r"clashes with the method 'tb_numbers_b' \(tb_numbers_local\.Tool\); give"):
        plugins._add(_method("tb_numbers_b", "tb_numbers_elsewhere"), Plugin("tb_numbers_b", "x:Tool", None, None,
                                                                             "module:Class"))
    plugin = Plugin("tb_numbers_b", "tb_numbers_local:Tool", None, None, "module:Class")
    plugins._add(local, plugin)  # the same class: now recorded as the plugin it is
    assert PLUGINS["tb_numbers_b"] is plugin and METHODS["tb_numbers_b"] is local


def test_distribution_of_reads_the_top_level_package(monkeypatch):
    asked = []
    monkeypatch.setattr(plugins, "_distribution_of_top", lambda top: asked.append(top) or ("tb-x", "2.0"))
    assert plugins._distribution_of("tb_x.sub.mod") == ("tb-x", "2.0") and asked == ["tb_x"]


class _EntryPoint:
    """An entry point as an importlib without ``dist`` gives it (``dist`` set only when passed)."""

    def __init__(self, name, value, cls=None, error=None, dist=None):
        self.name, self.value, self._cls, self._error = name, value, cls, error
        if dist is not None:
            self.dist = dist

    def load(self):
        if self._error is not None:
            raise self._error
        return self._cls


def _entry_points(monkeypatch, eps):
    monkeypatch.setattr(importlib.metadata, "entry_points", lambda group: list(eps) if group == plugins.GROUP else [])


def test_entry_points_are_read_once_each_with_or_without_a_distribution(monkeypatch, clean):
    a, b = _method("tb_numbers_c", "tb_numbers_c"), _method("tb_numbers_d", "tb_numbers_d")
    dist = types.SimpleNamespace(name="tb-c", version="3.1")
    broken = _EntryPoint("tb_numbers_e", "tb_numbers_e:Tool", error=RuntimeError("boom"))
    _entry_points(monkeypatch, [broken, broken, _EntryPoint("tb_numbers_c", "tb_numbers_c:Tool", a, dist=dist),
                                _EntryPoint("tb_numbers_d", "tb_numbers_d:Tool", b)])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        plugins.load_entry_points()
    assert PLUGINS["tb_numbers_c"] == Plugin("tb_numbers_c", "tb_numbers_c:Tool", "tb-c", "3.1", "entry point")
    assert PLUGINS["tb_numbers_d"] == Plugin("tb_numbers_d", "tb_numbers_d:Tool", None, None, "entry point")
    assert FAILURES == {"tb_numbers_e": ("tb_numbers_e:Tool (no installed distribution)", "RuntimeError: boom")}
    assert [str(w.message) for w in caught] == [  # the entry point found twice is read, and warned about, once
        "plugin method 'tb_numbers_e' of tb_numbers_e:Tool (no installed distribution) could not be loaded: "
        "RuntimeError: boom; the other methods are unaffected"]


def test_an_entry_point_that_is_no_method_or_named_otherwise_is_named_in_its_failure(monkeypatch, clean):
    _entry_points(monkeypatch, [_EntryPoint("tb_numbers_f", "tb_numbers_f:thing", object()),
                                _EntryPoint("tb_numbers_g", "tb_numbers_g:Tool", _method("tb_numbers_other"))])
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        plugins.load_entry_points()
    assert FAILURES["tb_numbers_f"][1].startswith(
        "TypeError: entry point tb_numbers_f = 'tb_numbers_f:thing': <object object at")
    assert FAILURES["tb_numbers_g"][1] == (
        "ValueError: the entry point is named 'tb_numbers_g' but Tool.name = 'tb_numbers_other'; give both the same "
        "name")


@pytest.fixture
def module(monkeypatch):
    """A module ``tb_numbers_mod`` (a file on sys.path) holding a method and a nested one."""
    def make(tmp_path, body):
        (tmp_path / "tb_numbers_mod.py").write_text(body)
        monkeypatch.syspath_prepend(str(tmp_path))
        monkeypatch.delitem(sys.modules, "tb_numbers_mod", raising=False)
        importlib.invalidate_caches()
    yield make
    sys.modules.pop("tb_numbers_mod", None)


METHOD_MODULE = '''
from tissuebench.rom import RomMethod
from tissuebench.rom.base import Applies


class Outer:
    class Inner(RomMethod):
        name, kind, training_kinds, applies = "tb_numbers_inner", "map", ("path",), Applies()

        def build(self, training):
            return None


Alias = Outer.Inner  # the name an entry point may give it
settings = object()  # an attribute without a __name__
'''


def test_load_source_follows_a_dotted_class_path_and_records_where_it_comes_from(tmp_path, module, clean):
    module(tmp_path, METHOD_MODULE)
    cls = plugins.load_source("tb_numbers_mod:Outer.Inner")
    assert cls.__qualname__ == "Outer.Inner" and METHODS["tb_numbers_inner"] is cls
    assert PLUGINS["tb_numbers_inner"] == Plugin("tb_numbers_inner", "tb_numbers_mod:Outer.Inner", None, None,
                                                 "module:Class")
    with pytest.raises(ValueError) as err:
        plugins.load_source("tb_numbers_mod:Missing")
    assert str(err.value) == "method 'tb_numbers_mod:Missing': 'tb_numbers_mod' has no attribute 'Missing'"
    with pytest.raises(ValueError) as err:
        plugins.load_source("tb_numbers_mod:Outer.Missing")
    assert str(err.value) == "method 'tb_numbers_mod:Outer.Missing': 'Outer' has no attribute 'Missing'"
    with pytest.raises(ValueError) as err:  # an object without a name: the module is named
        plugins.load_source("tb_numbers_mod:settings.Missing")
    assert str(err.value) == "method 'tb_numbers_mod:settings.Missing': 'tb_numbers_mod' has no attribute 'Missing'"
    with pytest.raises(TypeError) as err:
        plugins.load_source("tb_numbers_mod:Outer")
    assert str(err.value).startswith("method 'tb_numbers_mod:Outer': <class 'tb_numbers_mod.Outer'> is not a named")


def test_load_source_names_the_import_error_and_the_missing_module(tmp_path, module):
    module(tmp_path, "raise RuntimeError('boom at import')\n")
    with pytest.raises(ValueError) as err:
        plugins.load_source("tb_numbers_mod:Tool")
    assert str(err.value) == "method 'tb_numbers_mod:Tool': importing 'tb_numbers_mod' failed: RuntimeError: boom " \
                             "at import"
    with pytest.raises(ValueError) as err:
        plugins.load_source("tb_numbers_absent:Tool")
    assert str(err.value) == ("method 'tb_numbers_absent:Tool': cannot import 'tb_numbers_absent' (No module named "
                              "'tb_numbers_absent'); install its package (pip install -e FOLDER) or put its folder "
                              "on PYTHONPATH")


def test_a_shipped_class_by_its_path_is_no_plugin_and_a_class_of_this_process_becomes_one(clean):
    assert plugins.load_source("tissuebench.rom.baselines:Nearest") is Nearest and "nearest" not in PLUGINS
    here = sys.modules[__name__]
    local = _method("tb_numbers_here", __name__, "LocalTool")
    here.LocalTool = local
    try:
        dict.__setitem__(METHODS, "tb_numbers_here", local)  # registered by @register in this process
        assert plugins.origin("tb_numbers_here") == f"registered in this process ({__name__}.LocalTool)"
        assert plugins.load_source(f"{__name__}:LocalTool") is local
        assert PLUGINS["tb_numbers_here"] == Plugin("tb_numbers_here", f"{__name__}:LocalTool", None, None,
                                                    "module:Class")
    finally:
        del here.LocalTool


@pytest.mark.parametrize("module, qualname, source", [
    ("tissuebench.rom.baselines", "Tool", ""),
    ("__main__", "Tool", ""),
    ("__mp_main__", "Tool", ""),
    ("pkg.mod", "make.<locals>.Tool", ""),
    ("pkg.mod", "Outer.Tool", "pkg.mod:Outer.Tool"),
])
def test_source_of_is_empty_where_another_process_cannot_import_the_class(module, qualname, source):
    assert plugins.source_of(_method("x", module, qualname)) == source


def test_third_party_records_a_plugins_source_and_code_and_nothing_for_shipped(tmp_path, module, clean, monkeypatch):
    assert plugins.third_party("nearest") == {} and plugins.third_party(Nearest) == {}
    module(tmp_path, METHOD_MODULE)
    plugins.load_source("tb_numbers_mod:Outer.Inner")
    # as an entry point naming it by the module's alias: the source is the entry point's, not the class path
    PLUGINS["tb_numbers_inner"] = Plugin("tb_numbers_inner", "tb_numbers_mod:Alias", "tb-mod", "0.3", "entry point")
    code = plugins._files_hash.__wrapped__("tb_numbers_mod")
    assert len(code) == 64
    assert plugins.third_party("tb_numbers_inner") == {"source": "tb_numbers_mod:Alias", "distribution":
                                                       "tb-mod", "version": "0.3", "code_hash": code}
    # a class registered in this process, in a module without a file: its path, its package's distribution, no hash
    frozen = types.ModuleType("tb_numbers_nofile.sub")
    cls = _method("tb_numbers_nofile", "tb_numbers_nofile.sub", "Tool")
    frozen.Tool = cls
    monkeypatch.setitem(sys.modules, "tb_numbers_nofile.sub", frozen)
    dict.__setitem__(METHODS, "tb_numbers_nofile", cls)
    asked = []
    monkeypatch.setattr(plugins, "_distribution_of", lambda m: asked.append(m) or ("tb-nofile", "9"))
    assert plugins.third_party(cls) == {"source": "tb_numbers_nofile.sub:Tool", "distribution": "tb-nofile",
                                        "version": "9", "code_hash": None}
    assert asked == ["tb_numbers_nofile.sub"]


def test_third_party_hashes_the_top_level_package_of_a_nested_module(tmp_path, monkeypatch, clean):
    pkg = tmp_path / "tb_numbers_pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text(METHOD_MODULE.replace("tb_numbers_inner", "tb_numbers_nested"))
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    try:
        cls = plugins.load_source("tb_numbers_pkg.sub:Outer.Inner")
        assert plugins.third_party(cls)["code_hash"] == plugins._files_hash.__wrapped__("tb_numbers_pkg")
        assert plugins.third_party(cls)["code_hash"] != plugins._files_hash.__wrapped__("tb_numbers_pkg.sub")
        # a class of a module made in memory inside that package: its code is not on disk, no hash
        made = types.ModuleType("tb_numbers_pkg.made")
        made.Tool = _method("tb_numbers_made", "tb_numbers_pkg.made", "Tool")
        sys.modules["tb_numbers_pkg.made"] = made
        dict.__setitem__(METHODS, "tb_numbers_made", made.Tool)
        assert plugins.third_party(made.Tool)["code_hash"] is None
    finally:
        for name in ("tb_numbers_pkg.sub", "tb_numbers_pkg.made", "tb_numbers_pkg"):
            sys.modules.pop(name, None)


def test_origin_of_each_kind_of_method(clean):
    assert plugins.origin("nearest") == "" and plugins.origin("tb_numbers_unknown") == ""
    PLUGINS["tb_numbers_i"] = Plugin("tb_numbers_i", "m:I", "tb-i", "1.0", "entry point")
    PLUGINS["tb_numbers_j"] = Plugin("tb_numbers_j", "m:J", None, None, "module:Class")
    try:
        assert plugins.origin("tb_numbers_i") == "plugin tb-i 1.0 (m:I)"
        assert plugins.origin("tb_numbers_j") == "plugin no installed distribution (m:J)"
    finally:
        PLUGINS.pop("tb_numbers_i")
        PLUGINS.pop("tb_numbers_j")
