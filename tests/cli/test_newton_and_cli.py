"""Newton-Raphson controls (step cutting, radius as data, strict mode, AMG-CG) and the run command."""
import json

import numpy as np
import pandas as pd
import pytest

from _closed_forms import uniaxial_closed_form
from tissuebench.cases.bar import bar_tension
from tissuebench.cases.meshes import box_mesh
from tissuebench.cli import main
from tissuebench.refsolvers import (Dirichlet, MooneyRivlin, NeoHookean, PointLoad, Problem, SaintVenantKirchhoff,
                                    make_backend)
from tissuebench.refsolvers.newton import NewtonError, NewtonOptions, newton_solve


def _cantilever(force, material=None, element="P1"):
    mesh = box_mesh((4.0, 1.0, 1.0), (8, 2, 2), "tetra")
    return Problem(mesh, material or SaintVenantKirchhoff(1e3, 0.3), element,
                   dirichlet=[Dirichlet(lambda x: x[:, 0] < 1e-9)],
                   loads=[PointLoad(lambda x: np.isclose(x[:, 0], 4.0), np.asarray(force, float) / 9)])


def test_bar_tension_converges_and_is_reproduced_by_amg_cg():
    case = bar_tension("ci")
    be = make_backend("skfem", case.problem)
    direct = newton_solve(be, 1.0, n_increments=2)
    amg = newton_solve(be, 1.0, n_increments=2, linear_solver="amg-cg",
                       linear_solver_options={"rtol": 1e-12})
    assert direct.success and amg.success
    assert np.linalg.norm(amg.u - direct.u) <= 1e-8 * np.linalg.norm(direct.u)
    assert sum(i.linear_iterations for i in amg.increments) > len(amg.increments)  # Krylov counts reported
    # quadratic convergence at the last increment: residual falls below 1e-9 of its start in <= 6 iterations
    last = direct.increments[-1]
    assert last.converged and last.iterations <= 6
    m = case.monitors(direct.u, be.internal_force(direct.u))
    # as test_catalogue_runs: the stress at 30 % strain within 2 % of the incompressible
    # Mooney-Rivlin closed form (mu1 + mu2 / l)(l - l^-2) (measured -0.3 %: compressibility
    # softens, the clamped ends stiffen); the volume ratio within 2 % of J = l1 l2^2 of the
    # homogeneous compressible state with free sides (1.0511; measured 1.0616, +1.0 %, the
    # clamped ends hold the cross-section near them)
    mu1, mu2 = 500.0, 600.0  # Pa (wsc App. B); kappa: bulk modulus of a nu = 0.4 solid (bar.py)
    kappa = 2 * (mu1 + mu2) * (1 + 0.4) / (3 * (1 - 2 * 0.4))
    mat = case.problem.material
    assert (mat.mu1, mat.mu2, mat.kappa) == pytest.approx((mu1, mu2, kappa), rel=1e-12)
    l1 = 1.0 + case.stretch
    assert m["nominal_stress_kPa"] == pytest.approx((mu1 + mu2 / l1) * (l1 - l1 ** -2) / 1e3, rel=0.02)
    l2, _ = uniaxial_closed_form(MooneyRivlin(mu1, mu2, kappa), l1)
    assert l1 * l2 ** 2 == pytest.approx(1.0511, abs=1e-4)
    assert m["volume_ratio"] == pytest.approx(l1 * l2 ** 2, rel=0.02)


def test_newton_radius_is_returned_as_data_and_strict_raises():
    # a compressive follower-free load that buckles/inverts the bar: Newton cannot reach lam = 1
    pb = _cantilever((-5e5, 0.0, 0.0), NeoHookean(1e3, 0.3))
    be = make_backend("skfem", pb)
    res = newton_solve(be, 1.0, n_increments=1, min_increment=1 / 64, max_iterations=12)
    assert res.status == "stalled"
    assert 0.0 <= res.load_factor < 1.0
    assert np.all(np.isfinite(res.u))
    assert any(not i.converged for i in res.increments)
    assert "last converged load factor" in res.message
    table = res.table()
    # every attempt inverts an element at its first Newton iteration, even at 1/64 of the load
    # (axial strain ~ 5e5 / 64 / E = 7.8): the increment is halved from 1 down to
    # min_increment = 1/64 and nothing converges, so the last converged load factor is 0
    assert table["load_factor"].tolist() == [2.0 ** -k for k in range(7)]
    assert not table["converged"].any() and res.load_factor == 0.0
    assert table["message"].str.contains("inverted element").all()
    # the residual of each attempt is the external force at u = 0: 9 nodes of lam 5e5 / 9 N
    np.testing.assert_allclose(table["final_residual"], table["load_factor"] * 5e5 / 3, rtol=1e-12)
    with pytest.raises(NewtonError) as info:
        newton_solve(be, 1.0, n_increments=1, min_increment=1 / 64, max_iterations=12, strict=True)
    assert info.value.result.load_factor == pytest.approx(res.load_factor)


def test_step_cutting_recovers_a_too_large_first_increment():
    pb = _cantilever((0.0, 0.0, -12.0))
    be = make_backend("skfem", pb)
    res = newton_solve(be, 1.0, n_increments=1, max_iterations=6)
    assert res.success
    assert any(not i.converged for i in res.increments)  # a cut happened
    ref = newton_solve(be, 1.0, n_increments=8)
    assert np.linalg.norm(res.u - ref.u) <= 1e-7 * np.linalg.norm(ref.u)
    tip = res.u.reshape(-1, 3)[np.isclose(pb.nodes[:, 0], 4.0), 2].mean()
    assert tip < -1.0  # large deflection: a quarter of the length or more


def test_line_search_gives_the_same_solution():
    pb = _cantilever((0.0, 0.0, -30.0))
    be = make_backend("skfem", pb)
    a = newton_solve(be, 1.0, n_increments=2)
    b = newton_solve(be, 1.0, n_increments=2, line_search=True)
    assert a.success and b.success
    assert np.linalg.norm(a.u - b.u) <= 1e-8 * np.linalg.norm(a.u)


def test_newton_options_are_validated():
    with pytest.raises(ValueError, match="rtol"):
        NewtonOptions(rtol=-1.0)
    with pytest.raises(ValueError, match="max_iterations"):
        NewtonOptions(max_iterations=0)
    be = make_backend("skfem", _cantilever((0, 0, -1.0)))
    with pytest.raises(ValueError, match="load_factor"):
        newton_solve(be, float("nan"))
    with pytest.raises(ValueError, match="unknown linear solver 'lu'"):
        newton_solve(be, 1.0, linear_solver="lu")


def test_run_command_writes_results_atomically(tmp_path, capsys):
    out = tmp_path / "bar"
    assert main(["run", "cube_tension_twist", "--variant", "tension", "--out", str(out), "--quiet"]) == 0
    table = pd.read_parquet(out / "results.parquet")
    for col in ("case", "backend", "step", "load_factor", "newton_iterations", "converged", "wall_s",
                "nominal_stress_kPa", "volume_ratio"):
        assert col in table
    assert table["load_factor"].iloc[-1] == pytest.approx(1.0)
    fields = np.load(out / "fields.npz", allow_pickle=False)
    # the initial state and one state per converged increment
    assert fields["displacement"].shape[0] == table["converged"].sum() + 1
    assert fields["steps"][0] == 0.0 and fields["steps"][-1] == pytest.approx(1.0)
    # the pulled end moved by 30 % of 8 cm
    assert fields["displacement"][-1][:, 0].max() == pytest.approx(0.024, rel=1e-12)
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["status"] == "success" and manifest["versions"]["numpy"]
    assert manifest["case"] == "cube_tension_twist" and manifest["variant"] == "tension"
    assert len(manifest["scene_hash"]) == 64 and manifest["plan"]
    assert (out / "deformed.png").stat().st_size > 10_000 and (out / "deformed.vtu").exists()
    assert (out / "monitors.png").stat().st_size > 10_000
    # an existing folder is not overwritten unless asked
    assert main(["run", "cube_tension_twist", "--out", str(out), "--quiet"]) == 2
    assert "exists" in capsys.readouterr().err
    # an unknown case lists the valid ones and leaves nothing behind
    assert main(["run", "no_such_case", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "unknown case 'no_such_case'" in err and "liver_palpation" in err
    assert not (tmp_path / "x").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["bar"]
