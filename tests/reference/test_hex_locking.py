"""Locking on hexahedra (issue 54, item 1): the mean-dilatation hexahedra that do not lock, the
indicator that measures trilinear hexahedra (Q1) against them, and the formulation the catalogue's
cornea gets from it.

Before: every nearly incompressible scene on hexahedra got "trilinear hexahedra may lock, and no
formulation that does not lock is available on hexahedra to measure it", the cornea's reference
was Q1 whatever it cost. The non-locking side is validated first: by hand on one cube, against
the closed form of a thick cylinder (Lame) at nu = 0.499, and against Q1 at nu = 0.3 as the mesh
is refined."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tissuebench.cases.meshes import box_mesh
from tissuebench.cases.scene import CATALOGUE_DIR, load
from tissuebench.cli import main
from tissuebench.reference import formulation as fm
from tissuebench.reference import locking
from tissuebench.reference.formulation import formulation_of, scene_backend
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.materials import LinearElastic, NeoHookean, SaintVenantKirchhoff
from tissuebench.refsolvers.mean_dilatation import MeanDilatationBackend, hex_gradients, mean_dilatation_applies
from tissuebench.refsolvers.mesh import Mesh
from tissuebench.refsolvers.problem import Dirichlet, Problem

ALL = lambda x: np.ones(len(x), bool)  # noqa: E731
BASE = lambda x: np.abs(x[:, 2]) < 1e-9  # noqa: E731


def _problem(mesh, material, dirichlet=None):
    return Problem(mesh, material, "Q1", dirichlet=dirichlet or [Dirichlet(BASE)])


# ------------------------------------------------------------------ the element, by hand
def test_gradients_and_volumes_by_hand():
    """One 2 x 3 x 4 box cell: 8 Gauss points of 24 / 8 = 3 each; on a distorted mesh the points'
    volumes add up to the mesh's cell volumes, and the gradients reproduce a linear field
    (sum_a X_a grad N_a = I, sum_a grad N_a = 0)."""
    grad, dx = hex_gradients(*(lambda m: (m.points, m.cells))(box_mesh((2.0, 3.0, 4.0), (1, 1, 1), "hexahedron")))
    assert grad.shape == (1, 8, 8, 3) and dx.shape == (1, 8)
    np.testing.assert_allclose(dx, 3.0, rtol=1e-14)
    mesh = box_mesh((1.0, 2.0, 1.5), (3, 2, 2), "hexahedron", jitter=0.25, seed=3)
    grad, dx = hex_gradients(mesh.points, mesh.cells)
    np.testing.assert_allclose(dx.sum(axis=1), mesh.cell_volumes(), rtol=1e-13)
    X = mesh.points[mesh.cells]
    np.testing.assert_allclose(np.einsum("eai,eqaj->eqij", X, grad), np.broadcast_to(np.eye(3), (12, 8, 3, 3)),
                               atol=1e-13)
    np.testing.assert_allclose(grad.sum(axis=2), 0.0, atol=1e-13)


def test_a_bilinear_mode_by_hand():
    """The unit cube, u_x = x y, E = 1, nu = 0.25 (lambda = mu = 0.4, kappa = lambda + 2 mu / 3 = 2/3):
    eps_xx = y, eps_xy = x / 2, so Q1 (2x2x2 Gauss, exact here) stores int lambda/2 y^2 + mu (y^2 + x^2/2)
    = lambda/6 + mu/2 = 4/15. The dilatation y has the mean 1/2 and the mean square 1/3: the
    mean-dilatation correction is kappa/2 (1/4 - 1/3) = -kappa/24 = -1/36, so 4/15 - 1/36 = 43/180."""
    mesh = box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "hexahedron")
    pb = _problem(mesh, LinearElastic(1.0, 0.25))
    u = np.zeros((8, 3))
    u[:, 0] = mesh.points[:, 0] * mesh.points[:, 1]
    u = u.ravel()
    q1, md = make_backend("skfem", pb), MeanDilatationBackend(pb)
    assert q1.strain_energy(u) == pytest.approx(4 / 15, rel=1e-14)
    assert md.strain_energy(u) == pytest.approx(43 / 180, rel=1e-14)
    energy, force, _ = md.cell_correction(u)
    assert energy[0] == pytest.approx(-1 / 36, rel=1e-14)
    assert float(force[0] @ u.reshape(-1, 3)[mesh.cells[0]].ravel()) == pytest.approx(-2 / 36, rel=1e-13)  # 2 x energy


@pytest.mark.parametrize("material", [LinearElastic(2.0, 0.48), SaintVenantKirchhoff(2.0, 0.48)])
def test_homogeneous_deformations_are_q1s(material):
    """A uniform strain has the same dilatation at every point: no correction, so the patch test
    Q1 passes is passed alike (small strain and SVK's Green-Lagrange strain)."""
    mesh = box_mesh((1.0, 1.0, 2.0), (2, 2, 3), "hexahedron", jitter=0.2, seed=1)
    pb = _problem(mesh, material)
    q1, md = make_backend("skfem", pb), MeanDilatationBackend(pb)
    u = (mesh.points @ np.array([[0.02, 0.01, -0.03], [0.0, -0.015, 0.01], [0.02, 0.0, 0.025]]).T).ravel()
    np.testing.assert_allclose(md.internal_force(u), q1.internal_force(u), rtol=0, atol=1e-14)
    assert md.strain_energy(u) == pytest.approx(q1.strain_energy(u), rel=1e-13)


@pytest.mark.parametrize("material", [LinearElastic(2.0, 0.48), SaintVenantKirchhoff(2.0, 0.48)])
def test_force_and_tangent_are_the_energys_derivatives(material):
    mesh = box_mesh((1.0, 1.0, 2.0), (2, 2, 3), "hexahedron", jitter=0.2, seed=2)
    pb = _problem(mesh, material)
    md = MeanDilatationBackend(pb)
    rng = np.random.default_rng(0)
    u, du = 0.05 * rng.normal(size=pb.ndof), 1e-6 * rng.normal(size=pb.ndof)
    f, K = md.internal_force_and_tangent(u)
    assert (md.strain_energy(u + du) - md.strain_energy(u - du)) / 2 == pytest.approx(f @ du, rel=1e-7)
    np.testing.assert_allclose((md.internal_force(u + du) - md.internal_force(u - du)) / 2, K @ du,
                               rtol=0, atol=1e-8 * np.abs(K @ du).max())
    assert abs(K - K.T).max() <= 1e-14 * abs(K).max()
    assert K.nnz == make_backend("skfem", pb).tangent(u).nnz  # Q1's pattern (one factorisation per pattern)
    np.testing.assert_allclose(md.element_strain_energies(u).sum(), md.strain_energy(u), rtol=1e-13)
    np.testing.assert_allclose(md._scatter(md.element_internal_forces(u)), f, atol=1e-13)


def test_the_cell_kernel_is_the_cells_share_of_the_assembled_operators():
    """The correction is cell by cell: a subset's kernel (what a hyper-reduction samples) sums, over
    every cell, to the assembled energy, force and tangent; the Galerkin models' Voigt kernel, which
    would integrate the volumetric part at the Gauss points, refuses it."""
    from tissuebench.rom.galerkin.kernel import cell_geometry

    mesh = box_mesh((1.0, 1.0, 2.0), (2, 2, 3), "hexahedron", jitter=0.2, seed=4)
    md = MeanDilatationBackend(_problem(mesh, SaintVenantKirchhoff(2.0, 0.48)))
    u = 0.05 * np.random.default_rng(1).normal(size=md.ndof)
    kernel = md.cell_kernel()
    assert not hasattr(kernel, "grad") and not hasattr(kernel, "dx")
    W, f = kernel.energies_and_forces(kernel.gather(u))
    f2, K = kernel.forces_and_tangents(kernel.gather(u))
    assert W.sum() == pytest.approx(md.strain_energy(u), rel=1e-13)
    np.testing.assert_allclose(md._scatter(f), md.internal_force(u), atol=1e-13)
    np.testing.assert_array_equal(f, f2)
    np.testing.assert_allclose(md.pattern.assemble(K).toarray(), md.tangent(u).toarray(), atol=1e-12)
    some = md.cell_kernel(np.array([5, 1, 5]))
    np.testing.assert_allclose(some.energies(some.gather(u)), W[[5, 1, 5]], rtol=1e-14)
    with pytest.raises(NotImplementedError, match="Voigt kernel integrates the material law at the Gauss points"):
        cell_geometry(md, [0, 1])
    from tissuebench.rom import Training, element_kernel  # what another library's hyper-reduction is given

    public = element_kernel(Training(backend=md), np.array([2, 3]))
    assert isinstance(public, type(kernel)) and public.cells.tolist() == [2, 3]


@pytest.mark.ngsolve
def test_both_backends_give_the_same_element():
    """The correction is computed here on the quadrature both backends share: the two agree to round-off."""
    pb = load("cornea_pinch").to_problem()
    u = 0.01 * np.random.default_rng(0).normal(size=pb.ndof)
    sk, ng = MeanDilatationBackend(pb, "skfem"), MeanDilatationBackend(pb, "ngsolve")
    f = sk.internal_force(u)
    np.testing.assert_allclose(ng.internal_force(u), f, rtol=0, atol=1e-13 * np.abs(f).max())
    assert abs(ng.tangent(u) - sk.tangent(u)).max() <= 1e-13 * abs(sk.tangent(u)).max()
    assert ng.strain_energy(u) == pytest.approx(sk.strain_energy(u), rel=1e-13)


def test_what_it_refuses_is_named():
    tet = Problem(box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "tetra"), LinearElastic(1.0, 0.3), "P1",
                  dirichlet=[Dirichlet(BASE)])
    assert mean_dilatation_applies(tet) == "the mean-dilatation formulation is for trilinear hexahedra (Q1), not P1"
    nh = _problem(box_mesh((1.0, 1.0, 1.0), (1, 1, 1), "hexahedron"), NeoHookean(1.0, 0.3))
    with pytest.raises(ValueError, match="material 'neo_hookean' is not one whose volume part is kappa/2"):
        MeanDilatationBackend(nh)


# ------------------------------------------------------------------ validation
def _annulus(nr, nt, a=1.0, b=2.0, t=0.25) -> Mesh:
    """A quarter of the ring a <= r <= b, one layer of hexahedra of thickness t."""
    r, th = np.linspace(a, b, nr + 1), np.linspace(0.0, np.pi / 2, nt + 1)
    R, T, Z = np.meshgrid(r, th, [0.0, t], indexing="ij")
    points = np.column_stack([(R * np.cos(T)).ravel(), (R * np.sin(T)).ravel(), Z.ravel()])
    idx = np.arange(len(points)).reshape(nr + 1, nt + 1, 2)
    quads = [(idx[i, j], idx[i + 1, j], idx[i + 1, j + 1], idx[i, j + 1]) for i in range(nr) for j in range(nt)]
    return Mesh(points, np.array([[v[0] for v in q] + [v[1] for v in q] for q in quads]), "hexahedron")


def _lame(nu, nr, nt, a=1.0, b=2.0, t=0.25, delta=0.01):
    """The thick cylinder in plane strain, its inner radius pushed out by delta, outer free: the
    strain energy of Q1 and of the mean-dilatation hexahedra relative to the closed form
    u_r = A r + B / r, sigma_rr(b) = 0 (A = mu B / ((lambda + mu) b^2)), W = p delta (a pi / 2) t / 2."""
    mesh = _annulus(nr, nt, a, b, t)
    rad = lambda x: np.hypot(x[:, 0], x[:, 1])  # noqa: E731
    pb = Problem(mesh, LinearElastic(1.0, nu), "Q1", dirichlet=[
        Dirichlet(lambda x: np.abs(rad(x) - a) < 1e-9, (0, 1), lambda x: delta * x[:, :2] / rad(x)[:, None]),
        Dirichlet(ALL, (2,), 0.0), Dirichlet(lambda x: np.abs(x[:, 1]) < 1e-9, (1,), 0.0),
        Dirichlet(lambda x: np.abs(x[:, 0]) < 1e-9, (0,), 0.0)])
    lam, mu = pb.material.lame
    B = delta / (mu / ((lam + mu) * b * b) * a + 1.0 / a)
    A = mu * B / ((lam + mu) * b * b)
    p = 2 * mu * B / a**2 - 2 * (lam + mu) * A
    exact = 0.5 * p * delta * a * np.pi / 2 * t
    q1 = make_backend("skfem", pb)
    out = {}
    for name, be in (("Q1", q1), ("mean_dilatation", MeanDilatationBackend(pb, q1))):
        u, K = locking._linear_solution(be, pb)
        out[name] = 0.5 * float(u @ (K @ u)) / exact - 1.0
    return out


def test_at_nu_0499_the_mean_dilatation_matches_the_closed_form_where_q1_locks():
    """Hughes' test of volumetric locking. Q1's energy is 5.7 times too large on the 2 x 4 mesh
    (1.6 on the 4 x 8 mesh: it locks, and only slowly refines away); the mean-dilatation hexahedra
    are within 0.3 % (0.1 %) of the closed form."""
    coarse, fine = _lame(0.499, 2, 4), _lame(0.499, 4, 8)
    assert coarse["Q1"] > 5.0 and fine["Q1"] > 1.5
    assert abs(coarse["mean_dilatation"]) < 0.004 and abs(fine["mean_dilatation"]) < 0.0015


def test_at_nu_03_q1_and_the_mean_dilatation_agree_as_the_mesh_is_refined():
    """Away from incompressibility both converge to the closed form and to each other: their
    energies differ by 2.2 %, 0.6 %, 0.16 % on the 2 x 4, 4 x 8, 8 x 16 meshes (h^2)."""
    gaps = []
    for n in ((2, 4), (4, 8), (8, 16)):
        e = _lame(0.3, *n)
        gaps.append(abs((1 + e["Q1"]) / (1 + e["mean_dilatation"]) - 1))
    assert gaps[0] > 3.5 * gaps[1] > 3.5 * 3.5 * gaps[2] and gaps[2] < 0.002
    assert abs(e["Q1"]) < 0.002 and abs(e["mean_dilatation"]) < 0.0005


# ------------------------------------------------------------------ the indicator's numbers
class _Scene:
    """Two nodes, one displacement monitor ``tip`` (the x of node 1), as the tetrahedra's tests."""

    monitors = [{"name": "tip", "quantity": "displacement"}]
    material = {"name": "svk", "E": 7.0, "nu": 0.49}

    def evaluate_monitors(self, pb, u, f_int):
        return {"tip": float(u[3])}

    def to_problem(self, element):
        assert element == "Q1"
        return _Pb()


@dataclasses.dataclass(frozen=True)
class _Pb:
    material: object = None


def _indicator(monkeypatch, q1_tip, ref_tip, scene=None):
    """The indicator with the two linear solves replaced by fields of the given tips (K = 2 I)."""
    u = lambda x: np.array([0.0, 0.0, 0.0, x, 0.0, 0.0])  # noqa: E731
    calls = []
    monkeypatch.setattr(locking, "make_backend", lambda backend, pb: calls.append(("Q1", backend, pb)) or "Q1")
    monkeypatch.setattr(locking, "MeanDilatationBackend", lambda pb, be: calls.append(("MD", pb, be)) or "MD")
    monkeypatch.setattr(locking, "_linear_solution",
                        lambda be, pb: (u(q1_tip if be == "Q1" else ref_tip), 2.0 * np.eye(6)))
    return locking._hex_indicator(scene or _Scene(), "ngsolve"), calls


# the tip's deviation d gives an energy deviation (1 + d)^2 - 1, which carries the verdict
@pytest.mark.parametrize("ratio, locks", [
    (np.sqrt(1.02) * (1 - 1e-9), False), (np.sqrt(1.02) * (1 + 1e-9), True),
    (np.sqrt(0.98) * (1 + 1e-9), False), (np.sqrt(0.98) * (1 - 1e-9), True),
])
def test_verdict_both_sides_of_the_tolerance(monkeypatch, ratio, locks):
    ind, calls = _indicator(monkeypatch, ratio, 1.0)
    assert ind["computed"] and ind["element"] == "Q1" and ind["headline"] == "tip"
    assert ind["compared"]["tip"] == {"Q1": pytest.approx(ratio, rel=1e-15), "reference": 1.0,
                                      "deviation": pytest.approx(ratio - 1.0, abs=1e-14)}
    assert ind["energy_deviation"] == pytest.approx(ratio ** 2 - 1.0, abs=1e-14)
    assert ind["locks"] is locks
    # both solves on the linear material of the scene's E and nu, the same problem, the named backend
    pb = _Pb(material=LinearElastic(7.0, 0.49))
    assert calls == [("Q1", "ngsolve", pb), ("MD", pb, "Q1")]
    assert ind["material_note"] == "small-strain comparison with the linear material of the same E and nu (svk)"
    assert ind["method"] == "linear solves at rest, Q1 against mean-dilatation (B-bar) hexahedra on the same mesh"


def test_a_law_without_e_and_nu_is_not_measured_and_the_text_names_q1(monkeypatch):
    scene = _Scene()
    scene.material = {"name": "mooney_rivlin", "mu1": 1.0, "mu2": 1.0, "kappa": 100.0}
    ind, calls = _indicator(monkeypatch, 0.9, 1.2, scene)
    assert ind == {"computed": False, "why": "material 'mooney_rivlin' has no E and nu: the hexahedra's comparison "
                   "solves the linear material of the scene's E and nu"} and calls == []
    ind, _ = _indicator(monkeypatch, 0.8, 1.0)
    ind.update(bulk_to_shear=49.67, threshold=locking.LOCKING_BULK_TO_SHEAR, tolerance=0.02)
    assert locking.indicator_text(ind, {"length": "mm"}) == (
        "Q1 locks (K/G = 49.67 >= 9.667, i.e. nu >= 0.45): tip 0.8 mm with Q1 against 1 mm without locking "
        "(-20.0 %), strain energy -36.0 % (tolerance 2 %; small strain, same mesh)")


# ------------------------------------------------------------------ the formulation's rules
class _FScene:
    """What formulation_of reads of a scene on hexahedra."""

    def __init__(self, name="svk", given=False, **analysis):
        self.material = {"name": name, "E": 3.0, "nu": 0.48}
        self.element, self.element_given, self.analysis = "Q1", given, analysis
        self.units = {"length": "mm"}
        self.is_fe = True


LOCKS = {"computed": True, "locks": True, "element": "Q1"}
FREE = {"computed": True, "locks": False, "element": "Q1"}


@pytest.fixture
def indicator(monkeypatch):
    state = {"value": LOCKS}
    monkeypatch.setattr(fm, "locking_indicator", lambda scene, backend="skfem": state["value"])
    monkeypatch.setattr(fm, "indicator_text", lambda ind, units: f"TEXT({ind['locks']})")
    return state


@pytest.mark.parametrize("given, kept", [(True, "the scene's element"), (False, "Q1 on hexahedra")])
def test_under_the_tolerance_q1_is_kept_with_the_figure_and_no_warning(indicator, given, kept):
    indicator["value"] = FREE
    assert formulation_of(_FScene(given=given)) == fm.Formulation("displacement", "Q1", f"{kept}: TEXT(False)",
                                                                  indicator=FREE)


def test_over_the_tolerance_the_reference_takes_mean_dilatation_unless_q1_is_asked_for(indicator):
    assert formulation_of(_FScene()) == fm.Formulation("mean_dilatation", "Q1", "chosen because TEXT(True)",
                                                       indicator=LOCKS)
    assert formulation_of(_FScene()).label == "mean-dilatation trilinear hexahedra (Q1, B-bar)"
    assert formulation_of(_FScene(given=True)) == fm.Formulation(
        "displacement", "Q1", "mesh.element = 'Q1' asked for (TEXT(True))", indicator=LOCKS,
        warning="WARNING: TEXT(True); leave out mesh.element for mean-dilatation hexahedra, which do not lock")
    asked = formulation_of(_FScene(formulation="displacement"))
    assert asked.name == "displacement" and asked.warning == (
        "WARNING: TEXT(True); leave out analysis.formulation for mean-dilatation hexahedra, which do not lock")
    none = ("WARNING: TEXT(True); no formulation that does not lock on hexahedra for material 'neo_hookean' "
            "(mean-dilatation hexahedra: linear, svk)")
    assert formulation_of(_FScene(name="neo_hookean")) == fm.Formulation(
        "displacement", "Q1", "kept: material 'neo_hookean' has no mean-dilatation hexahedra here",
        indicator=LOCKS, warning=none)
    assert formulation_of(_FScene(name="neo_hookean", given=True)).warning == none


def test_not_measured_is_said_with_the_reason(indicator):
    indicator["value"] = {"computed": False, "why": "no E and nu"}
    form = formulation_of(_FScene(name="mooney_rivlin"))
    assert form.name == "displacement" and form.warning == (
        "WARNING: K/G = 24.67 >= 9.667 (nu >= 0.45): trilinear hexahedra may lock and the locking indicator was not "
        "computed (no E and nu)")


# ------------------------------------------------------------------ real scenes, both sides
BAR = """[case]
name = "hex_bar"
description = "a hexahedral bar pulled at its end"
[units]
length = "mm"
force = "N"
stress = "MPa"
[mesh]
builder = "box"
{element}[mesh.params]
lengths = [4.0, 1.0, 1.0]
cell_type = "hexahedron"
divisions = [8, 2, 2]
[mesh.ci]
[mesh.paper]
[material]
name = "svk"
E = 1.0
nu = 0.48
{supports}
[[load]]
name = "pull"
type = "traction"
region = {{ plane = "x", value = 4.0, tol = 1e-9 }}
value = [0.01, 0.0, 0.0]
history = {{ type = "ramp", t0 = 0.0, t1 = 1.0 }}
[analysis]
type = "static"
load_steps = 2
[[monitor]]
name = "tip"
quantity = "displacement"
point = [4.0, 0.5, 0.5]
component = "x"
"""
# rollers (each face held normal to itself): a uniform stress, which Q1 represents exactly
ROLLERS = "\n".join(f'[[dirichlet]]\nname = "{a} roller"\nregion = {{ plane = "{a}", value = 0.0, tol = 1e-9 }}\n'
                    f'components = "{a}"' for a in "xyz")
CLAMPED = '[[dirichlet]]\nname = "clamped"\nregion = { plane = "x", value = 0.0, tol = 1e-9 }\ncomponents = "xyz"'


def _bar(tmp_path, supports, element=False):
    path = tmp_path / "bar.toml"
    path.write_text(BAR.format(element='element = "Q1"\n' if element else "", supports=supports))
    return path


@pytest.mark.parametrize("element", [False, True])
def test_a_hexahedral_scene_under_the_tolerance_gets_no_warning(tmp_path, capsys, element):
    """Rollers: the stress is uniform, Q1 and the mean-dilatation hexahedra agree to round-off."""
    path = _bar(tmp_path, ROLLERS, element)
    form = formulation_of(load(path))
    assert form.name == "displacement" and form.element == "Q1" and form.warning == ""
    assert abs(form.indicator["deviation"]) < 1e-10 and abs(form.indicator["energy_deviation"]) < 1e-10
    assert "Q1 does not lock noticeably" in form.reason
    assert main(["scene", "check", str(path), "--out", "-"]) == 0
    assert "WARNING" not in capsys.readouterr().out


def test_a_hexahedral_scene_over_the_tolerance_warns_only_where_q1_is_asked_for(tmp_path, capsys):
    """Clamped at x = 0: Q1 7.2 % stiffer than the mean-dilatation hexahedra at nu = 0.48."""
    scene = load(_bar(tmp_path, CLAMPED))
    form = formulation_of(scene)
    assert form.name == "mean_dilatation" and form.warning == "" and isinstance(scene_backend(scene),
                                                                               MeanDilatationBackend)
    assert form.indicator["deviation"] == pytest.approx(-0.0724, abs=5e-4)
    path = _bar(tmp_path, CLAMPED, element=True)
    asked = formulation_of(load(path))
    assert asked.name == "displacement" and asked.warning.startswith("WARNING: Q1 locks")
    assert main(["scene", "check", str(path), "--out", "-"]) == 0
    assert "WARNING: Q1 locks" in capsys.readouterr().out and "-7.2 %" in asked.warning


# ------------------------------------------------------------------ the catalogue's cornea
@pytest.mark.parametrize("case, headline, deviation, energy", [
    ("cornea_pinch", "max_displacement", -0.3648, -0.3738),
    ("cornea_cut", "max_displacement", -0.4066, -0.4162),
])
def test_the_catalogue_cornea_locks_and_its_reference_does_not(case, headline, deviation, energy):
    """At ci (219 nodes, 2 layers of cells through 0.55 mm, SVK at nu = 0.48) Q1 is 36-41 % stiffer
    than the mean-dilatation hexahedra: the reference takes those, without a warning."""
    scene = load(case)
    ind = locking.locking_indicator(scene)
    assert ind["computed"] and ind["locks"] and ind["element"] == "Q1" and ind["headline"] == headline
    assert ind["deviation"] == pytest.approx(deviation, abs=1e-3)
    assert ind["energy_deviation"] == pytest.approx(energy, abs=1e-3)
    form = formulation_of(scene)
    assert form.name == "mean_dilatation" and form.warning == "" and "Q1 locks" in form.reason
    assert isinstance(scene_backend(scene), MeanDilatationBackend)


def test_the_cornea_asking_for_q1_is_warned_with_the_figure(tmp_path):
    """The catalogue's scene before issue 54 (``element = "Q1"``): the warning now carries the number."""
    text = (CATALOGUE_DIR / "cornea_pinch.toml").read_text()
    text = text.replace('builder = "cornea_dome"\n', 'builder = "cornea_dome"\nelement = "Q1"\n', 1)
    (tmp_path / "cornea.toml").write_text(text)
    form = formulation_of(load(tmp_path / "cornea.toml"))
    assert form.name == "displacement" and form.warning.startswith(
        "WARNING: Q1 locks (K/G = 24.67 >= 9.667, i.e. nu >= 0.45): max_displacement 0.01847 mm with Q1 against "
        "0.02908 mm without locking (-36.5 %), strain energy -37.4 %")


def test_run_cornea_pinch_prints_the_figure_and_no_warning(tmp_path, capsys):
    """Issue 54's "done when": the run says which formulation and the measured deviation, no WARNING."""
    assert main(["run", "cornea_pinch", "--out", str(tmp_path / "res"), "--quiet"]) == 0
    out, err = capsys.readouterr()
    assert "WARNING" not in err and "WARNING" not in out
    assert "formulation: mean_dilatation (Q1): chosen because Q1 locks" in out and "(-36.5 %)" in out


@pytest.mark.parametrize("E, computed", [(2.0, True), (1e308, False)])
def test_solves_that_fail_leave_the_indicator_uncomputed_with_the_reason(tmp_path, E, computed):
    """At E = 1e308 the small-strain system overflows (a singular factor): the indicator says so and
    the reference runs on Q1 with a warning, so its own Newton failure is the run's result (was: an
    internal error before any result); at the catalogue's E = 2 it is computed."""
    text = (CATALOGUE_DIR / "cornea_pinch.toml").read_text()
    assert "E = 2.0" in text
    (tmp_path / "cornea.toml").write_text(text.replace("E = 2.0", f"E = {E!r}", 1))
    scene = load(tmp_path / "cornea.toml")
    ind = locking.locking_indicator(scene)
    assert ind["computed"] is computed
    if not computed:
        assert ind["why"].startswith("its small-strain solves failed (LinearSolverError: ") or \
            ind["why"] == "its small-strain solves gave non-finite values"
        form = formulation_of(scene)
        assert form.name == "displacement" and "the locking indicator was not computed (its small-strain" in \
            form.warning
