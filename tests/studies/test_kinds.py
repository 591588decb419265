"""Training and evaluation kinds are registries (:mod:`tissuebench.studies.kinds`): each kind
declares its options, value checks, builder and the references it reads, and the spec, the
applicability rules and the units read them from there (issue 29: before, the keys were a table in
``spec.py`` beside the builders' if-chain). Shown by a toy kind registered from this test module:
the spec accepts its declared option, refuses any other naming it, and runs its value check."""
from __future__ import annotations

import pytest

from tissuebench.rom import method_class
from tissuebench.studies.evaluation import EVALUATION_KINDS, NEEDS_MODEL
from tissuebench.studies.kinds import Kind
from tissuebench.studies.spec import load_spec
from tissuebench.studies.training import TRAINING_KINDS

SPEC = """
[sweep]
name = "toy-kind"
[[case]]
name = "frame_2dof"
training = {TRAINING}
evaluation = { kind = "trajectory" }
[[method]]
name = "pgd_direct"
"""


@pytest.mark.parametrize("registry", [TRAINING_KINDS, EVALUATION_KINDS], ids=["training", "evaluation"])
def test_every_kind_declares_the_contract(registry):
    for name, kind in registry.items():
        assert isinstance(kind, Kind) and kind.name == name
        assert isinstance(kind.keys, frozenset) and all(isinstance(k, str) for k in kind.keys)
        assert "kind" not in kind.keys
        assert callable(kind.build) and callable(kind.references) and callable(kind.check)
    assert NEEDS_MODEL == tuple(n for n, k in EVALUATION_KINDS.items() if k.needs_model) == ("cut_lengths",
                                                                                            "contact_nodes")
    assert {k.analysis for k in TRAINING_KINDS.values()} == {"static", "dynamic", None}


def _spec(tmp_path, training):
    p = tmp_path / "toy.toml"
    p.write_text(SPEC.replace("{TRAINING}", training))
    return load_spec(p)


def test_a_kind_registered_elsewhere_is_validated_from_its_declaration(tmp_path, monkeypatch):
    seen = []

    def check(path, table, scene, training):
        seen.append((path, dict(table)))
        if table.get("alpha", 0) < 0:
            raise ValueError(f"{path}.alpha = {table['alpha']!r}: expected >= 0")

    trajectory = TRAINING_KINDS["trajectory"]
    toy = Kind("toy", frozenset({"alpha"}), trajectory.build, trajectory.references, check, analysis="dynamic")
    monkeypatch.setitem(TRAINING_KINDS, "toy", toy)
    method = method_class("pgd_direct")  # a method that learns from it: the other half of the plug
    monkeypatch.setattr(method, "training_kinds", (*method.training_kinds, "toy"))
    spec = _spec(tmp_path, '{ kind = "toy", alpha = 2 }')
    assert spec.cases[0].training == {"kind": "toy", "alpha": 2}
    assert seen == [("case[0].training", {"kind": "toy", "alpha": 2})]
    with pytest.raises(ValueError, match=r"case\[0\]\.training.*beta"):
        _spec(tmp_path, '{ kind = "toy", beta = 1 }')
    with pytest.raises(ValueError, match=r"case\[0\]\.training\.alpha = -1"):
        _spec(tmp_path, '{ kind = "toy", alpha = -1 }')
    with pytest.raises(ValueError, match=r"case\[0\]\.training.*every"):  # another kind's option
        _spec(tmp_path, '{ kind = "toy", every = 2 }')
