"""Helpers of the property-based fuzz tests: a TOML writer, mutations of parsed TOML documents,
the check that an error names a key, and the counts reported at the end of a fuzz run.

A mutation works on the parsed document (nested dicts and lists): it replaces a value by a
hostile one (wrong type, NaN/inf, huge or tiny numbers, unicode, path-like or markup strings,
empty tables), removes a key, adds an unknown key, empties a table or changes a value of the
right type into a neighbouring one (a number scaled or negated, a list shortened, a string
swapped for another word of the catalogue). The result is written back as TOML, so the
loader's own parser sees it too (integer literals above 1.8e308, NUL escapes).
"""
from __future__ import annotations

import json
import math
import os
import re
from collections import Counter

from hypothesis import strategies as st

# ------------------------------------------------------------------------------ TOML writer
_BARE = re.compile(r"[A-Za-z0-9_-]+")


def _string(s: str) -> str:
    out = []
    for ch in s:
        if ch in ('"', "\\"):
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04X}")
        else:
            out.append(ch)
    return '"' + "".join(out) + '"'


def _key(k: str) -> str:
    return k if _BARE.fullmatch(k) else _string(k)


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def dumps(doc: dict) -> str:
    """TOML text of ``doc``: one line per top-level key (inline tables and arrays)."""
    return "\n".join(f"{_key(k)} = {_value(v)}" for k, v in doc.items()) + "\n"


# ------------------------------------------------------------------------------ hostile values
HOSTILE_STRINGS = ["", " ", "../../x", "<script>alert(1)</script>", "a\x00b", "x" * 300, "12,3,3", "nan",
                   "1e308", "\u00e9\u4e2d\U0001F600", "\t\n", "/etc/passwd", "$(rm -rf /)", "; ls", "{}", "[]",
                   "__import__('os')", "%s%s%n"]
HOSTILE_NUMBERS = [0, -1, 1, 2, 3, 10 ** 400, -(10 ** 400), 2 ** 63, 2 ** 64, 1e308, -1e308, 1e-300, 5e-324,
                   -0.0, 0.5, 0.4999999, 1e9, float("nan"), float("inf"), float("-inf")]


def scalars(words=()):
    pool = HOSTILE_STRINGS + list(words)
    return st.one_of(st.integers(-10 ** 6, 10 ** 6), st.sampled_from(HOSTILE_NUMBERS),
                     st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
                     st.text(max_size=12), st.sampled_from(pool))


def values(words=()):
    """Any TOML value: scalars, lists and tables of them (nested, small)."""
    keys = st.one_of(st.text(max_size=8), st.sampled_from(list(words) or ["x"]))
    return st.recursive(scalars(words), lambda inner: st.lists(inner, max_size=4)
                        | st.dictionaries(keys, inner, max_size=3), max_leaves=6)


# ------------------------------------------------------------------------------ documents
def paths(doc, prefix=()):
    """Every path (tuple of keys and list indices) to a value inside ``doc``."""
    out = []
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        p = prefix + (k,)
        out.append(p)
        out.extend(paths(v, p))
    return out


def vocabulary(*docs) -> list:
    """Every key and string value of ``docs`` (plausible but misplaced words)."""
    words = set()

    def walk(v):
        if isinstance(v, dict):
            for k, x in v.items():
                words.add(k)
                walk(x)
        elif isinstance(v, list):
            for x in v:
                walk(x)
        elif isinstance(v, str) and len(v) < 40:
            words.add(v)
    for d in docs:
        walk(d)
    return sorted(words)


def _get(doc, path):
    for k in path:
        doc = doc[k]
    return doc


def _neighbour(data, v, words):
    """A value of the same type as ``v``, changed (numbers scaled, lists cut, strings swapped)."""
    if isinstance(v, bool):
        return not v
    if isinstance(v, (int, float)):
        factor = data.draw(st.sampled_from([-1, 0, 0.5, 2, 10, 1e6, 1e-6, 1e300]), label="factor")
        try:
            out = v * factor
        except OverflowError:  # an integer beyond the float range times a float
            return -v
        return int(out) if isinstance(v, int) and math.isfinite(out) else out
    if isinstance(v, str):
        return data.draw(st.sampled_from(list(words) + HOSTILE_STRINGS), label="word")
    if isinstance(v, list):
        if v and data.draw(st.booleans(), label="shorten"):
            return v[:-1]
        return v + [data.draw(scalars(words), label="item")]
    if isinstance(v, dict):
        return {}
    return v


MUTATIONS = ("replace", "neighbour", "delete", "extra", "empty", "wrap")


def mutate(data, doc, words, n_max=3, protect=()):
    """Apply 1..``n_max`` random mutations to a copy of ``doc``; returns (doc, descriptions).
    Paths starting with a key of ``protect`` are left alone."""
    doc = json.loads(json.dumps(doc))  # deep copy (TOML values are JSON values, NaN included)
    done = []
    for _ in range(data.draw(st.integers(1, n_max), label="n_mutations")):
        candidates = [p for p in paths(doc) if p[0] not in protect]
        if not candidates:
            break
        path = data.draw(st.sampled_from(candidates), label="path")
        parent, key = _get(doc, path[:-1]), path[-1]
        kind = data.draw(st.sampled_from(MUTATIONS), label="mutation")
        old = parent[key]
        if kind == "replace":
            parent[key] = data.draw(values(words), label="value")
        elif kind == "neighbour":
            parent[key] = _neighbour(data, old, words)
        elif kind == "delete":
            del parent[key]
        elif kind == "extra":
            target = old if isinstance(old, dict) else parent if isinstance(parent, dict) else None
            if target is None:
                continue
            name = data.draw(st.one_of(st.sampled_from(list(words)), st.text(min_size=1, max_size=8)), label="key")
            target[name] = data.draw(values(words), label="value")
        elif kind == "empty":
            parent[key] = {} if isinstance(old, dict) else [] if isinstance(old, list) else ""
        else:  # wrap: the right value in the wrong container
            parent[key] = data.draw(st.sampled_from([[old], {"value": old}, str(old)]), label="wrapped")
        done.append(f"{kind} {'.'.join(map(str, path))}")
    return doc, done


# ------------------------------------------------------------------------------ the verdict
def names_a_key(message: str, keys) -> bool:
    """Does ``message`` name one of ``keys`` as a key path (``material.nu = 0.7: ...``,
    ``case[0].name: missing required key``, ``load[2] = 5: expected a table``)?"""
    if re.match(r"^('[^']*'|\"[^\"]*\"|[\w-]+): unknown top-level key", message):
        return True  # the key is the one the file should not have
    alternatives = "|".join(re.escape(k) for k in sorted(keys, key=len, reverse=True))
    segment = r"""(\.([^\s=:'"\[]+|'[^']*'|"[^"]*"))"""
    pattern = rf"(^|[\s:'\"(]|\.)({alternatives})(\[\d+\])*({segment}(\[\d+\])*)*( = |: |\[)"
    return re.search(pattern, message) is not None


class Tally:
    """Counts of a fuzz test (examples tried, accepted, rejected with a named error)."""

    counts: dict = {}

    @classmethod
    def add(cls, test: str, outcome: str) -> None:
        cls.counts.setdefault(test, Counter())[outcome] += 1

    @classmethod
    def report(cls) -> str:
        lines = [f"{'fuzz test':48s} {'tried':>7s} {'accepted':>9s} {'rejected':>9s} {'other':>6s}"]
        total = Counter()
        for test, c in sorted(cls.counts.items()):
            tried = sum(c.values())
            total.update(c)
            lines.append(f"{test:48s} {tried:7d} {c['accepted']:9d} {c['rejected']:9d} {c['other']:6d}")
        lines.append(f"{'total':48s} {sum(total.values()):7d} {total['accepted']:9d} {total['rejected']:9d} "
                     f"{total['other']:6d}")
        return "\n".join(lines)

    @classmethod
    def write(cls) -> None:
        """Print the table; also to ``$TISSUEBENCH_FUZZ_REPORT`` when set."""
        if not cls.counts:
            return
        text = cls.report()
        print("\n" + text)
        target = os.environ.get("TISSUEBENCH_FUZZ_REPORT")
        if target:
            with open(target, "a") as fh:
                fh.write(text + "\n")


# ------------------------------------------------------------------------------ files read back
def damage_bytes(data, raw: bytes) -> tuple[bytes, str]:
    """``raw`` damaged as a disk fault or a careless edit would: truncated, a byte flipped, junk
    inserted or appended, emptied, or replaced by random bytes."""
    kind = data.draw(st.sampled_from(["truncate", "flip", "insert", "append", "empty", "random"]), label="damage")
    if kind == "empty" or not raw:
        return b"", "empty"
    at = data.draw(st.integers(0, len(raw) - 1), label="at")
    if kind == "truncate":
        return raw[:at], f"truncate at {at}"
    if kind == "flip":
        return raw[:at] + bytes([raw[at] ^ data.draw(st.integers(1, 255), label="xor")]) + raw[at + 1:], f"flip {at}"
    junk = data.draw(st.binary(min_size=1, max_size=64), label="junk")
    if kind == "insert":
        return raw[:at] + junk + raw[at:], f"insert at {at}"
    if kind == "append":
        return raw + junk, "append"
    return data.draw(st.binary(max_size=256), label="random"), "random"


def hostile_json(data, doc: dict, words) -> tuple[str, str]:
    """A JSON text derived from ``doc``: mutated as a document (:func:`mutate`), a document of
    another type, or the text damaged byte-wise (as UTF-8, invalid sequences included)."""
    how = data.draw(st.sampled_from(["mutate", "mutate", "mutate", "other_type", "bytes"]), label="how")
    if how == "mutate":
        mutated, done = mutate(data, doc, words)
        return json.dumps(mutated), "; ".join(done)
    if how == "other_type":
        value = data.draw(values(words), label="document")
        return json.dumps(value), f"document {type(value).__name__}"
    raw, done = damage_bytes(data, json.dumps(doc).encode())
    return raw.decode("utf-8", "surrogateescape"), done
