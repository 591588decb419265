"""The gate's baseline file (:mod:`tissuebench.gate.baseline`): every range at its boundary on
both sides, every refusal with the message that names the key, and the rewrite keeping what it
must (issue 41)."""
from __future__ import annotations

import errno
import re
from pathlib import Path

import pytest
import tomlkit

from tissuebench.gate import baseline as bl
from tissuebench.studies import atomic_files
from tissuebench.studies.atomic_files import OutputPathError
from tissuebench.gate.baseline import DEFAULTS, BaselineError, load_baseline, unit_identity, update_baseline

UNIT = ('case = "cube"\nmethod = "pod"\noptions = \'{"n":2,"a":1}\'\nerror = 0.01\n'
        'latency_per_calibration = 0.5\nlatency_per_reference = 0.02\nflagged_steps = 0\n')


def _write(tmp_path, text, name="b.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


def _refused(tmp_path, text, message):
    p = _write(tmp_path, text)
    with pytest.raises(BaselineError) as exc:
        load_baseline(p)
    assert str(exc.value) == message.format(p=p)


def test_a_valid_file_read_back_with_defaults_overrides_and_identity(tmp_path):
    p = _write(tmp_path, "[defaults]\nreference_latency_tolerance = 2.0\nerror_rtol = 0.5\n"
                         f"[[unit]]\n{UNIT}latency_floor = 0.25\n")
    defaults, units = load_baseline(p)
    assert defaults == {**DEFAULTS, "error_rtol": 0.5}
    assert units[0]["_identity"] == ("cube", "pod", '{"a":1,"n":2}') and units[0]["latency_floor"] == 0.25
    assert load_baseline(_write(tmp_path, f"[[unit]]\n{UNIT}", "c.toml"))[0] == DEFAULTS


def test_unit_identity_compares_options_parsed():
    assert unit_identity("c", "m", '{ "b": [1, 2], "a": {"y": 1, "x": 2}}') == ("c", "m",
                                                                             '{"a":{"x":2,"y":1},"b":[1,2]}')
    with pytest.raises(BaselineError, match=r"^options = 'nope': not JSON$"):
        unit_identity("c", "m", "nope")
    with pytest.raises(BaselineError, match=r"^options = None: not JSON$"):
        unit_identity("c", "m", None)
    with pytest.raises(BaselineError, match=r"^options = '\[1\]': expected a JSON object$"):
        unit_identity("c", "m", "[1]")


@pytest.mark.parametrize("key, low, inclusive", [(k, *v) for k, v in bl._RANGES.items() if k in DEFAULTS])
def test_each_default_at_its_lowest_value(tmp_path, key, low, inclusive):
    at, above = f"[defaults]\n{key} = {float(low)!r}\n[[unit]]\n{UNIT}", f"[defaults]\n{key} = {low + 1e-9!r}\n" \
                                                                          f"[[unit]]\n{UNIT}"
    assert load_baseline(_write(tmp_path, above))[0][key] == low + 1e-9
    if inclusive:
        assert load_baseline(_write(tmp_path, at))[0][key] == low
        below = f"[defaults]\n{key} = {low - 1e-9!r}\n[[unit]]\n{UNIT}"
        _refused(tmp_path, below, f"{{p}}: defaults.{key} = {low - 1e-9!r}: must be >= {low:g}")
    else:
        _refused(tmp_path, at, f"{{p}}: defaults.{key} = {float(low)!r}: must be > {low:g}")


@pytest.mark.parametrize("key", ["error", "latency_per_calibration", "latency_per_reference"])
def test_unit_values_may_be_zero_not_negative(tmp_path, key):
    text = f"[[unit]]\n{UNIT}".replace(f"\n{key} = ", f"\n{key} = 0.0 #")
    assert load_baseline(_write(tmp_path, text))[1][0][key] == 0.0
    text = f"[[unit]]\n{UNIT}".replace(f"\n{key} = ", f"\n{key} = -1e-300 #")
    _refused(tmp_path, text, f"{{p}}: unit[0].{key} = -1e-300: must be >= 0")


def test_flagged_steps_is_a_non_negative_integer(tmp_path):
    _refused(tmp_path, f"[[unit]]\n{UNIT}".replace("flagged_steps = 0", "flagged_steps = -1"),
             "{p}: unit[0].flagged_steps = -1: must be >= 0")
    _refused(tmp_path, f"[[unit]]\n{UNIT}".replace("flagged_steps = 0", "flagged_steps = 1.0"),
             "{p}: unit[0].flagged_steps = 1.0: expected an integer")
    assert load_baseline(_write(tmp_path, f"[[unit]]\n{UNIT}".replace("flagged_steps = 0", "flagged_steps = 3")))[1][0][
        "flagged_steps"] == 3


FINITE = "must be a finite number (a non-finite baseline value or tolerance gates nothing)"


@pytest.mark.parametrize("key", sorted(DEFAULTS))
def test_an_infinite_tolerance_is_refused(tmp_path, key):
    # an infinite tolerance would make every comparison hold (issue 37): error_atol included
    _refused(tmp_path, f"[defaults]\n{key} = inf\n[[unit]]\n{UNIT}", f"{{p}}: defaults.{key} = inf: {FINITE}")


@pytest.mark.parametrize("key", ["error", "latency_per_calibration", "latency_per_reference"])
def test_an_infinite_unit_value_is_refused(tmp_path, key):
    text = f"[[unit]]\n{UNIT}".replace(f"\n{key} = ", f"\n{key} = inf #")
    _refused(tmp_path, text, f"{{p}}: unit[0].{key} = inf: {FINITE}")
    assert load_baseline(_write(tmp_path, f"[[unit]]\n{UNIT}".replace(f"\n{key} = ", f"\n{key} = 1e308 #"),
                                "big.toml"))[1][0][key] == 1e308


@pytest.mark.parametrize("value, why", [("true", "expected a number"), ('"1"', "expected a number"),
                                        ("nan", FINITE), ("-inf", FINITE)])
def test_a_default_that_is_not_a_number(tmp_path, value, why):
    shown = {"true": "True", '"1"': "'1'", "nan": "nan", "-inf": "-inf"}[value]
    _refused(tmp_path, f"[defaults]\nerror_rtol = {value}\n[[unit]]\n{UNIT}",
             f"{{p}}: defaults.error_rtol = {shown}: {why}")


def test_a_number_too_large_for_a_float(tmp_path):
    with pytest.raises(BaselineError, match="^" + re.escape(f"unit[0].flagged_steps = 1{'0' * 19}...: a number too "
                                                            "large") + "$"):
        bl._number("unit[0].flagged_steps", 10 ** 400, int)
    assert bl._number("x.error", 7, float) == 7 and bl._number("x.other", -5.0, float) == -5.0


@pytest.mark.parametrize("text, message", [
    ("[[unit]]\n" + UNIT + "[extra]\n", "extra: unknown top-level key in {p} (valid: ['defaults', 'unit'])"),
    ("defaults = 1\n[[unit]]\n" + UNIT, "defaults: expected a table in {p}"),
    ("[defaults]\nerror_tol = 1\n[[unit]]\n" + UNIT,
     "{p}: defaults.error_tol: unknown key (valid: " + str(sorted(DEFAULTS)) + ")"),
    ("unit = 3\n", "{p}: unit: expected an array of tables ([[unit]])"),
    ("unit = [1]\n", "{p}: unit: expected an array of tables ([[unit]])"),
    ("[defaults]\n", "unit: {p} has no [[unit]]: a gate that compares nothing passes vacuously (write one with "
                     "--update-baseline)"),
    ("[[unit]]\n" + UNIT + "[[unit]]\n" + UNIT.replace('{"n":2,"a":1}', '{"a":1, "n":2}'),
     '{p}: unit[1]: the same unit as unit[0] (cube pod {{"a":1,"n":2}})'),
    ("[[unit]]\n" + UNIT.replace("flagged_steps = 0\n", ""), "{p}: unit[0].flagged_steps: missing required key"),
    ("[[unit]]\n" + UNIT.replace('case = "cube"', "case = 1"), "{p}: unit[0].case = 1: expected a string"),
    ("[[unit]]\n" + UNIT + "speed = 1\n", "{p}: unit[0].speed: unknown key (valid: " + str(
        sorted(bl.UNIT_KEYS) + sorted(DEFAULTS) + sorted(bl.DECLARATION_KEYS)) + ")"),
    ("[[unit]]\n" + UNIT + "error_rtol = -1.0\n", "{p}: unit[0].error_rtol = -1.0: must be >= 0"),
    ("[[unit]]\n" + UNIT + 'error_rtol = "a"\n', "{p}: unit[0].error_rtol = 'a': expected a number"),
    ("[[unit]]\n" + UNIT.replace('{"n":2,"a":1}', "[2]"), "{p}: unit[0].options = '[2]': expected a JSON object"),
    ("[[unit]]\n" + UNIT.replace("error = 0.01", "error = [1]"), "{p}: unit[0].error = [1]: expected a number"),
    ("[[unit\n", None),
])
def test_every_refusal_names_the_key(tmp_path, text, message):
    p = _write(tmp_path, text)
    with pytest.raises(BaselineError) as exc:
        load_baseline(p)
    if message is None:
        assert str(exc.value).startswith(f"{p}: not valid TOML: ")
    else:
        assert str(exc.value) == message.format(p=p)


def test_a_retired_key_in_a_unit_is_read_and_ignored(tmp_path):
    units = load_baseline(_write(tmp_path, f"[[unit]]\n{UNIT}reference_latency_tolerance = 2.0\n"))[1]
    assert units[0]["reference_latency_tolerance"] == 2.0


def test_a_missing_or_unreadable_file(tmp_path):
    missing = tmp_path / "none.toml"
    with pytest.raises(BaselineError, match=re.escape(f"baseline {missing} does not exist or is not a file (create it "
                                                      "with --update-baseline)")):
        load_baseline(missing)
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"\xff\xfe[[unit]]")
    with pytest.raises(BaselineError, match=re.escape(f"baseline {bad}: cannot be read: ")):
        load_baseline(bad)
    with pytest.raises(BaselineError, match=re.escape(f"baseline {tmp_path} does not exist or is not a file")):
        load_baseline(tmp_path)


# ---------------------------------------------------------------- the rewrite
ROW = {"case": "cube", "method": "pod", "options": '{"n":2}', "error": 0.02, "latency_per_calibration": 0.5,
       "latency_per_reference": 0.02, "flagged_steps": 1}


def test_update_writes_defaults_and_sorted_units(tmp_path):
    p = tmp_path / "sub" / "dir" / "base.toml"
    rows = {unit_identity("z", "m", "{}"): {**ROW, "case": "z", "method": "m", "options": "{}"},
            unit_identity("a", "m", "{}"): {**ROW, "case": "a", "method": "m", "options": "{}"}}
    assert update_baseline(rows, p) == 2
    defaults, units = load_baseline(p)
    assert defaults == DEFAULTS and [u["case"] for u in units] == ["a", "z"] and units[0]["error"] == 0.02
    doc = tomlkit.parse(p.read_text())
    assert dict(doc["defaults"]) == DEFAULTS
    assert list(p.parent.iterdir()) == [p]  # no temporary file left


def test_update_keeps_comments_defaults_and_overrides_and_replaces_damaged_units(tmp_path):
    unit = UNIT.replace('{"n":2,"a":1}', '{"n":2}')
    p = _write(tmp_path, "# keep me\n[defaults]\nerror_rtol = 0.5\n"
                         f"[[unit]]\ncase = \"broken\"\n[[unit]]\n{unit}error_atol = 0.125\n")
    rows = {unit_identity("cube", "pod", '{"n":2}'): ROW}
    assert update_baseline(rows, p) == 1
    text = p.read_text()
    assert text.startswith("# keep me\n")
    defaults, units = load_baseline(p)
    assert defaults["error_rtol"] == 0.5 and "error_atol" not in p.read_text().split("[[unit]]")[0]
    assert units[0]["error_atol"] == 0.125 and units[0]["error"] == 0.02 and units[0]["flagged_steps"] == 1
    assert len(units) == 1


def test_update_refuses_no_rows_a_folder_and_bad_toml(tmp_path):
    p = tmp_path / "b.toml"
    with pytest.raises(BaselineError, match=re.escape(f"--update-baseline: the results have no unit that finished ok; "
                                                      f"{p} is left as it was (a baseline of failed units would gate "
                                                      "nothing)")):
        update_baseline({}, p)
    with pytest.raises(BaselineError, match=re.escape(f"baseline {tmp_path}: not a file")):
        update_baseline({("a", "b", "{}"): ROW}, tmp_path)
    p.write_text("[[unit\n")
    with pytest.raises(BaselineError, match=re.escape(f"{p}: not valid TOML, not overwritten: ")):
        update_baseline({("a", "b", "{}"): ROW}, p)
    assert p.read_text() == "[[unit\n"


def test_update_that_cannot_write_names_the_file(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    target = blocker / "b.toml"
    # a parent that is a file: refused as an output path before any write, naming the option and the file
    with pytest.raises(OutputPathError, match="^" + re.escape(f"--baseline {target}: '{blocker}' is not a folder")
                       + "$"):
        update_baseline({("a", "b", "{}"): ROW}, target)


def test_the_rewrite_goes_through_a_hidden_temporary_beside_the_file(tmp_path, monkeypatch):
    # beside it: os.replace is atomic on one file system only; hidden: a kill leaves no stray baseline
    p = _write(tmp_path, "# old\n")
    moves = []

    def refuse(src, dst):
        moves.append((Path(src), Path(dst)))
        raise PermissionError(errno.EACCES, "denied")

    monkeypatch.setattr(atomic_files.os, "replace", refuse)
    with pytest.raises(BaselineError, match="^" + re.escape(f"baseline {p}: cannot be written: denied") + "$"):
        update_baseline({("a", "b", "{}"): ROW}, p)
    (src, dst), = moves
    assert dst == p and src.parent == p.parent and src.name.startswith(".b.toml.") and src.name.endswith(".tmp")
    assert sorted(tmp_path.iterdir()) == [p] and p.read_text() == "# old\n"


def test_an_interrupted_rewrite_leaves_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    p = _write(tmp_path, "# old\n")

    def interrupt(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(atomic_files.os, "fsync", interrupt)
    with pytest.raises(KeyboardInterrupt):
        update_baseline({("a", "b", "{}"): ROW}, p)
    assert sorted(tmp_path.iterdir()) == [p] and p.read_text() == "# old\n"
