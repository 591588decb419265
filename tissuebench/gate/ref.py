"""REF, the code a change is compared with (``tissuebench check --against REF``): found in git,
exported, and its own sweep run on this machine.

REF's packages of the project under test (:mod:`.project`: tissuebench's own when the project
is tissuebench, :func:`export_ref`; a user's method package otherwise) are exported with ``git
archive`` into a scratch folder (no worktree bookkeeping left in the repository, any commit,
branch or tag); they run with the dependencies installed here, first on ``PYTHONPATH`` of REF's
own processes (:class:`~.sides.Code`), which are checked to import them and not HEAD's copies.
Its sweep of the same spec gives the errors HEAD's are compared with, exactly: same machine,
same packages, same references, so identical code gives bit-identical errors and any change is
the code's.
"""
from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import tomlkit

from ..cases.scene import list_cases
from .sides import MODULE_FILES, Code, as_code, code_env, foreign
from .scratch import child_options

__all__ = ["check_ref_text", "resolve_ref", "export_ref", "ref_import_error", "portable_spec_text", "run_ref_sweep",
           "file_at_ref", "code_env"]


def _git(repo, *args) -> subprocess.CompletedProcess:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True)


MAX_REF_CHARS = 1024  # a git revision longer than this is not one a user typed
_SHA = re.compile(r"[0-9a-f]{40}|[0-9a-f]{64}")  # a commit's name, SHA-1 or SHA-256


def check_ref_text(ref) -> str:
    """``ref`` when it can be handed to git as a revision, else ValueError naming ``--against`` and
    the value: not a string, empty, option-like (``-x``: git would read it as an option), a control
    character (NUL, a newline: not in any ref name) or longer than :data:`MAX_REF_CHARS`."""
    if (not isinstance(ref, str) or not ref.strip() or ref.lstrip().startswith("-") or len(ref) > MAX_REF_CHARS
            or any(ord(c) < 0x20 or ord(c) == 0x7F for c in ref)):
        raise ValueError(f"--against = {ref!r}: expected a git ref (a commit, branch or tag, e.g. HEAD~1)")
    return ref


def resolve_ref(repo, ref: str) -> tuple[str | None, str]:
    """``(commit sha, "")`` of ``ref`` in the git repository ``repo``; ``(None, why)`` only when
    ``repo`` is a shallow clone that cannot resolve it (its history is cut: the gate's documented
    fallback to the baseline file). Every other failure is a ValueError naming the ref and the
    repository searched: git missing, ``repo`` not in a git checkout, a ref that is not a commit
    there (a typo must not pass as a shallow clone)."""
    check_ref_text(ref)
    if shutil.which("git") is None:
        raise ValueError(f"--against = {ref!r}: git is not installed (needed to find {ref} in {repo})")
    top = _git(repo, "rev-parse", "--show-toplevel")
    if top.returncode != 0:
        raise ValueError(f"--against = {ref!r}: {repo} is not inside a git checkout (no repository to find "
                         f"{ref} in)")
    sha = _git(repo, "rev-parse", "--verify", "--quiet", f"{ref}^{{commit}}")
    if sha.returncode == 0 and _SHA.fullmatch(sha.stdout.strip()):
        return sha.stdout.strip(), ""
    if sha.returncode == 0:  # '^HEAD' verifies as a negated revision, '^<sha>': not one commit
        raise ValueError(f"--against = {ref!r}: not a single commit (git rev-parse gives {sha.stdout.strip()[:60]!r} "
                         f"in {top.stdout.strip()})")
    where = top.stdout.strip()
    if _git(repo, "rev-parse", "--is-shallow-repository").stdout.strip() == "true":
        return None, f"{ref} is not in the history of {where}, a shallow clone"
    raise ValueError(f"--against = {ref!r}: not a commit of the repository {where} (a branch, tag or commit "
                     f"that git rev-parse resolves there, e.g. HEAD~1)")


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


# run by REF's interpreter: which of the spec's method names (registry names, the installed plugins'
# included, or "module:Class") REF's registry resolves, each with its class's module, and where the
# modules of the project's packages (TOPS) came from
_KNOWN = """import json, sys
from tissuebench.rom import method_class
known = {}
for name in json.loads(sys.argv[1]):
    try:
        known[name] = method_class(name).__module__
    except Exception:
        pass
TOPS = set(json.loads(sys.argv[2]))
print(json.dumps({"known": known, "files": %s}))
""" % MODULE_FILES


def _methods_of(code: Code, names) -> dict | None:
    """``{name: why REF cannot run it}`` for the method names of ``names`` REF's processes do not
    resolve to REF's code: unknown there, or of a package of the project that those processes import
    from elsewhere (HEAD's copy: REF has no such package, or an import hook served it); None when
    REF cannot say."""
    code = as_code(code)
    proc = subprocess.run([sys.executable, "-c", _KNOWN, json.dumps(sorted(names)), json.dumps(sorted(code.packages))],
                          env=code_env(code), capture_output=True, text=True, **child_options())
    try:
        said = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.returncode == 0 else None
        known, files = (said["known"], said["files"]) if said is not None else (None, None)
    except (ValueError, IndexError, KeyError, TypeError):
        return None
    if not isinstance(known, dict) or not isinstance(files, dict):
        return None
    elsewhere = foreign(files, code)
    out = {}
    for name in sorted(names):
        top = str(known.get(name, "")).split(".")[0]
        if name not in known:
            out[name] = "unknown to REF's code"
        elif top in elsewhere:
            out[name] = f"not REF's code: {elsewhere[top]}"
    return out


def _spec_for(ref: Code | Path, spec_text: str) -> tuple[str, dict]:
    """The spec without the ``[[method]]`` entries REF cannot run with its own code (a method added
    since: REF would refuse the whole spec; or a package REF's processes would take from HEAD);
    ``{name left out: why}``."""
    doc = tomlkit.parse(spec_text)
    if "method" not in doc:
        return spec_text, {}
    dropped = _methods_of(as_code(ref), {str(m.get("name")) for m in doc["method"]})
    if not dropped:
        return spec_text, {}
    kept = tomlkit.aot()
    for m in doc["method"]:
        if str(m.get("name")) not in dropped:
            kept.append(m)
    doc["method"] = kept
    return tomlkit.dumps(doc), dropped


def run_ref_sweep(ref: Code | Path, spec_text: str, resolution: str, case_ids: list, out: Path,
                  log=print) -> tuple[bool, str]:
    """Run the sweep ``spec_text`` (only ``case_ids``) with REF's code (:class:`~.sides.Code`, or
    a folder holding REF's tissuebench) into ``out``, its spec written beside it (``out`` +
    ``.toml``); ``(True, note)`` when REF's sweep ran (failed units included), else ``(False,
    why)``. REF's process dies with this one (:mod:`.scratch`)."""
    text, dropped = _spec_for(ref, spec_text)
    note = ("methods REF cannot run with its own code, left to the baseline file: " + "; ".join(
        f"{name} ({why})" for name, why in dropped.items())) if dropped else ""
    if dropped and not tomlkit.parse(text).get("method"):
        return False, "REF cannot run any method of the spec: " + note.split(": ", 1)[1]
    spec = Path(f"{out}.toml")
    spec.write_text(text)
    cmd = [sys.executable, "-m", "tissuebench.cli", "sweep", str(spec), "--out", str(out), "--quiet",
           "--resolution", resolution, "--cases", ",".join(case_ids)]
    log(f"REF sweep: {len(case_ids)} cases with REF's code" + (f" ({note})" if note else ""))
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=code_env(ref), capture_output=True, text=True, **child_options())
    log(f"REF sweep: {time.perf_counter() - t0:.0f} s")
    if proc.returncode not in (0, 1):
        tail = " | ".join((proc.stderr or proc.stdout).strip().splitlines()[-2:])
        return False, f"REF's sweep exited {proc.returncode}: {tail[:400]}"
    return True, note


# what REF's sweep imports first (a REF that cannot import them cannot run the sweep at all), then the
# project's other packages REF has (argv[1]), and the file of every module of the project's packages
# imported (TOPS): an editable install's import hook hands out HEAD's module for a name REF's package lacks
_REF_IMPORTS = """import importlib, json, sys
import tissuebench, tissuebench.cli, tissuebench.rom, tissuebench.studies.sweep
for name in json.loads(sys.argv[1]):
    importlib.import_module(name)
TOPS = set(json.loads(sys.argv[2]))
print()
print(json.dumps(%s))
""" % MODULE_FILES


def ref_import_error(ref: Code | Path) -> str:
    """``""`` when REF's code (:class:`~.sides.Code`, or a folder holding REF's tissuebench)
    imports in REF's processes, else why not, to follow "REF's code": "failed to import: " and
    the last line of the error (a SyntaxError, an ImportError: REF cannot run anything, which is
    not a result to compare), or the module those processes import from elsewhere than REF's
    package (tissuebench, and each package of the project REF has)."""
    code = as_code(ref)
    others = sorted(n for n, folder in code.packages.items() if folder is not None and n != "tissuebench")
    proc = subprocess.run([sys.executable, "-c", _REF_IMPORTS, json.dumps(others), json.dumps(sorted(code.packages))],
                          env=code_env(code), capture_output=True, text=True, **child_options())
    if proc.returncode != 0:
        lines = [ln.strip() for ln in (proc.stderr or proc.stdout or "").splitlines() if ln.strip()]
        return "failed to import: " + (lines[-1][:400] if lines else f"the interpreter exited {proc.returncode}")
    try:
        files = json.loads(proc.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        files = None
    if not isinstance(files, dict):
        return f"did not say where it imports tissuebench from ({proc.stdout[-200:]!r})"
    elsewhere = {top: why for top, why in foreign(files, code).items() if code.packages.get(top) is not None}
    if elsewhere:
        return "is not what REF's processes import: " + "; ".join(elsewhere.values())
    return ""


def portable_spec_text(manifest: dict) -> str:
    """The sweep's spec (``_sweep.json``: ``spec_text``) as it reads from any folder: a case named
    by a scene file relative to the spec's own folder (the spec ``sweep --scene`` writes beside
    its results) is given the absolute path the sweep resolved it to (``cases``, by id; every case
    of the same file, selected by ``--cases`` or not). REF's sweep and the A/B load the spec from a
    scratch folder, where the relative path means nothing."""
    text = manifest["spec_text"]
    try:
        doc = tomlkit.parse(text)
    except Exception:  # noqa: BLE001 - a damaged spec: left as it is, for the spec loader to name
        return text
    raw = doc.get("case")
    cases = manifest.get("cases")
    if not isinstance(raw, list) or not isinstance(cases, list):
        return text
    resolved = {c.get("id"): c.get("name") for c in cases if isinstance(c, dict) and isinstance(c.get("id"), str)}
    catalogue, names = set(list_cases()), {}
    for c in raw:
        name = c.get("name") if isinstance(c, dict) else None
        if not isinstance(name, str) or name in catalogue or Path(name).is_absolute():
            continue
        cid = c.get("id", Path(name).stem)
        full = resolved.get(cid) if isinstance(cid, str) else None
        if isinstance(full, str) and Path(full).is_absolute():
            names[name] = full
    if not names:
        return text
    for c in raw:
        if isinstance(c, dict) and isinstance(c.get("name"), str) and c["name"] in names:
            c["name"] = names[c["name"]]
    return tomlkit.dumps(doc)
