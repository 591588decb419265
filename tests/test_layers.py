"""The layer rule of the README ("each layer imports only the ones above it"), checked on every
import of the package, those inside functions included (issue 29: 41 cross-package imports hid
inside functions, among them ``studies`` drawing with ``reports``)."""
from __future__ import annotations

import ast
from pathlib import Path

import tissuebench

#: the README's table, top to bottom: a package may import itself and those before it
LAYERS = ("refsolvers", "cases", "rom", "studies", "reports")
ROOT = Path(tissuebench.__file__).parent


def _imports(path: Path):
    """``(line, imported tissuebench package)`` of every import in ``path``."""
    package = path.relative_to(ROOT).parts
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the module's package
                base = list(package[:-1])[: len(package) - node.level] if node.level > 1 else list(package[:-1])
                parts = base + (node.module.split(".") if node.module else [])
                names = [parts[0]] if parts else [alias.name for alias in node.names]
            elif node.module and node.module.split(".")[0] == "tissuebench":
                names = node.module.split(".")[1:2] or [a.name for a in node.names]
            else:
                continue
            yield from ((node.lineno, n) for n in names)
        elif isinstance(node, ast.Import):
            yield from ((node.lineno, a.name.split(".")[1]) for a in node.names
                        if a.name.startswith("tissuebench."))


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
