"""The outcome of a reference run (:class:`ReferenceResult`) and its table of a dynamics run."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from .plan import ModelPlan

__all__ = ["ReferenceResult", "dynamics_output", "TABLE_COLUMNS"]

# result-table columns that are bookkeeping, not monitored quantities
TABLE_COLUMNS = {"case", "backend", "step", "load_factor", "time", "newton_iterations", "converged", "wall_s",
                 "assembly_s", "solve_s", "final_residual", "message", "kinetic_energy", "strain_energy",
                 "external_work", "energy_error"}

# statuses where the run did what the scene asked (a stall is the measurement for
# scenes run "until Newton stops converging")
_OK = {"success"}


@dataclass
class ReferenceResult:
    """Outcome of :func:`solve`.

    Attributes
    ----------
    case, variant, resolution, backend : str
    plan : ModelPlan
    status : str
        ``success``; ``stalled`` (Newton stopped before the target load factor);
        ``newton_failed``, ``blow_up``, ``energy_growth`` (dynamics).
    message : str
    table : pandas.DataFrame
        One row per load increment (static: ``load_factor``) or time step (``time``).
    points : (n_nodes, 3) array
        Reference coordinates of the discretisation nodes (P2: vertices then edges).
    cells : (n_cells, k) int array
    cell_type : str
        ``tetra``, ``hexahedron`` or ``line``.
    components : tuple of str
        Names of the nodal displacement components.
    steps : (n_states,) array
        Load factor or time of each stored state (the first is the initial state).
    displacement : (n_states, n_nodes, n_components) array
    velocity : (n_states, n_nodes, n_components) array or None
        Velocities of the stored states (dynamics only).
    wall_s : float
    info : dict
        Counters and settings (mesh metadata, Newton increments, integrator).
    """

    case: str
    variant: str | None
    resolution: str
    backend: str
    plan: ModelPlan
    status: str
    message: str
    table: pd.DataFrame
    points: np.ndarray
    cells: np.ndarray
    cell_type: str
    components: tuple
    steps: np.ndarray
    displacement: np.ndarray
    velocity: np.ndarray | None = None
    wall_s: float = 0.0
    info: dict = field(default_factory=dict)
    problem: object = None

    @property
    def ok(self) -> bool:
        """The run did what the scene asks (a stall counts when the scene runs to divergence)."""
        return self.status in _OK or (self.status == "stalled" and self.info.get("stop_at_divergence", False))

    @property
    def final_displacement(self) -> np.ndarray:
        return self.displacement[-1]

    def monitors_at(self, key: str | None = None, value: float | None = None) -> dict:
        """The monitored scalars of the converged table row where ``key == value`` (the last
        converged row without ``key``); ``{}`` when there is none."""
        t = self.table
        if "converged" in t:
            t = t[t["converged"].astype(bool)]
        if key is not None:
            t = t[np.isclose(t[key].to_numpy(float), value, rtol=1e-12, atol=1e-12)] if key in t else t.iloc[:0]
        if t.empty:
            return {}
        row = t.iloc[0] if key is not None else t.iloc[-1]
        return {n: float(row[n]) for n in t.columns if n not in TABLE_COLUMNS and _is_number(row[n])}


def _is_number(v) -> bool:
    try:
        return bool(np.isfinite(float(v)))
    except (TypeError, ValueError):
        return False


def dynamics_output(res, monitors_per_step, fields, n_comp):
    """Table and fields of a :class:`~.dynamics.DynamicsResult` (shared with the 1D models)."""
    n = len(res.t)
    table = pd.DataFrame({
        "step": np.arange(n), "time": res.t, "newton_iterations": res.newton_iterations,
        "converged": res.converged, "wall_s": res.wall_time, "kinetic_energy": res.kinetic_energy,
        "strain_energy": res.strain_energy, "external_work": res.external_work,
        "energy_error": res.energy_error})
    mon = pd.DataFrame(monitors_per_step[:n])
    table = pd.concat([table, mon], axis=1)
    disp = res.u.reshape(len(res.stored_steps), -1, n_comp)
    vel = res.v.reshape(len(res.stored_steps), -1, n_comp)
    info = {"integrator": res.method, "dt": res.dt, "energy_growth_ratio": res.energy_growth_ratio,
            "failed_step": res.failed_step, "rejected_step": res.rejected_step, "blow_up_step": res.blow_up_step,
            "options": res.options}
    return dict(status=res.status, message=res.message, table=table, steps=res.t[res.stored_steps],
                displacement=disp, velocity=vel, info=info, **fields)
