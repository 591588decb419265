"""The locking indicator: how far linear tetrahedra (P1) are from a formulation that does not lock.

Soft tissue is nearly incompressible (nu = 0.45 .. 0.499). At fixed E the shear modulus barely
changes over that range while the bulk modulus grows without bound, and P1 answers that with
volumetric locking: a dome of neo-Hookean tissue pressed at its apex moved 4.9 mm with P1
against 9.3 mm with P2 at nu = 0.499 on the same coarse mesh. Every ROM measured against such
a reference is measured against a yardstick off by a factor of two.

:func:`locking_indicator` solves the scene's small-strain problem (the tangent at rest, the
loads and prescribed displacements at load factor 1) twice on the same mesh: with P1 and with
the average nodal pressure formulation (:mod:`~tissuebench.refsolvers.anp`), which does not
lock, and compares the monitored quantities and the strain energy. Two linear solves: about as
long as one Newton iteration of each, so ``scene check`` and every reference solve can afford
it. It is computed when the ratio of bulk to shear modulus at rest reaches
:data:`LOCKING_BULK_TO_SHEAR` (nu >= 0.45), and says P1 locks when a compared quantity moves by
more than :data:`LOCKING_TOL`.

On hexahedra the same comparison solves trilinear hexahedra (Q1) as the backend assembles them
(2x2x2 Gauss points) against the mean-dilatation (B-bar) hexahedra of
:mod:`~tissuebench.refsolvers.mean_dilatation` on the same nodes (:func:`_hex_indicator`). Not the
hexahedra split into tetrahedra with average nodal pressure: the two hexahedra differ only in the
volumetric part, so their difference is the volumetric locking alone, where linear tetrahedra bring
a bending stiffness of their own (the cornea: 0.55 mm thin, 2 layers of cells at ci). Both solve the
linear material of the scene's E and nu; a law given otherwise (Mooney-Rivlin, Guccione) is not measured.

Locking is a small-strain property of the discretisation (the constraint count), so the
linear comparison measures it; on the dome the nonlinear deviations at 2 N followed the
linear ones (see the tests and the project's notes).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..refsolvers.anp import AnpBackend, anp_applies
from ..refsolvers.backends import make_backend
from ..refsolvers.materials import LinearElastic
from ..refsolvers.mean_dilatation import MeanDilatationBackend
from ..refsolvers.solver_base import LinearSolverError
from ..refsolvers.sparse_direct import factorized
from .memo import MEMO

__all__ = ["LOCKING_NU", "LOCKING_BULK_TO_SHEAR", "LOCKING_TOL", "HEX_METHOD", "bulk_to_shear",
           "locking_indicator", "indicator_text", "decided_elsewhere"]

#: the Poisson ratio from which the indicator is computed
LOCKING_NU = 0.45
#: the same threshold as the ratio of bulk to shear modulus at rest, K/G = 2 (1 + nu) / (3 (1 - 2 nu))
LOCKING_BULK_TO_SHEAR = 2 * (1 + LOCKING_NU) / (3 * (1 - 2 * LOCKING_NU))
#: P1 locks when its monitored displacement or strain energy is this far (relative) from the reference's
LOCKING_TOL = 0.02
#: what the indicator of a scene on hexahedra solves
HEX_METHOD = "linear solves at rest, Q1 against mean-dilatation (B-bar) hexahedra on the same mesh"


def bulk_to_shear(material: dict | None) -> float | None:
    """K/G of a scene's ``[material]`` table at rest, None where the law does not say (1D models)."""
    m = material or {}
    if "E" in m and "nu" in m:
        nu = float(m["nu"])
        return 2 * (1 + nu) / (3 * (1 - 2 * nu))
    if m.get("name") == "mooney_rivlin":
        return float(m["kappa"]) / (2.0 * (m["mu1"] + m["mu2"]))
    if m.get("name") == "guccione":  # the transverse shear modulus of the linearised law: C bt
        return float(m["kappa"]) / (float(m["C"]) * float(m["bt"]))
    return None


def _linear_solution(be, pb):
    u = np.zeros(pb.ndof)
    K = be.tangent(u)
    free, fixed = pb.free_dofs, pb.fixed_dofs
    u[fixed] = pb.prescribed_values(1.0)
    f = be.external_force(np.zeros(pb.ndof), 1.0)
    u[free] = factorized(K[free][:, free])(f[free] - K[free][:, fixed] @ u[fixed])
    return u, K


def _compare(scene, pb, solutions, locked: str = "P1"):
    """Monitors, max displacement and strain energy of the ``locked`` element's (P1, or Q1 on
    hexahedra: :func:`_hex_indicator`) and the reference solutions."""
    rows = {}
    for name, (u, K) in solutions.items():
        f_int = K @ u
        vals = {k: v for k, v in scene.evaluate_monitors(pb, u, f_int).items() if np.isfinite(v)}
        vals["max_displacement"] = float(np.linalg.norm(u.reshape(-1, 3), axis=1).max())
        vals["strain_energy"] = 0.5 * float(u @ f_int)
        rows[name] = vals
    out = {}
    for k, ref in rows["reference"].items():
        p1 = rows[locked].get(k)
        if p1 is not None and abs(ref) > 0:
            out[k] = {locked: p1, "reference": ref, "deviation": (p1 - ref) / ref}
    return out


def _headline(scene, compared):
    """The quantity the indicator states: the scene's first displacement monitor, else the max
    displacement (and the strain energy beside it, which also sees prescribed displacements)."""
    for m in scene.monitors:
        if m["quantity"] in ("displacement", "max_displacement") and m["name"] in compared:
            return m["name"]
    return "max_displacement"


def locking_indicator(scene, backend: str = "skfem") -> dict:
    """How far P1 is from the average nodal pressure formulation on the scene's mesh (on hexahedra:
    Q1 from the mean-dilatation hexahedra, with ``element = "Q1"``; not computed for a law without
    E and nu there).

    Returns
    -------
    dict
        ``computed`` (bool), ``bulk_to_shear``, ``threshold``, ``why`` (when not computed),
        and when computed: ``compared`` ({quantity: {P1, reference, deviation}}), ``headline``
        (the quantity stated), ``deviation`` (its relative deviation (P1 - reference) / reference:
        -0.4 is P1 40 % short), ``energy_deviation``, ``locks`` (bool), ``material_note``.
    """
    ratio = bulk_to_shear(scene.material)
    out = {"computed": False, "bulk_to_shear": ratio, "threshold": LOCKING_BULK_TO_SHEAR, "tolerance": LOCKING_TOL}
    if not scene.is_fe or ratio is None or ratio < LOCKING_BULK_TO_SHEAR:
        return {**out, "why": "not nearly incompressible" if ratio is not None else "no bulk and shear modulus"}
    if scene.mesh.cell_type == "hexahedron":  # Q1 against mean-dilatation hexahedra
        return MEMO.get("locking", (scene.content_hash(), backend), lambda: {**out, **_solved(_hex_indicator, scene,
                                                                                             backend)})
    if scene.mesh.cell_type != "tetra":
        return {**out, "why": f"{scene.mesh.cell_type} cells: no formulation that does not lock to compare with"}
    return MEMO.get("locking", (scene.content_hash(), backend), lambda: {**out, **_solved(_indicator, scene, backend)})


def decided_elsewhere(scene, why: str, backends=("skfem", "ngsolve")) -> None:
    """Record that ``scene``'s formulation was decided without its own indicator (``why``): the
    h/2 mesh of the convergence check takes the h mesh's, and its two linear solves at rest, of
    the size of the refined mesh, cost minutes on an organ (1.5 min at 108k dofs) for a number
    nobody reads. :func:`locking_indicator` then returns it as not computed, saying ``why``."""
    if not why:
        raise ValueError("decided_elsewhere: why must say where the formulation was decided")
    ratio = bulk_to_shear(scene.material)
    entry = {"computed": False, "bulk_to_shear": ratio, "threshold": LOCKING_BULK_TO_SHEAR,
             "tolerance": LOCKING_TOL, "why": why}
    for backend in backends:
        MEMO.get("locking", (scene.content_hash(), backend), lambda: dict(entry))


def _solved(indicator, scene, backend) -> dict:
    """``indicator(scene, backend)``, or not computed with the reason when its linear solves fail
    (a scene at the edge of the floating-point range, E = 1e308: a singular or non-finite
    system): the reference's own solve then reports the failure as a result, which an internal
    error here would hide."""
    try:
        with np.errstate(all="ignore"):
            result = indicator(scene, backend)
    except (LinearSolverError, FloatingPointError, np.linalg.LinAlgError) as exc:
        return {"computed": False, "why": f"its small-strain solves failed ({type(exc).__name__}: {exc})"}
    values = [q[k] for q in result.get("compared", {}).values() for k in q if isinstance(q[k], float)]
    if not np.isfinite(values).all():
        return {"computed": False, "why": "its small-strain solves gave non-finite values"}
    return result


def _indicator(scene, backend):
    pb = scene.to_problem("P1")
    note = ""
    if anp_applies(pb):  # SVK: its tangent at rest is the linear material's, which ANP averages
        E, nu = scene.material["E"], scene.material["nu"]
        pb = dataclasses.replace(pb, material=LinearElastic(E, nu))
        note = f"small-strain comparison with the linear material of the same E and nu ({scene.material['name']})"
    be = make_backend(backend, pb)
    solutions = {"P1": _linear_solution(be, pb), "reference": _linear_solution(AnpBackend(pb, be), pb)}
    return {**_verdict(scene, _compare(scene, pb, solutions)), "material_note": note,
            "method": "linear solves at rest, P1 against average nodal pressure tetrahedra on the same mesh"}


def _hex_indicator(scene, backend):
    """The indicator on hexahedra (module docstring): Q1 against the mean-dilatation hexahedra, the
    compared quantities keyed ``"Q1"`` and ``element = "Q1"``."""
    mat = scene.material
    if "E" not in mat or "nu" not in mat:
        return {"computed": False, "why": f"material {mat.get('name')!r} has no E and nu: the hexahedra's comparison "
                "solves the linear material of the scene's E and nu"}
    pb = dataclasses.replace(scene.to_problem("Q1"), material=LinearElastic(float(mat["E"]), float(mat["nu"])))
    note = "" if mat.get("name") == "linear" else \
        f"small-strain comparison with the linear material of the same E and nu ({mat.get('name')})"
    be = make_backend(backend, pb)
    solutions = {"Q1": _linear_solution(be, pb), "reference": _linear_solution(MeanDilatationBackend(pb, be), pb)}
    return {**_verdict(scene, _compare(scene, pb, solutions, locked="Q1")), "element": "Q1", "material_note": note,
            "method": HEX_METHOD}


def _verdict(scene, compared):
    """The indicator's numbers and verdict from the ``compared`` quantities (:func:`_compare`): the
    headline's and the strain energy's deviations, locking when the larger passes :data:`LOCKING_TOL`."""
    head = _headline(scene, compared)
    dev = compared[head]["deviation"] if head in compared else float("nan")
    energy = compared.get("strain_energy", {}).get("deviation", float("nan"))
    worst = max(abs(x) for x in (dev, energy) if np.isfinite(x)) if np.isfinite([dev, energy]).any() else 0.0
    return {"computed": True, "compared": compared, "headline": head, "deviation": dev, "energy_deviation": energy,
            "locks": bool(worst > LOCKING_TOL)}


def indicator_text(ind: dict, units: dict | None = None) -> str:
    """One line: the indicator's verdict and its numbers."""
    if not ind.get("computed"):
        ratio = ind.get("bulk_to_shear")
        return (f"locking indicator not computed: {ind.get('why', '')}"
                + (f" (K/G = {ratio:.4g}, threshold {ind['threshold']:.4g})" if ratio is not None else ""))
    c = ind["compared"][ind["headline"]] if ind["headline"] in ind["compared"] else None
    unit = (units or {}).get("length", "")
    el = ind.get("element", "P1")  # Q1 on hexahedra (:func:`_hex_indicator`)
    what = (f"{ind['headline']} {c[el]:.4g} {unit} with {el} against {c['reference']:.4g} {unit} without locking "
            f"({100 * ind['deviation']:+.1f} %)" if c else "")
    energy = f"strain energy {100 * ind['energy_deviation']:+.1f} %"
    verdict = f"{el} locks" if ind["locks"] else f"{el} does not lock noticeably"
    return (f"{verdict} (K/G = {ind['bulk_to_shear']:.4g} >= {ind['threshold']:.4g}, i.e. nu >= {LOCKING_NU}): "
            f"{what}, {energy} (tolerance {100 * ind['tolerance']:.0f} %; small strain, same mesh)")
