"""The convergence check's h/2 run (issue 54, item 2): the formulation that does not lock where the
scene asks for P1 that locks, and a refinement that would not fit refused before any solve."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.cli import main
from tissuebench.reference import convergence
from tissuebench.reference.convergence import RefinementTooLarge, convergence_check, refined_formulation
from tissuebench.reference.formulation import Formulation
from tissuebench.reference.runner import solve
from tissuebench.reference.memory import MEMORY_MARGIN, RefinedMemory, size_text

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _mesh_scene import TIP_MONITOR as MONITOR, scene_file, write_block  # noqa: E402

SCENES = Path(__file__).resolve().parents[2] / "tissuebench" / "studies" / "presets" / "scenes"
LOCKS = {"computed": True, "locks": True, "deviation": -0.3}
DOES_NOT_LOCK = {"computed": True, "locks": False, "deviation": -0.01}


#: an estimate of 2 GB, whatever this process's memory did (the probe itself: test_memory_estimate.py)
TWO_GB = RefinedMemory(2_000_000_000, 100_000_000, 100_000_000, 108, 600, 0.01)


@pytest.fixture
def block(tmp_path, monkeypatch):
    write_block(tmp_path)
    monkeypatch.setattr(convergence, "estimate_refined_peak", lambda backend, n: TWO_GB)
    return scene_file(tmp_path, extra=MONITOR)


def test_p1_that_locks_is_checked_against_anp_at_h_half_and_same_formulation_keeps_it():
    scene = load(SCENES / "dome_p1.toml")
    p1 = Formulation("displacement", "P1", "mesh.element = 'P1' asked for", indicator=LOCKS)
    name, why = refined_formulation(scene, p1)
    assert name == "anp" and "P1 locks on the h mesh" in why and "--same-formulation" in why
    assert refined_formulation(scene, p1, same_formulation=True) == ("displacement", "the h mesh's")
    # the other side of the indicator's verdict, and an indicator not computed: the h mesh's
    for ind in (DOES_NOT_LOCK, {"computed": False, "why": "not nearly incompressible"}, None):
        form = Formulation("displacement", "P1", "asked", indicator=ind)
        assert refined_formulation(scene, form) == ("displacement", "the h mesh's")
    # a formulation that does not lock already, and a law without a volumetric part, keep theirs
    assert refined_formulation(scene, Formulation("anp", "P1", "chosen", indicator=LOCKS))[0] == "anp"
    svk = dataclasses.replace(scene, material={"name": "saint_venant_kirchhoff", "E": 3000.0, "nu": 0.499})
    name, why = refined_formulation(svk, p1)
    assert name == "displacement" and "no formulation that does not lock" in why


def test_a_refinement_estimated_above_the_limit_is_refused_before_any_solve(block, monkeypatch):
    def no_solve(*_args, **_kwargs):
        raise AssertionError("solved although the refinement was refused")

    monkeypatch.setattr(convergence, "solve", no_solve)
    scene = load(block)
    said = []
    limit = int(MEMORY_MARGIN * TWO_GB.peak)  # the margin's product: a byte below it is refused
    product = size_text(MEMORY_MARGIN * TWO_GB.peak)
    refused = rf"would not fit: h/2 estimated at 2 GB .* x {MEMORY_MARGIN:g} margin = {product} > memory_limit "
    refused += product
    with pytest.raises(RefinementTooLarge, match=refused + "; nothing was solved") as info:
        convergence_check(scene, "skfem", log=said.append, memory_limit=limit - 1)
    assert info.value.estimate is TWO_GB and info.value.limit == limit - 1
    assert any("h/2 estimated at 2 GB" in line for line in said)
    # the other side: at the margin's product the check runs
    monkeypatch.setattr(convergence, "solve", solve)
    table = convergence_check(scene, "skfem", memory_limit=limit)
    assert (table["status_h_half"] == "success").all()
    assert (table["memory_estimate_h_half"] == 2e9).all()
    with pytest.raises(ValueError, match="memory_limit must be > 0 bytes, got 0"):
        convergence_check(scene, "skfem", memory_limit=0)


def test_verify_refuses_a_refinement_over_memory_limit_with_the_estimate(block, capsys):
    assert main(["verify", "--convergence", str(block), "--backend", "skfem", "--memory-limit", "2.4"]) == 1
    err = capsys.readouterr().err  # 1.25 x 2 GB > 2.4 GB
    assert "verify: refused: block: the h/2 run would not fit: h/2 estimated at 2 GB" in err and "2.4 GB" in err
    assert "increment" not in err  # nothing solved
    assert main(["verify", "--convergence", str(block), "--memory-limit", "-1"]) == 2
    assert "--memory-limit must be > 0 GB, got -1" in capsys.readouterr().err


@pytest.mark.slow
def test_the_check_of_a_locking_p1_scene_solves_h_half_with_anp(capsys):
    """dome_p1 at ci (nu = 0.499, P1 asked for, 37 % short of ANP at h): h/2 with ANP, the table
    and the report say which formulation each mesh had; --same-formulation keeps P1 (P1 at h/2
    is stiffer than ANP at h/2, the locking the default's difference contains)."""
    assert main(["verify", "--convergence", str(SCENES / "dome_p1.toml"), "--backend", "skfem"]) == 0
    out = capsys.readouterr().out
    assert "h: P1 displacement" in out and "h/2: average nodal pressure tetrahedra (ANP) (P1 locks" in out
    scene = load(SCENES / "dome_p1.toml")
    anp = convergence_check(scene, "skfem")
    p1 = convergence_check(scene, "skfem", same_formulation=True)
    assert list(anp["formulation_h_half"]) == ["average nodal pressure tetrahedra (ANP)"]
    assert list(p1["formulation_h_half"]) == ["P1 displacement"]
    assert np.allclose(anp["h"], p1["h"], rtol=1e-12)  # the same h run
    assert abs(p1["h_half"].iloc[0]) < abs(anp["h_half"].iloc[0])  # P1 at h/2 still locks
    assert anp["rel_diff"].iloc[0] > p1["rel_diff"].iloc[0]
