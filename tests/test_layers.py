"""The layer rule of docs/explanation/architecture.md ("each layer imports only the ones above it"), checked on every
import of the package, those inside functions included (issue 29: 41 cross-package imports hid
inside functions, among them ``studies`` drawing with ``reports``); imports of another
package inside a function say why (a ``# lazy:`` comment), except in ``cli.py``, whose
docstring states its one reason; and no two modules import each other, directly or through
others (issue 55: circles inside rooms, e.g. ``rom/base.py`` -> ``registry.py`` -> ``plugins.py``
-> ``registry.py``, hid inside functions too), the imports under ``if TYPE_CHECKING:`` aside
(annotations only: never run). An old import path kept for one release (``tissuebench._moved``)
names its new module by a string, and no module of the package reads one."""
from __future__ import annotations

import ast
from pathlib import Path

import tissuebench

#: the layout table of docs/explanation/architecture.md, top to bottom: a package may import itself and those before it
LAYERS = ("refsolvers", "cases", "reference", "rom", "studies", "reports", "gate", "testing")
ROOT = Path(tissuebench.__file__).parent


def _node_imports(node, package):
    """The tissuebench packages one import statement of a module at ``package`` (its path
    parts below ``ROOT``) names."""
    if isinstance(node, ast.ImportFrom):
        if node.level:  # relative: resolve against the module's package
            base = list(package[:-1])[: len(package) - node.level] if node.level > 1 else list(package[:-1])
            parts = base + (node.module.split(".") if node.module else [])
            return [parts[0]] if parts else [alias.name for alias in node.names]
        if node.module and node.module.split(".")[0] == "tissuebench":
            return node.module.split(".")[1:2] or [a.name for a in node.names]
        return []
    if isinstance(node, ast.Import):
        return [a.name.split(".")[1] for a in node.names if a.name.startswith("tissuebench.")]
    return []


def _imports(path: Path):
    """``(line, imported tissuebench package)`` of every import in ``path``."""
    package = path.relative_to(ROOT).parts
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        yield from ((node.lineno, n) for n in _node_imports(node, package))


def _function_imports(path: Path):
    """``(line, package, has_reason)`` of every import of another tissuebench layer inside a
    function of ``path``; the reason is a ``# lazy:`` comment on the import or the 3 lines above."""
    package = path.relative_to(ROOT).parts
    source = path.read_text(encoding="utf-8")
    lines = source.splitlines()
    for fn in ast.walk(ast.parse(source)):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                for name in _node_imports(node, package):
                    if name in LAYERS and name != package[0]:
                        around = lines[max(0, node.lineno - 4):node.lineno]
                        yield node.lineno, name, any("# lazy:" in text for text in around)


def test_no_layer_imports_a_layer_below_it():
    broken = []
    for path in sorted(ROOT.rglob("*.py")):
        layer = path.relative_to(ROOT).parts[0]
        if layer not in LAYERS:
            continue  # cli.py, __init__.py: the top, they may import anything
        allowed = set(LAYERS[: LAYERS.index(layer) + 1])
        broken += [f"{path.relative_to(ROOT)}:{line} imports {name}" for line, name in _imports(path)
                   if name in LAYERS and name not in allowed]
    assert not broken, "\n".join(broken)


def test_the_checker_sees_an_import_inside_a_function(tmp_path, monkeypatch):
    """The test above can fail: a ``reports`` import inside a ``studies`` function is found."""
    fake = tmp_path / "studies" / "x.py"
    fake.parent.mkdir()
    fake.write_text("def f():\n    from ..reports import html\n    from tissuebench.reports.gate import check\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    assert [n for _, n in _imports(fake)] == ["reports", "reports"]


def test_imports_of_another_package_inside_a_function_say_why():
    """Imports belong at the module top; one inside a function hides a dependency (the layer
    rule was broken behind 41 of them), so each states its reason. ``cli.py`` imports the
    package's subcommand modules in its handlers, so a command loads only what it runs."""
    assert "imported inside the handlers" in (ROOT / "cli.py").read_text(encoding="utf-8")
    silent = [f"{path.relative_to(ROOT)}:{line} imports {name}" for path in sorted(ROOT.rglob("*.py"))
              if path.name != "cli.py" or path.parent != ROOT
              for line, name, why in _function_imports(path) if not why]
    assert not silent, "\n".join(silent)


def test_the_reason_checker_can_fail(tmp_path, monkeypatch):
    fake = tmp_path / "rom" / "x.py"
    fake.parent.mkdir()
    fake.write_text("def f():\n    from ..cases import load\n\n\ndef g():\n"
                    "    # lazy: gmsh is an optional extra\n    from ..cases import builders\n"
                    "    from .base import Training\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path)
    assert list(_function_imports(fake)) == [(2, "cases", False), (7, "cases", True)]


# ------------------------------------------------------------------ circles between modules
def _module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _type_checking(node) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _imported_modules(path: Path, root: Path, modules: set) -> set:
    """The modules of the package (names in ``modules``) that ``path`` imports, at its top or
    inside a function; ``from package import name`` counts the module ``package.name`` where there
    is one, else ``package``. Imports under ``if TYPE_CHECKING:`` are left out (never run)."""
    name = _module_name(path, root)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    found = set()

    def nearest(module: str) -> str | None:
        while module and module not in modules:
            module = module.rpartition(".")[0]
        return module or None

    def visit(node):
        if isinstance(node, ast.If) and _type_checking(node):
            for child in node.orelse:
                visit(child)
            return
        if isinstance(node, ast.ImportFrom):
            base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else [])) \
                if node.level else (node.module or "")
            found.update(filter(None, (f"{base}.{a.name}" if f"{base}.{a.name}" in modules else nearest(base)
                                       for a in node.names)))
        elif isinstance(node, ast.Import):
            found.update(filter(None, (nearest(a.name) for a in node.names)))
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(ast.parse(path.read_text(encoding="utf-8")))
    return found - {name}


def _import_graph(root: Path) -> dict:
    """``{module: modules of the package it imports}`` of every module under ``root``."""
    paths = {_module_name(p, root): p for p in sorted(root.rglob("*.py"))}
    return {name: _imported_modules(path, root, set(paths)) for name, path in paths.items()}


def _circles(graph: dict) -> list:
    """The strongly connected components of more than one module (Tarjan), each sorted."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            part = []
            while not part or part[-1] != v:
                part.append(stack.pop())
                on.discard(part[-1])
            if len(part) > 1:
                out.append(sorted(part))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_two_modules_import_each_other_directly_or_through_others():
    """Each room's files import one way: a contract module below its users (issue 55)."""
    graph = _import_graph(ROOT)
    circles = _circles(graph)
    assert not circles, "\n".join(" <-> ".join(c) + ": " + "; ".join(f"{m} imports {sorted(graph[m] & set(c))}"
                                                                      for m in c) for c in circles)


def test_the_circle_checker_sees_a_circle_through_a_function_and_not_through_type_checking(tmp_path):
    """The test above can fail: a circle closed by an import inside a function is one, a chain is
    none, and an import under ``if TYPE_CHECKING:`` closes none."""
    pkg = tmp_path / "tissuebench"
    (pkg / "room").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "room" / "__init__.py").write_text("")
    (pkg / "room" / "contract.py").write_text("import numpy\n")
    (pkg / "room" / "user.py").write_text("from .contract import X\nfrom tissuebench.room import helper\n")
    (pkg / "room" / "helper.py").write_text("from typing import TYPE_CHECKING\n\nif TYPE_CHECKING:\n"
                                            "    from .user import Y\nelse:\n    from . import contract\n")
    assert _circles(_import_graph(pkg)) == []
    assert _import_graph(pkg)["tissuebench.room.helper"] == {"tissuebench.room.contract"}
    (pkg / "room" / "contract.py").write_text("def f():\n    from ..room.user import Y\n")
    assert _circles(_import_graph(pkg)) == [["tissuebench.room.contract", "tissuebench.room.helper",
                                            "tissuebench.room.user"]]


# ------------------------------------------------------------------ the old paths of moved names
def _old_paths(root: Path) -> dict:
    """``{old module: new module (every name) or {name: new module}}`` of every module whose
    names moved (its ``__getattr__ = moved(__name__, NEW)``)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if (isinstance(node, ast.Assign) and [getattr(t, "id", None) for t in node.targets] == ["__getattr__"]
                    and isinstance(node.value, ast.Call) and getattr(node.value.func, "id", None) == "moved"):
                new = node.value.args[1]
                if isinstance(new, ast.DictComp):  # {name: module for name in (...)}
                    new = {n: new.value.value for n in ast.literal_eval(new.generators[0].iter)}
                out[_module_name(path, root)] = ast.literal_eval(new) if isinstance(new, ast.AST) else new
    return out


def test_no_module_of_the_package_reads_an_old_path():
    """An old path imports its new module when a name is read there, which no layer check sees:
    the package itself never reads one, so those imports only ever run in a user's code."""
    old = _old_paths(ROOT)
    assert "tissuebench.studies.latency_ab" in old and "tissuebench.reports.gate" in old  # the checker sees them
    modules = {_module_name(p, ROOT): p for p in sorted(ROOT.rglob("*.py"))}
    readers = []
    for name, path in modules.items():
        package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom):
                base = ".".join(package[:len(package) - node.level + 1] + ([node.module] if node.module else [])) \
                    if node.level else (node.module or "")
                for a in node.names:
                    moved = old.get(f"{base}.{a.name}") if f"{base}.{a.name}" in old else old.get(base)
                    if isinstance(moved, str) or (isinstance(moved, dict) and a.name in moved):
                        readers.append(f"{name}:{node.lineno} reads {base}.{a.name}")
            elif isinstance(node, ast.Import):
                readers += [f"{name}:{node.lineno} imports {a.name}" for a in node.names
                            if isinstance(old.get(a.name), str)]
    assert not readers, "\n".join(readers)
