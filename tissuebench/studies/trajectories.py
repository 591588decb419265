"""Trajectory trainings from reference runs of catalogue scenes, every step stored.

The sweep harness builds its trajectory trainings from the cached reference runs
(:mod:`.training`, at the scene's ``store_every``); this module integrates afresh with
any step, horizon or integrator (the direct integrator's studies and tests).

:func:`reference_run` integrates a scene's semi-discrete system exactly as the reference
runner does (same system, mass, integrator and options as ``reference.solve``) but keeps
every step's displacement *and velocity*; :func:`trajectory_training` wraps it in a
:class:`~tissuebench.rom.base.Training` of kind "trajectory" (snapshots, velocities,
``{"time", "load_factor"}`` per column, the system, the load history, ``dt``) with the
scene's displacement monitors as linear output functionals.

The reaction monitors (``reaction_force``, ``nominal_stress``, ``moment``) of a dynamic
state read the force the supports exert, ``[M a + C v + f_int - f_ext(t)]`` on the fixed
dofs (:meth:`~tissuebench.refsolvers.dynamics.SecondOrderSystem.reactions`): the static
``f_int - f_ext`` plus the inertia and damping the supports carry. :func:`run_monitors`
evaluates every monitor along a run.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..cases import load as load_scene
from ..cases.monitors import REACTION_QUANTITIES, linear_outputs
from ..refsolvers.dynamics import SecondOrderSystem, integrate
from ..refsolvers.line_models import assemble_line_model
from ..reference.line import line_monitor_fn
from ..reference.formulation import scene_backend
from ..reference.plan import plan_for
from ..rom.base import Training

__all__ = ["SceneSystem", "output_functionals", "reference_run", "run_monitors", "scene_system",
           "trajectory_training"]


@dataclass
class SceneSystem:
    """The semi-discrete system of a dynamic scene and what the monitors need.

    Attributes
    ----------
    scene : Scene
    system : SecondOrderSystem
    history : callable
        Load factor versus time.
    backend : Backend or None
        FE scenes only.
    monitors : callable ``(u, t=None, v=None, a=None) -> {name: value}``
        The scene's monitors at the full displacement ``u`` (n_dof,); the reaction monitors
        also need the time ``t`` [s] and the full velocity ``v`` and acceleration ``a`` of the
        state (ValueError naming what is missing).
    n_comp : int
        Components per node (3 for FE, 1 or 2 for the 1D models).
    """

    scene: object
    system: SecondOrderSystem
    history: object
    backend: object
    monitors: object
    n_comp: int


def scene_system(case, resolution: str = "ci", variant: str | None = None, backend: str = "skfem") -> SceneSystem:
    """The system the reference runner integrates for a dynamic scene (mass as its plan says)."""
    scene = case if hasattr(case, "analysis") else load_scene(case, resolution=resolution, variant=variant)
    plan = plan_for(scene)
    if plan.analysis != "dynamic":
        raise ValueError(f"{scene.name}: not a dynamic scene (analysis {plan.analysis!r})")
    if scene.is_fe:
        pb = scene.to_problem()
        be = scene_backend(scene, backend, pb)
        system = SecondOrderSystem.from_backend(be, scene.history, lumped=plan.mass == "lumped",
                                                linear=plan.linear)
        return SceneSystem(scene, system, scene.history, be, _fe_monitors(scene, pb, system), 3)
    ls = assemble_line_model(scene.line_model())
    M = ls.M_lumped if plan.mass == "lumped" else ls.M
    system = SecondOrderSystem.linear_system(M, ls.K, ls.load_vector, free=ls.free)
    line = line_monitor_fn(scene, ls)  # the 1D models have no reaction monitors (refused there)
    return SceneSystem(scene, system, scene.history, None, lambda u, t=None, v=None, a=None: line(u),
                       ls.dofs_per_node)


def _fe_monitors(scene, pb, system):
    """``monitors(u, t=None, v=None, a=None)`` of an FE scene; the reaction monitors read
    ``system.reactions(t, u, v, a)`` (the support force of the dynamic state)."""
    reading = [m["name"] for m in scene.monitors if m["quantity"] in REACTION_QUANTITIES]

    def monitors(u, t=None, v=None, a=None):
        if not reading:
            return scene.evaluate_monitors(pb, u)
        missing = [k for k, x in (("t", t), ("v", v), ("a", a)) if x is None]
        if missing:
            raise ValueError(f"{scene.name}: monitors {reading} read the support reactions of a dynamic state, "
                             f"which need {', '.join(missing)} (the load at t, the velocity and acceleration "
                             "for the damping and inertia the supports carry)")
        return scene.evaluate_monitors(pb, u, system.reactions(t, u, v, a))
    return monitors


def run_monitors(ss: SceneSystem, res) -> list[dict]:
    """The scene's monitors at every stored step of ``res`` (a run of ``ss.system`` storing
    all dofs, e.g. :func:`reference_run`), reactions included: one dict per stored step."""
    n = ss.system.n
    if len(res.dofs) != n or np.any(res.dofs != np.arange(n)):
        raise ValueError(f"res stores {len(res.dofs)} of the {n} dofs: the monitors need the full state "
                         "(integrate with dofs=None)")
    return [ss.monitors(u, t, v, a) for t, u, v, a in zip(res.t_stored, res.u, res.v, res.a)]


def reference_run(ss: SceneSystem, dt: float | None = None, t_end: float | None = None,
                  integrator: str | None = None, **options):
    """Integrate ``ss`` from rest with the scene's integrator (or ``integrator``), storing every step.

    Returns the :class:`~tissuebench.refsolvers.dynamics.DynamicsResult` (u, v, a per step).
    """
    a = ss.scene.analysis
    if integrator is None:
        integrator, options = a.get("integrator", "hht"), {**a.get("integrator_options", {}), **options}
    return integrate(ss.system, None, None, float(dt or a["dt"]), float(t_end or a["t_end"]), method=integrator,
                     store_every=1, **options)


def output_functionals(ss: SceneSystem) -> dict:
    """``{name: c (n_dof,)}`` of the scene's linear monitors (a displacement component at a point).

    ``c_i`` is the monitor of the unit vector ``e_i`` (monitors are linear in u); a
    monitor that is not linear (a norm, a maximum) is left out.
    """
    n = ss.system.n
    specs = [m for m in ss.scene.monitors if m["quantity"] == "displacement" and m.get("component") != "norm"]
    if not specs:
        return {}
    if ss.backend is not None:
        # FE: the probes' weights directly (evaluating every monitor at e_i would need the reactions)
        return linear_outputs(ss.scene, ss.backend.problem)
    names = [m["name"] for m in specs]
    C = np.zeros((len(names), n))
    for i in range(n):
        e = np.zeros(n)
        e[i] = 1.0
        vals = ss.monitors(e)
        C[:, i] = [vals[k] for k in names]
    return {k: C[j] for j, k in enumerate(names)}


def trajectory_training(case, resolution: str = "ci", variant: str | None = None, backend: str = "skfem",
                        dt: float | None = None, t_end: float | None = None, integrator: str | None = None,
                        **options) -> Training:
    """A "trajectory" Training from the reference run of a dynamic scene.

    Parameters
    ----------
    case : str or Scene
    resolution, variant, backend : str
    dt, t_end : float, optional
        Step and horizon [s] (default: the scene's ``[analysis]``).
    integrator : str, optional
        Integrator of the training run (default: the scene's, with its options).
    **options
        Integrator options.

    Raises
    ------
    RuntimeError
        The reference run did not complete (status and message in the text).
    """
    ss = case if isinstance(case, SceneSystem) else scene_system(case, resolution, variant, backend)
    res = reference_run(ss, dt, t_end, integrator, **options)
    if res.status not in ("success", "energy_growth"):
        raise RuntimeError(f"{ss.scene.name}: reference run {res.status}: {res.message}")
    t = res.t[res.stored_steps]
    params = [{"time": float(tk), "load_factor": float(ss.history(tk))} for tk in t]
    return Training(snapshots=res.u.T.copy(), parameters=params, backend=ss.backend,
                    free_dofs=np.asarray(ss.system.free), outputs=output_functionals(ss),
                    trajectories=np.zeros(len(t), dtype=np.int64), velocities=res.v.T.copy(), system=ss.system,
                    history=ss.history, dt=float(res.dt), scene=ss.scene,
                    info={"case": ss.scene.name, "variant": ss.scene.variant, "resolution": ss.scene.resolution,
                          "integrator": res.method, "options": res.options, "status": res.status,
                          "n_comp": ss.n_comp})
