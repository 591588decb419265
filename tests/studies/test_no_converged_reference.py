"""A reference that converged at no step is a failed unit saying so, naming the case (issue 37,
item 4): it was "cannot reshape array of size 0 into shape (0,newaxis) (in studies/training.py:61)"
on every unit of a sweep whose scene stalled at its first increment."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from tissuebench.studies.results import read_units
from tissuebench.studies.spec import load_spec
from tissuebench.studies.sweep import run_sweep
from tissuebench.studies.training import reference_states

from _mesh_scene import scene_file, write_block


def _ref(n_states):
    return SimpleNamespace(case="block", variant=None, backend="skfem", status="stalled", message="Newton stopped",
                           displacement=np.zeros((n_states, 5, 3)), steps=np.linspace(0.0, 1.0, n_states))


def test_a_reference_with_no_converged_state_is_refused_naming_the_case_and_why():
    with pytest.raises(RuntimeError, match=r"case 'block': the reference run \(skfem\) converged at no step, so there "
                                           r"is no state to learn from or measure against: stalled: Newton stopped"):
        reference_states(_ref(1))
    U, steps = reference_states(_ref(2))  # the other side: one converged state is a state
    assert U.shape == (15, 1) and steps.tolist() == [1.0]


def test_a_sweep_on_a_scene_whose_load_is_below_round_off_fails_its_units_saying_so(tmp_path):
    write_block(tmp_path)  # 40 x 20 x 20 mm, scaled to 40 000 km: 0.1 N is below round-off there
    scene = scene_file(tmp_path, mesh='file = "block.msh"\nscale = 1e6\nelement = "P1"')
    spec = tmp_path / "spec.toml"
    spec.write_text(f'[sweep]\nname = "tiny"\n[[case]]\nname = "{scene.name}"\nid = "path"\n'
                    'training = { kind = "path" }\nevaluation = { kind = "path" }\n'
                    '[[method]]\nname = "nearest"\n')
    run_sweep(load_spec(spec), tmp_path / "out", progress=False, log=lambda *a, **k: None)
    units = read_units(tmp_path / "out")
    assert units["unit_status"].tolist() == ["failed"]
    message = units["message"].iloc[0]
    assert message.startswith("RuntimeError: case 'block': the reference run (skfem) converged at no step"), message
    assert "the load is below round-off" in message and "cannot reshape" not in message, message
