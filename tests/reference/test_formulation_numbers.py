"""Which formulation a reference uses, every branch by its exact fields (issue 50, item 10: the
mutation testing of reference/formulation.py): the name, element, reason and warning a user reads
in the manifest, the indicator recorded, the mixed formulation's bulk modulus, and the backend the
reference and the ROMs solve with. The locking indicator is replaced by fixed verdicts (its numbers:
test_locking_numbers.py), so each rule is checked on both sides of it without a solve."""
from __future__ import annotations

import pytest

from tissuebench.reference import formulation as fm
from tissuebench.refsolvers.materials import LinearElastic

LOCKS = {"computed": True, "locks": True, "headline": "tip", "compared": {}, "deviation": -0.4,
         "energy_deviation": -0.5, "bulk_to_shear": 49.67, "threshold": 9.667, "tolerance": 0.02}
FREE = {**LOCKS, "locks": False, "deviation": -0.01, "energy_deviation": -0.015}


class _Scene:
    """What formulation_of reads of a scene."""

    def __init__(self, nu=0.49, name="neo_hookean", element="P1", given=False, **analysis):
        self.material = {"name": name, "E": 3.0, "nu": nu}
        self.element, self.element_given, self.analysis = element, given, analysis
        self.units = {"length": "mm"}
        self.is_fe = True

    def make_material(self):
        return LinearElastic(self.material["E"], self.material["nu"])


@pytest.fixture
def indicator(monkeypatch):
    """Replace the indicator by a fixed verdict; the calls it got are listed in ``calls``."""
    state = {"value": LOCKS, "calls": []}

    def fake(scene, backend="skfem"):
        state["calls"].append((scene, backend))
        return state["value"]

    monkeypatch.setattr(fm, "locking_indicator", fake)
    monkeypatch.setattr(fm, "indicator_text", lambda ind, units: f"TEXT({ind.get('locks')}, {units['length']})")
    return state


def test_locks_without_an_element_given_chooses_anp_and_records_the_indicator(indicator):
    scene = _Scene()
    form = fm.formulation_of(scene, "ngsolve")
    assert form == fm.Formulation("anp", "P1", "chosen because TEXT(True, mm)", indicator=LOCKS)
    assert indicator["calls"] == [(scene, "ngsolve")]
    assert form.label == "average nodal pressure tetrahedra (ANP)"
    assert form.manifest() == {"formulation": "anp", "element": "P1", "formulation_reason": "chosen because "
                               "TEXT(True, mm)", "locking_warning": "", "locking_indicator": LOCKS}


def test_does_not_lock_keeps_p1_with_the_indicator_text(indicator):
    indicator["value"] = FREE
    form = fm.formulation_of(_Scene())
    assert form == fm.Formulation("displacement", "P1", "TEXT(False, mm)", indicator=FREE)
    assert form.label == "P1 displacement"
    assert form.manifest() == {"formulation": "displacement", "element": "P1", "formulation_reason":
                               "TEXT(False, mm)", "locking_warning": "", "locking_indicator": FREE}


def test_an_indicator_not_computed_says_why(indicator):
    indicator["value"] = {"computed": False, "why": "no formulation to compare with"}
    form = fm.formulation_of(_Scene())
    assert (form.name, form.element, form.reason) == ("displacement", "P1", "no formulation to compare with")
    indicator["value"] = {"computed": False, "locks": True}  # never computed: its verdict is not read
    assert fm.formulation_of(_Scene()).reason == ""


@pytest.mark.parametrize("given, asked, how", [
    (True, None, "mesh.element = 'P1'"),
    (False, "displacement", "analysis.formulation = 'displacement'"),
    (True, "displacement", "mesh.element = 'P1'"),
])
@pytest.mark.parametrize("locks", [True, False])
def test_p1_asked_for_is_kept_and_warned_about_only_where_it_locks(indicator, given, asked, how, locks):
    indicator["value"] = LOCKS if locks else FREE
    scene = _Scene(given=given, **({"formulation": asked} if asked else {}))
    form = fm.formulation_of(scene, "ngsolve")
    text = f"TEXT({locks}, mm)"
    warning = (f"WARNING: {text}; leave out mesh.element (or set analysis.formulation = 'anp') for a reference "
               "that does not lock") if locks else ""
    assert form == fm.Formulation("displacement", "P1", f"{how} asked for ({text})", warning=warning,
                                  indicator=indicator["value"])
    assert indicator["calls"] == [(scene, "ngsolve")]


def test_a_law_without_a_volumetric_part_keeps_p1_and_warns(indicator):
    form = fm.formulation_of(_Scene(name="svk"))
    assert form == fm.Formulation(
        "displacement", "P1", "kept: material 'svk' has no volumetric part for average nodal pressure tetrahedra",
        indicator=LOCKS, warning="WARNING: TEXT(True, mm); no formulation that does not lock for material 'svk': a "
        "law with a volumetric part (neo_hookean, neo_hookean_decoupled, mooney_rivlin, guccione, linear) gets one")
    assert fm.formulation_of(_Scene(name="linear")).name == "anp"  # linear: ANP averages it


@pytest.mark.parametrize("nu, near", [(0.4499, False), (0.45, True)])
def test_anp_asked_for_records_the_indicator_only_when_nearly_incompressible(indicator, nu, near):
    scene = _Scene(nu=nu, formulation="anp")
    form = fm.formulation_of(scene, "ngsolve")
    assert form == fm.Formulation("anp", "P1", "analysis.formulation = 'anp'", indicator=LOCKS if near else None)
    assert indicator["calls"] == ([(scene, "ngsolve")] if near else [])
    assert form.manifest()["locking_indicator"] == (LOCKS if near else {})


@pytest.mark.parametrize("given, reason", [(True, "the scene's element"),
                                           (False, "not nearly incompressible: K/G below the locking threshold")])
def test_below_the_threshold_the_element_is_kept_without_an_indicator(indicator, given, reason):
    form = fm.formulation_of(_Scene(nu=0.4499, element="Q1", given=given))
    assert form == fm.Formulation("displacement", "Q1", reason) and indicator["calls"] == []
    assert form.label == "Q1 displacement" and "bulk_modulus" not in form.manifest()


def test_hexahedra_above_the_threshold_are_measured(indicator):
    """Issue 54: Q1 gets the indicator too (against mean-dilatation hexahedra; the rules on both sides
    of the tolerance: test_hex_locking.py); neo-Hookean has no mean-dilatation hexahedra here."""
    scene = _Scene(nu=0.45, element="Q1")
    form = fm.formulation_of(scene)
    assert form == fm.Formulation("displacement", "Q1", "kept: material 'neo_hookean' has no mean-dilatation "
                                  "hexahedra here", indicator=LOCKS, warning=(
                                      "WARNING: TEXT(True, mm); no formulation that does not lock on hexahedra for "
                                      "material 'neo_hookean' (mean-dilatation hexahedra: linear, svk)"))
    assert indicator["calls"] == [(scene, "skfem")]


def test_p2_above_the_threshold_is_kept_and_points_to_the_mixed_formulation(indicator):
    form = fm.formulation_of(_Scene(element="P2"))
    assert form == fm.Formulation("displacement", "P2", "the scene's element (P2 locks less than P1; the mixed "
                                  "formulation does not: analysis.formulation = 'mixed')")
    assert indicator["calls"] == [] and form.label == "P2 displacement"


def test_mixed_takes_the_volumetric_modulus_by_hand_unless_incompressible(indicator):
    # lambda of E = 3, nu = 0.25: E nu / ((1 + nu) (1 - 2 nu)) = 0.75 / 0.625 = 1.2
    form = fm.formulation_of(_Scene(nu=0.25, formulation="mixed"))
    assert form == fm.Formulation("mixed", "P2", "analysis.formulation = 'mixed': perturbed Lagrangian with the "
                                  "material's volumetric modulus kappa = 1.2 (from its E and nu or its kappa)",
                                  bulk_modulus=pytest.approx(1.2, rel=1e-15))
    assert form.label == "mixed u-p (Taylor-Hood P2-P1)"
    assert form.manifest() == {"formulation": "mixed", "element": "P2", "formulation_reason": form.reason,
                               "locking_warning": "", "locking_indicator": {}, "bulk_modulus": form.bulk_modulus}
    incompressible = fm.formulation_of(_Scene(formulation="mixed", incompressible=True))
    assert incompressible == fm.Formulation("mixed", "P2", "analysis.formulation = 'mixed' with incompressible = "
                                            "true: J = 1 imposed by a pressure field, the material's volumetric "
                                            "part unused")
    assert incompressible.manifest()["bulk_modulus"] is None and indicator["calls"] == []


class _Problem:
    def __init__(self, element):
        self.element = element


@pytest.mark.parametrize("is_fe, element, name, wrapped", [
    (True, "P1", "anp", True), (True, "P1", "displacement", False), (True, "P2", "anp", False),
    (False, "P1", "anp", False),
])
def test_scene_backend_wraps_the_backend_only_for_anp_on_p1(monkeypatch, is_fe, element, name, wrapped):
    scene = _Scene()
    scene.is_fe = is_fe
    scene.to_problem = lambda: _Problem("P1")
    made = []
    monkeypatch.setattr(fm, "make_backend", lambda backend, pb: made.append((backend, pb)) or "backend")
    monkeypatch.setattr(fm, "AnpBackend", lambda pb, be: ("ANP", pb, be))
    monkeypatch.setattr(fm, "formulation_of", lambda s: fm.Formulation(name, "P1", "") if s is scene else None)
    problem = _Problem(element)
    be = fm.scene_backend(scene, "ngsolve", problem)
    assert made == [("ngsolve", problem)]
    assert be == (("ANP", problem, "backend") if wrapped else "backend")
    made.clear()
    fm.scene_backend(scene)  # the scene's own problem, the default backend
    assert made[0][0] == "skfem" and made[0][1].element == "P1"
