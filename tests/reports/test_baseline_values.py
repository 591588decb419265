"""Every numeric field of the gate's baseline file is finite (issue 37, item 2): ``error = inf``,
``latency_per_calibration = inf`` or ``defaults.error_atol = inf`` were accepted, and the gate then
passed an error of 0.5 against a true 0.179. Both sides of each field's boundary, without a sweep."""
from __future__ import annotations

import math
import re

import pytest

from tissuebench.gate import BaselineError, load_baseline
from tissuebench.gate.baseline import DEFAULTS, UNIT_KEYS
from tissuebench.gate.checks import _error_changed

UNIT = {"case": '"cornea_pinch"', "method": '"pod_interp"', "options": """'{"n_modes":4}'""", "error": "0.0123",
        "latency_per_calibration": "0.012", "latency_per_reference": "0.0004", "flagged_steps": "0"}
FLOAT_UNIT_KEYS = [k for k, kind in UNIT_KEYS.items() if kind is float]
# the largest finite value each field accepts (tolerances > 1 allowed up to any finite number)
BIG = "1.0e300"


def _baseline(tmp_path, defaults=None, unit=None):
    d = {k: repr(v) for k, v in DEFAULTS.items()} | (defaults or {})
    u = UNIT | (unit or {})
    text = "[defaults]\n" + "".join(f"{k} = {v}\n" for k, v in d.items())
    text += "\n[[unit]]\n" + "".join(f"{k} = {v}\n" for k, v in u.items())
    path = tmp_path / "baseline.toml"
    path.write_text(text)
    return path


@pytest.mark.parametrize("value", ["inf", "+inf", "-inf", "nan", "-nan"])
@pytest.mark.parametrize("where, key", [("defaults", k) for k in DEFAULTS] + [("unit", k) for k in FLOAT_UNIT_KEYS]
                         + [("override", k) for k in DEFAULTS])
def test_a_non_finite_value_is_refused_naming_the_key_and_the_value(tmp_path, where, key, value):
    path = _baseline(tmp_path, **({"defaults": {key: value}} if where == "defaults" else {"unit": {key: value}}))
    name = f"defaults.{key}" if where == "defaults" else f"unit[0].{key}"
    shown = repr(float(value.replace("-nan", "nan")))
    with pytest.raises(BaselineError, match=rf"{re.escape(str(path))}: {re.escape(name)} = {re.escape(shown)}: must "
                                            "be a finite number"):
        load_baseline(path)


@pytest.mark.parametrize("where, key", [("defaults", k) for k in DEFAULTS] + [("unit", k) for k in FLOAT_UNIT_KEYS]
                         + [("override", k) for k in DEFAULTS])
def test_a_large_finite_value_is_accepted(tmp_path, where, key):
    path = _baseline(tmp_path, **({"defaults": {key: BIG}} if where == "defaults" else {"unit": {key: BIG}}))
    defaults, units = load_baseline(path)
    got = defaults[key] if where == "defaults" else units[0][key]
    assert got == 1e300


def test_an_integer_count_is_finite_by_type_and_its_range_still_holds(tmp_path):
    assert load_baseline(_baseline(tmp_path, unit={"flagged_steps": "9223372036854775807"}))[1][0]["flagged_steps"] \
        == 2 ** 63 - 1
    with pytest.raises(BaselineError, match=r"unit\[0\].flagged_steps = inf: expected an integer"):
        load_baseline(_baseline(tmp_path, unit={"flagged_steps": "inf"}))


@pytest.mark.parametrize("was, now, changed", [
    (math.inf, 0.5, True), (0.5, math.inf, True), (math.inf, math.inf, False), (0.179, 0.179, False),
    (0.179, 0.5, True)])
def test_an_infinite_error_on_either_side_is_a_change(was, now, changed):
    """The gate's comparison itself: inf against a finite error is never within a tolerance
    (|inf - x| <= rtol * inf held before)."""
    tol = {"error_rtol": 1e-3, "error_atol": 1e-9}
    assert _error_changed(was, now, tol) is changed
