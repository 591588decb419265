"""Reference runs of catalogue scenes: ``solve(case, backend=...)``.

One entry point for every case of :mod:`tissuebench.cases`: the scene's
:class:`~.plan.ModelPlan` picks the algorithm (linear static, Newton-Raphson with load
stepping, or a time integrator; the 1D models in :mod:`.line`), and the
result carries one table row per load increment or time step (with the scene's
monitored quantities as columns) and the displacement fields. A numerical failure is a
status of the result, never an exception; bad input raises ``ValueError``.
"""
from __future__ import annotations

import time

import numpy as np
import pandas as pd

from ..cases.monitors import needs_reactions
from ..cases.scene import Scene, load
from ..refsolvers.dynamics import SecondOrderSystem, integrate
from ..refsolvers.mixed import static_run
from ..refsolvers.sparse_direct import factorized
from ..refsolvers.newton import NewtonOptions, newton_solve
from .formulation import formulation_of, scene_backend
from .line import line_dynamics_system, solve_line
from .plan import plan_for
from .result import ReferenceResult, dynamics_output

__all__ = ["ReferenceResult", "solve", "dynamics_system", "progress_bar"]


def _scene_of(case, resolution, variant):
    if isinstance(case, Scene):
        return case
    return load(case, resolution=resolution, variant=variant)


def solve(case, backend: str = "skfem", resolution: str = "ci", variant: str | None = None,
          progress=None, linear_solver: str = "auto") -> ReferenceResult:
    """Reference solution of a catalogue scene.

    Parameters
    ----------
    case : str, path or Scene
        A case name, a scene file, or a scene from :func:`tissuebench.cases.load`.
    backend : {"skfem", "ngsolve"}
        Finite-element backend (ignored by the 1D models, which assemble their own matrices).
    resolution, variant : str
        Used when ``case`` is a name or path.
    progress : callable, optional
        ``progress(done, total)`` with the load factor or time reached.
    linear_solver : {"auto", "direct", "cholesky", "amg-cg"}
        Linear solver of the Newton iterations (FE statics).
    """
    scene = _scene_of(case, resolution, variant)
    plan = plan_for(scene)
    t0 = time.perf_counter()
    if not scene.is_fe:
        out = solve_line(scene, plan, progress)
        backend_name = "line"
    else:
        pb = scene.to_problem()
        be = scene_backend(scene, backend, pb)
        backend_name = backend if isinstance(backend, str) else backend.__name__
        runner = _static if plan.analysis == "static" else _dynamic
        out = runner(scene, plan, be, progress, linear_solver)
        out["problem"] = pb
        out["info"] = {**formulation_of(scene).manifest(), **out.get("info", {})}
    out["table"].insert(0, "backend", backend_name)
    out["table"].insert(0, "case", scene.name)
    info = {"mesh": scene.mesh_info, "stop_at_divergence": bool(scene.analysis.get("stop_at_divergence")),
            **out.pop("info", {})}
    return ReferenceResult(case=scene.name, variant=scene.variant, resolution=scene.resolution,
                           backend=backend_name, plan=plan, wall_s=time.perf_counter() - t0, info=info, **out)


def progress_bar(label: str, analysis: str, time_unit: str = "s", file=None, leave: bool = True):
    """A tqdm bar of a reference run and its ``update(done, total)`` callback.

    The bar counts what the solver reports, in its unit: the load factor reached (statics,
    ``load factor 0.45/1``) or the time (dynamics, ``t 0.25/5 s``), with the percentage beside
    and the time left. A solver's last time may pass its end by round-off (k dt > t_end): the
    bar stops at its total (tqdm would warn "clamping frac to range [0, 1]")."""
    from tqdm import tqdm

    what = "t {n:.4g}/{total:.4g} " + time_unit if analysis == "dynamic" else "load factor {n:.4g}/{total:.4g}"
    bar = tqdm(total=1.0, desc=label, file=file, leave=leave, bar_format="{desc}: {percentage:3.0f}%|{bar}| " + what
               + " [{elapsed}<{remaining}]")

    def update(done, total):
        total = float(total)
        bar.total = total
        bar.n = min(max(float(done), 0.0), total) if total > 0 else float(done)
        bar.refresh()
    return bar, update


# ============================================================================ FE statics
def _fields(pb):
    nodes, cell_nodes = pb.layout
    return dict(points=nodes, cells=cell_nodes, cell_type=pb.mesh.cell_type, components=("x", "y", "z"))


def _monitor_fn(scene, pb, be):
    """``monitors(u, load_factor)``: the scene's monitors of state ``u`` under the loads at
    ``load_factor`` (the supports' reactions ``f_int - f_ext`` on the fixed dofs, when read)."""
    if not needs_reactions(scene):
        return lambda u, load_factor: scene.evaluate_monitors(pb, u)

    def monitors(u, load_factor):
        return scene.evaluate_monitors(pb, u, pb.support_reactions(be.internal_force(u),
                                                                   be.external_force(u, load_factor)))
    return monitors


def _static(scene, plan, be, progress, linear_solver):
    a = scene.analysis
    n_steps, target = int(a.get("load_steps", 1)), float(a.get("max_load_factor", 1.0))
    if plan.algorithm == "newton_solve:mixed":
        return _mixed_static(scene, be, n_steps, target, progress)
    monitors = _monitor_fn(scene, be.problem, be)
    if plan.linear:
        states, rows, status, message = _linear_static(be, n_steps, target, monitors, progress)
    else:
        states, rows, status, message = _newton_static(be, n_steps, target, monitors, progress, linear_solver,
                                                       bool(a.get("stop_at_divergence")), a.get("max_cuts"))
    disp = np.array(states).reshape(len(states), -1, 3)
    steps = np.array([0.0] + [r["load_factor"] for r in rows if r["converged"]])
    return dict(status=status, message=message, table=pd.DataFrame(rows), steps=steps, displacement=disp,
                **_fields(be.problem))


def _mixed_static(scene, be, n_steps, target, progress):
    """The u-p Taylor-Hood run of ``refsolvers.mixed`` on the displacement backend's problem."""
    pb = be.problem
    return static_run(pb, be, n_steps, target, lambda u, r: scene.evaluate_monitors(pb, u, r),
                      needs_force=needs_reactions(scene), progress=progress,
                      bulk_modulus=formulation_of(scene).bulk_modulus)


def _linear_static(be, n_steps, target, monitors, progress):
    pb = be.problem
    free, fixed = pb.free_dofs, pb.fixed_dofs
    u0 = np.zeros(pb.ndof)
    tic = time.perf_counter()
    K = be.tangent(u0)
    lu = factorized(K[free][:, free])  # NGSolve's LDL^T from 1000 dofs, SuperLU below
    K_fc = K[free][:, fixed]
    assembly_s = time.perf_counter() - tic
    states, rows = [u0], []
    for k in range(1, n_steps + 1):
        tic = time.perf_counter()
        lam = target * k / n_steps
        u = np.zeros(pb.ndof)
        u[fixed] = pb.prescribed_values(lam)
        u[free] = lu(be.external_force(u0, lam)[free] - K_fc @ u[fixed])
        wall = time.perf_counter() - tic + (assembly_s if k == 1 else 0.0)
        states.append(u)
        rows.append({"step": k, "load_factor": lam, "newton_iterations": 1, "converged": True, "wall_s": wall,
                     **monitors(u, lam)})
        if progress:
            progress(lam, target)
    return states, rows, "success", f"linear static solution at {n_steps} load factors up to {target:g}"


def _newton_static(be, n_steps, target, monitors, progress, linear_solver, to_divergence, max_cuts=None):
    # run to divergence: the first increment that fails ends the run (no cutting), so
    # the reported radius is that of the scene's fixed increment; max_cuts halvings of an
    # increment before the run stalls (a path continued past its top: where it stops, cheaply)
    smallest = 1.0 / 4096 if max_cuts is None else 1.0 / (n_steps * 2 ** int(max_cuts))
    opts = NewtonOptions(n_increments=n_steps, max_increment=1.0 / n_steps, linear_solver=linear_solver,
                         min_increment=1.0 / n_steps if to_divergence else smallest)
    res = newton_solve(be, target, opts, progress=progress)
    stored, rows = res.increment_rows(lambda u, lam: (u, monitors(u, lam)))
    states = [np.zeros(be.ndof)] + stored
    status, message = res.status, res.message
    if to_divergence and status == "stalled":
        status, message = _divergence_verdict(res, message)
    return states, rows, status, message


def _divergence_verdict(res, message):
    """A run "until Newton stops converging" measures a radius only if some increment
    converged and the residual stayed finite; otherwise it is a failure, not a measurement."""
    if not res.converged_increments:
        return "failed", (f"no load increment converged (the first one, to load factor "
                          f"{res.increments[0].load_factor:.6g}, already fails): no convergence radius; {message}")
    # the residual at the start of an increment (a converged state, the next load) or of a
    # converged one is the model's, not a diverging iterate's: non-finite means overflow
    norms = [r for inc in res.increments for r in (inc.residual_norms if inc.converged else inc.residual_norms[:1])]
    if not np.all(np.isfinite(norms)):
        return "failed", f"non-finite residual (overflow in the material or the loads): {message}"
    return "stalled", message


# ============================================================================ FE dynamics
def dynamics_system(scene, backend="skfem") -> SecondOrderSystem:
    """The semi-discrete system the scene's reference integrates (FE: from a backend name
    or instance; 1D models: their assembled matrices), as the plan decides (mass, linearity)."""
    plan = plan_for(scene)
    if not scene.is_fe:
        return line_dynamics_system(scene, plan)
    be = scene_backend(scene, backend) if isinstance(backend, str) else backend
    return SecondOrderSystem.from_backend(be, scene.history, lumped=plan.mass == "lumped", linear=plan.linear)


def _dynamic(scene, plan, be, progress, linear_solver):
    a = scene.analysis
    pb = be.problem
    system = dynamics_system(scene, be)
    dt, t_end = float(a["dt"]), float(a["t_end"])
    n_steps = int(np.ceil(t_end / dt - 1e-9))
    store_every = int(a.get("store_every", max(1, n_steps // 200)))
    monitors = _monitor_fn(scene, pb, be)

    def observe(t, u):
        if progress:
            progress(t, t_end)
        # the supports' reactions without the inertia of the supported dofs (zero with a lumped mass)
        return monitors(u, float(scene.history(t)))

    name = a.get("integrator", "hht")
    res = integrate(system, None, None, dt, t_end, method=name, store_every=store_every, observe=observe,
                    **a.get("integrator_options", {}))
    return dynamics_output(res, monitors_per_step=res.observations, fields=_fields(pb), n_comp=3)
