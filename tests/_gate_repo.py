"""Git repositories for the tests of ``check --against REF`` on a project's own repository:
``commit(repo, files)`` writes files (None deletes one) and commits them; ``example_repo`` is the
user's repository of the example method package (examples/bring_your_own_method) at its top;
``readme_history`` a repository of two commits whose content does not matter; ``recipe_repo`` and
``recipe_env`` a user's repository holding the example's CI recipe (``ci/gate.sh``) and the
environment that runs it with tissuebench stood in."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path


EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "bring_your_own_method"


def git(cwd, *args) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout.strip()


def init(repo: Path) -> Path:
    repo.mkdir(parents=True, exist_ok=True)
    git(repo, "init", "-q", "-b", "main")
    git(repo, "config", "user.email", "t@t")
    git(repo, "config", "user.name", "t")
    return repo


def commit(repo: Path, files: dict, message: str = "change") -> str:
    """Write ``files`` (path relative to ``repo`` -> text, None removes it), commit; the commit's sha."""
    for name, text in files.items():
        path = repo / name
        if text is None:
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    git(repo, "add", "-A", ".")
    git(repo, "commit", "-qm", message, "--allow-empty")
    return git(repo, "rev-parse", "HEAD")


def example_repo(root: Path, files: dict, message: str = "base") -> tuple[Path, str]:
    """``(repo, sha)``: the example package copied to ``root/podreg`` (no build leftovers), a git
    repository whose first commit adds ``files`` too."""
    repo = root / "podreg"
    shutil.copytree(EXAMPLE, repo, ignore=shutil.ignore_patterns("build", "*.egg-info", "out", "__pycache__", ".cache"))
    init(repo)
    return repo, commit(repo, files, message)


def readme_history(root: Path) -> Path:
    """``root`` made a git repository (kept when it is one) with two commits of a README: a
    ``HEAD~1`` to resolve in a repository whose content does not matter."""
    repo = init(root)
    commit(repo, {"README": "1"})
    commit(repo, {"README": "2"})
    return repo


def recipe_repo(root: Path) -> tuple[Path, str, str]:
    """``(repo, base, head)``: ``root/repo`` holding the example's CI recipe (``ci/``) and a spec,
    committed on ``main`` (``base``), then branch ``feature`` checked out one commit ahead (``head``)."""
    repo = init(root / "repo")
    shutil.copytree(EXAMPLE / "ci", repo / "ci")
    base = commit(repo, {"spec.toml": "x"}, "base")
    git(repo, "checkout", "-q", "-b", "feature")
    return repo, base, commit(repo, {"a.txt": "1"}, "feature")


#: tissuebench stood in for the CI recipe: each call appends its arguments to $TB_CALLS (one JSON
#: line); ``check`` exits $TB_CHECK_EXIT (default 0)
RECIPE_STUB = """import json, os, sys
with open(os.environ["TB_CALLS"], "a") as fh:
    fh.write(json.dumps(sys.argv[1:]) + "\\n")
sys.exit(int(os.environ.get("TB_CHECK_EXIT", "0")) if sys.argv[1] == "check" else 0)
"""


def recipe_env(root: Path) -> tuple[dict, Path]:
    """``(env, calls)``: this process's environment with ``$TISSUEBENCH`` the stand-in
    (:data:`RECIPE_STUB`, written to ``root/stub.py``) recording into ``calls`` (``root/calls.jsonl``)."""
    calls = root / "calls.jsonl"
    (root / "stub.py").write_text(RECIPE_STUB)
    return {**os.environ, "TISSUEBENCH": f"{sys.executable} {root / 'stub.py'}", "TB_CALLS": str(calls)}, calls


def recipe_calls(calls: Path) -> list:
    """The argument lists the stand-in recorded, in order ([] when it was not called)."""
    return [json.loads(line) for line in calls.read_text().splitlines()] if calls.exists() else []
