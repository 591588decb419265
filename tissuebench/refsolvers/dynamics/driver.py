"""Front door: :func:`integrate` runs an integrator over [t0, t_end] and records it."""
from __future__ import annotations

import time

import numpy as np

from .base import check_dt
from .registry import make_integrator
from .result import DynamicsResult, Recorder


def _n_steps(dt, t0, t_end) -> int:
    t0, t_end = float(t0), float(t_end)
    total = t_end - t0
    if not np.isfinite(total) or total <= 0:
        raise ValueError(f"total time t_end - t0 must be > 0, got t_end={t_end!r}, t0={t0!r}")
    # fixed dt; the last step may end slightly past t_end (relative slack 1e-9 absorbs round-off)
    return max(1, int(np.ceil(total / dt - 1e-9)))


def integrate(system, u0, v0, dt, t_end, method="newmark", t0=0.0, store_every=1, dofs=None,
              blowup_factor=1e8, growth_tol=None, observe=None, **opts) -> DynamicsResult:
    """Integrate ``system`` from (u0, v0) at ``t0`` to ``t_end`` with fixed step ``dt``.

    Parameters
    ----------
    system : SecondOrderSystem
    u0, v0 : (n,) arrays or None
        Initial displacement [m] and velocity [m/s] on the full dof vector (None: zero,
        and the prescribed displacement on the fixed dofs of a prescribed motion).
    dt, t_end, t0 : float
        Step and times [s]; ``ceil((t_end - t0) / dt)`` steps are taken.
    method : str, Integrator class or instance
        See :data:`~tissuebench.refsolvers.dynamics.INTEGRATORS`.
    store_every : int
        Keep the state every this many steps (plus the last one) to limit memory.
    dofs : int array, optional
        Store only these full-vector dofs (monitored dofs); energies use all dofs.
    blowup_factor : float
        Stop with status ``"blow_up"`` when KE + IE + D exceeds this factor times the
        largest energy supplied so far (the largest ``|KE_0 + IE_0 + W|`` over the steps,
        W the work of the loads and supports), or on non-finite values
        in an explicit scheme.
    growth_tol : float, optional
        Report ``"energy_growth"`` when ``energy_growth_ratio > 1 + growth_tol``;
        default: the integrator's own (forward Euler: 1e-3; others: not checked).
    observe : callable ``(t, u) -> dict``, optional
        Called at every completed step (and step 0) with the time and the full
        displacement vector; its dicts are returned in ``observations`` (monitored
        quantities per step without storing every state).
    **opts
        Integrator options (``alpha``, ``force``, ``newton_rtol``, ...).

    Returns
    -------
    DynamicsResult
        Never raises on a numerical failure: the status says what happened and at which
        step, and the arrays stop at the last completed step: the one before
        ``rejected_step`` (a step that could not be computed) or ``blow_up_step`` itself (a
        computed step whose energy exploded). Bad input raises ValueError.
    """
    dt = check_dt(dt)
    n = _n_steps(dt, t0, t_end)
    if not (np.isfinite(blowup_factor) and blowup_factor > 1):
        raise ValueError(f"blowup_factor must be a finite number > 1, got {blowup_factor!r}")
    integ = make_integrator(method, **opts)
    integ.start(system, u0, v0, dt, t0)
    moving = system.has_prescribed
    rec = Recorder(system, integ.mass_ff, n, dofs, store_every, integ.damping_force,
                   integ.mass_full if moving else None, integ.damping_full if moving else None)
    rec.record(integ.t, integ.u, integ.v, integ.a, integ.f_ext, integ.f_int,
               constrained=(integ.uc, integ.vc, integ.ac))
    observations = [] if observe is None else [observe(integ.t, integ.full_u())]
    status, message, failed, blown_up = "success", f"{n} steps completed", None, False
    for k in range(1, n + 1):
        tic = time.perf_counter()
        rep = integ.step()
        wall = time.perf_counter() - tic
        if not rep.converged:
            status = "newton_failed" if integ.implicit else "blow_up"
            message, failed = f"step {k}: {rep.message}", k
            break
        rec.record(integ.t, integ.u, integ.v, integ.a, integ.f_ext, integ.f_int, rep.iterations, True, wall,
                   force_store=(k == n), constrained=(integ.uc, integ.vc, integ.ac))
        if observe is not None:
            observations.append(observe(integ.t, integ.full_u()))
        mech, supplied = rec.mechanical()
        scale = max(np.max(np.abs(supplied)), 0.0)
        if not np.isfinite(mech[-1]) or (scale > 0 and mech[-1] > blowup_factor * scale):
            status, failed, blown_up = "blow_up", k, True
            message = (f"step {k} (t={integ.t:.6g}): energy {mech[-1]:.3e} J exceeds "
                       f"{blowup_factor:.1e} x the energy supplied ({scale:.3e} J)")
            break
    rec.store(rec.k, integ.u, integ.v, integ.a, (integ.uc, integ.vc, integ.ac))  # always keep the last state
    name = getattr(integ, "name", type(integ).__name__)
    res = rec.finish(name, dt, status, message, failed, opts, blown_up)
    res.observations = observations
    tol = integ.growth_tol if growth_tol is None else float(growth_tol)
    if status == "success" and tol is not None and res.energy_growth_ratio > 1.0 + tol:
        res.status = "energy_growth"
        res.message = (f"{n} steps completed, but the energy grew: energy_growth_ratio = "
                       f"{res.energy_growth_ratio:.6g} > 1 + {tol:g}")
    return res
