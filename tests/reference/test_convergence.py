"""The reference's h/2 convergence check (issue 43): the refined scene, the CLI, the report."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tissuebench.cases.scene import load
from tissuebench.cli import main
from tissuebench.reference.convergence import CONVERGENCE_COLUMNS, refined_scene

SCENES = Path(__file__).resolve().parents[2] / "tissuebench" / "studies" / "presets" / "scenes"
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def test_refined_scene_halves_the_cells_and_keeps_the_formulation():
    scene = load(SCENES / "dome.toml")
    fine = refined_scene(scene, "anp")
    assert fine.mesh.n_cells == 8 * scene.mesh.n_cells
    assert fine.mesh.cell_volumes().sum() == pytest.approx(scene.mesh.cell_volumes().sum(), rel=1e-12)
    assert fine.analysis["formulation"] == "anp" and fine.content_hash() != scene.content_hash()
    # the selectors are re-evaluated on the refined mesh: the same load, more nodes
    f0 = scene.to_problem()
    f1 = fine.to_problem()
    assert len(f1.fixed_dofs) > len(f0.fixed_dofs)
    with pytest.raises(ValueError, match="refines tetrahedra"):
        refined_scene(load("cornea_pinch"), "displacement")


def test_the_refined_scene_takes_the_coarse_formulation_without_solving_its_own_indicator(monkeypatch):
    """The h/2 mesh's indicator would be two linear solves of the refined size (1.5 min at 108k
    dofs on the 5k-node organ), for a choice the h mesh made: not computed, and said why."""
    import tissuebench.reference.locking as locking
    from tissuebench.reference.formulation import formulation_of

    scene = load(SCENES / "dome.toml")
    fine = refined_scene(scene, "displacement")

    def refuse(*_args):
        raise AssertionError("the h/2 mesh solved its own locking indicator")

    monkeypatch.setattr(locking, "_indicator", refuse)
    for backend in ("skfem", "ngsolve"):
        form = formulation_of(fine, backend)
        assert form.name == "displacement" and not form.warning
        assert not form.indicator["computed"] and "h mesh's" in form.indicator["why"]
    # the other side: a scene not refined by the check computes its own (here: refused)
    with pytest.raises(AssertionError, match="solved its own"):
        formulation_of(_other_nu(scene))


def _other_nu(scene):
    import dataclasses

    return dataclasses.replace(scene, material={**scene.material, "nu": 0.4991})


@pytest.mark.slow
def test_verify_convergence_writes_the_table_the_report_shows(tmp_path, capsys):
    from _report_store import build_store

    results = build_store(tmp_path / "results")
    assert main(["verify", "--convergence", str(SCENES / "dome.toml"), str(results)]) == 0
    out = capsys.readouterr().out
    assert "apex_uz" in out and "average nodal pressure" in out
    table = pd.read_parquet(results / "_convergence.parquet")
    assert list(table.columns) == CONVERGENCE_COLUMNS and list(table["quantity"]) == ["apex_uz"]
    row = table.iloc[0]
    assert row["dofs_h_half"] > 5 * row["dofs_h"] and np.isfinite(row["rel_diff"])
    assert row["rel_diff"] == pytest.approx(abs(row["h"] - row["h_half"]) / abs(row["h_half"]))
    assert main(["report", str(results), "--out", str(tmp_path / "r.html")]) == 0
    html = (tmp_path / "r.html").read_text()
    assert "Reference convergence (h and h/2)" in html and "average nodal pressure tetrahedra" in html
    assert "No convergence check" not in html


def test_sweep_convergence_goes_with_a_scene(capsys):
    assert main(["sweep", "--preset", "extremes", "--convergence"]) == 2
    assert "--convergence go with --scene" in capsys.readouterr().err
