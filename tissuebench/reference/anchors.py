"""Our values of the external anchors: the full-model solves behind ``tissuebench verify``.

Each function returns ``(value, how)``: our value of one anchored quantity at a resolution
(``"ci"`` or ``"paper"``) on a backend, and a short description of the discretisation (with
the solver's message when it did not converge). The anchors themselves (published values,
intervals, sources) and the verdicts are the report's (:mod:`tissuebench.reports.anchors`).

* Cook's membrane (:mod:`tissuebench.cases.cook`): the tip displacement of the deal.II code
  gallery's configurations (Pelteret and McBride 2016, doi:10.5281/zenodo.1228964) and of the
  linear membrane.
* Land et al. 2015 (Proc. R. Soc. A 471: 20150641), beam and ventricle: the catalogue scenes
  solved with the mixed u-p formulation (:func:`~tissuebench.refsolvers.mixed.static_run`), one
  solve per (case, resolution, backend) per process, kept in :data:`~.memo.MEMO` (the
  ventricle's two apex rows share it).
* the clamped beam's first angular frequency (generalised eigenproblem of the Hermite beam)
  and the cube's nominal stress at 30 % stretch (:func:`~.runner.solve`).
"""
from __future__ import annotations

import math

from ..cases.cook import CORNER, MIDPOINT, cook_problem, cook_tip
from ..cases.scene import load
from ..refsolvers.line_models import assemble_line_model
from ..refsolvers.mixed import static_run
from .memo import MEMO
from .runner import solve

__all__ = ["cook_value", "cook_linear_value", "cook_coupled", "cook_decoupled_p2", "mixed_scene_value", "land_beam",
           "left_ventricle", "clamped_beam_frequency", "cube_stress"]


# ----------------------------------------------------------------------------- Cook
def cook_value(n, element, material, plane_strain, point, backend):
    """Tip displacement [mm] at ``point`` of Cook's membrane on an ``n x n`` mesh."""
    tip, res = cook_tip(cook_problem(n, element, material, plane_strain=plane_strain), backend, point)
    return tip, f"{element} {n}x{n}" + ("" if res.success else f" ({res.message})")


def cook_linear_value(res, backend):
    """Corner u_y of the linear membrane (E = 70 MPa, nu = 1/3, 6.25 MPa), P2."""
    n = 8 if res == "ci" else 16
    tip, r = cook_tip(cook_problem(n, "P2", "linear", traction=6.25), backend, CORNER)
    return tip, f"P2 {n}x{n}" + ("" if r.success else f" ({r.message})")


def cook_coupled(res, backend):
    """Corner u_y, plane strain, coupled neo-Hookean, P2."""
    return cook_value(8 if res == "ci" else 16, "P2", "coupled", True, CORNER, backend)


def cook_decoupled_p2(res, backend):
    """Midpoint u_y, plane strain, decoupled neo-Hookean, P2."""
    return cook_value(8 if res == "ci" else 16, "P2", "decoupled", True, MIDPOINT, backend)


# ----------------------------------------------------------------------------- cardiac
def mixed_scene_value(case, variant, monitors, res, backend, penalty_weight=0.0):
    """Final monitored values of a catalogue scene solved with the mixed formulation
    (``penalty_weight``: the fraction of the volumetric penalty kept, see ``refsolvers.mixed``)."""
    scene = load(case, resolution=res, variant=variant)
    pb = scene.to_problem("P2")
    a = scene.analysis
    out = static_run(pb, backend, int(a.get("load_steps", 1)), float(a.get("max_load_factor", 1.0)),
                     lambda u, f: scene.evaluate_monitors(pb, u, f), penalty_weight=penalty_weight)
    how = f"mixed P2-P1, {pb.mesh.n_cells} tets, {pb.ndof + pb.mesh.n_vertices} dofs" + (
        f", penalty kept x{penalty_weight:g}" if penalty_weight else "")
    if out["status"] != "success":
        return {m: float("nan") for m in monitors}, f"{how} ({out['message']})"
    last = out["table"][out["table"]["converged"]].iloc[-1]
    return {m: float(last[m]) for m in monitors}, how


def land_beam(res, backend):
    """The beam's tip z [mm] (Land et al. 2015, problem 1), incompressible Guccione."""
    vals, how = MEMO.get("anchors", ("land_beam", res, backend),
                         lambda: mixed_scene_value("land_beam", None, ("tip_z",), res, backend))
    return vals["tip_z"], how


def left_ventricle(monitor):
    """``compute(res, backend)`` of one apex monitor of the ventricle (Land et al. 2015,
    problem 2, isotropic Guccione at 10 kPa); both monitors come from one solve."""
    def compute(res, backend):
        # the pure u-p run inverts elements at 32 % of the pressure on the ci mesh; keeping a
        # tenth of the volumetric penalty beside the pressure (refsolvers.mixed: damps what the
        # P1 pressure cannot see) reaches 10 kPa: -26.51 / -28.26 mm at ci (all of it: -26.49 /
        # -28.24, in 25 increments instead of 20)
        vals, how = MEMO.get("anchors", ("left_ventricle", res, backend), lambda: mixed_scene_value(
            "left_ventricle", "guccione", ("apex_endo_z", "apex_epi_z"), res, backend, penalty_weight=0.1))
        return vals[monitor], how
    return compute


# ----------------------------------------------------------------------------- closed forms
def clamped_beam_frequency(res, backend):
    """First angular frequency [rad/s] of the clamped Hermite beam (``backend`` unused: one
    implementation)."""
    import scipy.linalg as sla

    model = load("clamped_beam", resolution=res).line_model()
    system = assemble_line_model(model)
    f = system.free
    w2 = sla.eigh(system.K[f][:, f].toarray(), system.M[f][:, f].toarray(), eigvals_only=True)
    return math.sqrt(w2[0]), f"{len(model.mesh.cells)} Hermite beam elements"


def cube_stress(res, backend):
    """Nominal stress [kPa] of the cube bar at 30 % stretch (the scene's last converged row)."""
    r = solve("cube_tension_twist", backend=backend, resolution=res, variant="tension")
    return float(r.table["nominal_stress_kPa"].dropna().iloc[-1]), f"P1 penalty, {res} mesh"
