"""Validation primitives of the scene files: value checkers and the table checker.

Every checker has the signature ``check(path, value) -> normalised value`` and raises
``ValueError`` naming the key path and the offending value (``material.nu = 0.7: ...``),
so a scene author sees *where* in the file the mistake is, not only what it is.
:func:`check_table` applies a ``{key: checker}`` table to a TOML table.

Every checker also says in words what it accepts (its ``accepts`` attribute, read with
:func:`accepts_text`): the scene-format reference of the documentation is generated from the
schema tables and these words, so the documented format is the one the loader checks.
"""
from __future__ import annotations

import json
import math
import re

__all__ = ["AXES", "COMPONENTS_1D", "MODELS", "fail", "require", "is_num", "c_str", "c_bool", "c_num",
           "c_pos", "c_nonneg", "c_int1", "c_nu", "c_vec3", "c_numlist", "c_table", "c_any", "c_enum",
           "c_axis", "c_frame", "check_table", "check_components", "key_text", "c_int_range", "c_name",
           "value_text", "accepts", "accepts_text"]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
MODELS = ("fe", "poisson1d", "frame2dof", "hermite_beam")
AXES = {"x": 0, "y": 1, "z": 2}
# the 1D models name their degrees of freedom instead of using x, y, z
COMPONENTS_1D = {"poisson1d": {"u": 0}, "frame2dof": {"u": 0}, "hermite_beam": {"w": 0, "theta": 1}}


def accepts(text: str):
    """Decorator attaching to a checker the words of what it accepts (``checker.accepts``,
    Markdown), which the format reference of the documentation shows beside the key."""
    def mark(checker):
        checker.accepts = text
        return checker
    return mark


def accepts_text(checker) -> str:
    """What ``checker`` accepts, in words (``""`` for a checker that does not say)."""
    return getattr(checker, "accepts", "")


def fail(path, value, what):
    """Raise the ``ValueError`` ``"<path> = <value>: <what>"`` (a long value shortened)."""
    raise ValueError(f"{path} = {value_text(value)}: {what}")


def value_text(value, limit: int = 200) -> str:
    """``repr(value)``, cut to ``limit`` characters (a scene may hold a megabyte string)."""
    try:
        text = repr(value)
    except ValueError:  # an integer beyond Python's digit limit for str()
        text = f"<integer of about {value.bit_length() * 0.30103:.0f} digits>"
    return text if len(text) <= limit else text[: limit - 5] + " ...>"


def require(path, table, keys, context):
    """Raise ``"<path>.<key>: missing required key <context>"`` for the first of ``keys``
    absent from ``table``."""
    for key in keys:
        if key not in table:
            raise ValueError(f"{path}.{key}: missing required key {context}")


def is_num(v):
    """A finite number that converts to a float: not a bool (an int subclass: `true` must not
    pass as 1), not NaN/inf, not an integer literal beyond the float range (1.8e308)."""
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def key_text(key) -> str:
    """A key as a message shows it: bare words as they are, anything else quoted (``repr``),
    so a key path stays readable and no control character of a key reaches the terminal."""
    return key if isinstance(key, str) and _BARE_KEY.fullmatch(key) else repr(key)


def _is_int(v):
    return isinstance(v, int) and not isinstance(v, bool)


def c_int_range(lo, hi):
    """A checker of an integer in ``[lo, hi]`` (an upper bound keeps a typo from asking for
    10**12 steps or cells, which would exhaust the memory long after the scene loaded)."""
    @accepts(f"an integer from {lo} to {hi}")
    def check(path, v):
        if not (_is_int(v) and lo <= v <= hi):
            fail(path, v, f"expected an integer in [{lo}, {hi}]")
        return v
    return check


@accepts("a non-empty string")
def c_str(path, v):
    if not isinstance(v, str) or not v.strip():
        fail(path, v, "expected a non-empty string")
    return v


@accepts("a name: printable text of at most 100 characters")
def c_name(path, v):
    """A name shown in tables, titles and (sanitised) folder names: a non-empty printable
    string of at most 100 characters (no NUL, newline or other control character)."""
    if not isinstance(v, str) or not v.strip() or not v.isprintable() or len(v) > 100:
        fail(path, v, "expected a name: non-empty printable text of at most 100 characters")
    return v


@accepts("`true` or `false`")
def c_bool(path, v):
    if not isinstance(v, bool):
        fail(path, v, "expected true or false")
    return v


@accepts("a finite number")
def c_num(path, v):
    if not is_num(v):
        fail(path, v, "expected a finite number")
    return float(v)


@accepts("a finite number > 0")
def c_pos(path, v):
    if not (is_num(v) and v > 0):
        fail(path, v, "expected a finite number > 0")
    return float(v)


@accepts("a finite number >= 0")
def c_nonneg(path, v):
    if not (is_num(v) and v >= 0):
        fail(path, v, "expected a finite number >= 0")
    return float(v)


@accepts("an integer >= 1")
def c_int1(path, v):
    if not (_is_int(v) and v >= 1):
        fail(path, v, "expected an integer >= 1")
    return v


@accepts("a Poisson ratio in (-1, 0.5)")
def c_nu(path, v):
    if not (is_num(v) and -1 < v < 0.5):
        fail(path, v, "expected a Poisson ratio in (-1, 0.5)")
    return float(v)


@accepts("a list of 3 finite numbers")
def c_vec3(path, v):
    if not (isinstance(v, list) and len(v) == 3 and all(is_num(x) for x in v)):
        fail(path, v, "expected a list of 3 finite numbers")
    return [float(x) for x in v]


@accepts("a non-empty list of finite numbers")
def c_numlist(path, v):
    if not (isinstance(v, list) and v and all(is_num(x) for x in v)):
        fail(path, v, "expected a non-empty list of finite numbers")
    return [float(x) for x in v]


@accepts("a table")
def c_table(path, v):
    if not isinstance(v, dict):
        fail(path, v, "expected a table")
    return v


@accepts("see *what*")
def c_any(path, v):
    return v


def c_enum(*choices):
    """A checker accepting exactly the values ``choices``."""
    @accepts("one of " + ", ".join(f"`{json.dumps(c)}`" for c in choices))  # as TOML writes them
    def check(path, v):
        if v not in choices:
            fail(path, v, f"expected one of {list(choices)}")
        return v
    return check


c_axis = c_enum(*AXES)
c_frame = c_enum("absolute", "bbox")


def check_table(path, table, schema, required=(), free=False):
    """Check ``table`` against ``schema`` {key: checker}; unknown keys are errors unless ``free``."""
    c_table(path, table)
    require(path, table, required, f"(in {path})")
    out = {}
    for key, value in table.items():
        if key not in schema:
            if free:
                out[key] = value
                continue
            raise ValueError(f"{path}.{key_text(key)}: unknown key (valid: {sorted(schema)})")
        out[key] = schema[key](f"{path}.{key}", value)
    return out


def check_components(path, v, model):
    """Component indices from names (``"xyz"``, ``["x", "z"]``, ``["w", "theta"]``) or indices."""
    names = AXES if model == "fe" else COMPONENTS_1D[model]
    # "xyz" is shorthand for ["x", "y", "z"] only where component names are single letters
    items = list(v) if isinstance(v, str) and model == "fe" else v
    if isinstance(items, str):
        items = [items]
    if not isinstance(items, list) or not items:
        fail(path, v, f"expected a list of components from {sorted(names)}")
    out = []
    for c in items:
        if _is_int(c) and c in names.values():
            out.append(c)
        elif isinstance(c, str) and c in names:
            out.append(names[c])
        else:
            fail(path, v, f"unknown component {c!r}; valid: {sorted(names)}")
    if len(set(out)) != len(out):
        fail(path, v, "repeated component")
    return out
