"""The locking indicator by its numbers, worked by hand (issue 50, item 10): the deviation is
``(P1 - reference) / reference``, the strain energy ``u . K u / 2``, the verdict flips where the
larger of the two deviations passes :data:`~tissuebench.reference.locking.LOCKING_TOL` (2 %),
on both sides of it, whichever of the two carries it."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.reference import locking


class _Scene:
    """Two nodes, one displacement monitor ``tip`` (the x of node 1)."""

    monitors = [{"name": "tip", "quantity": "displacement"}]
    mesh = type("M", (), {"cell_type": "tetra"})()
    material = {"name": "neo_hookean", "E": 1.0, "nu": 0.49}
    is_fe = True

    def evaluate_monitors(self, pb, u, f_int):
        return {"tip": float(u[3]), "reaction": float("nan")}  # a NaN monitor is left out of the comparison

    def to_problem(self, element):
        return "problem"

    def content_hash(self):
        return "by-hand"


def _pair(p1_tip, ref_tip, stiffness=2.0):
    """(u, K) of P1 and of the reference: node 1 moved along x by the tip value, K = stiffness * I."""
    K = stiffness * np.eye(6)
    u = lambda x: np.array([0.0, 0.0, 0.0, x, 0.0, 0.0])
    return {"P1": (u(p1_tip), K), "reference": (u(ref_tip), K)}


def test_deviation_is_relative_to_the_reference_by_hand():
    compared = locking._compare(_Scene(), None, _pair(0.9, 1.2))
    # tip: (0.9 - 1.2) / 1.2 = -0.25 exactly; relative to P1 it would be -1/3
    assert compared["tip"] == {"P1": 0.9, "reference": 1.2, "deviation": pytest.approx(-0.25, abs=1e-15)}
    # the largest nodal displacement: the same numbers (node 1 is the largest)
    assert compared["max_displacement"]["deviation"] == pytest.approx(-0.25, abs=1e-15)
    # strain energy u . K u / 2 = 2 * x^2 / 2: 0.81 against 1.44, deviation (0.81 - 1.44) / 1.44 = -0.4375
    energy = compared["strain_energy"]
    assert energy["P1"] == pytest.approx(0.81, rel=1e-14) and energy["reference"] == pytest.approx(1.44, rel=1e-14)
    assert energy["deviation"] == pytest.approx(-0.4375, abs=1e-14)
    assert "reaction" not in compared  # not finite: not compared


def test_a_zero_reference_quantity_is_not_compared():
    compared = locking._compare(_Scene(), None, _pair(0.0, 0.0))
    assert compared == {}  # every reference quantity is 0: no relative deviation exists


def test_headline_is_the_first_displacement_monitor_else_the_largest_displacement():
    assert locking._headline(_Scene(), {"tip": {}, "max_displacement": {}}) == "tip"
    assert locking._headline(_Scene(), {"max_displacement": {}}) == "max_displacement"


def _indicator(monkeypatch, p1_tip, ref_tip):
    """The indicator on the by-hand pair: the two linear solves replaced by the pair's solutions."""
    pair = _pair(p1_tip, ref_tip)
    solutions = iter([pair["P1"], pair["reference"]])
    monkeypatch.setattr(locking, "anp_applies", lambda pb: False)
    monkeypatch.setattr(locking, "make_backend", lambda backend, pb: "P1 backend")
    monkeypatch.setattr(locking, "AnpBackend", lambda pb, be: "ANP backend")
    monkeypatch.setattr(locking, "_linear_solution", lambda be, pb: next(solutions))
    return locking._indicator(_Scene(), "skfem")


# the tip's deviation d gives an energy deviation (1 + d)^2 - 1: the energy carries the verdict
# (|2d + d^2| > |d|) and flips at 1 + d = sqrt(1.02) above and sqrt(0.98) below
@pytest.mark.parametrize("ratio, locks", [
    (np.sqrt(1.02) * (1 - 1e-9), False), (np.sqrt(1.02) * (1 + 1e-9), True),  # P1 too soft: above
    (np.sqrt(0.98) * (1 + 1e-9), False), (np.sqrt(0.98) * (1 - 1e-9), True),  # P1 too stiff (locking): below
])
def test_verdict_both_sides_of_the_tolerance(monkeypatch, ratio, locks):
    ind = _indicator(monkeypatch, ratio, 1.0)
    assert ind["computed"] and ind["headline"] == "tip"
    assert ind["deviation"] == pytest.approx(ratio - 1.0, abs=1e-14)
    assert ind["energy_deviation"] == pytest.approx(ratio ** 2 - 1.0, abs=1e-14)
    assert ind["locks"] is locks


def test_verdict_follows_the_displacement_when_it_is_the_larger(monkeypatch):
    """The energy of a P1 field twice the reference's at a quarter of the stiffness would agree;
    here the energies agree to 1e-3 while the tip is 3 % off: the tip's 3 % carries the verdict."""
    monkeypatch.setattr(locking, "anp_applies", lambda pb: False)
    monkeypatch.setattr(locking, "make_backend", lambda backend, pb: None)
    monkeypatch.setattr(locking, "AnpBackend", lambda pb, be: None)
    u = lambda x: np.array([0.0, 0.0, 0.0, x, 0.0, 0.0])
    k_p1 = 2.0 / 1.03 ** 2 * 1.001  # energy P1 = 1.001 * energy reference
    solutions = iter([(u(1.03), k_p1 * np.eye(6)), (u(1.0), 2.0 * np.eye(6))])
    monkeypatch.setattr(locking, "_linear_solution", lambda be, pb: next(solutions))
    ind = locking._indicator(_Scene(), "skfem")
    assert ind["deviation"] == pytest.approx(0.03, abs=1e-14)
    assert ind["energy_deviation"] == pytest.approx(0.001, abs=1e-12)
    assert ind["locks"] is True


def test_text_states_the_signed_percentages():
    ind = {"computed": True, "compared": {"tip": {"P1": 0.9, "reference": 1.2, "deviation": -0.25}},
           "headline": "tip", "deviation": -0.25, "energy_deviation": -0.4375, "locks": True,
           "bulk_to_shear": 49.67, "threshold": locking.LOCKING_BULK_TO_SHEAR, "tolerance": 0.02}
    text = locking.indicator_text(ind, {"length": "mm"})
    assert text.startswith("P1 locks (K/G = 49.67 >= 9.667, i.e. nu >= 0.45)")
    assert "tip 0.9 mm with P1 against 1.2 mm without locking (-25.0 %)" in text
    assert "strain energy -43.8 %" in text and "tolerance 2 %" in text


def test_threshold_constant_by_hand():
    # K/G = 2 (1 + nu) / (3 (1 - 2 nu)) at nu = 0.45: 2.9 / 0.3
    assert locking.LOCKING_BULK_TO_SHEAR == pytest.approx(2.9 / 0.3, rel=1e-15)
    assert locking.bulk_to_shear({"E": 3.0, "nu": 0.25}) == pytest.approx(2 * 1.25 / 1.5, rel=1e-15)
    assert locking.bulk_to_shear({"name": "mooney_rivlin", "kappa": 12.0, "mu1": 1.0, "mu2": 2.0}) == 2.0
    assert locking.bulk_to_shear({"name": "guccione", "kappa": 10.0, "C": 2.0, "bt": 5.0}) == 1.0
    assert locking.bulk_to_shear({"name": "other"}) is None and locking.bulk_to_shear(None) is None


@pytest.mark.parametrize("nu, cell, why", [
    (0.4499, "tetra", "not nearly incompressible"),
    (0.45, "wedge", "wedge cells: no formulation that does not lock"),  # hexahedra: test_hex_locking.py
])
def test_not_computed_below_the_threshold_or_without_tetrahedra(nu, cell, why):
    scene = _Scene()
    scene.material = {"name": "neo_hookean", "E": 1.0, "nu": nu}
    scene.mesh = type("M", (), {"cell_type": cell})()
    ind = locking.locking_indicator(scene)
    assert ind["computed"] is False and why in ind["why"]
    assert ind["bulk_to_shear"] == pytest.approx(2 * (1 + nu) / (3 * (1 - 2 * nu)), rel=1e-15)


# ---- the two linear solves, the inputs of the comparison and the verdict's edges, by hand (issue 50,
# item 10: mutation testing of reference/locking.py). The solves are called directly: locking_indicator
# keeps its results per scene in MEMO, which a process that has run other tests may already hold.

class _Problem:
    """Three dofs: dof 0 prescribed (0.1 at load factor 1), dofs 1 and 2 free; a load 1.5 on dof 2."""

    ndof, free_dofs, fixed_dofs = 3, np.array([1, 2]), np.array([0])

    def prescribed_values(self, lam):
        return np.array([0.1 * lam])


class _Backend:
    """Two springs in a chain, stiffness 2 and 1: K = [[2, -2, 0], [-2, 3, -1], [0, -1, 1]]."""

    K = np.array([[2.0, -2.0, 0.0], [-2.0, 3.0, -1.0], [0.0, -1.0, 1.0]])

    def tangent(self, u):
        assert isinstance(u, np.ndarray) and u.shape == (3,) and not u.any()  # the tangent at rest
        return sp.csr_matrix(self.K)

    def external_force(self, u, lam):
        assert isinstance(u, np.ndarray) and u.shape == (3,) and not u.any()
        return np.array([0.0, 0.0, 1.5 * lam])


def test_linear_solution_by_hand_with_a_prescribed_value():
    """Free rows: [[3, -1], [-1, 1]] u_f = [0, 1.5] - [-2, 0] * 0.1 = [0.2, 1.5], so u_1 = 1.7 / 2 = 0.85
    and u_2 = 1.5 + 0.85 = 2.35; the prescribed dof holds its value at load factor 1 (0.1)."""
    u, K = locking._linear_solution(_Backend(), _Problem())
    np.testing.assert_allclose(u, [0.1, 0.85, 2.35], rtol=1e-14, atol=1e-15)
    np.testing.assert_array_equal(K.toarray(), _Backend.K)


@dataclasses.dataclass(frozen=True)
class _Pb:
    """A problem whose material the Saint Venant-Kirchhoff branch replaces (a dataclass, as the real
    one), and the dof the ``peak`` monitor reads."""

    material: object = None
    dof: int = 3


class _MonitoredScene(_Scene):
    """A ``peak`` monitor of quantity max_displacement first, whose value the problem's dof
    names, and a reaction read from the internal force."""

    monitors = [{"name": "reaction", "quantity": "force"}, {"name": "peak", "quantity": "max_displacement"}]

    def evaluate_monitors(self, pb, u, f_int):
        return {"peak": float(u[pb.dof]), "reaction": float(f_int[0])}


def test_compare_passes_the_problem_and_the_internal_force_to_the_monitors():
    # two nodes moved: (3, 4, 0) and (0, 0, 1): the largest nodal displacement is 5, the norm of all 26 ** 0.5
    u_p1, u_ref = np.array([3.0, 4.0, 0.0, 0.0, 0.0, 1.0]), np.array([6.0, 8.0, 0.0, 0.0, 0.0, 1.0])
    K = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, 2.0])
    compared = locking._compare(_MonitoredScene(), _Pb(dof=5), {"P1": (u_p1, K), "reference": (u_ref, K)})
    assert compared["peak"] == {"P1": 1.0, "reference": 1.0, "deviation": 0.0}  # u[5] through pb
    assert compared["reaction"] == {"P1": 3.0, "reference": 6.0, "deviation": -0.5}  # f_int[0] = K u
    assert compared["max_displacement"] == {"P1": 5.0, "reference": 10.0, "deviation": -0.5}
    # 0.5 u.K.u: (9 + 16 + 2) / 2 = 13.5 against (36 + 64 + 2) / 2 = 51
    assert compared["strain_energy"]["P1"] == 13.5 and compared["strain_energy"]["reference"] == 51.0
    assert locking._headline(_MonitoredScene(), compared) == "peak"  # a max_displacement monitor is one too


def test_indicator_of_a_law_anp_cannot_average_compares_the_linear_material_of_its_e_and_nu(monkeypatch):
    """Saint Venant-Kirchhoff: both solves run on LinearElastic(E, nu) of the scene's E and nu, the
    note says so; every call gets the P1 problem, the backend name and the P1 backend."""
    calls = []
    scene = _MonitoredScene()
    scene.material = {"name": "svk", "E": 7.0, "nu": 0.49}
    scene.to_problem = lambda element: calls.append(("to_problem", element)) or _Pb()
    monkeypatch.setattr(locking, "anp_applies", lambda pb: calls.append(("anp_applies", pb)) or "no U(J)")
    monkeypatch.setattr(locking, "make_backend", lambda backend, pb: calls.append(("make_backend", backend, pb))
                        or "P1 backend")
    monkeypatch.setattr(locking, "AnpBackend", lambda pb, be: calls.append(("AnpBackend", pb, be)) or "ANP backend")
    u = {"P1 backend": np.array([0.0, 0.0, 0.0, 0.9, 0.0, 0.0]), "ANP backend": np.array([0, 0, 0, 1.0, 0, 0])}
    monkeypatch.setattr(locking, "_linear_solution", lambda be, pb: calls.append(("solve", be, pb))
                        or (u[be], np.eye(6)))
    ind = locking._indicator(scene, "ngsolve")
    linear = locking.LinearElastic(7.0, 0.49)
    pb = _Pb(material=linear)
    assert calls == [("to_problem", "P1"), ("anp_applies", _Pb()), ("make_backend", "ngsolve", pb),
                     ("solve", "P1 backend", pb), ("AnpBackend", pb, "P1 backend"), ("solve", "ANP backend", pb)]
    assert ind["material_note"] == "small-strain comparison with the linear material of the same E and nu (svk)"
    assert ind["headline"] == "peak" and ind["compared"]["peak"]["deviation"] == pytest.approx(-0.1, abs=1e-15)
    assert ind["method"] == "linear solves at rest, P1 against average nodal pressure tetrahedra on the same mesh"


def _indicator_of(monkeypatch, compared):
    monkeypatch.setattr(locking, "anp_applies", lambda pb: "")
    monkeypatch.setattr(locking, "make_backend", lambda backend, pb: None)
    monkeypatch.setattr(locking, "AnpBackend", lambda pb, be: None)
    monkeypatch.setattr(locking, "_linear_solution", lambda be, pb: None)
    monkeypatch.setattr(locking, "_compare", lambda scene, pb, solutions: compared)
    return locking._indicator(_Scene(), "skfem")


def test_exactly_the_tolerance_does_not_lock_and_nothing_compared_does_not_lock(monkeypatch):
    """P1 locks when a deviation is *more* than 2 %: exactly 2 % does not; with no quantity to
    compare (every reference value 0) the deviations are NaN and nothing locks."""
    at = _indicator_of(monkeypatch, {"tip": {"deviation": locking.LOCKING_TOL},
                                     "strain_energy": {"deviation": -locking.LOCKING_TOL}})
    assert at["locks"] is False and at["deviation"] == 0.02 and at["energy_deviation"] == -0.02
    nothing = _indicator_of(monkeypatch, {})
    assert nothing["headline"] == "max_displacement" and nothing["compared"] == {} and nothing["locks"] is False
    assert np.isnan(nothing["deviation"]) and np.isnan(nothing["energy_deviation"]) and nothing["material_note"] == ""
    only_tip = _indicator_of(monkeypatch, {"tip": {"deviation": -0.03}})  # no strain energy: the tip decides
    assert only_tip["locks"] is True and np.isnan(only_tip["energy_deviation"])


def test_locking_indicator_keeps_the_solve_per_scene_and_backend(monkeypatch):
    from tissuebench.reference.memo import Memo

    monkeypatch.setattr(locking, "MEMO", Memo({"locking": None}))
    calls = []
    monkeypatch.setattr(locking, "_indicator", lambda scene, backend: calls.append((scene, backend)) or {
        "computed": True, "locks": True})
    scene = _Scene()
    ind = locking.locking_indicator(scene, "ngsolve")
    assert ind == {"computed": True, "bulk_to_shear": pytest.approx(2 * 1.49 / (3 * 0.02), rel=1e-14),
                   "threshold": locking.LOCKING_BULK_TO_SHEAR, "tolerance": 0.02, "locks": True}
    assert calls == [(scene, "ngsolve")]
    assert locking.locking_indicator(scene, "ngsolve") is ind and len(calls) == 1  # kept


def test_not_computed_for_a_scene_that_is_not_finite_elements_or_has_no_moduli():
    scene = _Scene()
    scene.is_fe = False  # nearly incompressible, but no mesh to solve on
    ind = locking.locking_indicator(scene)
    assert ind == {"computed": False, "bulk_to_shear": pytest.approx(2 * 1.49 / (3 * 0.02), rel=1e-14),
                   "threshold": locking.LOCKING_BULK_TO_SHEAR, "tolerance": 0.02, "why": "not nearly incompressible"}
    scene.material = {"name": "other"}
    assert locking.locking_indicator(scene)["why"] == "no bulk and shear modulus"
    assert locking.bulk_to_shear({"E": 3.0}) is None  # E without nu: no K/G from it


def test_text_when_not_computed_and_without_a_headline_or_a_unit():
    text = locking.indicator_text({"computed": False, "why": "not nearly incompressible", "bulk_to_shear": 8.5,
                                   "threshold": 9.6667})
    assert text == "locking indicator not computed: not nearly incompressible (K/G = 8.5, threshold 9.667)"
    assert locking.indicator_text({"computed": False, "why": "no bulk and shear modulus", "bulk_to_shear": None}) \
        == "locking indicator not computed: no bulk and shear modulus"
    assert locking.indicator_text({"computed": False}) == "locking indicator not computed: "
    ind = {"computed": True, "compared": {"tip": {"P1": 0.99, "reference": 1.0, "deviation": -0.01}},
           "headline": "tip", "deviation": -0.01, "energy_deviation": -0.015, "locks": False,
           "bulk_to_shear": 12.0, "threshold": 9.6667, "tolerance": 0.02}
    assert locking.indicator_text(ind) == (
        "P1 does not lock noticeably (K/G = 12 >= 9.667, i.e. nu >= 0.45): tip 0.99  with P1 against 1  without "
        "locking (-1.0 %), strain energy -1.5 % (tolerance 2 %; small strain, same mesh)")
    ind["headline"] = "max_displacement"  # not among the compared quantities: no headline numbers
    assert locking.indicator_text(ind).startswith("P1 does not lock noticeably (K/G = 12 >= 9.667, i.e. nu >= 0.45): "
                                                  ", strain energy -1.5 %")
