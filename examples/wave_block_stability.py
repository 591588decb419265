"""Wave in a block (pgd-pod §6.1-6.2) and long-time stability of implicit integrators.

The case
--------
Block ``[0, 5] x [0, 5] x [0, 10]`` m (z vertical), E = 2.66e8 Pa, nu = 0.33,
rho = 2000 kg/m^3, so the P-wave speed is ``c = sqrt((lambda + 2 mu) / rho) = 443.9 m/s``.
A 4 kPa Heaviside pressure acts on the top face z = 10 (a dead traction (0, 0, -4000) Pa
times ``H(t)``, on from t = 0, so the initial acceleration is consistent with it); the
normal displacement is fixed on the five other faces (x = 0, 5: u_x = 0; y = 0, 5:
u_y = 0; z = 0: u_z = 0), tangential motion free. Reference integrator: HHT with
alpha = -0.05, dt = 0.00125 s. Units: SI (m, kg, s, N, Pa, J).

With lateral normal constraints and a uniform top load the exact solution is 1D
(uniaxial strain): a step wave of particle velocity ``p / (rho c)`` runs down, reflects at
the fixed bottom, and the top displacement is a triangle wave between 0 and
``-2 p L / (lambda + 2 mu)`` with period ``4 L / c`` (:func:`column_top_displacement`).

The stability study
-------------------
``python examples/wave_block_stability.py --t-end 10 --out results/wave`` integrates
the SVK block with the trapezoidal rule (``newmark``), Bathe's composite scheme and
HHT(alpha = -0.05), writes the per-step energy balance of every method to
``energy.csv`` (columns method, t, kinetic, strain, external_work, energy_error,
relative_energy_error, newton_iterations), a per-method summary to ``summary.csv`` and
``energy_error.png`` (relative energy error vs time). The relative energy error is
``energy_error / max(max |KE + IE|, max |W|)`` over the run (see
:class:`tissuebench.refsolvers.dynamics.DynamicsResult`).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers import (BACKENDS, Dirichlet, LinearElastic, Problem, SaintVenantKirchhoff,
                                    SurfaceTraction, make_backend)
from tissuebench.refsolvers.dynamics import SecondOrderSystem, integrate

# ------------------------------------------------------------------ case data (SI)
LENGTHS = (5.0, 5.0, 10.0)        # m, z is vertical
YOUNG = 2.66e8                    # Pa
POISSON = 0.33
DENSITY = 2000.0                  # kg/m^3
PRESSURE = 4000.0                 # Pa, Heaviside on the top face
HHT_ALPHA = -0.05
DT = 0.00125                      # s
METHODS = {"newmark": {}, "bathe": {}, "hht": {"alpha": HHT_ALPHA}}

__all__ = ["LENGTHS", "YOUNG", "POISSON", "DENSITY", "PRESSURE", "HHT_ALPHA", "DT", "METHODS",
           "lame", "p_wave_speed", "heaviside", "wave_block_problem", "make_backend_with", "wave_block_system",
           "column_top_displacement", "column_displacement", "node_at", "run_study", "main"]


def lame(E=YOUNG, nu=POISSON):
    """(lambda, mu) [Pa]."""
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def p_wave_speed(E=YOUNG, nu=POISSON, rho=DENSITY) -> float:
    """c = sqrt((lambda + 2 mu) / rho) [m/s] (443.9 m/s for the case data)."""
    lam, mu = lame(E, nu)
    return float(np.sqrt((lam + 2 * mu) / rho))


def heaviside(t: float) -> float:
    """H(t): 1 for t >= 0 (the load is on at t = 0), else 0."""
    return 1.0 if t >= 0.0 else 0.0


def wave_block_problem(material="linear", divisions=(2, 2, 8), element="Q1", pressure=PRESSURE,
                       lengths=LENGTHS) -> Problem:
    """The wave-in-a-block problem (load factor 1 = full pressure).

    Parameters
    ----------
    material : {"linear", "svk"}
        Small-strain linear elastic or Saint Venant-Kirchhoff, E = 2.66e8 Pa, nu = 0.33.
    divisions : (nx, ny, nz)
        Structured cells per direction; ``element="P1"`` splits each hexahedron into 6 tets.
    element : {"Q1", "P1"}
    pressure : float
        Top pressure [Pa] (4000 in the paper); the traction is (0, 0, -pressure).
    lengths : (3,) floats
        Block size [m].
    """
    if material == "linear":
        mat = LinearElastic(YOUNG, POISSON)
    elif material == "svk":
        mat = SaintVenantKirchhoff(YOUNG, POISSON)
    else:
        raise ValueError(f"material={material!r} is not one of ['linear', 'svk']")
    cell_type = {"Q1": "hexahedron", "P1": "tetra"}.get(element)
    if cell_type is None:
        raise ValueError(f"element={element!r} is not one of ['P1', 'Q1']")
    Lx, Ly, Lz = (float(v) for v in lengths)
    mesh = box_mesh((Lx, Ly, Lz), divisions, cell_type)
    tol = 1e-9 * max(Lx, Ly, Lz)
    dirichlet = [
        Dirichlet(lambda x: (np.abs(x[:, 0]) < tol) | (np.abs(x[:, 0] - Lx) < tol), components=(0,)),
        Dirichlet(lambda x: (np.abs(x[:, 1]) < tol) | (np.abs(x[:, 1] - Ly) < tol), components=(1,)),
        Dirichlet(lambda x: np.abs(x[:, 2]) < tol, components=(2,)),
    ]
    top = SurfaceTraction(lambda x: np.abs(x[:, 2] - Lz) < tol, np.array([0.0, 0.0, -float(pressure)]))
    return Problem(mesh, mat, element=element, dirichlet=dirichlet, loads=[top], density=DENSITY)


def make_backend_with(name, problem, **options):
    """A backend by name; ``options`` go to its constructor (e.g. ``threads=1`` for NGSolve)."""
    if not options:
        return make_backend(name, problem)
    import importlib

    if name not in BACKENDS:
        raise ValueError(f"unknown backend {name!r}; valid: {sorted(BACKENDS)}")
    module, cls = BACKENDS[name].split(":")
    return getattr(importlib.import_module(module), cls)(problem, **options)


def wave_block_system(problem, backend="skfem", lumped=False, **backend_options):
    """(backend object, SecondOrderSystem) with the Heaviside load history.

    ``backend_options`` go to the backend's constructor (NGSolve: ``threads=1`` avoids
    entering the TaskManager on every call, which costs ~0.2 s each on small meshes).
    """
    be = make_backend_with(backend, problem, **backend_options)
    linear = bool(problem.material.is_linear)
    return be, SecondOrderSystem.from_backend(be, heaviside, lumped=lumped, linear=linear)


def column_displacement(z, t, pressure=PRESSURE, height=LENGTHS[2], E=YOUNG, nu=POISSON, rho=DENSITY):
    """Exact 1D (uniaxial strain) vertical displacement [m] at height z [m] and time t [s].

    Column 0 <= z <= H, u = 0 at z = 0, stress -p H(t) at z = H, M = lambda + 2 mu::

        u(z, t) = -(p / M) sum_k (-1)^k [R(c t - (2kH + H - z)) - R(c t - (2kH + H + z))]

    with the ramp R(x) = max(x, 0): the incident down-going ramp, its reflection at the
    fixed bottom (displacement sign flipped) and the reflections at the loaded top
    (stress sign flipped), i.e. the method of images.
    """
    lam, mu = lame(E, nu)
    Mmod, c = lam + 2 * mu, p_wave_speed(E, nu, rho)
    z, t = np.broadcast_arrays(np.asarray(z, float), np.asarray(t, float))
    u = np.zeros(z.shape)
    n_max = int(np.ceil(np.max(t) * c / (2 * height))) + 2
    for k in range(n_max):
        s = (-1.0) ** k
        d_down = (height - z) + 2 * k * height
        d_up = (height + z) + 2 * k * height
        u += s * (np.maximum(c * t - d_down, 0.0) - np.maximum(c * t - d_up, 0.0))
    return -pressure / Mmod * u


def column_top_displacement(t, **kw):
    """Exact 1D top displacement: -p c t / (lambda + 2 mu) until t = 2 H / c (triangle wave)."""
    height = kw.get("height", LENGTHS[2])
    return column_displacement(height, t, **kw)


def node_at(problem, point) -> int:
    """Index of the discretisation node nearest to ``point``."""
    return int(np.argmin(np.linalg.norm(problem.nodes - np.asarray(point, float), axis=1)))


# ------------------------------------------------------------------ stability study
def _frame(method, res):
    import pandas as pd

    scale = max(np.max(np.abs(res.total_energy)), np.max(np.abs(res.external_work)), 1e-300)
    df = pd.DataFrame({
        "method": method, "t": res.t, "kinetic": res.kinetic_energy, "strain": res.strain_energy,
        "external_work": res.external_work, "energy_error": res.energy_error,
        "relative_energy_error": res.energy_error / scale, "newton_iterations": res.newton_iterations,
    })
    return df


def run_study(out, t_end=10.0, divisions=(2, 2, 8), dt=DT, material="svk", element="Q1",
              backend="skfem", methods=None, pressure=PRESSURE, plot=True, verbose=True):
    """Integrate the block with each method, write ``energy.csv``, ``summary.csv`` and the PNG.

    Returns
    -------
    dict with ``energy`` (DataFrame of all steps), ``summary`` (one row per method) and
    ``paths`` (written files).
    """
    import pandas as pd

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    methods = dict(METHODS if methods is None else methods)
    problem = wave_block_problem(material, divisions, element, pressure=pressure)
    _, system = wave_block_system(problem, backend, **({"threads": 1} if backend == "ngsolve" else {}))
    top = node_at(problem, (LENGTHS[0] / 2, LENGTHS[1] / 2, LENGTHS[2]))
    mon = np.array([3 * top + 2])
    frames, rows = [], []
    for name, opts in methods.items():
        tic = time.perf_counter()
        res = integrate(system, None, None, dt, t_end, method=name, dofs=mon,
                        store_every=max(1, int(round(0.01 / dt))), **opts)
        wall = time.perf_counter() - tic
        df = _frame(name, res)
        frames.append(df)
        rel = df["relative_energy_error"].to_numpy()
        e_tot = res.total_energy
        rows.append({
            "method": name, "status": res.status, "message": res.message, "steps": res.n_steps,
            "t_reached": float(res.t[-1]), "final_relative_energy_error": float(rel[-1]),
            "max_abs_relative_energy_error": float(np.max(np.abs(rel))),
            "energy_growth_ratio": float(res.energy_growth_ratio),
            "final_total_energy": float(e_tot[-1]), "max_total_energy": float(np.max(e_tot)),
            "mean_newton_iterations": float(np.mean(res.newton_iterations[1:])) if res.n_steps else 0.0,
            "max_abs_top_uz": float(np.max(np.abs(res.u[:, 0]))), "wall_s": wall,
        })
        if verbose:
            print(f"{name:8s} {res.status:14s} t={res.t[-1]:8.4f} s  rel. energy error: final "
                  f"{rel[-1]:+.3e}, max |.| {np.max(np.abs(rel)):.3e}  growth ratio "
                  f"{res.energy_growth_ratio:.6f}  Newton it/step {rows[-1]['mean_newton_iterations']:.2f}"
                  f"  ({wall:.1f} s)", flush=True)
    energy = pd.concat(frames, ignore_index=True)
    summary = pd.DataFrame(rows)
    paths = {"energy": out / "energy.csv", "summary": out / "summary.csv"}
    energy.to_csv(paths["energy"], index=False)
    summary.to_csv(paths["summary"], index=False)
    if plot:
        paths["plot"] = out / "energy_error.png"
        _plot(energy, paths["plot"], f"wave block, {material}, {element} {tuple(divisions)}, dt={dt:g} s")
    return {"energy": energy, "summary": summary, "paths": paths}


def _plot(energy, path, title):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 4.5))
    for name, df in energy.groupby("method", sort=False):
        ax.plot(df["t"], df["relative_energy_error"], label=name, lw=0.8)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("(KE + IE - W - E0) / max energy")
    ax.set_title(title)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _divisions(text):
    parts = [int(v) for v in text.replace("x", ",").split(",") if v.strip()]
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"--divisions needs three integers (nx,ny,nz), got {text!r}")
    return tuple(parts)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--t-end", type=float, default=10.0, help="end time [s] (paper: 10)")
    ap.add_argument("--divisions", type=_divisions, default=(2, 2, 8), help="cells nx,ny,nz (default 2,2,8)")
    ap.add_argument("--dt", type=float, default=DT, help=f"time step [s] (default {DT})")
    ap.add_argument("--out", type=Path, default=Path("results/wave_block_stability"), help="output folder")
    ap.add_argument("--material", choices=["svk", "linear"], default="svk")
    ap.add_argument("--element", choices=["Q1", "P1"], default="Q1")
    ap.add_argument("--backend", choices=["skfem", "ngsolve"], default="skfem")
    ap.add_argument("--pressure", type=float, default=PRESSURE, help="top pressure [Pa] (paper: 4000)")
    ap.add_argument("--methods", default=",".join(METHODS), help="comma-separated subset of newmark,bathe,hht")
    args = ap.parse_args(argv)
    names = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = sorted(set(names) - set(METHODS))
    if unknown:
        ap.error(f"unknown method(s) {unknown}; valid: {list(METHODS)}")
    res = run_study(args.out, args.t_end, args.divisions, args.dt, args.material, args.element,
                    args.backend, {m: METHODS[m] for m in names}, args.pressure)
    print(res["summary"].drop(columns=["message"]).to_string(index=False))
    print("written:", ", ".join(str(p) for p in res["paths"].values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
