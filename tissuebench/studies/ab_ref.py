"""REF, the code a change is compared with (``tissuebench check --against REF``): found in git,
exported, and its own sweep run on this machine.

REF's ``tissuebench`` package is exported with ``git archive`` into a scratch folder (no
worktree bookkeeping left in the repository, any commit, branch or tag); it runs with the
dependencies installed here, first on ``PYTHONPATH`` of its own processes. Its sweep of the
same spec gives the errors HEAD's are compared with, exactly: same machine, same packages,
same references, so identical code gives bit-identical errors and any change is the code's.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import tomlkit

__all__ = ["resolve_ref", "export_ref", "run_ref_sweep", "file_at_ref", "code_env"]


def _git(repo, *args) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True)


def resolve_ref(repo, ref: str) -> tuple[str | None, str]:
    """``(commit sha, "")`` of ``ref`` in the git repository ``repo``, or ``(None, why not)``:
    not a git checkout, an unknown ref, or history cut by a shallow clone."""
    if not isinstance(ref, str) or not ref.strip() or ref.startswith("-"):
        raise ValueError(f"--against = {ref!r}: expected a git ref (a commit, branch or tag, e.g. HEAD~1)")
    if shutil.which("git") is None:
        return None, "git is not installed"
    top = _git(repo, "rev-parse", "--show-toplevel")
    if top.returncode != 0:
        return None, f"{repo} is not inside a git checkout"
    sha = _git(repo, "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}")
    if sha.returncode == 0:
        return sha.stdout.strip(), ""
    shallow = _git(repo, "rev-parse", "--is-shallow-repository").stdout.strip() == "true"
    return None, (f"{ref} is not in this clone's history (a shallow clone)" if shallow
                  else f"{ref} is not a commit of {top.stdout.strip()}")


def export_ref(repo, sha: str, dest: Path) -> Path:
    """REF's ``tissuebench`` package exported into ``dest`` (``git archive``); returns ``dest``."""
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(repo), "archive", "--format=tar", sha, "tissuebench"],
                             capture_output=True)
    if archive.returncode != 0:
        raise ValueError(f"--against: git archive {sha[:12]} failed: {archive.stderr.decode()[:300]}")
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    if not (dest / "tissuebench" / "__init__.py").is_file():
        raise ValueError(f"--against: commit {sha[:12]} has no tissuebench package")
    return dest


def file_at_ref(repo, sha: str, path) -> str | None:
    """The text of ``path`` (a file inside ``repo``'s work tree) at commit ``sha``: None when the
    file is outside the repository, ``""`` when that commit does not have it."""
    top = _git(repo, "rev-parse", "--show-toplevel").stdout.strip()
    try:
        rel = Path(path).resolve().relative_to(Path(top).resolve())
    except ValueError:
        return None
    shown = _git(repo, "show", f"{sha}:{rel.as_posix()}")
    return shown.stdout if shown.returncode == 0 else ""


def code_env(root: Path) -> dict:
    """This process's environment with ``root`` (a folder holding a tissuebench package) first
    on ``PYTHONPATH``: a child process then runs that code."""
    return {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(root)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}


# run by REF's interpreter: which of the spec's method names (registry names, the installed plugins'
# included, or "module:Class") REF's registry resolves
_KNOWN = """import json, sys
from tissuebench.rom import method_class
known = []
for name in json.loads(sys.argv[1]):
    try:
        method_class(name)
        known.append(name)
    except Exception:
        pass
print(json.dumps(known))
"""


def _methods_of(ref_root: Path, names) -> set | None:
    """The method names of ``names`` REF's registry resolves (None when REF cannot say)."""
    proc = subprocess.run([sys.executable, "-c", _KNOWN, json.dumps(sorted(names))], env=code_env(ref_root),
                          capture_output=True, text=True)
    try:
        return set(json.loads(proc.stdout.strip().splitlines()[-1])) if proc.returncode == 0 else None
    except (ValueError, IndexError):
        return None


def _spec_for(ref_root: Path, spec_text: str) -> tuple[str, list]:
    """The spec without the ``[[method]]`` entries REF does not have (a method added since:
    REF cannot run it, and would refuse the whole spec); the names left out."""
    doc = tomlkit.parse(spec_text)
    if "method" not in doc:
        return spec_text, []
    known = _methods_of(ref_root, {str(m.get("name")) for m in doc["method"]})
    if known is None:
        return spec_text, []
    dropped = sorted({m.get("name") for m in doc["method"] if m.get("name") not in known})
    if not dropped:
        return spec_text, []
    kept = tomlkit.aot()
    for m in doc["method"]:
        if m.get("name") in known:
            kept.append(m)
    doc["method"] = kept
    return tomlkit.dumps(doc), dropped


def run_ref_sweep(ref_root: Path, spec_text: str, resolution: str, case_ids: list, out: Path,
                  log=print) -> tuple[bool, str]:
    """Run the sweep ``spec_text`` (only ``case_ids``) with REF's code into ``out``;
    ``(True, note)`` when REF's sweep ran (failed units included), else ``(False, why)``."""
    text, dropped = _spec_for(ref_root, spec_text)
    note = f"methods REF does not have, left to the baseline file: {dropped}" if dropped else ""
    with tempfile.TemporaryDirectory(prefix="tissuebench-refspec.") as tmp:
        spec = Path(tmp) / "sweep.toml"
        spec.write_text(text)
        cmd = [sys.executable, "-m", "tissuebench.cli", "sweep", str(spec), "--out", str(out), "--quiet",
               "--resolution", resolution, "--cases", ",".join(case_ids)]
        log(f"REF sweep: {len(case_ids)} cases with REF's code" + (f" ({note})" if note else ""))
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, env=code_env(ref_root), capture_output=True, text=True)
        log(f"REF sweep: {time.perf_counter() - t0:.0f} s")
    if proc.returncode not in (0, 1):
        tail = " | ".join((proc.stderr or proc.stdout).strip().splitlines()[-2:])
        return False, f"REF's sweep exited {proc.returncode}: {tail[:400]}"
    return True, note
