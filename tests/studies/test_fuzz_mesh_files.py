"""Property-based fuzzing of the mesh files a scene reads (``[mesh] file = ...``, issue 37): valid
files of every format meshio writes and reads back here, the same files damaged byte-wise
(truncated, a byte flipped, junk inserted or appended, emptied, random bytes) or given another
format's extension, special files (a folder, a FIFO, a loop of symbolic links, a dangling link,
``/dev/zero``, ``/dev/null``, a link to a good file) and hostile paths (empty, a NUL byte, a name
too long, an unknown ``~user``, a trailing slash, a folder of the path that is a file).

Each example writes a scene around the file and loads it, builds its mesh and hashes its content
(what ``scene check``, ``run`` and ``sweep`` do first). It either loads, or raises a ValueError
whose message names the file (as written in the scene, or its path) and the field (``mesh.file``,
or what of the file is wrong: its cells, its points, meshio's reading of it); any other exception
fails the test, and so does a hang (a SIGALRM watchdog per example: a FIFO opened for reading,
a meshio reader looping at the end of a truncated file).

Examples: the default run 50 (a few seconds), the slow run (CI's second pass, ``pytest -m slow``)
:data:`LONG_EXAMPLES`, ``--hypothesis-profile=fuzz`` (``tox -e fuzz``) 10 000. The counts are
printed at the end of the module (and appended to ``$TISSUEBENCH_FUZZ_REPORT``).
"""
from __future__ import annotations

import contextlib
import io
import os
import shutil
import signal
import tempfile
from pathlib import Path
from unittest import mock

import meshio
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from _fuzz import Tally, damage_bytes, dumps
from _mesh_scene import SCENE
from tissuebench.cases import meshio_guard
from tissuebench.cases.meshes import box_mesh
from tissuebench.cases.scene import load

pytestmark = pytest.mark.fuzz

#: meshio's formats that write and read back tetrahedra (and hexahedra) without an optional package
FORMATS = {"gmsh22": ".msh", "gmsh": ".msh", "vtu": ".vtu", "vtk": ".vtk", "vtk42": ".vtk", "medit": ".mesh",
           "abaqus": ".inp", "avsucd": ".avs", "flac3d": ".f3grid", "nastran": ".nas", "su2": ".su2",
           "permas": ".post", "dolfin-xml": ".xml", "tetgen": ".node", "mdpa": ".mdpa", "tecplot": ".dat",
           "netgen": ".vol"}
OTHER_EXTENSIONS = sorted(set(FORMATS.values()) | {".stl", ".ply", ".off", ".obj", ".ans", ".ugrid", ".h5m", "",
                                                     ".txt", ".MSH", ".msh.gz", ".e"})
SPECIAL = ("folder", "fifo", "loop", "dangling", "dev_zero", "dev_null", "link_to_good")
HOSTILE_NAMES = ["", " ", ".", "..", "/", "a\x00b.msh", "x" * 300 + ".msh", "~no_such_user_h37/x.msh",
                 "block.msh/", "block.msh/inner.msh", "../../../../nowhere.msh", "sp ace é中.msh", "new\nline.msh",
                 "C:\\mesh.msh", "file:///block.msh", "-rf.msh", "*.msh", "block.msh\x7f"]
# what a message may say is wrong with the file itself (io.read_mesh and Mesh)
FIELDS = ("mesh.file", "cells", "cell ", "points", "coordinates", "cannot read it", "vertex")
FUZZ_PROFILE = settings.default.max_examples >= 1000
LONG_EXAMPLES = 2_000
_HEALTH = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow]
WATCHDOG_S = 120  # far past the patched meshio deadline below: only a true hang reaches it


def _written(fmt: str, cell: str, folder: Path) -> dict:
    """``{extension: bytes}`` of a small mesh in ``fmt`` (TetGen: the .node and its .ele)."""
    m = box_mesh((40.0, 20.0, 20.0), (2, 1, 1), cell)
    path = folder / f"base_{fmt}_{cell}{FORMATS[fmt]}"
    options = {"binary": False} if fmt == "gmsh22" else {}
    with contextlib.redirect_stdout(io.StringIO()):  # meshio's own remarks
        meshio.write(path, meshio.Mesh(m.points, [(cell, m.cells)]), file_format=fmt, **options)
    out = {FORMATS[fmt]: path.read_bytes()}
    if fmt == "tetgen":
        out[".ele"] = path.with_suffix(".ele").read_bytes()
    return out


class _Bases(dict):
    def __repr__(self):  # hypothesis prints the test's arguments: not 40 kB of mesh files
        return f"<{len(self)} base mesh files>"


@pytest.fixture(scope="module")
def bases(tmp_path_factory):
    """Every (format, cell type) meshio writes here: ``{(format, cell): {extension: bytes}}``."""
    folder = tmp_path_factory.mktemp("bases")
    out = _Bases()
    for fmt in FORMATS:
        for cell in ("tetra", "hexahedron"):
            try:
                out[(fmt, cell)] = _written(fmt, cell, folder)
            except meshio.WriteError:  # e.g. DOLFIN XML holds no hexahedra
                continue
    return out


@pytest.fixture(scope="module", autouse=True)
def short_deadline():
    """A looping reader stopped after 0.5 s rather than 60 (these files read in milliseconds; a
    good file read past it under load is a ValueError naming the file too, so the test's verdict
    does not depend on the machine's load, only the accepted / rejected counts could)."""
    with mock.patch.object(meshio_guard, "READ_SECONDS", 0.5):
        yield


@pytest.fixture(scope="module", autouse=True)
def fuzz_report():
    yield
    Tally.write()


def _special(data, folder: Path, good: Path) -> tuple[str, str]:
    kind = data.draw(st.sampled_from(SPECIAL), label="special")
    target = folder / "special.msh"
    if kind == "folder":
        target.mkdir()
    elif kind == "fifo":
        os.mkfifo(target)
    elif kind == "loop":
        target.symlink_to(target)
    elif kind == "dangling":
        target.symlink_to(folder / "nowhere.msh")
    elif kind == "link_to_good":
        target = folder / f"link{good.suffix}"
        target.symlink_to(good)
    else:
        return ("/dev/zero" if kind == "dev_zero" else "/dev/null"), kind
    return target.name, kind


def _example(data, folder: Path, bases: dict) -> tuple[str, str, str]:
    """Write the mesh file(s) of one example in ``folder``: ``(mesh.file as written, element, what)``."""
    fmt, cell = data.draw(st.sampled_from(sorted(bases)), label="base")
    files = bases[(fmt, cell)]
    ext = FORMATS[fmt]
    element = data.draw(st.sampled_from(["P1", "P1", "Q1", "P2"] if cell == "tetra" else ["Q1", "Q1", "P1"]),
                        label="element")
    how = data.draw(st.sampled_from(["valid", "damaged", "damaged", "damaged", "renamed", "special", "path"]),
                    label="how")
    for suffix, raw in files.items():
        (folder / f"block{suffix}").write_bytes(raw)
    name = f"block{ext}"
    if how == "damaged":
        raw, done = damage_bytes(data, files[ext])
        (folder / name).write_bytes(raw)
        how = f"{fmt} {done}"
    elif how == "renamed":
        new = data.draw(st.sampled_from(OTHER_EXTENSIONS), label="extension")
        (folder / f"renamed{new}").write_bytes(files[ext])
        name, how = f"renamed{new}", f"{fmt} as {new!r}"
    elif how == "special":
        name, how = _special(data, folder, folder / name)
    elif how == "path":
        name = data.draw(st.sampled_from(HOSTILE_NAMES), label="name")
        how = f"path {name!r}"
    return name, element, how


def _names_file_and_field(message: str, name: str, folder: Path) -> bool:
    shown = {repr(name), repr(name)[1:-1], str(folder / name), Path(name).name} - {""}
    try:
        shown.add(str((folder / name).resolve()))
    except (OSError, RuntimeError, ValueError):
        pass
    return any(s in message for s in shown) and any(f in message for f in FIELDS)


def _check(data, parent: Path, bases: dict) -> None:
    folder = Path(tempfile.mkdtemp(dir=parent))
    try:
        name, element, how = _example(data, folder, bases)
        scene = folder / "scene.toml"
        scene.write_text(SCENE.format(mesh=dumps({"file": name, "unit": "mm", "element": element}), case_extra="",
                                      analysis_extra="", extra=""))
        signal.alarm(WATCHDOG_S)
        try:
            loaded = load(scene)
            assert loaded.mesh.n_cells > 0
            loaded.content_hash()
        except (ValueError, TypeError) as exc:
            if not _names_file_and_field(str(exc), name, folder):
                Tally.add("mesh file in a scene", "other")
                raise AssertionError(f"{how}: {type(exc).__name__} names no file and field: {exc}") from exc
            Tally.add("mesh file in a scene", "rejected")
            if "did not finish" in str(exc):  # a reader looping on the file, stopped (meshio_guard)
                Tally.add("mesh file in a scene: reader stopped", "rejected")
            return
        except BaseException:
            Tally.add("mesh file in a scene", "other")
            raise
        finally:
            signal.alarm(0)
        Tally.add("mesh file in a scene", "accepted")
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _hang(*_):
    raise TimeoutError(f"an example ran {WATCHDOG_S} s: a hang")


@pytest.fixture(scope="module", autouse=True)
def watchdog():
    previous = signal.signal(signal.SIGALRM, _hang)
    yield
    signal.signal(signal.SIGALRM, previous)


@settings(suppress_health_check=_HEALTH, deadline=None, max_examples=10_000 if FUZZ_PROFILE else 50)
@given(data=st.data())
def test_mesh_files_in_scenes_load_or_name_the_file_and_the_field(tmp_path, bases, data):
    _check(data, tmp_path, bases)


@pytest.mark.slow
@pytest.mark.skipif(FUZZ_PROFILE, reason="the fuzz profile runs 10 000 examples in the fast variant")
@settings(suppress_health_check=_HEALTH, deadline=None, max_examples=LONG_EXAMPLES)
@given(data=st.data())
def test_mesh_files_in_scenes_load_or_name_the_file_and_the_field_long(tmp_path, bases, data):
    _check(data, tmp_path, bases)
