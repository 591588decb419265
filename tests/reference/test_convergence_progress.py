"""``tissuebench verify`` says what it does while it works (issue 50, item 8): the convergence
check printed its header and then nothing for 45 minutes on a 4.9k-node organ. Each mesh (its
size and formulation), each load increment (load factor, Newton iterations, residual) and each
mesh's end (status, time) is a line on stderr; ``--quiet`` silences them; stdout and the numbers
are those of a run without them."""
from __future__ import annotations

import os
import re

import pytest

from tissuebench.cases.scene import load
from tissuebench.cli import main
from tissuebench.reference import backend_comparison
from tissuebench.reference.cache import PROGRESS_ENV
from tissuebench.reference.convergence import _size, convergence_check
from tissuebench.reference.formulation import formulation_of
from tissuebench.reference.progress_lines import SolveLines
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.newton import newton_solve

from _mesh_scene import TIP_MONITOR as MONITOR, scene_file, write_block



@pytest.fixture
def block(tmp_path):
    """The 45-vertex block of tests/_mesh_scene.py (P1, nu = 0.45, 2 load steps), a monitor on its tip."""
    write_block(tmp_path)
    return scene_file(tmp_path, extra=MONITOR)


def _lines(text, label):
    return [line for line in text.splitlines() if line.startswith(label + ":")]


def test_verify_convergence_says_each_mesh_increment_and_end_on_stderr_and_quiet_silences_it(block, capsys):
    assert main(["verify", "--convergence", str(block), "--backend", "skfem"]) == 0
    out, err = capsys.readouterr()
    for mesh, vertices, dofs in (("h", 45, 135), ("h/2", 225, 675)):
        said = _lines(err, f"convergence block {mesh}")
        if mesh == "h/2":  # what comes before its solve: its formulation, its memory's estimate
            assert "refining the mesh (each tetrahedron split in eight)" in said.pop(0)
            assert re.search(r"h/2 estimated at \S+ [kMG]?B .*; the available memory \S+ [kMG]?B$", said.pop(0))
        size, *increments, end = said
        # P1 at nu = 0.45 locks on the block (its indicator): h/2 takes ANP (test_convergence_refinement.py)
        form = "P1 displacement" if mesh == "h" else "average nodal pressure tetrahedra (ANP)"
        assert f"{vertices} vertices" in size and f"{dofs} displacement dofs" in size and form in size
        assert "2 load steps" in size
        assert len(increments) == 2, said  # the scene's two load steps, each converged at once
        for k, (line, lam) in enumerate(zip(increments, ("0.5/1", "1/1")), start=1):
            assert re.search(rf"increment {k}: load factor {re.escape(lam)}, \d+ Newton iterations?, residual "
                             r"\S+ \(relative \S+\), converged \(\S+ s\)$", line), line
        assert re.search(r"done: success in \S+ s; tip_uy = -0\.00\d+$", end), end
    assert "formulation P1 displacement" in err and "both meshes in" in err
    assert "convergence block" not in out and "increment" not in out  # stdout: the header, the table, the how
    assert "dofs_h_half" in out and "tip_uy" in out

    assert main(["verify", "--convergence", str(block), "--backend", "skfem", "--quiet"]) == 0
    quiet_out, quiet_err = capsys.readouterr()
    assert "convergence block" not in quiet_err and "increment" not in quiet_err
    assert quiet_out == out  # the same table: the lines change no number


def test_the_lines_change_no_number_of_the_table(block):
    scene = load(block)
    said = []
    with_lines = convergence_check(scene, "skfem", log=said.append)
    without = convergence_check(scene, "skfem")
    assert len(said) == 2 + 2 * 4 + 3  # formulation (2), per mesh: size, 2 increments, end; refining, memory, total
    columns = [c for c in with_lines.columns if c not in ("wall_s", "memory_estimate_h_half")]
    assert with_lines[columns].equals(without[columns])


def test_size_line_counts_the_unknowns_the_table_reports(tmp_path):
    write_block(tmp_path)
    p1 = load(scene_file(tmp_path, extra=MONITOR))
    assert f"{p1.to_problem().ndof} displacement dofs;" in _size(p1, formulation_of(p1))
    mixed = load(scene_file(tmp_path, mesh='file = "block.msh"\nunit = "mm"', analysis_extra='formulation = "mixed"',
                            extra=MONITOR))
    text = _size(mixed, formulation_of(mixed))
    assert f"{mixed.to_problem().ndof} displacement dofs + 45 pressure dofs;" in text  # P2 nodes, P1 pressures
    assert "Taylor-Hood" in text


def test_a_cut_increment_is_a_line_with_its_reason(block):
    """Newton limited to one iteration fails every increment: each attempt (1, then 0.5, then
    0.25 of the load) is a line saying so, and no load factor was reached to report."""
    pb = load(block).to_problem()
    said, reached = [], []
    lines = SolveLines(said.append, "r", forward=lambda done, total: reached.append(done))
    res = newton_solve(make_backend("skfem", pb), 1.0, max_iterations=1, min_increment=0.25, progress=lines)
    assert res.status == "stalled" and len(res.increments) == 3 and reached == []
    assert [re.search(r"load factor (\S+)/1", s).group(1) for s in said] == ["1", "0.5", "0.25"]
    assert all(", not converged: no convergence in 1 iterations (residual" in s for s in said), said


def test_a_plain_progress_callable_still_gets_load_factors_only(block):
    pb = load(block).to_problem()
    reached = []
    newton_solve(make_backend("skfem", pb), 1.0, n_increments=2, max_increment=0.5,
                 progress=lambda done, total: reached.append((done, total)))
    assert reached == [(0.5, 1.0), (1.0, 1.0)]


def test_linear_static_runs_say_each_load_step():
    said = []
    lines = SolveLines(said.append, "r")
    for lam in (0.5, 1.0):
        lines(lam, 1.0)
    assert [s.split(" (")[0] for s in said] == ["r: load step 1: load factor 0.5/1", "r: load step 2: load factor 1/1"]


def test_dynamic_runs_say_every_twentieth_of_the_end_time_not_every_step():
    said = []
    lines = SolveLines(said.append, "r", "dynamic", "ms")
    lines(0.049, 1.0)  # below the first twentieth: nothing yet
    assert said == []
    lines(0.05, 1.0)  # at it: one line
    assert len(said) == 1 and said[0].startswith("r: t 0.05/1 ms (5%")
    for k in range(51, 1001):  # 1 ms steps of 1 s
        lines(k / 1000, 1.0)
    assert len(said) == 20 and said[-1].startswith("r: t 1/1 ms (100%")


def test_verify_says_each_anchor_and_each_backend_scene_and_quiet_silences_both(tmp_path, monkeypatch, capsys):
    """The anchors and the backend agreement of ``verify RESULTS`` (minutes of solves) name what
    they compute on stderr, and the references solved for the agreement show their bars (the
    sweep's switch, set for the call and restored); ``--quiet`` says nothing and switches the bars off."""
    import pandas as pd

    from tissuebench.reports import backends as reports_backends

    seen = []

    def agreement(scenes, progress=None):
        seen.append(os.environ.get(PROGRESS_ENV))
        if progress:
            progress("cube")
        return pd.DataFrame(columns=["case", "ndof", "field_rel_diff", "worst_monitor", "monitor_rel_diff",
                                     "verdict", "how"])

    monkeypatch.setattr(backend_comparison, "backend_agreement", agreement)
    monkeypatch.setattr(reports_backends, "scenes_of_results", lambda results: [])
    monkeypatch.delenv(PROGRESS_ENV, raising=False)
    (tmp_path / "_sweep.json").write_text("{}")
    assert main(["verify", str(tmp_path), "--cases", "clamped_beam", "--backend", "skfem"]) == 0
    out, err = capsys.readouterr()
    assert "verify: anchor clamped_beam: first angular frequency (skfem, ci)" in err
    assert "verify: cube on both backends" in err and "on both backends" not in out
    assert "anchor clamped_beam" not in out
    monkeypatch.setenv(PROGRESS_ENV, "1")  # exported by the user: --quiet still wins, and it is restored
    assert main(["verify", str(tmp_path), "--cases", "clamped_beam", "--backend", "skfem", "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert "anchor" not in err and "both backends" not in err and "clamped_beam" in out
    assert seen == ["1", "0"]
    assert os.environ[PROGRESS_ENV] == "1"
