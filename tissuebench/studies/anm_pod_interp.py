"""Interpolation between stored load positions: PODI versus Grassmann (anm-pod §5).

The load of a scene is moved along a line of positions (a 1D parameter ``s``): the
cornea pinch along x through the apex, the liver palpation point along x of the
bounding box. A Newton reference is run at every lattice position and at held-out
positions between them; a POD basis is stored per lattice position, and at each
held-out position the basis is interpolated (PODI: aligned modes interpolated
piecewise linearly and re-orthonormalised; Grassmann: log/exp maps about the nearest
stored basis). The error is that of projecting the held-out reference states on the
interpolated basis, ``max_k ||u_k - Phi Phi^T u_k|| / ||u_k||`` (the best any Galerkin
ROM on that basis can do), reported against the distance to the nearest stored position.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..cases.scene import load
from ..refsolvers import solve
from ..rom.interpolation import grassmann_interpolate, podi_interpolate
from ..rom.pod import pod_basis

__all__ = ["LINES", "moved_scene", "interpolation_rows"]

# position s -> the load region's point; (s_min, s_max) of the lattice at each resolution
LINES = {
    "cornea_pinch": {"point": lambda s: [s, 0.0, 2.805], "range": (-1.2, 1.2)},
    "liver_palpation": {"point": lambda s: [s, 1.0, 0.5], "range": (0.35, 0.65)},
}


def moved_scene(scene, s, max_load_factor=None, load_steps=None):
    """``scene`` with its (first) load region's point at position ``s`` of its line."""
    line = LINES[scene.name]
    loads = [dict(scene.loads[0], region={**scene.loads[0]["region"], "nearest": line["point"](s)})]
    loads += list(scene.loads[1:])
    analysis = dict(scene.analysis, stop_at_divergence=False)
    if max_load_factor is not None:
        analysis["max_load_factor"] = max_load_factor
    if load_steps is not None:
        analysis["load_steps"] = load_steps
    return dataclasses.replace(scene, loads=loads, analysis=analysis)


def _states(scene, free):
    r = solve(scene)
    if r.status != "success":
        raise RuntimeError(f"{scene.name}: reference at a moved load did not converge: {r.message}")
    U = r.displacement[1:].reshape(len(r.displacement) - 1, -1).T
    return U[free]


def _projection_error(Phi, U):
    R = U - Phi @ (Phi.T @ U)
    return float(np.max(np.linalg.norm(R, axis=0) / np.linalg.norm(U, axis=0)))


def interpolation_rows(case, n_lattice=5, n_modes=4, resolution="ci", max_load_factor=1.0, load_steps=4,
                       progress=None):
    """Rows: one per held-out position and method (PODI, Grassmann, nearest stored basis)."""
    scene = load(case, resolution=resolution)
    lo, hi = LINES[case]["range"]
    lattice = np.linspace(lo, hi, n_lattice)
    held = 0.5 * (lattice[:-1] + lattice[1:])
    held = np.concatenate([held, lattice[:-1] + 0.25 * np.diff(lattice)])
    free = scene.to_problem().free_dofs
    bases = []
    for s in lattice:
        U = _states(moved_scene(scene, s, max_load_factor, load_steps), free)
        bases.append(pod_basis(U, n_modes=n_modes).modes)
        if progress:
            progress()
    m = min(b.shape[1] for b in bases)  # rank-limited per position: a common size
    bases = [b[:, :m] for b in bases]
    rows = []
    for s in held:
        U = _states(moved_scene(scene, s, max_load_factor, load_steps), free)
        methods = {"podi": podi_interpolate(bases, lattice, s), "grassmann": grassmann_interpolate(bases, lattice, s)}
        nearest = int(np.argmin(np.abs(lattice - s)))
        for name, interp in methods.items():
            rows.append({"case": case, "method": name, "position": float(s), "distance": interp.distance,
                         "spacing": float(lattice[1] - lattice[0]), "modes": m,
                         "projection_error": _projection_error(interp.value, U),
                         "extrapolation": interp.extrapolation})
        rows.append({"case": case, "method": "nearest", "position": float(s),
                     "distance": float(abs(lattice[nearest] - s)), "spacing": float(lattice[1] - lattice[0]),
                     "modes": m, "projection_error": _projection_error(bases[nearest], U), "extrapolation": False})
        if progress:
            progress()
    return rows
