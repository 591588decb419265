"""Git repositories for the tests of ``check --against REF`` on a project's own repository:
``commit(repo, files)`` writes files (None deletes one) and commits them; ``example_repo`` is the
user's repository of the example method package (examples/bring_your_own_method) at its top."""
from __future__ import annotations

import shutil
import subprocess
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
