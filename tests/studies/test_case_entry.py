"""The typed case entry of a sweep (studies/case_entry.py): its dict form is the one unit keys
hash and ``_sweep.json`` stores, it travels to a dask worker, and it refuses a malformed field
naming the field and the value."""
from __future__ import annotations

import json

import pytest
from distributed.protocol import deserialize, serialize

from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.spec import expand_units, load_spec
from tissuebench.studies.units import unit_key

TINY = """[sweep]
name = "entry"
[[case]]
name = "cornea_pinch"
id = "pinch"
training = { kind = "path", every = 2 }
evaluation = { kind = "path", held_out = true }
[[case]]
name = "cube_tension_twist"
variant = "tension"
mu = { load_scale = 0.5 }
mesh = { ci = { divisions = [8, 2, 2] } }
[[method]]
name = "nearest"
"""


@pytest.fixture(scope="module")
def spec(tmp_path_factory):
    path = tmp_path_factory.mktemp("entry") / "entry.toml"
    path.write_text(TINY)
    return load_spec(path)


def test_the_dict_form_is_the_one_the_spec_wrote(spec):
    pinch, cube = spec.cases
    assert pinch.as_dict() == {"id": "pinch", "name": "cornea_pinch", "variant": None, "resolution": "ci",
                               "backend": "skfem", "training": {"kind": "path", "every": 2},
                               "evaluation": {"kind": "path", "held_out": True}}
    # optional keys appear only where the spec gave them, after the others, in this order
    assert list(cube.as_dict()) == ["id", "name", "variant", "resolution", "backend", "training", "evaluation",
                                    "mu", "mesh"]
    assert cube.evaluation == {"kind": "path"} and cube.mesh_at_resolution() == {"divisions": [8, 2, 2]}
    for c in spec.cases:
        assert CaseEntry.from_dict(json.loads(json.dumps(c.as_dict()))) == c  # _sweep.json round trip
        assert deserialize(*serialize(c)) == c  # as the dask executor ships a unit to a worker


def test_unit_keys_hash_the_dict_form(spec):
    for u in expand_units(spec):
        scene_hash = u.key  # any fixed text: the key hashes it beside the case
        assert unit_key(u.case, scene_hash, u.method, u.options, u.protocol) == unit_key(
            CaseEntry.from_dict(u.case.as_dict()), scene_hash, u.method, u.options, u.protocol)


def test_the_entry_is_frozen_and_as_dict_a_copy(spec):
    pinch = spec.cases[0]
    with pytest.raises(AttributeError):
        pinch.backend = "ngsolve"
    pinch.as_dict()["training"]["every"] = 5
    assert pinch.training["every"] == 2


def test_defaults_fill_the_kinds_as_the_spec_does():
    assert CaseEntry(id="c", name="cornea_pinch").training == {"kind": "path"}
    assert CaseEntry(id="c", name="cornea_pinch").evaluation == {"kind": "path"}
    # a training kind that is no evaluation kind: measured on a map, as load_spec defaults it
    assert CaseEntry(id="c", name="cornea_cut", training={"kind": "operators"}).evaluation_kind == "map"


@pytest.mark.parametrize("field, value, match", [
    ("backend", 3, "backend = 3: expected a string"),
    ("variant", ["a"], r"variant = \['a'\]: expected a string or None"),
    ("mu", [1.0], r"mu = \[1.0\]: expected a table or None"),
    ("training", {"kind": "nope"}, "training.kind = 'nope': valid: "),
    ("evaluation", {"kind": "nope"}, "evaluation.kind = 'nope': valid: "),
    ("paper_points", {"label": "x"}, "paper_points = .*expected a list"),
])
def test_a_malformed_field_is_named_with_its_value(field, value, match):
    with pytest.raises(ValueError, match=match):
        CaseEntry(id="c", name="cornea_pinch", **{field: value})


def test_from_dict_refuses_an_unknown_key():
    with pytest.raises(TypeError, match="case entry.bogus: unknown key"):
        CaseEntry.from_dict({"id": "c", "name": "cornea_pinch", "bogus": 1})
