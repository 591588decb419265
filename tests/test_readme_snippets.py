"""Every ``python`` block of the README runs (issue 38: the "Reduced-order models" snippet, run
verbatim, failed with ``AttributeError: 'dict' object has no attribute 'name'``; two more blocks
used names nothing defined or an import that had moved).

The blocks run in order in one fresh interpreter, as a reader runs them one after another (a
block may use what an earlier one defined), in a scratch working folder: they are written into a
script with the README's line numbers (every other line blank), so an error names its README
line. A block whose first line is ``# readme: not run (WHY)`` (one that takes minutes) keeps only
its imports.
"""
from __future__ import annotations

import ast
import os
import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"
NOT_RUN = "# readme: not run"
_BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def python_blocks(text: str) -> list[tuple[int, str]]:
    """``(line number of the block's first code line, code)`` of every python block of ``text``."""
    return [(text.count("\n", 0, m.start(1)) + 1, m.group(1)) for m in _BLOCK.finditer(text)]


def script_of(text: str) -> str:
    """The python blocks of ``text`` at their own line numbers, every other line blank (a block
    marked not run: its import statements only)."""
    lines = text.split("\n")
    out = [""] * len(lines)
    for start, code in python_blocks(text):
        rows = code.split("\n")
        keep = range(len(rows))
        if code.lstrip().startswith(NOT_RUN):
            keep = [i for node in ast.parse(code).body if isinstance(node, (ast.Import, ast.ImportFrom))
                    for i in range(node.lineno - 1, node.end_lineno)]
        for i in keep:
            out[start - 1 + i] = rows[i]
    return "\n".join(out)


def run_readme(text: str, folder: Path) -> subprocess.CompletedProcess:
    """Run the blocks of ``text`` as ``folder/README.md.py`` in a fresh interpreter, in ``folder``."""
    script = folder / "README.md.py"
    script.write_text(script_of(text), encoding="utf-8")
    return subprocess.run([sys.executable, str(script)], cwd=folder, capture_output=True, text=True,
                          env={**os.environ, "MPLBACKEND": "Agg"})


def test_every_python_block_of_the_readme_runs(tmp_path):
    text = README.read_text(encoding="utf-8")
    blocks = python_blocks(text)
    marked = [line for line, code in blocks if code.lstrip().startswith(NOT_RUN)]
    assert len(blocks) >= 4 and len(marked) <= 1, (len(blocks), marked)
    proc = run_readme(text, tmp_path)
    assert proc.returncode == 0, f"README.md.py's line numbers are the README's:\n{proc.stderr[-3000:]}"


def test_a_broken_block_fails_naming_its_line_and_a_marked_one_keeps_its_imports_only(tmp_path):
    ok = run_readme("```python\nx = 1\n```\nprose\n```python\nassert x == 1\n```\n", tmp_path)
    assert ok.returncode == 0, ok.stderr  # one namespace, in order
    broken = run_readme("text\n```python\n{}.name\n```\n", tmp_path)
    assert broken.returncode != 0 and 'README.md.py", line 3' in broken.stderr and "AttributeError" in broken.stderr
    marked = run_readme(f"```python\n{NOT_RUN} (slow)\nimport json\nraise SystemExit('never run')\n```\n", tmp_path)
    assert marked.returncode == 0, marked.stderr
    moved = run_readme(f"```python\n{NOT_RUN} (slow)\nfrom tissuebench.refsolvers import solve\n```\n", tmp_path)
    assert moved.returncode != 0 and 'line 3' in moved.stderr and "ImportError" in moved.stderr
