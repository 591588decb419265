"""The command line over the catalogue: cases, describe, run; its bad input and atomicity."""
from __future__ import annotations

import json

import meshio
import numpy as np
import pandas as pd
import pytest

from tissuebench.cases.scene import CATALOGUE_DIR, list_cases, load
from tissuebench.cli import main
from tissuebench.reports.run_files import write_result
from tissuebench.studies.run import run_case


def test_cases_lists_the_catalogue_with_sizes(capsys):
    assert main(["cases"]) == 0
    out = capsys.readouterr().out
    for name in list_cases():
        assert name in out
    # structured meshes are counted without meshing, at both resolutions
    assert "208 / 648" in out and "7744 / 37800" in out       # cube bar ci / paper
    assert "219 / 128" in out and "8365 / 6512" in out        # cornea ci / paper


@pytest.mark.parametrize("case,expected,absent", [
    ("liver_palpation", ["no mass matrix", "Newton-Raphson", "run until Newton stops converging"], ["lumped"]),
    ("frame_2dof", ["lumped mass", "no tangent per step"], ["no mass matrix"]),
    ("wave_block", ["consistent mass", "linear system", "factorised once"], ["Newton per time step"]),
    ("land_beam", ["follower pressure", "no mass matrix"], ["linear path"]),
])
def test_describe_says_what_is_modelled_and_why(case, expected, absent, capsys):
    assert main(["describe", case]) == 0
    out = capsys.readouterr().out
    for text in expected:
        assert text in out, text
    for text in absent:
        assert text not in out, text


def test_describe_svk_wave_block_iterates(capsys):
    assert main(["describe", "wave_block", "--variant", "svk"]) == 0
    assert "Newton per time step" in capsys.readouterr().out


def test_run_of_a_1d_case_writes_every_file(tmp_path):
    out = tmp_path / "frame"
    assert main(["run", "frame_2dof", "--out", str(out), "--quiet"]) == 0
    t = pd.read_parquet(out / "results.parquet")
    assert {"time", "u1", "u2", "kinetic_energy", "energy_error"} <= set(t.columns)
    assert len(t) == 501 and t["time"].iloc[-1] == pytest.approx(5.0)
    f = np.load(out / "fields.npz", allow_pickle=False)
    assert f["displacement"].shape[1:] == (3, 1) and list(f["components"]) == ["u"]
    assert meshio.read(out / "deformed.vtu").cells[0].type == "line"
    m = json.loads((out / "manifest.json").read_text())
    assert m["ok"] and m["backend"] == "line" and m["plan"]


def _scene_copy(tmp_path, case, replace):
    text = (CATALOGUE_DIR / f"{case}.toml").read_text()
    for old, new in replace:
        assert old in text, old
        text = text.replace(old, new)
    path = tmp_path / f"{case}_copy.toml"
    path.write_text(text)
    return path


def test_missing_mesh_file_is_named(tmp_path, capsys):
    missing = tmp_path / "nowhere" / "liver.vtu"
    scene = _scene_copy(tmp_path, "liver_palpation", [("[mesh.ci]\n", f"[mesh.ci]\npath = \"{missing}\"\n")])
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "does not exist" in err
    assert not (tmp_path / "out").exists()


def test_degenerate_mesh_file_is_refused_with_its_path(tmp_path, capsys):
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0.0]], float)
    cells = np.array([[0, 1, 2, 3], [0, 1, 2, 4]])  # the second is flat (z = 0)
    bad = tmp_path / "flat.vtu"
    meshio.Mesh(pts, [("tetra", cells)]).write(bad)
    scene = _scene_copy(tmp_path, "liver_palpation", [("[mesh.ci]\n", f"[mesh.ci]\npath = \"{bad}\"\n")])
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and ("zero" in err or "degenerate" in err)


def test_mistyped_and_unknown_keys_are_named(tmp_path, capsys):
    scene = _scene_copy(tmp_path, "land_beam", [("load_steps = 10", "load_steps = \"ten\"")])
    assert main(["run", str(scene), "--quiet"]) == 2
    assert "analysis.load_steps" in capsys.readouterr().err
    scene = _scene_copy(tmp_path, "land_beam", [("load_steps = 10", "load_step = 10")])
    assert main(["run", str(scene), "--quiet"]) == 2
    assert "load_step" in capsys.readouterr().err
    assert main(["run", "cube_tension_twist", "--variant", "bend", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "bend" in err and "tension" in err and "twist" in err


def test_a_run_that_fails_midway_leaves_nothing(tmp_path, monkeypatch):
    import tissuebench.reports.plots as plots

    def broken(*args, **kwargs):
        raise RuntimeError("renderer crashed")
    monkeypatch.setattr(plots, "plot_deformed", broken)
    out = tmp_path / "res"
    with pytest.raises(RuntimeError, match="renderer crashed"):
        write_result(run_case("cornea_pinch", progress=False), load("cornea_pinch"), out)
    assert list(tmp_path.iterdir()) == []  # neither the folder nor a temporary sibling


@pytest.mark.slow  # ~15 s: the ventricle to its pressure maximum; test_run_reliability keeps a failed run by default
def test_numerical_failure_is_stored_with_its_status(tmp_path):
    # the MR ventricle at 1 kPa passes its pressure maximum: Newton stalls; the run is stored, exit 1
    scene = _scene_copy(tmp_path, "left_ventricle", [("value = 0.5", "value = 1.0")])
    out = tmp_path / "lv"
    assert main(["run", str(scene), "--variant", "mooney_rivlin", "--out", str(out), "--quiet"]) == 1
    m = json.loads((out / "manifest.json").read_text())
    assert m["status"] == "stalled" and not m["ok"] and "last converged load factor" in m["message"]
    t = pd.read_parquet(out / "results.parquet")
    assert not t["converged"].iloc[-1] and t["apex_endo_z"].iloc[-1] != t["apex_endo_z"].iloc[-1]  # NaN, flagged


@pytest.mark.slow  # ~5 s: a liver run
def test_liver_without_the_shared_folder_runs_on_the_fallback_shape_and_says_so(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("TISSUEBENCH_DATA", str(tmp_path / "empty"))
    (tmp_path / "empty").mkdir()
    out = tmp_path / "liver"
    with pytest.warns(UserWarning, match="fallback"):
        code = main(["run", "liver_palpation", "--out", str(out), "--quiet"])
    assert code == 0
    assert "fallback" in capsys.readouterr().err
    m = json.loads((out / "manifest.json").read_text())
    assert m["info"]["mesh"]["fallback"] is True and m["ok"]
