"""The three 1D models of the catalogue (poisson1d, frame2dof, hermite_beam) against
closed forms: nodal exactness, natural frequencies and their convergence rates, the
undamped step response of the frame, explicit dynamics of the lumped beam, bad input."""
import dataclasses

import numpy as np
import pytest
from scipy.linalg import eigh

from tissuebench.cases import scene
from tissuebench.cases.assembly import LineModel
from tissuebench.cases.builtmesh import LineMesh
from tissuebench.cases.histories import History
from tissuebench.refsolvers.dynamics import SecondOrderSystem, critical_time_step, integrate
from tissuebench.refsolvers.line_models import (LineSystem, assemble_line_model, frame_step_response,
                                                solve_static)

CONST = History({"type": "constant"})
BETA1 = 4.730040745  # first root of cos(b) cosh(b) = 1 (clamped-clamped beam)


def line_mesh(x):
    x = np.asarray(x, float)
    n = len(x)
    return LineMesh(np.c_[x, np.zeros((n, 2))], np.c_[np.arange(n - 1), np.arange(1, n)])


def slope(h, err):
    """Fitted exponent p of err ~ C h^p (least squares in log-log)."""
    return np.polyfit(np.log(h), np.log(err), 1)[0]


def free_block(A, free):
    return A.toarray()[np.ix_(free, free)]


# ----------------------------------------------------------------------------- poisson1d
def poisson_exact(x, s, q, k):
    """Closed form of k u'' = q delta(x - s), u(0) = u(1) = 0."""
    return q / k * ((x - s) * (x > s) - (1 - s) * x)


def poisson_model(x, loads, q=1.0, k=1.0):
    """A poisson1d LineModel on nodes ``x`` with u = 0 at both ends; loads: [(node, value)]."""
    return LineModel("poisson1d", line_mesh(x), {"q": q, "conductivity": k},
                     [(np.array([0]), 0), (np.array([len(x) - 1]), 0)],
                     [(np.array([i]), v, CONST) for i, v in loads])


@pytest.mark.parametrize("resolution", ["ci", "paper"])
def test_poisson_scene_nodally_exact(resolution):
    lm = scene.load("heat1d_source", resolution=resolution).line_model()
    sysm = assemble_line_model(lm)
    assert sysm.M is None and sysm.M_lumped is None and sysm.components == ("u",)
    u = solve_static(sysm)
    x = lm.mesh.x
    s = x[lm.loads[0][0][0]]
    assert s == pytest.approx(0.5)
    # the scene's value (1) is the intensity; u(0.5) = -q/4 < 0 fixes the sign convention
    assert u[np.argmin(abs(x - 0.5))] == pytest.approx(-0.25, abs=1e-12)
    assert np.max(np.abs(u - poisson_exact(x, s, 1.0, 1.0))) < 1e-12


def test_poisson_nonuniform_mesh_any_node():
    # P1 Galerkin is nodally exact in 1D on any mesh (the Green's function is in the space)
    rng = np.random.default_rng(7)
    x = np.r_[0.0, np.sort(rng.uniform(0, 1, 30)), 1.0]
    q, k = 3.0, 2.5
    for node in (1, 9, 17, 30):
        sysm = assemble_line_model(poisson_model(x, [(node, q)], q, k))
        u = solve_static(sysm)
        assert np.max(np.abs(u - poisson_exact(x, x[node], q, k))) < 1e-12
    K = sysm.K.toarray()
    assert np.allclose(K, K.T) and np.allclose(K.sum(axis=1), 0.0, atol=1e-9)


def test_poisson_source_between_nodes():
    """s = 1/3 never on a node of a uniform 2^j mesh: the load is split by the hat
    functions (the consistent load of the delta). Nodal values stay exact; at element
    midpoints only the element holding s errs, by (q/k) min(s - a, b - s) / 2 = (q/k) h/6
    here (1/3 sits at 1/3 or 2/3 of its element), so the max error is first order."""
    q, k, s = 3.0, 2.5, 1.0 / 3.0
    hs, errs = [], []
    for n in (4, 8, 16, 32, 64):
        x = np.linspace(0.0, 1.0, n + 1)
        h = 1.0 / n
        a = int(s // h)
        w = (s - x[a]) / h
        u = solve_static(assemble_line_model(poisson_model(x, [(a, (1 - w) * q), (a + 1, w * q)], q, k)))
        assert np.max(np.abs(u - poisson_exact(x, s, q, k))) < 1e-12
        xm = 0.5 * (x[:-1] + x[1:])
        err = np.max(np.abs(0.5 * (u[:-1] + u[1:]) - poisson_exact(xm, s, q, k)))
        assert err == pytest.approx(q / k * h / 6, rel=1e-9)
        hs.append(h)
        errs.append(err)
    assert slope(hs, errs) == pytest.approx(1.0, abs=0.05)


# ----------------------------------------------------------------------------- frame2dof
FRAME = scene.load("frame_2dof").line_model()
M1, M2 = FRAME.params["masses"]
KS = FRAME.params["storey_stiffness"]
F_STEP = FRAME.loads[0][1]


def frame_system():
    return assemble_line_model(FRAME)


def test_frame_matrices_and_statics():
    s = frame_system()
    assert s.free.tolist() == [1, 2] and s.fixed.tolist() == [0] and s.dofs_per_node == 1
    assert free_block(s.K, s.free) == pytest.approx(KS * np.array([[2, -1], [-1, 1]]), abs=1e-9)
    assert free_block(s.M, s.free) == pytest.approx(np.diag([M1, M2]))
    assert (s.M_lumped != s.M).nnz == 0
    assert s.load_vector(0.0).tolist() == [0.0, 0.0, F_STEP]  # step on at t >= 0, top slab
    assert s.load_vector(-1.0).tolist() == [0.0, 0.0, 0.0]
    # both storeys carry F: u1 = F/k, u2 = 2F/k
    assert solve_static(s) == pytest.approx([0.0, F_STEP / KS, 2 * F_STEP / KS], rel=1e-12)


def test_frame_natural_frequencies():
    s = frame_system()
    lam = eigh(free_block(s.K, s.free), free_block(s.M, s.free), eigvals_only=True)
    # det(K - lam M) = m1 m2 lam^2 - k (m1 + 2 m2) lam + k^2 = 0
    b = KS * (M1 + 2 * M2)
    roots = (b + np.array([-1.0, 1.0]) * np.sqrt(b**2 - 4 * M1 * M2 * KS**2)) / (2 * M1 * M2)
    assert lam == pytest.approx(roots, rel=1e-12)
    periods = 2 * np.pi / np.sqrt(lam)
    print("frame periods [s]", periods)
    assert periods == pytest.approx([1.8978034, 0.58837405], rel=1e-6)


def frame_errors(divisions, t_end):
    """Max relative error (to the peak) of Newmark vs the modal solution, per dt = T_min/d."""
    s = frame_system()
    T_min = 2 * np.pi / np.sqrt(eigh(free_block(s.K, s.free), free_block(s.M, s.free),
                                     eigvals_only=True)[-1])
    ode = SecondOrderSystem.linear_system(s.M, s.K, load=s.load_vector, free=s.free)
    dts, errs = [], []
    for d in divisions:
        res = integrate(ode, None, None, T_min / d, t_end, method="newmark")
        assert res.success
        ref = frame_step_response([M1, M2], KS, F_STEP, res.t, loaded_node=2)
        errs.append(np.max(np.abs(res.u[:, 1:] - ref)) / np.max(np.abs(ref)))
        dts.append(T_min / d)
    return np.array(dts), np.array(errs)


def test_frame_step_response_newmark():
    dts, errs = frame_errors([25, 50, 100, 200], t_end=4.0)  # about two fundamental periods
    p = slope(dts, errs)
    print("frame Newmark errors", errs, "slope", p)
    assert errs[-1] < 1e-3
    assert p == pytest.approx(2.0, abs=0.15)


@pytest.mark.parametrize("node", [1, 2])
def test_frame_step_response_closed_form(node):
    """The modal solution starts from rest and satisfies M u'' + K u = F (u'' by a
    fourth-order central difference; measured residual about 4e-10 F)."""
    t = np.linspace(0.0, 4.0, 4001)
    u = frame_step_response([M1, M2], KS, F_STEP, t, loaded_node=node)
    assert np.abs(u[0]).max() < 1e-15
    dt = t[1] - t[0]
    f = np.zeros(2)
    f[node - 1] = F_STEP
    # from rest: u(dt) = M^-1 F dt^2 / 2 (1 + O((w dt)^2)); a non-zero v(0) would add v0 dt
    assert u[1] == pytest.approx(f / [M1, M2] * dt**2 / 2, rel=1e-3, abs=1e-10)
    acc = (-u[4:] + 16 * u[3:-1] - 30 * u[2:-2] + 16 * u[1:-3] - u[:-4]) / (12 * dt**2)
    resid = acc * [M1, M2] + u[2:-2] @ (KS * np.array([[2, -1], [-1, 1]])) - f
    print("frame ODE residual / F", np.max(np.abs(resid)) / F_STEP)
    assert np.max(np.abs(resid)) < 1e-8 * F_STEP


# ----------------------------------------------------------------------------- hermite_beam
BEAM = scene.load("clamped_beam").line_model()
P = BEAM.params
EI, RHOA = P["E"] * P["I"], P["rho"] * P["A"]
W1 = BETA1**2 * np.sqrt(EI / RHOA)  # L = 1


def beam(n_el, loads=()):
    x = np.linspace(0.0, 1.0, n_el + 1)
    fixed = [(np.array([0]), 0), (np.array([0]), 1), (np.array([n_el]), 0), (np.array([n_el]), 1)]
    return assemble_line_model(dataclasses.replace(BEAM, mesh=line_mesh(x), fixed=fixed, loads=list(loads)))


def first_frequency(s, lumped=False):
    M = s.M_lumped if lumped else s.M
    return np.sqrt(eigh(free_block(s.K, s.free), free_block(M, s.free), eigvals_only=True)[0])


def test_beam_first_frequency_consistent_mass():
    # eigenvalue error of a 2m-order problem with degree-p elements: O(h^(2(p + 1 - m)));
    # cubic Hermite p = 3, beam m = 2: O(h^4), and omega = sqrt(lambda) keeps the rate
    ns = [2, 4, 8, 16]
    errs = np.array([first_frequency(beam(n)) / W1 - 1 for n in ns])
    e10 = first_frequency(beam(10)) / W1 - 1
    p = slope(1.0 / np.array(ns), errs)
    print(f"w1 = {W1:.6f} rad/s; consistent rel errors {errs}, at 10 el {e10:.3e}, slope {p:.3f}")
    assert np.all(errs > 0)  # Rayleigh-Ritz: the consistent mass bounds from above
    assert e10 < 1e-4
    assert p == pytest.approx(4.0, abs=0.3)


def test_beam_static_point_load_nodally_exact():
    s = assemble_line_model(BEAM)
    assert s.components == ("w", "theta") and s.dofs_per_node == 2
    assert s.fixed.tolist() == [0, 1, 20, 21]
    Pmid = BEAM.loads[0][1]
    u = s.nodal(solve_static(s))
    x = BEAM.mesh.x
    assert u[5, 0] == pytest.approx(Pmid / (192 * EI), rel=1e-12)
    # clamped-clamped, central load, x <= L/2: w = P x^2 (3L - 4x) / (48 EI), theta = w'
    left = x <= 0.5
    w = Pmid * x**2 * (3 - 4 * x) / (48 * EI)
    th = Pmid * x * (1 - 2 * x) / (8 * EI)
    scale = np.max(np.abs(w))
    assert np.max(np.abs(u[left, 0] - w[left])) < 1e-12 * scale
    assert np.max(np.abs(u[left, 1] - th[left])) < 1e-11 * scale
    assert u[:, 0] == pytest.approx(u[::-1, 0], abs=1e-12 * scale)  # symmetry
    # the sine history: static solve ignores it, load_vector applies it
    assert s.load_vector(0.25)[10] == pytest.approx(Pmid)


def test_beam_hrz_lumped_mass():
    s = beam(10)
    d = s.M_lumped.diagonal()
    assert np.array_equal(s.M_lumped.toarray(), np.diag(d))
    assert d[0::2].sum() == pytest.approx(RHOA * 1.0, rel=1e-12)
    rigid = np.tile([1.0, 0.0], 11)
    assert rigid @ (s.M @ rigid) == pytest.approx(RHOA * 1.0, rel=1e-12)
    assert np.all(d[s.free] > 0)
    assert d[3] == pytest.approx(2 * RHOA * 0.1**3 / 78, rel=1e-12)  # two elements share node 1
    # lumping loses the Rayleigh-Ritz bound and converges as O(h^2) (measured 1.6e-3 at 10 el)
    ns = [4, 8, 16, 32]
    errs = np.array([abs(first_frequency(beam(n), lumped=True) / W1 - 1) for n in ns])
    e10 = abs(first_frequency(s, lumped=True) / W1 - 1)
    p = slope(1.0 / np.array(ns), errs)
    print(f"HRZ rel errors {errs}, at 10 el {e10:.3e}, slope {p:.3f}")
    assert first_frequency(s, lumped=True) < first_frequency(s)
    assert e10 < 5e-3  # stated tolerance: 0.5 % at 10 elements
    assert p == pytest.approx(2.0, abs=0.3)


def test_beam_central_difference_lumped():
    s = assemble_line_model(BEAM)
    ode = SecondOrderSystem.linear_system(s.M_lumped, s.K, load=s.load_vector, free=s.free)
    dt_cr = critical_time_step(ode)
    dt, n = 0.9 * dt_cr, 400
    res = integrate(ode, None, None, dt, n * dt, method="central_difference")
    ref = integrate(ode, None, None, dt, n * dt, method="newmark")
    print(f"dt_cr = {dt_cr:.4e} s, peak w = {np.abs(res.u[:, 10]).max():.3e} m")
    assert res.success and res.n_steps == n
    peak = np.abs(ref.u).max()
    assert peak > 0
    assert np.max(np.abs(res.u - ref.u)) < 1e-2 * peak
    # just above the limit the same run explodes: the limit is the scheme's, not a guess
    bad = integrate(ode, None, None, 1.05 * dt_cr, n * dt, method="central_difference", force=True)
    assert bad.status == "blow_up"


# ----------------------------------------------------------------------------- API and bad input
def test_nodal_view_and_load_vector():
    s = assemble_line_model(BEAM)
    assert isinstance(s, LineSystem)
    x = np.arange(s.n, dtype=float)
    v = s.nodal(x)
    assert v.shape == (11, 2) and v[3, 1] == 7.0 and np.shares_memory(v, x)
    with pytest.raises(ValueError, match="shape"):
        s.nodal(np.zeros(5))
    t = 0.1
    assert s.load_vector(t)[10] == pytest.approx(20 * np.sin(2 * np.pi * t))


@pytest.mark.parametrize("change, field, value", [
    ({"model": "truss"}, "model", "'truss'"),
    ({"params": {"masses": [2000.0], "storey_stiffness": 1e5}}, "model.masses", r"\[2000.0\]"),
    ({"params": {"masses": [2000.0, 0.0], "storey_stiffness": 1e5}}, r"model.masses\[1\]", "0.0"),
    ({"params": {"masses": [2000.0, -4000.0], "storey_stiffness": 1e5}}, r"model.masses\[1\]", "-4000.0"),
    ({"params": {"masses": [2000.0, 4000.0], "storey_stiffness": -1.0}}, "model.storey_stiffness", "-1.0"),
    ({"params": {"masses": [2000.0, 4000.0]}}, "model.storey_stiffness", "None"),
    ({"loads": [(np.array([7]), 1e4, CONST)]}, r"load\[0\].nodes", "7"),
    ({"loads": [(np.array([-1]), 1e4, CONST)]}, r"load\[0\].nodes", "-1"),
    ({"loads": [(np.array([2]), [1.0, 2.0], CONST)]}, r"load\[0\].value", r"\[1.0, 2.0\]"),
    ({"fixed": [(np.array([3]), 0)]}, r"fixed\[0\].nodes", "3"),
    ({"fixed": [(np.array([0]), 1)]}, r"fixed\[0\].component", "1"),
])
def test_bad_frame_input(change, field, value):
    with pytest.raises(ValueError, match=f"{field} = {value}"):
        assemble_line_model(dataclasses.replace(FRAME, **change))


@pytest.mark.parametrize("name, field", [("E", "model.E"), ("rho", "model.rho")])
def test_bad_beam_parameter(name, field):
    with pytest.raises(ValueError, match=f"{field} = 0.0"):
        assemble_line_model(dataclasses.replace(BEAM, params=dict(BEAM.params, **{name: 0.0})))


def test_bad_poisson_and_response_input():
    lm = scene.load("heat1d_source").line_model()
    with pytest.raises(ValueError, match="model.conductivity = 'x'"):
        assemble_line_model(dataclasses.replace(lm, params=dict(lm.params, conductivity="x")))
    with pytest.raises(ValueError, match=r"load\[0\].nodes = 51"):
        assemble_line_model(dataclasses.replace(lm, loads=[(np.array([51]), 1.0, CONST)]))
    with pytest.raises(ValueError, match="loaded_node = 3"):
        frame_step_response([M1, M2], KS, F_STEP, [0.0], loaded_node=3)
    with pytest.raises(ValueError, match="masses"):
        frame_step_response([M1, 0.0], KS, F_STEP, [0.0], loaded_node=1)
