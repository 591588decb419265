"""Long-run energy drift of a trajectory: the reference's and a reduced model's, by one definition.

Where the load is constant, an undamped system conserves ``E = KE + W(u) - f . u`` (kinetic
energy, stored energy, potential of the dead load ``f``); a time integrator or a reduced
model that adds or removes energy shows it as a trend of ``E(t)``. Over the **conservative
window** (the final interval of the horizon where the load history does not change, at
least :data:`MIN_WINDOW` of it; e.g. after a step load, or the free vibration after a
release), the drift is the least-squares slope of ``E(t)`` times the window's length,
divided by the largest ``KE + W`` of the reference in the window:

    drift = slope(E) * (t_end - t_c) / max_window(KE + W)_reference

so a bounded oscillation of the discrete energy (an explicit scheme's) is not counted,
a steady loss (HHT's numerical dissipation: < 0) or gain (instability: > 0) is. The
reference's ``E`` comes from its own energy columns (its scheme's velocity); a reduced
model's from its reconstructed displacements, the velocity by central differences
``(u_{k+1} - u_{k-1}) / 2 dt`` of its own steps (the harness reconstructs the neighbours
of the stored steps in the window, :func:`~.protocol.drive`).

Both also keep the history they were fitted on (``times`` [s], ``history``: ``E(t) / scale``),
which the harness stores per evaluation point and draws beside the displacement history
(paper pgd-pod-direct Fig. 17: the 10 s run of Bathe inside the step).

No drift is computed (NaN, with the reason) for a damped system, a follower load, a
prescribed motion that moves in the window, a stored energy the system cannot evaluate,
or a load never constant long enough.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["MIN_WINDOW", "EnergyDrift", "conservative_window", "reference_drift", "model_drift"]

MIN_WINDOW = 0.25  # fraction of the horizon the constant-load window must cover


@dataclass
class EnergyDrift:
    """Drift (relative, signed), spread ``(max E - min E) / scale`` and the window; NaN + reason when undefined."""

    drift: float = float("nan")
    spread: float = float("nan")
    window_start: float = float("nan")
    scale: float = float("nan")
    message: str = ""
    times: np.ndarray = field(default_factory=lambda: np.empty(0))  # [s], the steps fitted
    history: np.ndarray = field(default_factory=lambda: np.empty(0))  # E(t) / scale at ``times``

    def at_steps(self, dt: float) -> dict:
        """``{step index k (t = k dt): E / scale}`` of the fitted history."""
        return {int(round(t / dt)): float(e) for t, e in zip(self.times, self.history)}

    def row(self) -> dict:
        """The unit columns of a model's drift (``energy_*``)."""
        return {"energy_drift": self.drift, "energy_spread": self.spread, "energy_window_start": self.window_start,
                "energy_message": self.message}


def conservative_window(history, dt: float, t_end: float, t0: float = 0.0) -> float | None:
    """Start ``t_c`` of the final interval of ``[t0, t_end]`` where ``history`` (load factor of
    time) is constant at every step, or None when it covers less than :data:`MIN_WINDOW`."""
    n = int(round((t_end - t0) / dt))
    t = t0 + dt * np.arange(1, n + 1)
    lam = np.array([float(history(x)) for x in t])
    changed = np.flatnonzero(np.abs(np.diff(lam)) > 1e-12 * max(1.0, float(np.max(np.abs(lam)))))
    start = t[changed[-1] + 1] if changed.size else t[0]
    return float(start) if t_end - start >= MIN_WINDOW * (t_end - t0) - 1e-12 else None


def _fit(times, E, span, scale) -> tuple[float, float]:
    if len(times) < 3 or not np.all(np.isfinite(E)):
        return (float("inf") if len(times) and not np.all(np.isfinite(E)) else float("nan")), float("nan")
    slope = np.polyfit(np.asarray(times) - times[0], E, 1)[0]
    return float(slope * span / scale), float((np.max(E) - np.min(E)) / scale)


def reference_drift(table, t_c: float, t_end: float) -> EnergyDrift:
    """Drift of a reference run from its per-step energy table (``time``, ``kinetic_energy``,
    ``strain_energy``, ``external_work``)."""
    rows = table[table["time"].to_numpy(float) >= t_c - 1e-12]
    if len(rows) < 3:
        return EnergyDrift(window_start=t_c, message=f"the reference has {len(rows)} steps in the window "
                           f"t >= {t_c:g} s")
    ke, ie, w = (rows[c].to_numpy(float) for c in ("kinetic_energy", "strain_energy", "external_work"))
    scale = float(np.max(ke + ie))
    if not scale > 0:
        return EnergyDrift(window_start=t_c, message="no energy in the window (the system is at rest)")
    times = rows["time"].to_numpy(float)
    drift, spread = _fit(times, ke + ie - w, t_end - t_c, scale)
    return EnergyDrift(drift, spread, t_c, scale, times=times, history=(ke + ie - w) / scale)


def _undefined(system, t_c, t_end) -> str:
    if system.damped:
        return "damped system: its dissipation is physical"
    if system.strain_energy is None:
        return "the system has no stored-energy function"
    if system.has_prescribed and not np.allclose(system.prescribed_values(t_c), system.prescribed_values(t_end)):
        return "the prescribed motion moves in the window (its reaction does work)"
    return ""


def model_drift(system, dt: float, t_c: float, t_end: float, fields: dict, scale: float) -> EnergyDrift:
    """Drift of a model's trajectory: ``fields`` maps step index ``k`` (``t = k dt``) to the full
    displacement (n,) of that step, for every stored step in the window and its neighbours."""
    why = _undefined(system, t_c, t_end)
    if why:
        return EnergyDrift(window_start=t_c, message=why)
    if not scale > 0:
        return EnergyDrift(window_start=t_c, message="no reference energy in the window to scale by")
    ks = sorted(k for k in fields if k * dt >= t_c - 1e-9 and k - 1 in fields and k + 1 in fields)
    if len(ks) < 3:
        return EnergyDrift(float("inf"), float("inf"), t_c, scale,
                           "fewer than 3 model steps in the window (failed or not reached)")
    f0 = np.asarray(system.load(t_c, fields[ks[0]]) if system.load_depends_on_u else system.load(t_c), float)
    if system.load_depends_on_u and not np.allclose(system.load(t_c, fields[ks[-1]]), f0, rtol=1e-9, atol=1e-300):
        return EnergyDrift(window_start=t_c, message="follower load: no load potential")
    E = []
    for k in ks:
        u = fields[k]
        v = (fields[k + 1] - fields[k - 1]) / (2.0 * dt)
        with np.errstate(over="ignore", invalid="ignore"):
            E.append(0.5 * float(v @ (system.M @ v)) + float(system.strain_energy(u)) - float(f0 @ u))
    times, E = np.array(ks, float) * dt, np.array(E)
    drift, spread = _fit(times, E, t_end - t_c, scale)
    return EnergyDrift(drift, spread, t_c, scale, times=times, history=E / scale)
