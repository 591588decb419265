"""What a reference run of a scene models, and why ("model only what a scene requires").

:func:`plan_for` reads a validated scene (:class:`tissuebench.cases.scene.Scene`) and
decides which operators the run builds: no mass for a static analysis, no tangent per
step for an explicit scheme (only the stiffness at the origin for the critical time
step), one factorisation for linear operators instead of Newton iterations. The runner
(:mod:`.reference`) follows the plan; ``tissuebench describe CASE`` prints it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

from .formulation import formulation_of

__all__ = ["ModelPlan", "plan_for", "EXPLICIT_INTEGRATORS"]

EXPLICIT_INTEGRATORS = ("central_difference", "forward_euler")


@dataclass(frozen=True)
class ModelPlan:
    """The operators and the algorithm of one reference run.

    Attributes
    ----------
    analysis : {"static", "dynamic"}
    model : {"fe", "poisson1d", "frame2dof", "hermite_beam"}
    linear : bool
        Constant operators: factorised once, no Newton iterations.
    mass : {None, "consistent", "lumped"}
    tangent : {"per_iteration", "once", "origin_only", "none"}
        When the stiffness is assembled: every Newton iteration, once (linear), at the
        origin only (explicit: critical time step), never (static linear 1D: ``once``).
    algorithm : str
        The solver that runs (``"newton_solve"``, ``"linear_static"``, ``"integrate:<name>"``).
    reasons : list of (item, reason)
    formulation : {"displacement", "anp", "mixed", "mean_dilatation"}
        The finite-element formulation (:mod:`.formulation`).
    """

    analysis: str
    model: str
    linear: bool
    mass: str | None
    tangent: str
    algorithm: str
    reasons: list = field(default_factory=list)
    formulation: str = "displacement"

    def lines(self) -> list[str]:
        return [f"- {item}: {why}" for item, why in self.reasons]


def _nonlinear_causes(scene) -> list[str]:
    causes = []
    if scene.material["name"] != "linear":
        causes.append(f"material {scene.material['name']!r} is nonlinear (finite strain)")
    if any(ld["type"] == "follower_pressure" for ld in scene.loads):
        causes.append("a follower pressure depends on the deformed surface")
    if any("motion" in d for d in scene.dirichlet):
        causes.append("a prescribed rotation is not linear in the load factor")
    return causes


def _static(scene, causes, reasons, formulation="displacement"):
    reasons.append(("no mass matrix", "static analysis: inertia plays no part"
                    + (" (the density in [material] is not used)" if scene.density else "")))
    a = scene.analysis
    if not causes:
        reasons.append(("linear path", "linear material, dead loads: K factorised once, "
                        f"each of the {a.get('load_steps', 1)} load steps is one back-substitution"))
        return dict(linear=True, mass=None, tangent="once", algorithm="linear_static")
    reasons.append(("Newton-Raphson with load stepping", "; ".join(causes)
                    + f": K_t assembled every iteration, {a.get('load_steps', 1)} initial increments "
                      f"up to load factor {a.get('max_load_factor', 1.0):g}, step cutting on failure"))
    if formulation == "mixed":
        return dict(linear=False, mass=None, tangent="per_iteration", algorithm="newton_solve:mixed")
    if a.get("stop_at_divergence"):
        reasons.append(("run until Newton stops converging", "the last converged load factor is "
                        "the measured radius of convergence, reported as status 'stalled'"))
    return dict(linear=False, mass=None, tangent="per_iteration", algorithm="newton_solve")


def _dynamic(scene, causes, reasons):
    a = scene.analysis
    name = a.get("integrator", "hht")
    explicit = name in EXPLICIT_INTEGRATORS
    lumped = explicit or bool(a.get("lumped", False))
    mass = "lumped" if lumped else "consistent"
    why_mass = ("the explicit scheme needs a diagonal mass (row-sum lumped)" if explicit
                else "requested by analysis.lumped" if lumped else "implicit scheme: consistent mass")
    reasons.append((f"{mass} mass", why_mass))
    if explicit:
        tangent = "origin_only"
        reasons.append(("no tangent per step", "explicit scheme: internal force only; the stiffness at "
                        "the origin is assembled once for the critical time step"))
    elif not causes:
        tangent = "once"
        reasons.append(("linear system", "linear material, dead loads: the effective matrix is "
                        "factorised once, each step is one solve"))
    else:
        tangent = "per_iteration"
        reasons.append(("Newton per time step", "; ".join(causes) + ": K_t assembled every iteration"))
    reasons.append((f"integrator {name}", f"dt = {a['dt']:g}, t_end = {a['t_end']:g} "
                    f"({round(a['t_end'] / a['dt'])} steps), options {a.get('integrator_options', {})}"))
    return dict(linear=not causes, mass=mass, tangent=tangent, algorithm=f"integrate:{name}")


def plan_for(scene) -> ModelPlan:
    """The :class:`ModelPlan` of a validated scene."""
    analysis = scene.analysis["type"]
    reasons = []
    name = "displacement"
    if scene.is_fe:
        form = formulation_of(scene)
        name = form.name
        causes = _nonlinear_causes(scene)
        reasons.append(("finite elements", f"{form.element} on {scene.mesh_label}, material {scene.material['name']}"))
        reasons.append((f"formulation: {form.label}", form.reason))
        if form.warning:
            reasons.append(("locking", form.warning))
    else:
        causes = []
        reasons.append((f"1D model {scene.model}", "linear discrete model: assembled once"))
    kw = _static(scene, causes, reasons, name) if analysis == "static" else _dynamic(scene, causes, reasons)
    if not scene.is_fe and analysis == "static":
        kw.update(mass=None)
    return ModelPlan(analysis=analysis, model=scene.model, reasons=reasons, formulation=name, **kw)
