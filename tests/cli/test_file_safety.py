"""Files the tool writes (issue 37, second hostile probe, items 6-8, and the scene picture).

Never inside the installed package; never over a device, a FIFO, a folder or a loop of links
(a link is written through: its target replaced, the link kept); new files and folders with
the mode the umask gives, a rewritten file with its own; no picture replaced without --force.
Devices are reached only through symbolic links to /dev/null made here (the tool is pointed at
the link, and /dev/null is checked to be a character device afterwards); FIFOs are made here.
Every test runs as root too: it asserts what appears on disk, not a permission error.
"""
from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

import pandas as pd
import pytest

import tissuebench.cases
import tissuebench.reports.scene_figure as scene_figure
from _report_store import build_store
from tissuebench.cli import main
from tissuebench.studies.atomic_files import OutputPathError, new_folder, write_text
from tissuebench.studies.atomic_folders import atomic_directory, check_output_location, write_json_atomic
from tissuebench.studies.results import write_table

CATALOGUE = Path(tissuebench.cases.__file__).resolve().parent / "catalogue"
SCENE = "cube_tension_twist"  # a catalogue FE scene of 208 vertices
KINDS = {"device": "character device", "fifo": "FIFO", "loop": "loop of symbolic links", "folder": "folder"}


def _target(tmp_path: Path, kind: str) -> Path:
    """A path of ``kind`` that no writer may replace: a link to /dev/null, a FIFO, a link to
    itself, a folder."""
    path = tmp_path / f"{kind}.out"
    if kind == "device":
        path.symlink_to("/dev/null")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "loop":
        path.symlink_to(path.name)
    else:
        path.mkdir()
    return path


def _unchanged(path: Path, kind: str) -> bool:
    st = os.lstat(path)
    if kind in ("device", "loop"):
        ok = stat.S_ISLNK(st.st_mode) and os.readlink(path) == ("/dev/null" if kind == "device" else path.name)
    else:
        ok = stat.S_ISFIFO(st.st_mode) if kind == "fifo" else stat.S_ISDIR(st.st_mode)
    return ok and stat.S_ISCHR(os.stat("/dev/null").st_mode)


@pytest.fixture
def umask():
    """Set the process umask for a test (``umask(0o022)``); the old one comes back after."""
    old = os.umask(0o022)
    yield os.umask
    os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


# ------------------------------------------------------------------ the shared writer (items 6, 7)
WRITERS = {
    "json": lambda p: write_json_atomic(p, {"a": 1}),
    "parquet": lambda p: write_table(pd.DataFrame({"a": [1.0]}), p),
    "text": lambda p: write_text(p, "new\n", "--opt"),
}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("writer", WRITERS)
def test_no_writer_replaces_what_is_not_a_regular_file(tmp_path, kind, writer):
    path = _target(tmp_path, kind)
    with pytest.raises(OutputPathError, match=KINDS[kind]) as err:
        WRITERS[writer](path)
    assert str(path) in str(err.value)
    assert _unchanged(path, kind)
    assert sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # no temporary left


@pytest.mark.parametrize("writer", WRITERS)
def test_a_link_is_written_through_and_stays_a_link(tmp_path, writer):
    target = tmp_path / "real" / "file"
    target.parent.mkdir()
    target.write_text("old\n")
    target.chmod(0o640)
    first = tmp_path / "link1"
    first.symlink_to(target)
    link = tmp_path / "link2"  # a chain of two links
    link.symlink_to(first.name)
    WRITERS[writer](link)
    assert link.is_symlink() and first.is_symlink() and os.readlink(link) == "link1"
    assert target.read_bytes() != b"old\n" and _mode(target) == 0o640
    dangling = tmp_path / "dangling"
    dangling.symlink_to("real/created")
    WRITERS[writer](dangling)
    assert dangling.is_symlink() and (tmp_path / "real" / "created").is_file()


@pytest.mark.parametrize("writer", WRITERS)
def test_new_files_get_the_umask_mode_and_rewritten_ones_keep_theirs(tmp_path, umask, writer):
    for mask, mode in [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)]:
        umask(mask)
        path = tmp_path / f"new-{mask:o}"
        WRITERS[writer](path)
        assert _mode(path) == mode
    umask(0o022)
    for mode in (0o600, 0o644, 0o660):
        path = tmp_path / f"old-{mode:o}"
        path.write_text("old\n")
        path.chmod(mode)
        WRITERS[writer](path)
        assert _mode(path) == mode and path.read_bytes() != b"old\n"


def test_folders_get_the_umask_mode_or_the_one_they_replace(tmp_path, umask):
    umask(0o027)
    assert _mode(new_folder(tmp_path, ".a.")) == 0o750
    old = tmp_path / "old"
    old.mkdir(mode=0o711)
    old.chmod(0o711)
    assert _mode(new_folder(tmp_path, ".b.", like=old)) == 0o711
    with atomic_directory(tmp_path / "run") as tmp:
        (tmp / "x").write_text("x")
    assert _mode(tmp_path / "run") == 0o750  # was 0755 whatever the umask
    with atomic_directory(old, overwrite=True) as tmp:
        (tmp / "x").write_text("x")
    assert _mode(old) == 0o711 and (old / "x").is_file()


def test_a_run_folder_that_is_a_link_is_replaced_through_it(tmp_path):
    """``run --out LINK --force``: the folder the link points to is replaced, the link stays."""
    real = tmp_path / "real"
    real.mkdir()
    (real / "old").write_text("old")
    link = tmp_path / "link"
    link.symlink_to(real)
    check_output_location(link, overwrite=True)
    with atomic_directory(link, overwrite=True) as tmp:
        (tmp / "new").write_text("new")
    assert link.is_symlink() and sorted(p.name for p in real.iterdir()) == ["new"]
    loop = tmp_path / "loop"
    loop.symlink_to("loop")
    with pytest.raises(ValueError, match=f"--out = {loop}: a loop of symbolic links"):
        check_output_location(loop, overwrite=True)


@pytest.mark.parametrize("kind", ["device", "fifo", "loop"])
def test_run_and_sweep_refuse_an_out_that_cannot_be_a_folder_before_any_work(tmp_path, monkeypatch, capsys, kind):
    from _gate_spec import SPEC

    def refuse(*args, **kwargs):
        raise AssertionError("worked before the output location was checked")
    monkeypatch.setattr("tissuebench.studies.run.solve", refuse)
    monkeypatch.setattr("tissuebench.studies.sweep._execute", refuse)
    spec = tmp_path / "gate.toml"
    spec.write_text(SPEC)
    path = _target(tmp_path, kind)
    for command in (["run", SCENE], ["sweep", str(spec)]):
        assert main([*command, "--out", str(path), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert f"--out = {path}: " in err and KINDS[kind] in err and len(err.strip().splitlines()) == 1
        assert _unchanged(path, kind)


def test_a_stores_derived_folder_has_the_mode_of_its_other_folders(tmp_path, umask):
    from tissuebench.studies.sweep import write_derived

    store = build_store(tmp_path / "st")
    write_derived(store)
    modes = {p.relative_to(store).as_posix(): _mode(p) for p in [store, *store.rglob("*")]}
    assert modes["_derived"] == 0o755  # was 0700 (mkdtemp)
    assert {m for p, m in modes.items() if (store / p).is_dir()} == {0o755}
    assert {m for p, m in modes.items() if (store / p).is_file()} == {0o644}


# ------------------------------------------------------------------ check --junit, --update-baseline
@pytest.fixture
def gated(tmp_path, capsys):
    store = build_store(tmp_path / "st")
    baseline = tmp_path / "baseline.toml"
    assert main(["check", str(store), "--baseline", str(baseline), "--update-baseline"]) == 0
    capsys.readouterr()
    return store, baseline


@pytest.mark.parametrize("kind", KINDS)
def test_check_junit_refuses_a_device_fifo_loop_or_folder_before_any_work(gated, tmp_path, kind, capsys):
    store, baseline = gated
    path = _target(tmp_path, kind)
    assert main(["check", str(store), "--baseline", str(baseline), "--junit", str(path)]) == 2
    out, err = capsys.readouterr()
    assert f"--junit {path}: " in err and KINDS[kind] in err and len(err.strip().splitlines()) == 1
    assert "units hold" not in out  # refused before the check ran
    assert _unchanged(path, kind)


def test_check_junit_through_a_link_writes_its_target(gated, tmp_path, umask):
    store, baseline = gated
    target = tmp_path / "reports" / "gate.xml"
    target.parent.mkdir()
    link = tmp_path / "gate.xml"
    link.symlink_to(target)
    assert main(["check", str(store), "--baseline", str(baseline), "--junit", str(link)]) == 0
    assert link.is_symlink() and target.read_text().startswith("<?xml")
    assert _mode(target) == 0o644  # was 0600 (mkstemp)
    target.chmod(0o664)
    assert main(["check", str(store), "--baseline", str(baseline), "--junit", str(link)]) == 0
    assert _mode(target) == 0o664


def test_update_baseline_writes_through_a_link_and_keeps_the_mode(gated, tmp_path, umask, capsys):
    store, baseline = gated
    target = tmp_path / "shared" / "ci.toml"
    target.parent.mkdir()
    target.write_text("# the team's baseline\n")
    target.chmod(0o644)
    link = tmp_path / "ci.toml"
    link.symlink_to(target)
    assert main(["check", str(store), "--baseline", str(link), "--update-baseline"]) == 0
    assert link.is_symlink() and "[[unit]]" in target.read_text() and "# the team's baseline" in target.read_text()
    assert _mode(target) == 0o644  # was turned into 0600
    fresh = tmp_path / "fresh.toml"
    assert main(["check", str(store), "--baseline", str(fresh), "--update-baseline"]) == 0
    assert _mode(fresh) == 0o644
    for kind in ("loop", "fifo", "device"):
        path = _target(tmp_path, kind)
        capsys.readouterr()
        assert main(["check", str(store), "--baseline", str(path), "--update-baseline"]) == 2
        assert str(path) in capsys.readouterr().err
        assert _unchanged(path, kind)


# ------------------------------------------------------------------ report --out
def _reader_released(fifo: Path):
    """A writer of ``fifo`` in a thread: opening a FIFO to read blocks until a writer comes, so a
    tool that opens it gets EOF instead of hanging. The returned ``join`` releases a writer still
    waiting by opening the FIFO to read without blocking, through a hard link (the FIFO itself,
    should the tool have replaced its name). No timing involved."""
    keep = fifo.parent / "kept" / fifo.name
    keep.parent.mkdir()
    os.link(fifo, keep)

    def write():
        with open(keep, "wb"):
            pass

    thread = threading.Thread(target=write, daemon=True)
    thread.start()

    def join():
        fd = os.open(keep, os.O_RDONLY | os.O_NONBLOCK)
        thread.join()
        os.close(fd)
    return join


def test_report_out_fifo_is_refused_up_front(tmp_path, capsys):
    store = build_store(tmp_path / "st")
    fifo = tmp_path / "report.html"
    os.mkfifo(fifo)
    join = _reader_released(fifo)
    try:
        code = main(["report", str(store), "--out", str(fifo)])
    finally:
        join()
    err = capsys.readouterr().err
    assert code == 2 and str(fifo) in err and "FIFO" in err
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_report_modes_follow_the_umask(tmp_path, umask, capsys):
    store = build_store(tmp_path / "st")
    umask(0o027)
    out = tmp_path / "r" / "report.html"
    assert main(["report", str(store), "--out", str(out)]) == 0
    assert _mode(out) == 0o640 and _mode(tmp_path / "r" / "report_data") == 0o750  # were 0644 and 0755


# ------------------------------------------------------------------ scene check (the picture)
@pytest.fixture
def drawn(monkeypatch):
    """The picture drawn by a stand-in renderer that writes a few bytes without blocking (a
    FIFO with no reader fails at once instead of hanging); the pictures it drew, by path."""
    drawn = []

    def fake_plot(mesh, markers, path):
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NONBLOCK, 0o666)
        os.write(fd, b"picture")
        os.close(fd)
        drawn.append(Path(path))
    monkeypatch.setattr(scene_figure, "_windows", lambda: [])
    monkeypatch.setattr(scene_figure, "_plot_matplotlib", fake_plot)
    return drawn


def test_a_catalogue_scene_is_drawn_in_the_working_folder_never_in_the_package(tmp_path, monkeypatch, capsys):
    """The catalogue folder made read-only (root ignores that: what is asserted is that no file
    appears in it); the picture, drawn by matplotlib, is ./scene.png."""
    monkeypatch.setattr(scene_figure, "_windows", lambda: [])
    monkeypatch.chdir(tmp_path)
    before, mode = sorted(os.listdir(CATALOGUE)), _mode(CATALOGUE)
    CATALOGUE.chmod(0o555)
    try:
        assert main(["scene", "check", SCENE]) == 0
    finally:
        CATALOGUE.chmod(mode)
        for name in set(os.listdir(CATALOGUE)) - set(before):  # what the defect left in the package
            (CATALOGUE / name).unlink()
        after = sorted(os.listdir(CATALOGUE))
    assert after == before
    out = capsys.readouterr().out
    assert f"picture: {tmp_path.resolve() / 'scene.png'} (matplotlib)" in out
    assert (tmp_path / "scene.png").read_bytes()[:4] == b"\x89PNG"


def test_a_scene_files_picture_goes_to_the_working_folder_with_the_umask_mode(tmp_path, monkeypatch, umask,
                                                                              drawn):
    scenes, work = tmp_path / "scenes", tmp_path / "work"
    scenes.mkdir()
    work.mkdir()
    (scenes / "bar.toml").write_text((CATALOGUE / f"{SCENE}.toml").read_text())
    monkeypatch.chdir(work)
    assert main(["scene", "check", str(scenes / "bar.toml")]) == 0
    assert sorted(os.listdir(scenes)) == ["bar.toml"] and sorted(os.listdir(work)) == ["scene.png"]
    assert _mode(work / "scene.png") == 0o644


def test_an_existing_picture_is_replaced_only_with_force(tmp_path, monkeypatch, capsys, drawn):
    monkeypatch.chdir(tmp_path)
    assert main(["scene", "check", SCENE, "--out", "new/sub/x.png"]) == 0  # missing folders made, as report does
    assert (tmp_path / "new" / "sub" / "x.png").read_bytes() == b"picture"
    drawn.clear()
    for args, path in [([], tmp_path / "scene.png"), (["--out", "pics/bar.png"], tmp_path / "pics" / "bar.png")]:
        path.parent.mkdir(exist_ok=True)
        path.write_bytes(b"mine")
        path.chmod(0o600)
        capsys.readouterr()
        assert main(["scene", "check", SCENE, *args]) == 2
        err = capsys.readouterr().err
        assert path.name in err and "--force" in err and path.read_bytes() == b"mine" and not drawn
        assert main(["scene", "check", SCENE, *args, "--force"]) == 0
        assert path.read_bytes() == b"picture" and _mode(path) == 0o600
        assert f"picture: {path.resolve()} " in capsys.readouterr().out
        drawn.clear()


@pytest.mark.parametrize("kind", ["folder", "fifo", "device", "loop", "no_suffix"])
def test_scene_out_refuses_what_is_not_a_png_file_naming_it(tmp_path, monkeypatch, capsys, drawn, kind):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / "plain" if kind == "no_suffix" else _target(tmp_path, kind)
    assert main(["scene", "check", SCENE, "--out", str(path)]) == 2
    err = capsys.readouterr().err
    assert f"--out {path}: " in err and len(err.strip().splitlines()) == 1
    assert (".png" if kind == "no_suffix" else KINDS[kind]) in err
    assert not drawn and "scene.png" not in os.listdir(tmp_path)
    assert not path.exists() if kind == "no_suffix" else _unchanged(path, kind)
    assert not any(p.name.endswith(".png") for p in tmp_path.rglob("*"))  # no DIR.png beside it


def test_scene_out_through_a_link_writes_its_target_and_prints_it(tmp_path, monkeypatch, capsys, drawn):
    monkeypatch.chdir(tmp_path)
    target = tmp_path / "real.png"
    link = tmp_path / "link.png"
    link.symlink_to(target.name)
    assert main(["scene", "check", SCENE, "--out", str(link)]) == 0
    assert link.is_symlink() and target.read_bytes() == b"picture"
    assert f"picture: {target.resolve()} " in capsys.readouterr().out
    assert sorted(os.listdir(tmp_path)) == ["link.png", "real.png"]
