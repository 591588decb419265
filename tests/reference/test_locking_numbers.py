"""The locking indicator by its numbers, worked by hand (issue 50, item 10): the deviation is
``(P1 - reference) / reference``, the strain energy ``u . K u / 2``, the verdict flips where the
larger of the two deviations passes :data:`~tissuebench.reference.locking.LOCKING_TOL` (2 %),
on both sides of it, whichever of the two carries it."""
from __future__ import annotations

import numpy as np
import pytest

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
    (0.45, "hexahedron", "hexahedron cells: no formulation that does not lock"),
])
def test_not_computed_below_the_threshold_or_without_tetrahedra(nu, cell, why):
    scene = _Scene()
    scene.material = {"name": "neo_hookean", "E": 1.0, "nu": nu}
    scene.mesh = type("M", (), {"cell_type": cell})()
    ind = locking.locking_indicator(scene)
    assert ind["computed"] is False and why in ind["why"]
    assert ind["bulk_to_shear"] == pytest.approx(2 * (1 + nu) / (3 * (1 - 2 * nu)), rel=1e-15)
