"""Every catalogue case runs at ci resolution, and checks what its physics allows.

- frame_2dof against its analytical step response (and second order in dt);
- wave_block: the front reaches mid-height at the P-wave speed (443.9 m/s) within 5 %;
- clamped_beam: first frequency against Euler-Bernoulli 4.730^2 sqrt(EI / (rho A L^4));
- heat1d_source against its closed form;
- cube_tension_twist: nominal stress and volume ratio at 30 % strain beside the paper's,
  and the stress against the incompressible Mooney-Rivlin closed form;
- liver_dynamic: the first natural period of its free vibration against a modal solve;
- liver_palpation: the small-load limit of the SVK run against the linear-elastic solution;
- land_beam and left_ventricle: monitored values converge under refinement (slow tests)
  and agree across backends.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg as sla
import scipy.sparse.linalg as spla

from _amplification import principal_eigenvalue, prony_root, scheme_matrix
from tissuebench.studies.describe import paper_comparison
from tissuebench.cases.scene import list_cases, load
from tissuebench.refsolvers import LinearElastic, make_backend
from tissuebench.refsolvers.line_models import assemble_line_model, frame_step_response
from tissuebench.reference import solve

CASES = [(name, variant) for name in list_cases() for variant in (load(name).variants or (None,))]
_RUNS = {}


def run(case, variant=None, backend="skfem"):
    """Each (case, variant, backend) is solved once per test session."""
    key = (case, variant, backend)
    if key not in _RUNS:
        _RUNS[key] = solve(case, backend=backend, variant=variant)
    return _RUNS[key]


def with_changes(scene, mesh=None, analysis=None):
    """A copy of ``scene`` with mesh parameters and analysis entries overridden."""
    spec = dict(scene.mesh_spec, params={**scene.mesh_spec["params"], **(mesh or {})})
    return dataclasses.replace(scene, mesh_spec=spec, analysis={**scene.analysis, **(analysis or {})})


#: the heaviest at ci run with the slow tests: the neo-Hookean liver's dynamics (~30 s; the default
#: run keeps the liver's dynamics by test_liver_dynamic_first_period_is_the_modal_one, linear
#: variant) and land_beam (~12 s; solved in the default run by test_backends_agree_on_the_catalogue)
SLOW_AT_CI = {("liver_dynamic", "neo_hookean"), ("land_beam", None)}


@pytest.mark.parametrize("case,variant", [pytest.param(c, v, id=f"{c}-{v}" if v else c,
                                                       marks=[pytest.mark.slow] if (c, v) in SLOW_AT_CI else [])
                                          for c, v in CASES])
def test_every_case_runs_at_ci(case, variant):
    scene = load(case, variant=variant)
    r = run(case, variant)
    assert r.ok, f"{case}: {r.status}: {r.message}"
    t = r.table
    for col in ("case", "backend", "step", "newton_iterations", "converged", "wall_s"):
        assert col in t, col
    assert ("load_factor" in t) != ("time" in t)
    assert (t["case"] == scene.name).all()
    done = t[t["converged"]]
    assert len(done) >= 1
    for m in scene.monitors:
        assert np.all(np.isfinite(done[m["name"]].to_numpy(float))), m["name"]
    assert np.all(np.isfinite(r.displacement))
    assert r.displacement.shape[1:] == (len(r.points), len(r.components))
    assert len(r.steps) == len(r.displacement)
    # something moved
    assert np.abs(r.final_displacement).max() > 0


# --------------------------------------------------------------------------- 1D models
def test_frame_matches_its_analytical_solution_to_second_order_in_dt():
    scene = load("frame_2dof")
    k, masses = scene.model_params["storey_stiffness"], scene.model_params["masses"]
    errors = []
    for dt in (0.01, 0.005):
        r = run("frame_2dof") if dt == 0.01 else solve(with_changes(scene, analysis={"dt": dt}))
        t = r.table["time"].to_numpy()
        exact = frame_step_response(masses, k, 1.0e4, t, loaded_node=2)
        got = r.table[["u1", "u2"]].to_numpy()
        errors.append(np.abs(got - exact).max() / np.abs(exact).max())
    # central difference at dt = T_min / 59: measured 7.3e-4 of the peak (1.8e-4 at dt / 2)
    assert errors[0] < 1.5e-3
    assert math.log2(errors[0] / errors[1]) == pytest.approx(2.0, abs=0.2)


def test_clamped_beam_first_frequency_is_euler_bernoulli():
    scene = load("clamped_beam")
    system = assemble_line_model(scene.line_model())
    f = system.free
    w2 = sla.eigh(system.K[f][:, f].toarray(), system.M[f][:, f].toarray(), eigvals_only=True)
    p = scene.model_params
    exact = 4.730040745 ** 2 * math.sqrt(p["E"] * p["I"] / (p["rho"] * p["A"] * 1.0 ** 4))
    assert math.sqrt(w2[0]) == pytest.approx(exact, rel=1e-4)  # 10 Hermite elements: 3.5e-5
    # the catalogue run: forced far below resonance (1 Hz vs 76 Hz), the midpoint follows the
    # static deflection P L^3 / (192 EI) sin(2 pi t); starting from rest excites the first mode
    # (1.1 % of the amplitude), which Bathe damps out (omega_1 dt = 2.4); after 0.5 s what is
    # left is the dynamic amplification 1 / (1 - (2 pi / omega_1)^2) - 1 = 1.7e-4
    t = run("clamped_beam").table
    amp = 20.0 / (192 * p["E"] * p["I"])
    time = t["time"].to_numpy()
    dev = np.abs(t["midpoint_w"].to_numpy() - amp * np.sin(2 * np.pi * time)) / amp
    assert dev.max() < 0.02
    assert dev[time > 0.5].max() < 3e-4


def test_heat1d_matches_its_closed_form():
    r = run("heat1d_source")
    x = r.points[:, 0]
    s, q = 0.5, 1.0
    exact = q * (x - s) * (x > s) - q * (1 - s) * x
    assert np.abs(r.final_displacement[:, 0] - exact).max() < 1e-12
    assert r.table["u_at_source"].iloc[-1] == pytest.approx(-0.25, abs=1e-12)


# --------------------------------------------------------------------------- dynamics
def test_wave_front_reaches_mid_height_at_the_p_wave_speed():
    """Arrival fitted on the mid-height displacement ramp u = -p/(rho c) (t - t_a), over the
    middle of the ramp before the reflection returns (as in test_wave_block)."""
    scene = load("wave_block")
    mat = scene.material
    E, nu, rho = mat["E"], mat["nu"], mat["density"]
    c = math.sqrt(E * (1 - nu) / ((1 + nu) * (1 - 2 * nu) * rho))
    assert c == pytest.approx(443.9, abs=0.05)
    t = run("wave_block", "linear").table
    H, p = 10.0, 4000.0
    t_mid, span = 0.5 * H / c, H / c
    w = (t["time"] > t_mid + 0.25 * span) & (t["time"] < t_mid + 0.75 * span)
    slope = -p / (rho * c)
    arrival = np.mean(t["time"][w] - t["mid_uz"][w] / slope)
    # paper mesh (4 layers along z): -2.5 %; 8 layers: -0.03 %
    assert arrival == pytest.approx(t_mid, rel=0.05)


@pytest.mark.slow  # ~9 s: a dynamic liver run; every catalogue case still runs at ci in the default run
def test_liver_dynamic_first_period_is_the_modal_one():
    """After the release (t > 0.5 s) the undamped liver vibrates freely, and HHT on a linear
    system decouples mode by mode: the first-mode coordinate q1 = phi1^T M u of the stored
    fields obeys the SDOF HHT recurrence at Om1 = omega1 dt exactly. So the root fitted to q1
    (every 5th step is stored) must equal the HHT amplification-matrix root at Om1 raised to
    the 5th power, where omega1 comes from eigsh on K, M of the same mesh and Dirichlet set
    (measured: 1.5e-14); the fitted period is T1 = 0.1216 s lengthened by HHT's period
    elongation at Om1 = 0.052 (2.5e-4). The mass is anchored to the scene's density: its
    total is density x mesh volume (1.458 kg)."""
    r = run("liver_dynamic")
    scene = load("liver_dynamic")
    assert scene.analysis["integrator"] == "hht"
    pb, plan = r.problem, r.plan
    be, free = make_backend("skfem", pb), pb.free_dofs
    M = be.mass(lumped=plan.mass == "lumped")
    volume = pb.mesh.cell_volumes().sum()
    assert M.sum() / 3 == pytest.approx(scene.material["density"] * volume, rel=1e-10)
    K = be.tangent(np.zeros(pb.ndof))[free][:, free].tocsc()
    Mf = M[free][:, free].tocsc()
    w2, phi = spla.eigsh(K, k=1, M=Mf, sigma=0.0, which="LM")
    omega1 = math.sqrt(w2[0])
    assert 2 * math.pi / omega1 == pytest.approx(0.1216, abs=1e-4)

    dt = r.info["dt"]
    stride = round((r.steps[1] - r.steps[0]) / dt)
    free_vibration = r.steps > 0.5 + 1e-9  # the load history is zero from 0.5 s on
    q1 = r.displacement[free_vibration].reshape(int(free_vibration.sum()), -1)[:, free] @ (Mf @ phi[:, 0])
    lam = prony_root(q1, skip=0)
    alpha = scene.analysis["integrator_options"]["alpha"]
    lam_hht = principal_eigenvalue(scheme_matrix("hht", omega1 * dt, 0.0, alpha)) ** stride
    assert abs(lam - lam_hht) < 1e-9, (lam, lam_hht)
    period = 2 * math.pi * stride * dt / abs(np.angle(lam))
    elongation = omega1 * dt / abs(np.angle(principal_eigenvalue(scheme_matrix("hht", omega1 * dt, 0.0, alpha)))) - 1
    assert elongation == pytest.approx(2.5e-4, abs=2e-5)
    assert period == pytest.approx(2 * math.pi / omega1 * (1 + elongation), rel=1e-8)


# --------------------------------------------------------------------------- cube
def test_cube_tension_reported_beside_the_paper():
    scene = load("cube_tension_twist", variant="tension")
    r = run("cube_tension_twist", "tension")
    cmp = paper_comparison(scene, r.table).set_index("monitor")
    assert set(cmp.index) == {"nominal_stress_kPa", "volume_ratio"}
    assert all(len(n) > 40 for n in cmp["note"])  # each difference carries its reason
    lam, mu1, mu2 = 1.3, 0.5, 0.6
    closed_form = (mu1 + mu2 / lam) * (lam - lam ** -2)  # incompressible MR, kPa
    # compressible (J = 1.06) and clamped ends: within 2 % of the incompressible closed form
    assert cmp.loc["nominal_stress_kPa", "ours"] == pytest.approx(closed_form, rel=0.02)
    assert 1.0 < cmp.loc["volume_ratio", "ours"] < 1.1
    assert cmp.loc["nominal_stress_kPa", "paper"] == 0.370


def test_twist_keeps_volume_and_turns_the_end():
    r = run("cube_tension_twist", "twist")
    t = r.table[r.table["converged"]]
    assert t["load_factor"].iloc[-1] == pytest.approx(1.0)
    assert abs(t["volume_ratio"].iloc[-1] - 1.0) < 0.01
    assert np.all(np.diff(t["moment"].to_numpy()) > 0)  # stiffening, monotone


def test_liver_palpation_runs_until_newton_stops():
    r = run("liver_palpation")
    assert r.status == "stalled" and r.ok  # the stall is the measurement of this scene
    t = r.table
    assert not t["converged"].iloc[-1] and t["converged"].iloc[:-1].all()
    # the paper's error curves reach about 5 mm under the tool: Newton gets past them
    assert -t["tool_tip_uy"].dropna().iloc[-1] > 5e-3


def test_liver_palpation_small_load_limit_is_linear_elasticity():
    """SVK linearised at u = 0 is linear elasticity with the same E, nu, so the run's field per
    unit load factor tends to the linear-elastic solution of the same mesh, Dirichlet set and
    point load (solved here with the LinearElastic material): u(lam) / lam = u_lin + lam b + O(lam^2).
    Measured on the shipped mesh: the tool tip deviates +1.67 % at lam = 0.5 (0.6 N) and
    +3.46 % at lam = 1 (ratio 2.07: first order in the load, as it must be); the Richardson
    extrapolation 2 u(0.5)/0.5 - u(1)/1 of the whole field matches u_lin to 3.1e-4 (relative l2,
    the O(lam^2) remainder; 1.2e-3 at the tool tip), asserted to 1e-3."""
    r = run("liver_palpation")
    lam = r.steps
    assert lam[1] == pytest.approx(0.5) and lam[2] == pytest.approx(1.0)
    scene = load("liver_palpation")
    pb = dataclasses.replace(r.problem, material=LinearElastic(scene.material["E"], scene.material["nu"]))
    be, free = make_backend("skfem", pb), pb.free_dofs
    K = be.tangent(np.zeros(pb.ndof))[free][:, free]
    u_lin = np.zeros(pb.ndof)
    u_lin[free] = spla.spsolve(K.tocsc(), be.external_force(np.zeros(pb.ndof), 1.0)[free])
    u_lin = u_lin.reshape(-1, 3)
    tip = pb.loads[0].nodes[0]  # the monitor is the loaded node
    assert r.table["tool_tip_uy"].iloc[0] == pytest.approx(r.displacement[1][tip, 1], rel=1e-12)
    dev = [r.displacement[k][tip, 1] / (lam[k] * u_lin[tip, 1]) - 1 for k in (1, 2)]
    assert 0.01 < dev[0] < 0.025 and dev[1] / dev[0] == pytest.approx(2.0, abs=0.15), dev
    extrapolated = 2 * r.displacement[1] / lam[1] - r.displacement[2] / lam[2]
    assert np.linalg.norm(extrapolated - u_lin) < 1e-3 * np.linalg.norm(u_lin)


# --------------------------------------------------------------------------- refinement, backends
# land_beam's refinement (the scene is mixed u-p since issue 11): monotone from below into the
# published spread, tests/reports/test_external_anchors.py::test_land_beam_mixed_converges_into_the_published_spread


@pytest.mark.slow
def test_left_ventricle_converges_under_refinement():
    """P2: with P1 and about one cell across the 3 mm wall the apex value is locking-dominated
    (it grows with refinement: -17.85, -17.83, -17.84, -18.06 at maxh 3, 2, 1.4, 1.0), and netgen
    keeps about 2.4 mm edges at the apex for maxh 3 .. 1.4. P2 on the same meshes converges."""
    scene = load("left_ventricle", variant="mooney_rivlin")
    scene = dataclasses.replace(scene, mesh_spec=dict(scene.mesh_spec, element="P2"))
    vals = []
    for h in (3.0, 2.0, 1.4):
        r = solve(with_changes(scene, mesh={"maxh": h}, analysis={"load_steps": 4}))
        assert r.status == "success", r.message
        vals.append(r.table["apex_endo_z"].dropna().iloc[-1])
    d1, d2 = abs(vals[1] - vals[0]), abs(vals[2] - vals[1])
    assert d2 < 0.5 * d1 and d1 < 0.005 * abs(vals[0]), vals


@pytest.mark.ngsolve
@pytest.mark.parametrize("case,variant", [pytest.param("land_beam", None, marks=pytest.mark.slow),  # ~16 s
                                          pytest.param("left_ventricle", "guccione", marks=pytest.mark.slow),  # ~20 s
                                          ("cornea_pinch", None), ("wave_block", "svk")])
def test_backends_agree_on_the_catalogue(case, variant):
    if case == "wave_block":  # the first 40 steps: the front and its reflection
        scene = with_changes(load(case, variant=variant), analysis={"t_end": 0.05})
        a, b = solve(scene, backend="skfem"), solve(scene, backend="ngsolve")
    else:
        a, b = run(case, variant, "skfem"), run(case, variant, "ngsolve")
    assert a.status == b.status == "success"
    ua, ub = a.final_displacement, b.final_displacement
    assert np.linalg.norm(ua - ub) <= 1e-6 * np.linalg.norm(ua)
    scene = load(case, variant=variant)
    for m in scene.monitors:
        x, y = a.table[m["name"]].dropna().to_numpy(), b.table[m["name"]].dropna().to_numpy()
        np.testing.assert_allclose(x, y, rtol=1e-6, atol=1e-9 * np.abs(x).max())
