"""``evaluation.beyond`` is bounded at spec load (issue 37, item 5): ``beyond = [1e308]`` passed
spec load, then every unit failed with an OverflowError (the continuation's increments,
factor x load_steps, in studies/evaluation.py)."""
from __future__ import annotations

import re

import pytest

from tissuebench.studies.limits import MAX_BEYOND_FACTOR
from tissuebench.studies.spec import load_spec

SPEC = """
[sweep]
name = "b"
[[case]]
name = "cornea_pinch"
training = {{ kind = "path", every = 2 }}
evaluation = {{ kind = "path", beyond = [2.0, {factor}] }}
[[method]]
name = "nearest"
"""


@pytest.mark.parametrize("factor", ["1e308", "1.7976931348623157e308", "1e7", "1000000.0000001"])
def test_a_beyond_factor_past_the_bound_is_refused_naming_the_key_and_the_value(tmp_path, factor):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(factor=factor))
    shown = re.escape(repr(float(factor)))
    with pytest.raises(ValueError, match=rf"case\[0\].evaluation.beyond\[1\] = {shown}: expected at most "
                                         r"1e\+06 \(times the path's top load"):
        load_spec(spec)


@pytest.mark.parametrize("factor", ["1000000.0", "100.0", "1.5"])
def test_a_beyond_factor_up_to_the_bound_is_accepted(tmp_path, factor):
    spec = tmp_path / "spec.toml"
    spec.write_text(SPEC.format(factor=factor))
    assert float(factor) <= MAX_BEYOND_FACTOR
    assert load_spec(spec).cases[0].evaluation["beyond"] == [2.0, float(factor)]
