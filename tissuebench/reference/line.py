"""Reference runs of the 1D scenes (poisson1d, frame2dof, hermite_beam).

Called by :func:`tissuebench.reference.solve`; assembles the
:class:`~.line_models.LineSystem` of the scene once and either solves it at the static
load factors or integrates it in time with the scene's integrator (explicit schemes get
the lumped mass).
"""
from __future__ import annotations

import time

import numpy as np
import pandas as pd

from ..refsolvers.dynamics import SecondOrderSystem, integrate
from ..refsolvers.line_models import assemble_line_model, solve_static
from .result import dynamics_output

__all__ = ["solve_line", "line_monitor_fn", "line_dynamics_system"]


def line_monitor_fn(scene, system):
    """``u -> {name: value}`` for the ``[[monitor]]`` entries of a 1D scene."""
    x = scene.mesh.points[:, 0]
    getters = []
    for m in scene.monitors:
        q = m["quantity"]
        if q == "displacement":
            node = int(np.argmin(np.abs(x - m["point"][0])))
            comp = system.components.index(m["component"]) if m["component"] in system.components else None
            if comp is None:
                raise ValueError(f"monitor {m['name']!r}: component {m['component']!r} is not one of "
                                 f"{system.components}")
            getters.append((m, lambda U, n=node, c=comp: U[n, c]))
        elif q == "max_displacement":
            getters.append((m, lambda U: np.abs(U[:, 0]).max()))
        else:
            raise ValueError(f"monitor {m['name']!r}: quantity {q!r} is not defined for the 1D model {scene.model}")

    def monitors(u):
        U = system.nodal(u)
        return {m["name"]: float(g(U)) * m.get("scale", 1.0) for m, g in getters}
    return monitors


def _fields(scene, system):
    mesh = scene.mesh
    return dict(points=mesh.points, cells=mesh.cells, cell_type="line", components=system.components)


def _static(scene, system, monitors, progress):
    a = scene.analysis
    n_steps, target = int(a.get("load_steps", 1)), float(a.get("max_load_factor", 1.0))
    states, rows = [np.zeros(system.n)], []
    for k in range(1, n_steps + 1):
        tic = time.perf_counter()
        lam = target * k / n_steps
        u = solve_static(system, lam)
        states.append(u)
        rows.append({"step": k, "load_factor": lam, "newton_iterations": 1, "converged": True,
                     "wall_s": time.perf_counter() - tic, **monitors(u)})
        if progress:
            progress(lam, target)
    disp = np.array([system.nodal(u) for u in states])
    return dict(status="success", message=f"linear static solution at {n_steps} load factors up to {target:g}",
                table=pd.DataFrame(rows), steps=np.array([0.0] + [r["load_factor"] for r in rows]),
                displacement=disp, **_fields(scene, system))


def line_dynamics_system(scene, plan, system=None) -> SecondOrderSystem:
    """The linear second-order system of a 1D scene (lumped or consistent mass, as planned)."""
    system = system or assemble_line_model(scene.line_model())
    M = system.M_lumped if plan.mass == "lumped" else system.M
    return SecondOrderSystem.linear_system(M, system.K, system.load_vector, free=system.free)


def _dynamic(scene, plan, system, monitors, progress):
    a = scene.analysis
    sos = line_dynamics_system(scene, plan, system)
    t_end = float(a["t_end"])

    def observe(t, u):
        if progress:
            progress(t, t_end)
        return monitors(u)

    res = integrate(sos, None, None, float(a["dt"]), t_end, method=a.get("integrator", "hht"),
                    store_every=int(a.get("store_every", 1)), observe=observe, **a.get("integrator_options", {}))
    return dynamics_output(res, res.observations, _fields(scene, system), n_comp=system.dofs_per_node)


def solve_line(scene, plan, progress=None) -> dict:
    """Fields and table of a 1D scene (the keyword arguments of a ReferenceResult)."""
    system = assemble_line_model(scene.line_model())
    monitors = line_monitor_fn(scene, system)
    if plan.analysis == "static":
        return _static(scene, system, monitors, progress)
    return _dynamic(scene, plan, system, monitors, progress)
