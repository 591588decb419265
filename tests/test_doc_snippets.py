"""Every code block of the README and of the documentation runs (issue 40).

A small runner over the fenced blocks of ``README.md`` and ``docs/**/*.md`` (the generated
reference pages and the study records of ``docs/studies/`` aside: ``NOT_PAGES``). Per page,
in a fresh temporary folder and in page order:

- ``python`` blocks run in one namespace (a later block sees the names of an earlier one);
- ``bash`` / ``sh`` blocks run with ``bash -e -o pipefail`` (the first failing command fails the
  block), the environment's ``tissuebench`` first on ``PATH``;
- ``toml`` blocks must parse (a scene or spec fragment shown on its own).

Blocks of other languages (``text``, output shown as it prints) are not code. The tutorials are
MyST notebooks that the docs build runs (myst-nb, ``{code-cell}``: a failing cell fails the
build); here their plain fenced blocks must be none but skipped ones.

Markers, an HTML comment on the line right before a block (invisible on GitHub and in the docs):

- ``<!-- snippet: skip REASON -->``: not run; the reason is required (a command that needs
  your cluster, your git history ...);
- ``<!-- snippet: file NAME -->``: the block is the content of the file ``NAME`` the page's
  later blocks use ("save it as ``NAME``"): written there (a ``toml`` block parsed first).

and for a whole page, anywhere in it:

- ``<!-- snippet-page: my-sweep -->``: its blocks run in a folder holding ``out/my-sweep``, the
  results of ``docs/howto/my-sweep.toml`` (the sweep the how-to guides use), computed once per
  session.

The README's blocks run in the default test run; the docs pages' with the tests marked slow
(they solve and sweep: tens of seconds a page).

The README's first block (its first lines: install, run, test) is special: its commands are run
without the install and without the test run (this test is part of it), i.e. its
``tissuebench run``.
"""
from __future__ import annotations

import os
import re
import runpy
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
BIN = Path(sys.executable).parent
FENCE = re.compile(r"^(?P<fence>`{3,}|~{3,})\s*(?P<info>[^\s`]*)")
MARKER = re.compile(r"^<!--\s*snippet:\s*(?P<what>\w+)\s*(?P<reason>.*?)\s*-->\s*$")
PAGE_MARKER = re.compile(r"<!--\s*snippet-page:\s*(?P<what>[\w-]+)\s*-->")
CODE = {"python": "python", "py": "python", "bash": "bash", "sh": "bash", "shell": "bash", "toml": "toml"}
SNIPPET_TIMEOUT_S = 900


def blocks(text: str) -> list[dict]:
    """The fenced blocks of a Markdown text: ``{lang, code, line, marker, reason}``."""
    lines, out, i = text.splitlines(), [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, info, start = m["fence"], m["info"], i
        body, i = [], i + 1
        while i < len(lines) and not (lines[i].startswith(fence[0] * len(fence)) and
                                      lines[i].strip() == lines[i].strip()[0] * len(lines[i].strip())):
            body.append(lines[i])
            i += 1
        before = lines[start - 1] if start else ""
        marker = MARKER.match(before.strip())
        out.append({"lang": info.lower(), "code": "\n".join(body) + "\n", "line": start + 1,
                    "marker": marker["what"] if marker else None, "reason": marker["reason"] if marker else ""})
        i += 1
    return out


def is_notebook(text: str) -> bool:
    return text.startswith("---") and "file_format: mystnb" in text.split("---", 2)[1]


# not pages of the site (conf.py's exclude_patterns): the generated reference, and docs/studies/, the
# records of studies at paper resolution written with their scripts (their commands run for hours)
NOT_PAGES = ("_generated", "_build", "studies")


def pages() -> list[Path]:
    return [ROOT / "README.md"] + sorted(p for p in DOCS.rglob("*.md")
                                         if not set(p.relative_to(DOCS).parts[:-1]) & set(NOT_PAGES))


def _page_id(path: Path) -> str:
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else path.name


def _run_bash(code: str, cwd: Path, where: str) -> None:
    env = {**os.environ, "PATH": os.pathsep.join([str(BIN), os.environ.get("PATH", "")]),
           "MPLBACKEND": "Agg", "PYVISTA_OFF_SCREEN": "true"}
    done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", code], cwd=cwd, env=env, text=True,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                          timeout=SNIPPET_TIMEOUT_S)
    assert done.returncode == 0, f"{where}: exit {done.returncode}\n{code}\n--- output ---\n{done.stdout[-4000:]}"


def _readme_first_block(code: str) -> str:
    """The README's first lines without the install and the test run: its ``tissuebench`` commands."""
    commands = [c.strip() for line in code.splitlines() for c in line.split("&&")]
    kept = [c.replace(".venv/bin/", "") for c in commands if c.startswith(".venv/bin/tissuebench")]
    assert kept, f"the README's first block runs no tissuebench command: {code!r}"
    return "\n".join(kept) + "\n"


def run_page(path: Path, cwd: Path) -> int:
    """Run every code block of ``path`` in ``cwd``; the number of blocks run."""
    text = path.read_text(encoding="utf-8")
    namespace: dict = {"__name__": f"snippets_{path.stem}"}
    ran, first = 0, True
    old = Path.cwd()
    os.chdir(cwd)
    try:
        for b in blocks(text):
            lang = CODE.get(b["lang"])
            where = f"{_page_id(path)}:{b['line']}"
            if lang is None:
                continue
            if b["marker"] == "skip":
                assert b["reason"], f"{where}: `<!-- snippet: skip -->` needs a reason"
                continue
            if b["marker"] == "file":
                assert b["reason"], f"{where}: `<!-- snippet: file -->` needs the file's name"
                if lang == "toml":
                    tomllib.loads(b["code"])
                (cwd / b["reason"]).write_text(b["code"], encoding="utf-8")
                ran += 1
                continue
            assert b["marker"] is None, f"{where}: unknown snippet marker {b['marker']!r}"
            if path.name == "README.md" and first and lang == "bash":
                b = {**b, "code": _readme_first_block(b["code"])}
            first = False
            if lang == "python":  # a file per block (tracebacks name it), run with the page's names so far
                script = cwd / f"_snippet_{path.stem}_{b['line']}.py"
                script.write_text(b["code"], encoding="utf-8")
                namespace = runpy.run_path(str(script), init_globals=namespace, run_name=namespace["__name__"])
            elif lang == "bash":
                _run_bash(b["code"], cwd, where)
            else:
                tomllib.loads(b["code"])
            ran += 1
    finally:
        os.chdir(old)
    return ran


def _kind(path: Path) -> str:
    text = path.read_text(encoding="utf-8")
    if is_notebook(text):
        return "notebook"
    m = PAGE_MARKER.search(text)
    return m["what"] if m else "plain"


_PAGES = pages()
_PLAIN = [p for p in _PAGES if _kind(p) == "plain"]
_SWEEP = [p for p in _PAGES if _kind(p) == "my-sweep"]


@pytest.fixture(scope="session")
def my_sweep(tmp_path_factory):
    """``out/my-sweep``: the results of docs/howto/my-sweep.toml, the sweep the how-to guides use."""
    folder = tmp_path_factory.mktemp("my-sweep")
    shutil.copy(DOCS / "howto" / "my-sweep.toml", folder)
    _run_bash("tissuebench sweep my-sweep.toml --out out/my-sweep --quiet", folder, "my-sweep fixture")
    return folder


def test_the_code_blocks_of_the_readme_run(tmp_path):
    run_page(ROOT / "README.md", tmp_path)


@pytest.mark.slow  # solves and sweeps: tens of seconds per page (the default run stays under 5 minutes)
@pytest.mark.parametrize("path", [p for p in _PLAIN if p.name != "README.md"], ids=_page_id)
def test_the_code_blocks_of_a_page_run(path, tmp_path):
    run_page(path, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("path", _SWEEP, ids=_page_id)
def test_the_code_blocks_of_a_how_to_guide_run_on_a_sweep(path, tmp_path, my_sweep):
    shutil.copytree(my_sweep, tmp_path, dirs_exist_ok=True)
    assert run_page(path, tmp_path) > 0


@pytest.mark.parametrize("path", [p for p in _PAGES if _kind(p) == "notebook"], ids=_page_id)
def test_a_tutorial_runs_as_a_notebook(path):
    """The docs build runs a tutorial's cells; a plain fenced code block there would not run."""
    text = path.read_text(encoding="utf-8")
    assert "```{code-cell}" in text
    plain = [b for b in blocks(text) if CODE.get(b["lang"]) and b["marker"] != "skip"]
    assert not plain, f"{_page_id(path)}: plain code blocks the build does not run, lines {[b['line'] for b in plain]}"


def test_the_runner_fails_a_broken_snippet(tmp_path):
    """The runner's negative control: a page whose second block fails is a failure naming its line."""
    page = tmp_path / "broken.md"
    page.write_text("# broken\n\n```python\nx = 1\n```\n\ntext\n\n```bash\ntissuebench cases --nonsense\n```\n")
    with pytest.raises(AssertionError, match=r"broken\.md:9: exit 2"):
        run_page(page, tmp_path)
    page.write_text("```python\nimport tissuebench\ntissuebench.no_such_name\n```\n")
    with pytest.raises(AttributeError):
        run_page(page, tmp_path)
    page.write_text("<!-- snippet: skip -->\n```bash\nfalse\n```\n")
    with pytest.raises(AssertionError, match="needs a reason"):
        run_page(page, tmp_path)
    page.write_text("<!-- snippet: skip your cluster -->\n```bash\nfalse\n```\n```text\nnot code\n```\n")
    assert run_page(page, tmp_path) == 0
