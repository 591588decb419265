"""Reliability of ``tissuebench run`` (issue 16, issue 11 §4): every finding is a named test.

Bad scenes and meshes get errors naming the key and value; runs to divergence that measure
nothing fail; output locations are checked before any work and names cannot escape ``out/``;
a full disk or a read-only folder leaves nothing behind; leftovers of killed runs are
cleaned; dynamics write a ParaView time series; the picture is rendered without a VTK
warning; the progress bar reads in load factor or time.
"""
from __future__ import annotations

import errno
import io
import json
import os
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import meshio
import numpy as np
import pandas as pd
import pytest

from tissuebench.cases.io import read_mesh
from tissuebench.cases.meshes import box_mesh
from tissuebench.cases.scene import CATALOGUE_DIR, load
from tissuebench.cli import main
from tissuebench.refsolvers.mesh import Mesh
from tissuebench.reports.run_files import write_result
from tissuebench.reference.runner import progress_bar
from tissuebench.studies.run import default_out, run_case, safe_name
from tissuebench.studies.atomic_folders import clean_leftovers

ROOT = Path(__file__).resolve().parents[2]


def scene_copy(tmp_path, case, replace=(), name=None):
    """A copy of catalogue ``case`` with text replacements (each must apply)."""
    text = (CATALOGUE_DIR / f"{case}.toml").read_text()
    for old, new in replace:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / f"{name or case + '_copy'}.toml"
    path.write_text(text)
    return path


def folded_box():
    """2 x 2 x 2 box of 48 tetrahedra, its centre vertex pushed through the bottom: 6 cells
    inverted, overlapping their neighbours."""
    m = box_mesh((1.0, 1.0, 1.0), (2, 2, 2), "tetra")
    pts = m.points.copy()
    pts[np.argmin(np.linalg.norm(pts - 0.5, axis=1))] = [0.5, 0.5, -0.5]
    return pts, m.cells.copy()


# ------------------------------------------------------------------------------ meshes
def test_folded_mesh_with_mixed_orientation_is_refused_naming_the_cells():
    pts, cells = folded_box()
    with pytest.raises(ValueError, match=r"folded mesh: cells \[(\d+, ){5}\d+\] are inverted.*6 of 48"):
        Mesh(pts, cells, "tetra")


def test_folded_mesh_file_fails_the_run_with_exit_2_naming_the_cells(tmp_path, capsys):
    path = tmp_path / "folded.vtu"
    meshio.Mesh(*folded_box()[:1], [("tetra", folded_box()[1])]).write(path)
    scene = scene_copy(tmp_path, "liver_palpation", [("[mesh.ci]\n", f'[mesh.ci]\npath = "{path}"\n')])
    assert main(["run", str(scene), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "folded mesh: cells [" in err
    assert not (tmp_path / "out").exists()


def test_mixed_node_order_without_a_fold_is_reoriented_and_counted():
    m = box_mesh((1.0, 1.0, 1.0), (2, 2, 2), "tetra")
    cells = m.cells.copy()
    cells[:7] = cells[:7][:, [0, 2, 1, 3]]
    fixed = Mesh(m.points, cells, "tetra")
    assert fixed.n_reoriented == 7 and fixed.cell_volumes().sum() == pytest.approx(1.0)


def test_duplicate_and_overlapping_cells_in_a_file_are_refused(tmp_path):
    m = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "tetra")
    path = tmp_path / "dup.vtu"
    meshio.Mesh(m.points, [("tetra", np.vstack([m.cells, m.cells[2:3]]))]).write(path)
    with pytest.raises(ValueError, match=r"dup.vtu: duplicate cells: cells \[2, 6\]"):
        read_mesh(path)


def test_uniformly_negative_mesh_is_reoriented_and_said_in_the_manifest(tmp_path, monkeypatch):
    m = box_mesh((100.0, 100.0, 100.0), (2, 2, 2), "tetra")  # mm, like the shipped liver
    path = tmp_path / "negative.vtu"
    meshio.Mesh(m.points, [("tetra", m.cells[:, [0, 2, 1, 3]])]).write(path)
    scene = scene_copy(tmp_path, "liver_palpation", [("[mesh.ci]\n", f'[mesh.ci]\npath = "{path}"\n'),
                                                     ("load_steps = 20", "load_steps = 2"),
                                                     ("max_load_factor = 10.0", "max_load_factor = 0.1")])
    monkeypatch.setattr("tissuebench.reports.plots.plot_deformed", lambda *a, **k: "stub")
    out = tmp_path / "out"
    main(["run", str(scene), "--out", str(out), "--quiet"])
    mesh_info = json.loads((out / "manifest.json").read_text())["info"]["mesh"]
    assert mesh_info["reoriented_cells"] == 48 and "node-order convention" in mesh_info["orientation_note"]


# ------------------------------------------------------------------------------ divergence
@pytest.mark.parametrize("edit, message", [
    (("value = [0.0, 0.0, -0.014]", "value = [0.0, 0.0, -140.0]"), "no load increment converged"),
    (("E = 2.0", "E = 1e308"), "no load increment converged"),
])
def test_run_to_divergence_that_converges_nothing_fails_with_exit_1(tmp_path, edit, message):
    scene = scene_copy(tmp_path, "cornea_pinch",
                       [edit, ("load_steps = 10", "load_steps = 10\nstop_at_divergence = true")])
    out = tmp_path / "out"
    assert main(["run", str(scene), "--out", str(out), "--quiet"]) == 1
    m = json.loads((out / "manifest.json").read_text())
    assert m["status"] == "failed" and not m["ok"] and message in m["message"]


def test_run_to_divergence_with_a_non_finite_residual_fails():
    from types import SimpleNamespace as NS

    from tissuebench.reference.runner import _divergence_verdict

    ok = NS(converged=True, residual_norms=[1.0, 1e-12], load_factor=0.5)
    bad = NS(converged=False, residual_norms=[np.inf], load_factor=1.0)
    res = NS(increments=[ok, bad], converged_increments=[ok])
    assert _divergence_verdict(res, "stalled at 1")[0] == "failed"
    diverging = NS(converged=False, residual_norms=[1.0, 1e3, np.inf], load_factor=1.0)  # a diverging iterate
    res = NS(increments=[ok, diverging], converged_increments=[ok])
    assert _divergence_verdict(res, "stalled at 1") == ("stalled", "stalled at 1")


# ------------------------------------------------------------------------------ loader findings
def _set(*path_value):
    *path, value = path_value

    def edit(doc):
        target = doc
        for k in path[:-1]:
            target = target[k]
        target[path[-1]] = value
    return edit


LOADER_FINDINGS = [  # (finding of issue 16, edit of the parsed cube_tension_twist scene, text of the error)
    ("case_is_a_number", _set("case", 5), "case = 5: expected a table"),
    ("integer_literal_beyond_float", _set("material", "mu1", 10 ** 400), "material.mu1 = 1000"),
    ("history_type_is_a_list", _set("variants", "tension", "load", [
        {"type": "point", "region": {"all": True}, "value": [0.0, 0.0, 0.0], "history": {"type": ["ramp"]}}]),
     "load[0].history.type = ['ramp']"),
    ("component_is_a_table", _set("dirichlet", 0, "components", [{"a": 1}]), "dirichlet[0].components = [{'a': 1}]"),
    ("material_name_is_a_list", _set("material", "name", ["svk"]), "material.name = ['svk']"),
    ("default_variant_is_a_list", _set("case", "default_variant", ["x"]), "case.default_variant = ['x']"),
    ("variant_load_not_an_array", _set("variants", "tension", "load", 5), "variants.tension.load = 5"),
    ("variant_paper_not_a_table", _set("variants", "tension", "paper", 5), "variants.tension.paper = 5"),
    ("variants_not_a_table", _set("variants", 5), "variants = 5: expected a table"),
    ("variant_name_is_a_list", None, "variant = ['tension']"),
    ("builder_divisions_a_string", _set("mesh", "ci", "divisions", "12,3,3"), "mesh.ci.divisions = '12,3,3'"),
    ("builder_divisions_too_many_cells", _set("mesh", "ci", "divisions", [12000, 3000, 3000]),
     "mesh.ci = {'divisions': [12000, 3000, 3000]}: asks for about"),
    ("builder_unknown_parameter", _set("mesh", "params", "lenghts", [1, 1, 1]), "mesh.params.lenghts: not a parameter"),
    ("case_name_is_a_list", _set("case", "name", ["a"]), "case.name = ['a']"),
    ("case_name_with_a_nul_byte", _set("case", "name", "a\x00b"), "case.name = 'a\\x00b'"),
    ("monitor_name_is_a_list", _set("monitor", 0, "name", ["m"]), "monitor[0].name = ['m']"),
    ("monitor_name_overwrites_a_column", _set("monitor", 0, "name", "step"), "monitor[0].name = 'step'"),
    ("load_steps_absurd", _set("analysis", "load_steps", 10 ** 9), "analysis.load_steps = 1000000000"),
    ("unknown_key_with_control_characters", _set("material", "a\x07b", 1), "material.'a\\x07b': unknown key"),
]


@pytest.mark.parametrize("finding, edit, named", LOADER_FINDINGS, ids=[f[0] for f in LOADER_FINDINGS])
def test_loader_findings_raise_errors_naming_key_and_value(tmp_path, finding, edit, named):
    from _fuzz import dumps

    doc = tomllib.loads((CATALOGUE_DIR / "cube_tension_twist.toml").read_text())
    if edit is not None:
        edit(doc)
    path = tmp_path / "bad.toml"
    path.write_text(dumps(doc))
    with pytest.raises(ValueError) as exc:
        load(path, variant=["tension"] if finding == "variant_name_is_a_list" else None)
    assert named in str(exc.value)


def test_scene_file_that_is_not_toml_or_not_utf8_is_named(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text("a = 1" + "0" * 5000)  # beyond Python's digit limit for int()
    with pytest.raises(ValueError, match="not valid TOML"):
        load(path)
    path.write_bytes(b"[case]\nname = \"\xff\"\n")
    with pytest.raises(ValueError, match="not UTF-8"):
        load(path)


def test_tiny_time_step_is_refused_naming_dt(tmp_path):
    from _fuzz import dumps

    doc = tomllib.loads((CATALOGUE_DIR / "wave_block.toml").read_text())
    doc["analysis"]["dt"] = 1e-300
    (tmp_path / "bad.toml").write_text(dumps(doc))
    with pytest.raises(ValueError, match=r"analysis.dt = 1e-300: t_end / dt = .* time steps; at most"):
        load(tmp_path / "bad.toml")


@pytest.mark.parametrize("scene, mu, named", [
    ("wave_block", {"t_end": 1e9}, r"mu.t_end = 1000000000.0: t_end / dt = 8e\+11"),
    ("cornea_pinch", {"load_steps": 10 ** 9}, r"mu.load_steps = 1000000000: expected an integer")])
def test_parameter_overrides_are_bounded_like_the_scene(scene, mu, named):
    with pytest.raises(ValueError, match=named):
        load(scene).at(mu)


# ------------------------------------------------------------------------------ output locations
@pytest.fixture
def no_solve(monkeypatch):
    """Any solve is a failure of the test: the checks must come first."""
    def refuse(*args, **kwargs):
        raise AssertionError("solved before the output location was checked")
    monkeypatch.setattr("tissuebench.studies.run.solve", refuse)


def test_output_under_a_file_is_refused_before_any_work(tmp_path, capsys, no_solve):
    afile = tmp_path / "passwd"
    afile.write_text("x")
    assert main(["run", "cornea_pinch", "--out", str(afile / "x"), "--quiet"]) == 2
    assert "is not a folder" in capsys.readouterr().err
    assert main(["run", "cornea_pinch", "--out", str(afile), "--quiet"]) == 2
    assert "exists and is not a folder" in capsys.readouterr().err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_output_folder_is_refused_before_any_work(tmp_path, capsys, no_solve):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main(["run", "cornea_pinch", "--out", str(ro / "x"), "--quiet"]) == 2
        assert "is not writable" in capsys.readouterr().err
    finally:
        ro.chmod(0o755)


def test_unwritable_parent_is_refused_before_any_work(tmp_path, capsys, no_solve, monkeypatch):
    # as root no folder is read-only: the write probe itself fails, as on a read-only mount
    import tissuebench.studies.atomic_folders as store

    monkeypatch.setattr(store, "_writable", lambda folder: False)
    assert main(["run", "cornea_pinch", "--out", str(tmp_path / "x"), "--quiet"]) == 2
    assert "is not writable" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_nul_byte_in_out_is_refused_before_any_work(tmp_path, capsys, no_solve):
    assert main(["run", "cornea_pinch", "--out", str(tmp_path / "a\0b"), "--quiet"]) == 2
    assert "NUL byte" in capsys.readouterr().err


def test_full_disk_exits_1_and_leaves_nothing(tmp_path, capsys, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(pd.DataFrame, "to_parquet", full)
    out = tmp_path / "res"
    assert main(["run", "frame_2dof", "--out", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert f"cannot write the results to {out}" in err and "No space left on device" in err
    assert "Traceback" not in err and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name, folder", [("../../x", "x-skfem-ci"), ("<script>alert(1)</script>",
                                                                        "script_alert_1_script-skfem-ci")])
def test_case_names_cannot_escape_the_output_folder(tmp_path, monkeypatch, name, folder):
    path = scene_copy(tmp_path, "frame_2dof", [('name = "frame_2dof"', f'name = "{name}"')])
    assert default_out(load(path), "skfem", "ci") == Path("out") / folder
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert main(["run", str(path), "--quiet"]) == 0
    assert [p.relative_to(work).as_posix() for p in work.rglob("manifest.json")] == [f"out/{folder}/manifest.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_2dof_copy.toml", "work"]


def test_safe_name_keeps_plain_names_and_never_returns_an_empty_or_hidden_one():
    assert safe_name("liver_palpation") == "liver_palpation"
    assert safe_name("..") == "case" and safe_name("/") == "case" and safe_name(".hidden") == "hidden"


# ------------------------------------------------------------------------------ leftovers
def test_leftovers_of_killed_runs_are_cleaned_and_live_ones_kept(tmp_path):
    out = tmp_path / "res"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        stale, running = tmp_path / f".res.tmp-{dead}-abcd", tmp_path / f".res.tmp-{live.pid}-efgh"
        legacy = tmp_path / ".res.k2j4h5g6"  # mkdtemp name of earlier versions
        for p in (stale, running, legacy):
            p.mkdir()
            (p / "results.parquet").write_bytes(b"half")
        os.utime(legacy, (time.time() - 7200, time.time() - 7200))
        assert sorted(clean_leftovers(out)) == sorted([stale, legacy])
        assert running.is_dir()
    finally:
        live.kill()
        live.wait()


def test_a_run_killed_between_its_renames_gets_the_previous_result_back(tmp_path):
    out = tmp_path / "res"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True).stdout.strip()
    old = tmp_path / f".res.old-{dead}"
    old.mkdir()
    (old / "manifest.json").write_text("{}")
    clean_leftovers(out)
    assert (out / "manifest.json").is_file() and not old.exists()


# ------------------------------------------------------------------------------ issue 11 §4
def test_progress_bar_reads_in_load_factor_or_time():
    for analysis, done, total, text in (("static", 0.5, 10.0, "load factor 0.5/10"), ("dynamic", 1.25, 5.0,
                                                                                       "t 1.25/5 s")):
        stream = io.StringIO()
        bar, update = progress_bar("case", analysis, file=stream)
        update(done, total)
        bar.close()
        shown = stream.getvalue().replace("\r", "\n").strip().splitlines()[-1]
        assert text in shown and f"{100 * done / total:3.0f}%" in shown, shown
        assert "/100%" not in shown


@pytest.mark.parametrize("case", ["wave_block", "frame_2dof"])
def test_dynamic_runs_write_a_paraview_time_series(tmp_path, case, monkeypatch):
    pv = pytest.importorskip("pyvista")
    monkeypatch.setattr("tissuebench.reports.plots.plot_deformed", lambda *a, **k: "stub")
    out = tmp_path / case
    write_result(run_case(case, progress=False), load(case), out)
    fields = np.load(out / "fields.npz", allow_pickle=False)
    reader = pv.get_reader(str(out / "motion.pvd"))
    assert np.allclose(reader.time_values, fields["steps"], rtol=0, atol=0)
    for k in (1, len(fields["steps"]) // 2, len(fields["steps"]) - 1):
        reader.set_active_time_value(reader.time_values[k])
        grid = reader.read()[0]
        vtu = meshio.read(out / "motion" / f"step_{k:05d}.vtu")
        if case == "wave_block":
            np.testing.assert_array_equal(grid.point_data["displacement"], fields["displacement"][k])
            np.testing.assert_array_equal(vtu.point_data["displacement"], fields["displacement"][k])
        else:
            np.testing.assert_array_equal(vtu.point_data["u"], fields["displacement"][k][:, 0])
        np.testing.assert_array_equal(vtu.points, fields["points"])


def test_run_prints_no_vtk_warning_and_renders_off_screen(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(PYTHONPATH=str(ROOT), PYVISTA_OFF_SCREEN="true")
    out = tmp_path / "res"
    # the command's own process never imports VTK (a Ctrl-C in its import segfaulted)
    code = ("import sys; from tissuebench.cli import main; rc = main(sys.argv[1:]); "
            "print('VTK imported' if 'vtkmodules' in sys.modules else 'VTK not imported'); sys.exit(rc)")
    done = subprocess.run([sys.executable, "-c", code, "run", "cornea_pinch", "--out", str(out), "--quiet"],
                          env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    # stderr holds nothing: the cornea's reference is the mean-dilatation Q1, which does not lock (issue 54)
    assert done.stderr == "", done.stderr
    assert done.stdout.endswith("VTK not imported\n")
    for text in ("X server", "WARN", "vtkXOpenGL", "Traceback"):
        assert text not in done.stdout
    renderer = json.loads((out / "manifest.json").read_text())["files"]["deformed.png"]
    assert renderer in ("rendered by pyvista", "rendered by matplotlib")
    assert (out / "deformed.png").stat().st_size > 10_000


def test_when_no_renderer_works_matplotlib_draws_the_picture(tmp_path, monkeypatch):
    import tissuebench.reports.plots as plots

    tried = []
    monkeypatch.setattr(plots, "_render_in_child", lambda *a: tried.append(a[-1]) or False)  # every child crashes
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.delenv("VTK_DEFAULT_OPENGL_WINDOW", raising=False)
    m = box_mesh((1.0, 1.0, 1.0), (2, 2, 2), "tetra")
    u = np.zeros(3 * m.n_vertices)
    u[2::3] = m.points[:, 0] * 0.1
    assert plots.plot_deformed(m, u, tmp_path / "d.png", title="t") == "matplotlib"
    assert tried == ["vtkEGLRenderWindow", "vtkOSOpenGLRenderWindow"]
    assert (tmp_path / "d.png").stat().st_size > 10_000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.png"]  # the temporary VTU is gone


@pytest.mark.parametrize("pid", [0, -1, True, 2 ** 63, "x", None, 1.5e30])
def test_a_lock_pid_that_is_not_a_positive_process_id_is_not_alive(pid):
    """A damaged lock file's pid: 0 and negative pids would signal process groups (always alive),
    True would be pid 1, a huge one raised OverflowError."""
    from tissuebench.studies.atomic_folders import process_alive

    assert process_alive(pid) is False


def test_this_process_is_alive():
    from tissuebench.studies.atomic_folders import process_alive

    assert process_alive(os.getpid()) and process_alive(str(os.getpid()))
