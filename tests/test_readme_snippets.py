"""Every ``python`` block of the README runs (issue 38: the "Reduced-order models" snippet, run
verbatim, failed with ``AttributeError: 'dict' object has no attribute 'name'``; two more blocks
used names nothing defined or an import that had moved).

The blocks run in order in one namespace, as a reader runs them one after another (a block may
use what an earlier one defined), in a scratch working folder. A block whose first line is
``# readme: not run (WHY)`` (one that takes minutes) is compiled and only its imports are run.
"""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
NOT_RUN = "# readme: not run"
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line number of the block's first code line, code)`` of every python block of ``text``."""
    return [(text.count("\n", 0, m.start(1)) + 1, m.group(1)) for m in _BLOCK.finditer(text)]


def run_blocks(text: str, name: str = "README.md") -> list[int]:
    """Run the python blocks of ``text`` (module docstring); the line numbers of the blocks run in
    full. An error is re-raised naming the block's line."""
    namespace, ran = {"__name__": "__readme__"}, []
    for line, code in python_blocks(text):
        tree = ast.parse(code, filename=f"{name}:{line}")
        if code.lstrip().startswith(NOT_RUN):
            tree.body = [node for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))]
        else:
            ran.append(line)
        try:
            exec(compile(ast.increment_lineno(tree, line - 1), name, "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"{name}: the python block at line {line} raised {type(exc).__name__}: {exc}") \
                from exc
    return ran


def test_every_python_block_of_the_readme_runs(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    text = README.read_text(encoding="utf-8")
    ran = run_blocks(text)
    blocks = python_blocks(text)
    skipped = [line for line, code in blocks if code.lstrip().startswith(NOT_RUN)]
    assert len(ran) + len(skipped) == len(blocks) >= 4 and len(skipped) <= 1, (ran, skipped)


def test_a_broken_block_fails_naming_its_line_and_a_marked_one_runs_its_imports_only():
    good = "```python\nx = 1\n```\n"
    uses = "```python\ny = x + 1\n```\n"
    assert run_blocks(good + uses) == [2, 5]  # one namespace, in order (the lines of their code)
    with pytest.raises(AssertionError, match=r"the python block at line 3 raised AttributeError"):
        run_blocks("text\n```python\n{}.name\n```\n")
    marked = f"```python\n{NOT_RUN} (slow)\nimport json\nraise SystemExit('never run')\n```\n"
    assert run_blocks(marked) == []
    with pytest.raises(AssertionError, match="line 2 raised ImportError"):
        run_blocks(f"```python\n{NOT_RUN} (slow)\nfrom tissuebench.refsolvers import solve\n```\n")
