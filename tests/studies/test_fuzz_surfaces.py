"""Property-based fuzzing of the option surfaces of issue 37: ``check --against REF``, ``--cache
URL`` and ``--workers N`` (with ``--executor`` and ``--scheduler``).

Every example is accepted, or refused with a ValueError whose message is one line naming the
option and the value: never another exception (a traceback), never a hang. The validation
functions are fuzzed directly (:func:`~tissuebench.gate.ref.check_ref_text`,
:func:`~tissuebench.reference.location.check_cache_url`,
:func:`~tissuebench.studies.executors.check_executor`): the profile's 200 examples each in the
default run, 2 000 in the slow variants (``_long``: CI's ``pytest -m slow``) and 10 000 with
``--hypothesis-profile=fuzz`` (``tox -e fuzz``). An accepted value is also checked for what
acceptance promises (a ref git can be handed, a protocol of a writable file system, a worker
count within the bound). The slow tests go further: REF strings resolved by git in a
repository and its shallow clone (2 000; 10 000 in the fuzz profile), and the three options
through the command line (300; 10 000).
The counts (tried / accepted / rejected) are printed at the end of the module.
"""
from __future__ import annotations

import contextlib
import io
import subprocess

import fsspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _fuzz import HOSTILE_STRINGS, Tally
from tissuebench.cli import main
from tissuebench.reference.cache_protocols import WRITABLE_PROTOCOLS, check_cache_url
from tissuebench.gate.ref import check_ref_text, resolve_ref
from tissuebench.studies.executors import EXECUTORS, check_executor, max_workers

pytestmark = pytest.mark.fuzz

FUZZ_PROFILE = settings.default.max_examples >= 1000
_HEALTH = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]


def _examples(default: int) -> int:
    return 10_000 if FUZZ_PROFILE else default


# the default run: the profile's examples (200; 10 000 in the fuzz profile); CI's slow pass: 2 000
FAST = settings(max_examples=_examples(settings.default.max_examples), suppress_health_check=_HEALTH, deadline=None)
LONG = settings(max_examples=2_000, suppress_health_check=_HEALTH, deadline=None)
# through git or the command line: a process or a parser per example
CLI = settings(max_examples=_examples(300), suppress_health_check=_HEALTH, deadline=None)


def _long(test):
    """The 2 000-example run of a fast property (CI's slow pass; in the fuzz profile the fast
    variant runs 10 000)."""
    return pytest.mark.slow(pytest.mark.skipif(FUZZ_PROFILE, reason="the fuzz profile runs 10 000 examples in the "
                                               "fast variant")(test))


@pytest.fixture(scope="module", autouse=True)
def fuzz_report():
    yield
    Tally.write()


def _verdict(test: str, call, option: str, value):
    """Run ``call``: 'accepted' (and what it returned), or 'rejected' for a one-line ValueError
    whose message starts ``<option> = `` and holds ``value`` (its repr or text); anything else
    fails the test. ``option`` may be a tuple of (option, value) pairs: the message names one."""
    pairs = option if isinstance(option, tuple) else ((option, value),)
    try:
        out = call()
    except ValueError as exc:
        msg = str(exc)
        named = any(msg.startswith(f"{o} = ") and (repr(v) in msg or str(v) in msg) for o, v in pairs)
        if "\n" in msg or not named:
            Tally.add(test, "other")
            raise AssertionError(f"the message does not name {pairs} on one line: {msg!r}") from exc
        Tally.add(test, "rejected")
        return "rejected", None
    except BaseException:
        Tally.add(test, "other")
        raise
    Tally.add(test, "accepted")
    return "accepted", out


# ------------------------------------------------------------------------------ --against REF
REV_PARTS = ["HEAD", "main", "master", "@", "FETCH_HEAD", "ORIG_HEAD", "v1.0", "refs/heads/main", "origin/main",
             "0" * 40, "deadbeef", "a" * 41, "HEAD~1", "HEAD^", "HEAD^2", "HEAD~99999999999999999999", "@{-1}",
             "HEAD@{1}", "HEAD@{yesterday}", "HEAD^{tree}", "HEAD^{/fix}", ":/message", "HEAD:README.md", "A..B",
             "A...B", "^HEAD", "HEAD^!", "HEAD^@", "--", "-", "--upload-pack=touch x", "--output=/tmp/x", "-n1",
             "--all", "--exec-path", "@{upstream}", "HEAD@{-1}", "stash@{0}", ".", "..", "/", "refs/", "*", "?",
             "[", "~", "^", ":", "\\", "HEAD\x00", "HEAD\n", "\t", " HEAD", "HEAD ", "HEAD~1 ", "héad", "HEAD\x7f"]


def refs():
    """Random text, git revision syntax, option-like and control-character strings."""
    part = st.one_of(st.sampled_from(REV_PARTS), st.text(max_size=12), st.sampled_from(HOSTILE_STRINGS))
    joined = st.lists(part, min_size=1, max_size=3).map("".join)
    return st.one_of(joined, st.text(max_size=40), st.binary(max_size=20).map(lambda b: b.decode("latin-1")),
                     st.sampled_from(["x" * 1024, "x" * 1025, "~" * 5000]), st.none(), st.integers(), st.booleans())


def _ref_property(ref):
    verdict, out = _verdict("--against: check_ref_text", lambda: check_ref_text(ref), "--against", ref)
    if verdict == "accepted":  # what git is then handed: no option, no control character
        assert out == ref and ref.strip() and not ref.lstrip().startswith("-") and len(ref) <= 1024
        assert all(ord(c) >= 0x20 and ord(c) != 0x7F for c in ref)


@FAST
@given(ref=refs())
def test_against_refs_are_accepted_or_refused_naming_the_option(ref):
    _ref_property(ref)


@_long
@LONG
@given(ref=refs())
def test_against_refs_are_accepted_or_refused_naming_the_option_long(ref):
    _ref_property(ref)


def _git(cwd, *args):
    subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True)


@pytest.fixture(scope="module")
def repos(tmp_path_factory):
    """A repository of three commits (a branch, a tag) and a shallow clone of it."""
    root = tmp_path_factory.mktemp("fuzz_refs")
    repo = root / "repo"
    (repo / "tissuebench").mkdir(parents=True)
    _git(repo, "init", "-q", "-b", "main")
    _git(repo, "config", "user.email", "t@t")
    _git(repo, "config", "user.name", "t")
    for k in range(3):
        (repo / "tissuebench" / "__init__.py").write_text(f"VERSION = {k}\n")
        _git(repo, "add", ".")
        _git(repo, "commit", "-qm", f"fix {k}")
    _git(repo, "tag", "v1.0")
    shallow = root / "shallow"
    _git(root, "clone", "-q", "--depth", "1", f"file://{repo}", str(shallow))
    return repo, shallow


@pytest.mark.slow
@settings(LONG, max_examples=_examples(2_000))
@given(ref=refs(), which=st.sampled_from(["repo", "shallow"]))
def test_against_refs_resolve_in_git_or_are_refused_naming_them(repos, ref, which):
    """Through git: a commit, the shallow clone's fallback (said), or a one-line ValueError naming
    the ref (and, when git cannot resolve it, the repository searched)."""
    repo = dict(zip(("repo", "shallow"), repos))[which]
    verdict, out = _verdict("--against: resolve_ref (git)", lambda: resolve_ref(repo, ref), "--against", ref)
    if verdict == "accepted":
        sha, why = out
        assert (sha is not None and len(sha) == 40 and why == "") or \
            (sha is None and which == "shallow" and "a shallow clone" in why)


# ------------------------------------------------------------------------------ --cache URL
PROTOCOLS = sorted(set(fsspec.available_protocols()) | WRITABLE_PROTOCOLS | {"file", "local", "nosuchproto", "S3",
                                                                             "s3 ", "", "a:b"})


def cache_urls():
    rest = st.one_of(st.text(max_size=20), st.sampled_from(HOSTILE_STRINGS + ["bucket/cache", "", "/", "a::b"]))
    url = st.builds(lambda p, sep, r: f"{p}{sep}{r}", st.sampled_from(PROTOCOLS),
                    st.sampled_from(["://", ":/", ":", "::", "://x::", "//"]), rest)
    chained = st.builds(lambda a, b: f"{a}::{b}", url, url)
    return st.one_of(url, chained, st.text(max_size=30), st.sampled_from(HOSTILE_STRINGS), st.none(),
                     st.integers(), st.floats(), st.binary(max_size=10))


def _cache_property(url):
    named = (("--cache", url), ("--cache", url.strip() if isinstance(url, str) else url))  # as given, or stripped
    verdict, out = _verdict("--cache: check_cache_url", lambda: check_cache_url(url), named, None)
    if verdict == "accepted":  # a local path, or a writable file system's URL whose package is here
        protocol, _ = fsspec.core.split_protocol(out)
        assert out == url.strip() and "::" not in out and protocol in {None, "file", "local"} | WRITABLE_PROTOCOLS


@FAST
@given(url=cache_urls())
def test_cache_urls_are_accepted_or_refused_naming_the_option(url):
    _cache_property(url)


@_long
@LONG
@given(url=cache_urls())
def test_cache_urls_are_accepted_or_refused_naming_the_option_long(url):
    _cache_property(url)


def _cli(argv) -> tuple[int, str]:
    """``tissuebench ARGV``: its exit status and stderr (argparse's own errors are SystemExit 2)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code
    return code, err.getvalue()


@pytest.mark.slow
@CLI
@given(url=st.one_of(cache_urls().filter(lambda u: isinstance(u, str) and "://" in u),
                     st.sampled_from(["zip://x", "data://abc", "dask://x", "memory://fuzz/cache"])))
def test_cache_ls_takes_a_url_or_exits_2_on_one_line(url):
    code, err = _cli(["cache", "ls", "--cache", url])
    Tally.add("--cache: cache ls (CLI)", "accepted" if code == 0 else "rejected")
    assert code in (0, 2), err
    if code == 2:
        assert err.startswith("tissuebench: error: --cache = ") and err.count("\n") == 1, err
    else:
        protocol, _ = fsspec.core.split_protocol(url.strip())  # None: a local path (':/x' is one)
        assert protocol in WRITABLE_PROTOCOLS | {None, "file", "local"}


# ------------------------------------------------------------------------------ --workers N
def workers():
    return st.one_of(st.none(), st.integers(-5, 2 * max_workers() + 5), st.integers(), st.sampled_from(
        [0, 1, max_workers(), max_workers() + 1, 10 ** 6, 2 ** 63, -(2 ** 63)]), st.booleans(), st.floats(),
        st.text(max_size=5))


def schedulers():
    host = st.one_of(st.sampled_from(["127.0.0.1", "[::1]", "localhost", "node-3.cluster.local", "", "h_x", "-h",
                                      "h.", "[::1", "1.2.3.4.5"]), st.text(max_size=8))
    port = st.one_of(st.integers(-1, 70000).map(str), st.sampled_from(["", "08786", "8786/x", "x", "99999"]))
    address = st.builds(lambda s, h, p: f"{s}{h}:{p}", st.sampled_from(["tcp://", "tls://", "inproc://", "ucx://",
                                                                        "ws://", "", "tcp:/"]), host, port)
    return st.one_of(st.none(), address, st.text(max_size=20), st.sampled_from(HOSTILE_STRINGS), st.integers())


def _executor_property(name, n, scheduler):
    options = (("executor", name), ("workers", n), ("scheduler", scheduler))
    verdict, _ = _verdict("--workers/--scheduler: check_executor", lambda: check_executor(name, n, scheduler),
                          options, None)
    if verdict == "accepted":  # a worker count a local pool can start, where one is started
        assert name in EXECUTORS
        assert n is None or (type(n) is int and 1 <= n <= max_workers() and name != "serial" and scheduler is None)
        assert scheduler is None or (name == "dask" and scheduler.startswith("tcp://"))


# mostly plausible values (a valid executor, no scheduler, a count near the bound), so that both
# sides of each rule are reached
EXECUTOR_NAMES = st.one_of(st.sampled_from(EXECUTORS), st.sampled_from(EXECUTORS), st.text(max_size=8))
WORKERS = st.one_of(st.none(), st.integers(1, max_workers() + 2), workers())
SCHEDULERS = st.one_of(st.none(), st.none(), schedulers())


@FAST
@given(name=EXECUTOR_NAMES, n=WORKERS, scheduler=SCHEDULERS)
def test_workers_and_schedulers_are_accepted_or_refused_naming_the_option(name, n, scheduler):
    _executor_property(name, n, scheduler)


@_long
@LONG
@given(name=EXECUTOR_NAMES, n=WORKERS, scheduler=SCHEDULERS)
def test_workers_and_schedulers_are_accepted_or_refused_naming_the_option_long(name, n, scheduler):
    _executor_property(name, n, scheduler)


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    path = tmp_path_factory.mktemp("fuzz_workers") / "s.toml"
    path.write_text('[sweep]\nname = "s"\n[[case]]\nname = "cornea_pinch"\n[[method]]\nname = "nearest"\n')
    return path


@pytest.mark.slow
@CLI
@given(executor=st.sampled_from(list(EXECUTORS) + ["threads"]), n=st.one_of(st.none(), st.integers(-2, 20),
       st.sampled_from(["x", "1.5", "", "1e3", "99999999999999999999"])), scheduler=st.one_of(st.none(), schedulers()))
def test_workers_through_the_command_line_exit_2_naming_the_option(spec, executor, n, scheduler):
    """``sweep SPEC --cases nope`` with the options: a bad option is named (before the spec is
    read), a good one lets the spec be read, and ``--cases`` is named. Nothing runs."""
    argv = ["sweep", str(spec), "--cases", "nope", "--executor", executor, "--quiet"]
    argv += [f"--workers={n}"] if n is not None else []
    argv += [f"--scheduler={scheduler}"] if scheduler is not None else []
    code, err = _cli(argv)
    assert code == 2, err
    last = err.strip().splitlines()[-1]
    if err.startswith("usage:"):  # argparse: a value that is not an integer (its usage line, then the error)
        Tally.add("--workers: sweep (CLI)", "rejected")
        assert "argument --workers: invalid int value" in last, err
        return
    assert err.count("\n") == 1 and last.startswith("tissuebench: error: "), err
    named = last.removeprefix("tissuebench: error: ").split(" = ", 1)[0]
    Tally.add("--workers: sweep (CLI)", "accepted" if named == "--cases" else "rejected")
    assert named in ("executor", "workers", "scheduler", "--cases"), err
