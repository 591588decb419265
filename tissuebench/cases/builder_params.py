"""Validation of the mesh builders' parameters when a scene loads (before any meshing).

``[mesh.params]``, ``[mesh.ci]`` and ``[mesh.paper]`` hold keyword arguments of the builder
named by ``mesh.builder`` (see :mod:`.builders`). They are checked here, key by key, so a
mistake (``divisions = "12,3,3"``, ``maxh = 0``, an unknown key) is a ``ValueError`` naming
the table it was written in (``mesh.ci.divisions = '12,3,3': ...``) when the scene loads,
not a ``TypeError`` from deep inside a mesher, minutes later. Sizes are bounded
(:data:`MAX_CELLS`): a typo of one digit must not ask for 10**12 cells.
"""
from __future__ import annotations

import errno
import math
import os
import stat
from pathlib import Path

from .schema import accepts, c_bool, c_enum, c_int_range, c_num, c_pos, c_str, fail, key_text, value_text

__all__ = ["MAX_CELLS", "BUILDER_PARAMS", "MeshFileNotFound", "check_builder_params", "require_regular_file"]

#: Largest mesh a scene may ask for (cells, estimated from the parameters before meshing).
MAX_CELLS = 5_000_000


class MeshFileNotFound(FileNotFoundError, ValueError):
    """A mesh file named by a scene does not exist: bad input (a ValueError) and a missing
    file (a FileNotFoundError), so either ``except`` clause catches it."""


_SPECIAL = {stat.S_IFIFO: "FIFO (named pipe)", stat.S_IFCHR: "character device", stat.S_IFBLK: "block device",
            stat.S_IFSOCK: "socket"}


def require_regular_file(p: Path, what: str, hint: str = "") -> None:
    """Refuse a mesh path ``p`` that is not a regular file, found from its metadata alone: it
    is never opened (a FIFO would block the reader, a device such as ``/dev/zero`` never end).
    :class:`MeshFileNotFound` where nothing is there (a dangling link included, ``hint`` added),
    ValueError saying what is there otherwise: a folder, a FIFO, a device, a socket, a loop of
    symbolic links. Messages start with ``what`` (``mesh.file = 'kidney.msh': mesh file /x``)."""
    try:
        st = os.stat(p)  # follows links: what a reader would open
    except FileNotFoundError:
        try:
            target = os.readlink(p)
        except OSError:  # not a link (or its folder is missing): nothing there
            raise MeshFileNotFound(f"{what} does not exist{hint}") from None
        raise MeshFileNotFound(f"{what} is a symbolic link to {target!r}, which does not exist{hint}") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ValueError(f"{what} is a loop of symbolic links: it never reaches a file") from None
        raise ValueError(f"{what} cannot be inspected: {exc.strerror or exc}") from None
    except ValueError as exc:  # an embedded NUL byte
        raise ValueError(f"{what}: not a usable file path ({exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise ValueError(f"{what} is a folder, not a mesh file")
    if not stat.S_ISREG(st.st_mode):
        kind = _SPECIAL.get(stat.S_IFMT(st.st_mode), "special file")
        raise ValueError(f"{what} is a {kind}, not a regular file: not read (a FIFO would block, a device such "
                         "as /dev/zero never end)")


def _vec(n, positive=False):
    @accepts(f"a list of {n} finite numbers" + (" > 0" if positive else ""))
    def check(path, v):
        ok = isinstance(v, list) and len(v) == n
        nums = [c_num(f"{path}[{i}]", x) for i, x in enumerate(v)] if ok else []
        if not ok or (positive and not all(x > 0 for x in nums)):
            fail(path, v, f"expected a list of {n} finite numbers" + (" > 0" if positive else ""))
        return nums
    return check


@accepts("a list of 3 integers from 1 to 100000 (cells along x, y, z)")
def _divisions(path, v):
    if not (isinstance(v, list) and len(v) == 3):
        fail(path, v, "expected a list of 3 integers >= 1 (cells along x, y, z)")
    return [c_int_range(1, 100_000)(f"{path}[{i}]", x) for i, x in enumerate(v)]


@accepts("a number in (0, 1)")
def _fraction(path, v):
    if not (c_num(path, v) and 0 < v < 1):
        fail(path, v, "expected a number in (0, 1)")
    return float(v)


@accepts("a mesh grading in (0, 1]")
def _grading(path, v):
    if not (c_num(path, v) and 0 < v <= 1):
        fail(path, v, "expected a mesh grading in (0, 1]")
    return float(v)


@accepts("the path of a mesh file")
def _mesh_file(path, v):
    c_str(path, v)
    try:
        Path(v).expanduser().is_file()
    except (OSError, ValueError, RuntimeError) as exc:  # NUL byte, name too long, unknown ~user
        fail(path, v, f"not a usable file path ({exc})")
    return v


def _require_file(path, v):
    p = Path(v).expanduser()
    require_regular_file(p, f"{path} = {value_text(v)}: mesh file {p}")


_COUNT = c_int_range(1, 100_000)
BUILDER_PARAMS = {  # builder: ({parameter: checker}, required parameters)
    "box": ({"lengths": _vec(3, True), "divisions": _divisions, "cell_type": c_enum("tetra", "hexahedron"),
             "origin": _vec(3)}, ("lengths", "divisions")),
    "netgen_box": ({"lengths": _vec(3, True), "maxh": c_pos, "origin": _vec(3)}, ("lengths", "maxh")),
    "cornea_dome": ({"radius": c_pos, "thickness": c_pos, "base_diameter": c_pos, "core_cells": _COUNT,
                     "ring_cells": _COUNT, "layers": _COUNT, "core_fraction": _fraction}, ()),
    "lv_ellipsoid": ({"endo": _vec(2, True), "epi": _vec(2, True), "z_base": c_num, "maxh": c_pos}, ()),
    "half_ellipsoid": ({"semi_axes": _vec(3, True), "maxh": c_pos}, ()),
    "liver": ({"path": _mesh_file, "scale": c_pos, "maxh": c_pos, "grading": _grading, "fallback_maxh": c_pos,
               "allow_fallback": c_bool}, ()),
    "file": ({"path": _mesh_file, "scale": c_pos}, ("path",)),
    "interval": ({"length": c_pos, "n_elements": c_int_range(1, 10_000_000)}, ()),
    "beam1d": ({"length": c_pos, "n_elements": c_int_range(1, 10_000_000)}, ()),
}


def _estimated_cells(builder, p):
    """Cells the builder would make from parameters ``p`` (netgen: volume / maxh^3 times the
    ~6 tetrahedra of a cube of side maxh), or None when the parameters do not tell."""
    if builder == "box":
        n = math.prod(p["divisions"])
        return n * (6 if p.get("cell_type", "tetra") == "tetra" else 1)
    if builder == "cornea_dome":
        c, r = p.get("core_cells", 4), p.get("ring_cells", 3)
        return p.get("layers", 2) * (c * c + 4 * c * r)
    if builder == "netgen_box":
        return 6 * math.prod(p["lengths"]) / p["maxh"] ** 3
    if builder == "lv_ellipsoid":
        a, c = p.get("epi", [10.0, 20.0])
        return 6 * a * a * c / p.get("maxh", 2.0) ** 3
    if builder == "half_ellipsoid":
        a, b, c = p.get("semi_axes", [60.0, 60.0, 120.0])
        return 6 * (2 * math.pi / 3) * a * b * c / p.get("maxh", 20.0) ** 3
    return None


def check_builder_params(builder: str, tables: dict, resolutions, resolution: str) -> dict:
    """Check ``tables`` ({"params": {...}, "ci": {...}, "paper": {...}}, each under
    ``mesh.<name>``) against the parameters of ``builder``; returns the merged parameters per
    resolution. ValueError names the table and key (``mesh.ci.divisions = ...``); a mesh
    file of the loaded ``resolution`` that does not exist is a :class:`MeshFileNotFound`."""
    schema, required = BUILDER_PARAMS[builder]
    checked = {}
    for name, table in tables.items():
        out = {}
        for key, value in table.items():
            if key not in schema:
                raise ValueError(f"mesh.{name}.{key_text(key)}: not a parameter of builder {builder!r} "
                                 f"(valid: {sorted(schema)})")
            out[key] = schema[key](f"mesh.{name}.{key}", value)
        checked[name] = out
    merged = {}
    for res in resolutions:
        p = {**checked.get("params", {}), **checked.get(res, {})}
        for key in required:
            if key not in p:
                raise ValueError(f"mesh.{res}.{key}: missing required parameter of builder {builder!r} "
                                 f"(in [mesh.params] or [mesh.{res}])")
        n = _estimated_cells(builder, p)
        if n is not None and not n <= MAX_CELLS:
            where = f"mesh.{res}" if res in tables and tables[res] else "mesh.params"
            fail(where, tables.get(res) or tables.get("params"),
                 f"asks for about {n:.3g} cells; at most {MAX_CELLS} (a mistyped parameter?)")
        if builder == "cornea_dome":
            _check_cornea(f"mesh.{res}", p)
        merged[res] = {**tables.get("params", {}), **tables.get(res, {})}
    if "path" in merged[resolution]:
        _require_file(f"mesh.{resolution if 'path' in tables.get(resolution, {}) else 'params'}.path",
                      merged[resolution]["path"])
    return merged


def _check_cornea(path, p):
    radius, thickness, base = p.get("radius", 7.8), p.get("thickness", 0.55), p.get("base_diameter", 11.5)
    if not (thickness < radius and base / 2 < radius - thickness / 2):
        fail(path, {"radius": radius, "thickness": thickness, "base_diameter": base},
             "inconsistent cornea: needs thickness < radius and base_diameter / 2 < radius - thickness / 2")
