"""Interpolation between stored load positions: PODI versus Grassmann (anm-pod §5).

The load of a scene is moved along a line of positions (a 1D parameter ``s``): the
cornea pinch along x through the apex, the liver palpation point along x of the
bounding box. A Newton reference is run at every lattice position and at held-out
positions between them; a POD basis is stored per lattice position, and at each
held-out position the basis is interpolated (PODI: aligned modes interpolated
piecewise linearly and re-orthonormalised; Grassmann: log/exp maps about the nearest
stored basis). Two errors are reported against the distance to the nearest stored
position: that of projecting the held-out reference states on the interpolated basis,
``max_k ||u_k - Phi Phi^T u_k|| / ||u_k||`` (the best any Galerkin ROM on that basis can
do), and that of the online ROM itself (``anm_pod_interp``: basis and reduced tensors, the
paper's f_nl terms, interpolated), ``max_k ||u_rom - u_k|| / ||u_k||`` along the load path;
the baseline is the nearest stored ANM-POD model used as is.

The moved load is one point force spread by the shape functions of its cell
(``distribute = "interpolate"``), so that the load, and the reference, move continuously
with the position (a nearest-node load would jump between nodes).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..cases.scene import load
from ..refsolvers import make_backend
from .reference import solve
from ..rom import Training, make_method
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
    region = {k: v for k, v in scene.loads[0]["region"].items() if k not in ("count", "boundary")}
    loads = [dict(scene.loads[0], region={**region, "nearest": line["point"](s)}, distribute="interpolate")]
    loads += list(scene.loads[1:])
    analysis = dict(scene.analysis, stop_at_divergence=False)
    if max_load_factor is not None:
        analysis["max_load_factor"] = max_load_factor
    if load_steps is not None:
        analysis["load_steps"] = load_steps
    return dataclasses.replace(scene, loads=loads, analysis=analysis)


def _reference(scene):
    """(full states (n_dof, k), load factors (k,), Training) of the scene's load path."""
    r = solve(scene)
    if r.status != "success":
        raise RuntimeError(f"{scene.name}: reference at a moved load did not converge: {r.message}")
    U = r.displacement[1:].reshape(len(r.displacement) - 1, -1).T
    lams = r.steps[1:]
    training = Training(U, [{"load_factor": float(lam)} for lam in lams], make_backend("skfem", r.problem))
    return U, lams, training


def _rom_error(model, U, lams, position=None):
    errs = []
    for k, lam in enumerate(lams):
        mu = {"load_factor": float(lam)} if position is None else {"load_factor": float(lam), "position": position}
        res = model.step(mu)
        u = model.reconstruct(res) if res.q is not None else np.full(U.shape[0], np.inf)
        errs.append(np.linalg.norm(u - U[:, k]) / np.linalg.norm(U[:, k]))
    return float(np.max(errs))


def _projection_error(Phi, U):
    R = U - Phi @ (Phi.T @ U)
    return float(np.max(np.linalg.norm(R, axis=0) / np.linalg.norm(U, axis=0)))


def interpolation_rows(case, n_lattice=5, n_modes=4, resolution="ci", max_load_factor=1.0, load_steps=4,
                       order=6, progress=None):
    """Rows: one per held-out position and method (PODI, Grassmann, nearest stored basis)."""
    scene = load(case, resolution=resolution)
    lo, hi = LINES[case]["range"]
    lattice = np.linspace(lo, hi, n_lattice)
    held = 0.5 * (lattice[:-1] + lattice[1:])
    held = np.concatenate([held, lattice[:-1] + 0.25 * np.diff(lattice)])
    free = scene.to_problem().free_dofs
    bases, groups = [], {}
    for s in lattice:
        U, _, training = _reference(moved_scene(scene, s, max_load_factor, load_steps))
        bases.append(pod_basis(U[free], n_modes=n_modes).modes)
        groups[float(s)] = training
        if progress:
            progress()
    m = min(b.shape[1] for b in bases)  # rank-limited per position: a common size
    bases = [b[:, :m] for b in bases]
    # the alignment of neighbouring bases decides in which coordinates the reduced tensors
    # are interpolated: both are measured
    roms = {(name, align): make_method("anm_pod_interp", n_modes=m, order=order, basis_interpolation=name,
                                       align=align).build(Training(groups=groups))
            for name in ("podi", "grassmann") for align in ("modes", "procrustes")}
    stored = [make_method("anm_pod", n_modes=m, order=order).build(groups[float(s)]) for s in lattice]
    rows = []
    for s in held:
        U, lams, _ = _reference(moved_scene(scene, s, max_load_factor, load_steps))
        base = {"case": case, "position": float(s), "spacing": float(lattice[1] - lattice[0]), "modes": m,
                "order": order}
        for name, interp in {"podi": podi_interpolate(bases, lattice, s),
                             "grassmann": grassmann_interpolate(bases, lattice, s)}.items():
            proj = _projection_error(interp.value, U[free])
            for align in ("modes", "procrustes"):
                rows.append({**base, "method": name, "align": align, "distance": interp.distance,
                             "projection_error": proj, "rom_error": _rom_error(roms[name, align], U, lams, float(s)),
                             "extrapolation": interp.extrapolation})
        nearest = int(np.argmin(np.abs(lattice - s)))
        rows.append({**base, "method": "nearest", "align": "", "distance": float(abs(lattice[nearest] - s)),
                     "projection_error": _projection_error(bases[nearest], U[free]),
                     "rom_error": _rom_error(stored[nearest], U, lams), "extrapolation": False})
        if progress:
            progress()
    return rows
