"""Measurements of direct-integrator trajectories: run, error, energy, frequency content.

Used by the study (``examples/direct_study.py``) and its tests; everything here is
offline (full-size fields are allowed).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Trajectory",
    "energy_history",
    "full_run",
    "relative_rmse",
    "simulate",
    "spectrum_peaks",
    "velocities_from_displacements",
]


@dataclass
class Trajectory:
    """A direct-integrator run.

    Attributes
    ----------
    t : (n_t,) array
        Times [s], ``t[0]`` the start.
    u : (n_t, n_dof) array
        Displacements [m] (row 0: the start state).
    v : (n_t, n_dof) array or None
        Velocities [m/s] when the scheme computes them.
    status : list of str
        Step statuses (``n_t - 1`` entries).
    failed_at : int or None
        First failed step (the run stops there).
    outputs : dict of arrays
        Monitored outputs per step (from :meth:`DirectModel.outputs`).
    """

    t: np.ndarray
    u: np.ndarray
    v: np.ndarray | None
    status: list
    failed_at: int | None = None
    outputs: dict = field(default_factory=dict)

    @property
    def extrapolations(self) -> int:
        return sum(s == "extrapolation" for s in self.status)


def simulate(model, times, history, state0=None) -> Trajectory:
    """Run ``model`` from ``state0`` at ``times[0]`` with load factor ``history(t)`` per step."""
    times = np.asarray(times, dtype=float)
    model.start({"time": times[0], "load_factor": float(history(times[0]))}, state0, times[1] - times[0])
    n = model.ndof
    u0 = np.zeros(n) if not state0 or state0.get("u") is None else np.asarray(state0["u"], float)
    v0 = np.zeros(n) if not state0 or state0.get("v") is None else np.asarray(state0["v"], float)
    has_v = "v" in model.vademecum.space
    U, V, status, outs, failed = [u0], [v0], [], [], None
    for k, t in enumerate(times[1:], start=1):
        r = model.step({"time": t, "load_factor": float(history(t))})
        status.append(r.status)
        if r.q is None:
            failed = k
            break
        U.append(model.reconstruct(r))
        if has_v:
            V.append(model.field(r, "v"))
        outs.append(model.outputs(r))
    names = outs[0].keys() if outs else ()
    outputs = {k: np.array([o[k] for o in outs]) for k in names}
    return Trajectory(times[:len(U)], np.array(U), np.array(V) if has_v else None, status, failed, outputs)


def full_run(model, times, history, state0=None) -> Trajectory:
    """The model's inner integrator on the full system: same scheme, mass, load convention
    and start as ``model``, no reduction (the reference of the reduction error)."""
    from .schemes import VectorAlgebra

    times = np.asarray(times, dtype=float)
    dt, scheme, free = times[1] - times[0], model.scheme, model.free_dofs
    n = model.ndof
    u0 = np.zeros(n) if not state0 or state0.get("u") is None else np.asarray(state0["u"], float)
    v0 = np.zeros(n) if not state0 or state0.get("v") is None else np.asarray(state0["v"], float)
    lam_prev = float(history(times[0]))
    alg = VectorAlgebra(model.ops, lam_prev)
    x = alg.initial_state(scheme, u0[free], v0[free], dt)
    U, V, status = [u0], [v0], []
    opts = model.vademecum.options
    for t in times[1:]:
        lam_new = float(history(t))
        lam = {"end": lam_new, "start": lam_prev, "mid": 0.5 * (lam_new + lam_prev)}[model.load_at]
        x = alg.step(scheme, x, dt, lam, **opts)
        lam_prev = lam_new
        if not (np.all(np.isfinite(x["u"])) and np.abs(x["u"]).max() < 1e150):
            status.append("failed")
            break
        status.append("ok")
        u, v = np.zeros(n), np.zeros(n)
        u[free] = x["u"]
        v[free] = x.get("v", 0.0)
        U.append(u)
        V.append(v)
    has_v = "v" in scheme.outputs
    failed = len(U) if status and status[-1] == "failed" else None
    return Trajectory(times[:len(U)], np.array(U), np.array(V) if has_v else None, status, failed)


def relative_rmse(u, u_ref) -> float:
    """``sqrt(sum_t |u_t - ref_t|^2 / sum_t |ref_t|^2)`` over a history (rows: time steps)."""
    u, u_ref = np.asarray(u, float), np.asarray(u_ref, float)
    if u.shape != u_ref.shape:
        raise ValueError(f"relative_rmse: shapes differ {u.shape} vs {u_ref.shape}")
    den = np.sqrt(np.sum(u_ref**2))
    return float(np.sqrt(np.sum((u - u_ref) ** 2)) / den) if den > 0 else float(np.sqrt(np.sum(u**2)))


def velocities_from_displacements(u, dt: float) -> np.ndarray:
    """Central differences ``(u_{n+1} - u_{n-1}) / 2 dt`` (one-sided at the ends), shape of ``u``."""
    return np.gradient(np.asarray(u, float), float(dt), axis=0)


def energy_history(u, v, M, f, lams, strain_energy) -> dict:
    """Kinetic, strain energy, external work and the balance error along a trajectory.

    Parameters
    ----------
    u, v : (n_t, n) arrays
        Displacement [m] and velocity [m/s] on the dofs of ``M`` (free dofs).
    M : (n, n) matrix
        Mass [kg].
    f : (n,) array
        Load at factor 1 [N].
    lams : (n_t,) array
        Load factor at each time (held over the step that ends there).
    strain_energy : callable ``(n,) -> float``
        Stored energy [J].

    Returns
    -------
    dict of (n_t,) arrays: ``kinetic``, ``strain``, ``work`` (trapezoidal in u, the load
    of the step ending at t_{n+1} held over it) and ``relative_error`` =
    ``(KE + SE - W - E_0) / max(max |KE + SE|, max |W|)``.
    """
    u, v = np.asarray(u, float), np.asarray(v, float)
    ke = 0.5 * np.einsum("ti,ti->t", v, np.asarray(M @ v.T).T)
    se = np.array([strain_energy(x) for x in u])
    du = np.diff(u, axis=0) @ f
    work = np.concatenate([[0.0], np.cumsum(np.asarray(lams, float)[1:] * du)])
    total = ke + se
    scale = max(np.max(np.abs(total)), np.max(np.abs(work)), 1e-300)
    return {"kinetic": ke, "strain": se, "work": work, "relative_error": (total - work - total[0]) / scale}


def spectrum_peaks(signal, dt: float, n_peaks: int = 3, min_relative: float = 0.05):
    """Frequencies [Hz] and amplitudes of the largest peaks of a signal's spectrum.

    The mean is removed and a Hann window applied; a peak is a local maximum of the
    amplitude spectrum above ``min_relative`` times the largest one.
    """
    x = np.asarray(signal, float)
    x = (x - x.mean()) * np.hanning(len(x))
    amp = np.abs(np.fft.rfft(x)) * 2.0 / max(np.sum(np.hanning(len(x))), 1e-300)
    freq = np.fft.rfftfreq(len(x), dt)
    is_peak = np.r_[False, (amp[1:-1] > amp[:-2]) & (amp[1:-1] >= amp[2:]), False]
    idx = np.flatnonzero(is_peak & (amp >= min_relative * amp.max()))
    idx = idx[np.argsort(amp[idx])[::-1][:n_peaks]]
    return freq[idx], amp[idx]
