"""Which finite-element formulation a scene's reference uses, and why.

* ``analysis.formulation`` given: that one ("displacement", "anp", "mixed").
* ``[mesh] element`` given (e.g. ``"P1"``): the displacement formulation of that element, even
  where it locks; the locking indicator (:mod:`.locking`) then states by how much.
* neither: P1 (or Q1 on hexahedra), unless the locking indicator says P1 locks on this mesh
  (nu >= 0.45 and P1's monitored displacement or strain energy more than 2 % off), then the
  average nodal pressure tetrahedra (:mod:`~tissuebench.refsolvers.anp`), which do not lock;
  on hexahedra the indicator measures Q1 against mean-dilatation hexahedra
  (:mod:`~tissuebench.refsolvers.mean_dilatation`, :mod:`.locking`) and the reference takes
  those where Q1 locks (linear and Saint Venant-Kirchhoff materials).

Why ANP and not P2 or the mixed P2-P1 by default: on the same mesh they have the same unknowns
as P1 (3 per vertex, the reference's cost stays that of P1 within a small factor; P2 has about
8 times the unknowns), a mass matrix (dynamics), and a displacement-only energy whose force and
tangent every ROM that reads the backend's operators uses unchanged. On the 4.9k-vertex dome
(nu = 0.499) ANP's apex displacement is within 3 % of the mixed P2-P1 on the same mesh, where
P1 is 40 % short (the project's notes: the measurements and the commands that make them).
"""
from __future__ import annotations

from dataclasses import dataclass

from ..cases.sections import VOLUMETRIC_MATERIALS
from ..refsolvers.anp import AnpBackend, volumetric_modulus
from ..refsolvers.backends import make_backend
from ..refsolvers.mean_dilatation import MEAN_DILATATION_MATERIALS, MeanDilatationBackend
from .locking import LOCKING_BULK_TO_SHEAR, bulk_to_shear, indicator_text, locking_indicator

__all__ = ["Formulation", "formulation_of", "scene_backend", "FORMULATION_LABELS"]

#: the materials average nodal pressure tetrahedra can model (a volumetric part U(J), or linear)
ANP_MATERIALS = VOLUMETRIC_MATERIALS + ("linear",)
FORMULATION_LABELS = {"displacement": "displacement", "anp": "average nodal pressure tetrahedra (ANP)",
                      "mixed": "mixed u-p (Taylor-Hood P2-P1)",
                      "mean_dilatation": "mean-dilatation trilinear hexahedra (Q1, B-bar)"}


@dataclass(frozen=True)
class Formulation:
    """The formulation of a reference run: ``name`` ("displacement" | "anp" | "mixed" |
    "mean_dilatation"), the ``element`` of its displacement, the ``reason`` it was chosen, the
    ``warning`` a user must see (P1 or Q1 asked for where it locks), the locking ``indicator``
    (dict, may be empty) and, for the mixed formulation, its ``bulk_modulus`` (None: J = 1 imposed)."""

    name: str
    element: str
    reason: str
    warning: str = ""
    indicator: dict | None = None
    bulk_modulus: float | None = None

    @property
    def label(self) -> str:
        return f"{self.element} {FORMULATION_LABELS[self.name]}" if self.name == "displacement" \
            else FORMULATION_LABELS[self.name]

    def manifest(self) -> dict:
        """What a reference's manifest (``info``) records of it."""
        return {"formulation": self.name, "element": self.element, "formulation_reason": self.reason,
                "locking_warning": self.warning, "locking_indicator": self.indicator or {},
                **({"bulk_modulus": self.bulk_modulus} if self.name == "mixed" else {})}


def _mixed(scene):
    a = scene.analysis
    if a.get("incompressible"):
        return Formulation("mixed", "P2", "analysis.formulation = 'mixed' with incompressible = true: J = 1 imposed "
                           "by a pressure field, the material's volumetric part unused")
    kappa = volumetric_modulus(scene.make_material())
    return Formulation("mixed", "P2", f"analysis.formulation = 'mixed': perturbed Lagrangian with the material's "
                       f"volumetric modulus kappa = {kappa:.6g} (from its E and nu or its kappa)", bulk_modulus=kappa)


def formulation_of(scene, backend: str = "skfem") -> Formulation:
    """The :class:`Formulation` of a finite-element ``scene`` (module docstring)."""
    asked = scene.analysis.get("formulation")
    if asked == "mixed":
        return _mixed(scene)
    ratio = bulk_to_shear(scene.material)
    near = ratio is not None and ratio >= LOCKING_BULK_TO_SHEAR
    if asked == "anp":
        ind = locking_indicator(scene, backend) if near else None
        return Formulation("anp", "P1", "analysis.formulation = 'anp'", indicator=ind)
    element = scene.element
    if not near:
        return Formulation("displacement", element, "the scene's element" if scene.element_given
                           else "not nearly incompressible: K/G below the locking threshold")
    if element == "Q1":
        return _hexahedra(scene, asked, ratio, backend)
    if element == "P2":
        return Formulation("displacement", "P2", "the scene's element (P2 locks less than P1; the mixed "
                           "formulation does not: analysis.formulation = 'mixed')")
    ind = locking_indicator(scene, backend)
    text = indicator_text(ind, scene.units)
    if scene.element_given or asked == "displacement":
        how = "mesh.element = 'P1'" if scene.element_given else "analysis.formulation = 'displacement'"
        warning = (f"WARNING: {text}; leave out mesh.element (or set analysis.formulation = 'anp') for a "
                   "reference that does not lock") if ind.get("locks") else ""
        return Formulation("displacement", "P1", f"{how} asked for ({text})", warning=warning, indicator=ind)
    if ind.get("computed") and ind["locks"]:
        if scene.material["name"] not in ANP_MATERIALS:
            return Formulation("displacement", "P1", f"kept: material {scene.material['name']!r} has no volumetric "
                               "part for average nodal pressure tetrahedra", indicator=ind, warning=(
                                   f"WARNING: {text}; no formulation that does not lock for material "
                                   f"{scene.material['name']!r}: a law with a volumetric part "
                                   f"({', '.join(ANP_MATERIALS)}) gets one"))
        return Formulation("anp", "P1", f"chosen because {text}", indicator=ind)
    return Formulation("displacement", "P1", text if ind.get("computed") else ind.get("why", ""), indicator=ind)


def _hexahedra(scene, asked, ratio, backend):
    """Q1 of a nearly incompressible scene: measured against mean-dilatation hexahedra
    (:mod:`.locking`); kept with a note below the tolerance, replaced by them above it
    unless Q1 is asked for (then a WARNING with the numbers)."""
    ind = locking_indicator(scene, backend)
    kept = "the scene's element" if scene.element_given else "Q1 on hexahedra"
    if not ind.get("computed"):
        return Formulation("displacement", "Q1", kept, indicator=ind, warning=(
            f"WARNING: K/G = {ratio:.4g} >= {LOCKING_BULK_TO_SHEAR:.4g} (nu >= 0.45): trilinear hexahedra may lock "
            f"and the locking indicator was not computed ({ind.get('why', '')})"))
    text = indicator_text(ind, scene.units)
    if not ind["locks"]:
        return Formulation("displacement", "Q1", f"{kept}: {text}", indicator=ind)
    name = scene.material["name"]
    none = (f"no formulation that does not lock on hexahedra for material {name!r} (mean-dilatation hexahedra: "
            f"{', '.join(MEAN_DILATATION_MATERIALS)})")
    if scene.element_given or asked == "displacement":
        how = "mesh.element = 'Q1'" if scene.element_given else "analysis.formulation = 'displacement'"
        keys = " and ".join(k for k, on in (("mesh.element", scene.element_given),
                                            ("analysis.formulation", asked == "displacement")) if on)
        remedy = f"leave out {keys} for mean-dilatation hexahedra, which do not lock" \
            if name in MEAN_DILATATION_MATERIALS else none
        return Formulation("displacement", "Q1", f"{how} asked for ({text})", indicator=ind,
                           warning=f"WARNING: {text}; {remedy}")
    if name not in MEAN_DILATATION_MATERIALS:
        return Formulation("displacement", "Q1", f"kept: material {name!r} has no mean-dilatation hexahedra here",
                           indicator=ind, warning=f"WARNING: {text}; {none}")
    return Formulation("mean_dilatation", "Q1", f"chosen because {text}", indicator=ind)


def scene_backend(scene, backend="skfem", problem=None):
    """The backend a reference and the ROMs of ``scene`` use: the displacement backend of its
    problem, wrapped by :class:`~tissuebench.refsolvers.anp.AnpBackend` when the formulation is
    ANP, by :class:`~tissuebench.refsolvers.mean_dilatation.MeanDilatationBackend` when it is
    mean dilatation (the mixed formulation's runner builds its own). ``backend``: a name or a
    Backend class."""
    pb = scene.to_problem() if problem is None else problem
    be = make_backend(backend, pb)
    if scene.is_fe and pb.element == "P1" and formulation_of(scene).name == "anp":
        return AnpBackend(pb, be)
    if scene.is_fe and pb.element == "Q1" and formulation_of(scene).name == "mean_dilatation":
        return MeanDilatationBackend(pb, be)
    return be
