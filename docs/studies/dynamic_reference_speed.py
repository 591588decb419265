"""Per-step cost of the nonlinear dynamic reference, before and after, beside NGSolve's own time stepping.

The same problem on the same mesh, in one run: the neo-Hookean liver of ``liver_dynamic``
(variant ``neo_hookean``: E = 50 kPa, nu = 0.45, 5 N palpation ramped over 0.25 s), HHT
(alpha = -0.05) at dt = 5 ms, on the catalogue's ci mesh (2866 nodes) or on the liver's surface
remeshed by gmsh to about ``--nodes`` nodes (``refsolvers.remesh``). Three runs of ``--steps``
steps from rest:

* ``newton``: tissuebench's integrator with Newton (``newton_tangent = "iteration"``: the tangent
  assembled and factorised at every iteration), what every dynamic reference did before issue 42;
* ``modified``: the default now (``"auto"``: modified Newton from 1000 unknowns, the factorised
  matrix kept across iterations and steps, refreshed on a poor contraction);
* ``ngsolve``: NGSolve's own time stepping, written as its tutorials do: the HHT step as an
  incremental potential ``(1 + alpha) W(u) + rho / (2 beta dt^2) |u|^2`` in one
  ``BilinearForm(Variation(...))``, Newton by ``Apply`` / ``AssembleLinearization`` /
  ``Inverse(freedofs, "sparsecholesky")`` at every iteration, on NGSolve's own mesh of the same
  vertices and tetrahedra (``build_ngsolve_mesh``) and its own integration rules, the energy
  compiled to C++ (``realcompile``) where a compiler is found, one thread.

Per run: wall and CPU seconds per step (median, total), Newton iterations (linear solves) per
step, and the largest difference of the tool-tip displacement to the ``newton`` run. Run::

    .venv/bin/python docs/studies/dynamic_reference_speed.py --steps 40
    .venv/bin/python docs/studies/dynamic_reference_speed.py --steps 40 --nodes 5000
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import meshio
import numpy as np
from threadpoolctl import threadpool_limits

from tissuebench.cases import load
from tissuebench.cases.monitors import linear_outputs
from tissuebench.reference import dynamics_system
from tissuebench.refsolvers.dynamics import make_integrator
from tissuebench.refsolvers.remesh import mean_edge_length, remesh

ALPHA = -0.05


def scene_with_nodes(nodes: int | None, folder: Path):
    """The neo-Hookean liver, on the ci mesh (``nodes`` None) or remeshed to about ``nodes`` nodes."""
    scene = load("liver_dynamic", variant="neo_hookean")
    if not nodes:
        return scene
    mesh = scene.mesh
    size = mean_edge_length(mesh) * (mesh.n_vertices / nodes) ** (1 / 3)
    fine = remesh(mesh, size)
    path = folder / "liver_remeshed.vtu"
    meshio.write(path, meshio.Mesh(fine.points, [("tetra", fine.cells)]))
    return scene.with_mesh({"path": str(path), "scale": 1.0})


def _tip(scene, pb):
    """The monitored tool-tip displacement (``tool_tip_uy``) as a linear functional (n_dof,)."""
    return linear_outputs(scene, pb)["tool_tip_uy"]


def ours(scene, steps: int, tangent: str):
    """tissuebench's HHT on the scene's system: (per-step wall, per-step CPU, iterations, tip history)."""
    system = dynamics_system(scene, "skfem")
    integ = make_integrator("hht", alpha=ALPHA, newton_tangent=tangent).start(system, None, None,
                                                                              float(scene.analysis["dt"]))
    wall, cpu, its, u = [], [], [], []
    for _ in range(steps):
        t0, c0 = time.perf_counter(), time.process_time()
        rep = integ.step()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        if not rep.converged:
            raise RuntimeError(rep.message)
        its.append(rep.iterations)
        u.append(integ.full_u())
    return np.array(wall), np.array(cpu), np.array(its), np.array(u)


def ngsolve_native(scene, steps: int):
    """NGSolve's own HHT time stepping of the same problem (module docstring)."""
    import ngsolve as ngs

    from tissuebench.refsolvers.backends.ngsolve_backend import build_ngsolve_mesh, energy_cf, real_compile

    pb = scene.to_problem()
    mesh = build_ngsolve_mesh(pb.mesh)
    fes = ngs.VectorH1(mesh, order=1)
    vd = np.array([fes.GetDofNrs(ngs.NodeId(ngs.VERTEX, v)) for v in range(mesh.nv)], dtype=np.int64)
    ng_of = np.empty(pb.ndof, dtype=np.int64)
    ng_of[(3 * np.arange(mesh.nv)[:, None] + np.arange(3)).ravel()] = vd.ravel()
    free = ngs.BitArray(fes.ndof)
    free.Set()
    for d in pb.fixed_dofs:
        free.Clear(int(ng_of[d]))
    mask = np.array([free[i] for i in range(fes.ndof)], dtype=bool)
    dt = float(scene.analysis["dt"])
    beta, gamma = (1 - ALPHA) ** 2 / 4, 0.5 - ALPHA
    rho = pb.density
    u, v = fes.TnT()
    W = energy_cf(pb.material, ngs.Id(3) + ngs.Grad(u))
    step_form = ngs.BilinearForm(fes, symmetric=True)  # (1 + alpha) W + rho / (2 beta dt^2) |u|^2
    # compiled to C++ where NGSolve's compiler wrappers work (as the NGSolve backend does), else interpreted
    step_form += ngs.Variation(real_compile((1 + ALPHA) * W + rho / (2 * beta * dt * dt) * ngs.InnerProduct(u, u))[0]
                               * ngs.dx)
    internal = ngs.BilinearForm(fes, symmetric=True)
    internal += ngs.Variation(real_compile(W)[0] * ngs.dx)
    mass = ngs.BilinearForm(fes, symmetric=True)
    mass += rho * ngs.InnerProduct(u, v) * ngs.dx
    mass.Assemble()
    load = np.zeros(fes.ndof)
    from tissuebench.refsolvers import make_backend

    load[ng_of] = make_backend("skfem", pb).external_force(np.zeros(pb.ndof), 1.0)
    gfu = ngs.GridFunction(fes)
    vec = gfu.vec.CreateVector
    U, V, A, Fint, R, tmp = (vec() for _ in range(6))
    for x in (U, V, A, Fint):
        x[:] = 0.0
    f_old = np.zeros(fes.ndof)
    wall, cpu, its, tips = [], [], [], []
    tip = _tip(scene, pb)[np.argsort(ng_of)]
    for k in range(1, steps + 1):
        t0, c0 = time.perf_counter(), time.process_time()
        f_new = scene.history(k * dt) * load
        un, vn, an = (x.FV().NumPy().copy() for x in (U, V, A))
        utilde = un + dt * vn + dt * dt * (0.5 - beta) * an
        const = ALPHA * Fint.FV().NumPy() + (1 + ALPHA) * f_new - ALPHA * f_old
        mass_ut = (mass.mat * _vector(tmp, utilde)).Evaluate().FV().NumPy() / (beta * dt * dt)
        gfu.vec.FV().NumPy()[:] = un + dt * vn + 0.5 * dt * dt * an
        ref = max(np.linalg.norm(const[mask]), 1e-300)
        n_it = 0
        for n_it in range(1, 26):
            step_form.Apply(gfu.vec, R)
            r = R.FV().NumPy() - mass_ut - const
            r[~mask] = 0.0
            if np.linalg.norm(r) <= 1e-10 * ref and n_it > 1:
                n_it -= 1
                break
            step_form.AssembleLinearization(gfu.vec)
            inv = step_form.mat.Inverse(free, inverse="sparsecholesky")
            gfu.vec.data -= inv * _vector(tmp, r)
        u1 = gfu.vec.FV().NumPy().copy()
        a1 = (u1 - utilde) / (beta * dt * dt)
        v1 = vn + dt * ((1 - gamma) * an + gamma * a1)
        U.FV().NumPy()[:], V.FV().NumPy()[:], A.FV().NumPy()[:] = u1, v1, a1
        internal.Apply(U, Fint)
        f_old = f_new
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
        its.append(n_it)
        tips.append(float(tip @ u1))
    return np.array(wall), np.array(cpu), np.array(its), np.array(tips)


def _vector(template, values):
    template.FV().NumPy()[:] = values
    return template


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--nodes", type=int, default=None, help="remesh the liver to about this many nodes")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp, threadpool_limits(1):
        scene = scene_with_nodes(args.nodes, Path(tmp))
        pb = scene.to_problem()
        print(f"liver: {pb.mesh.n_vertices} nodes, {pb.mesh.n_cells} tetrahedra, {len(pb.free_dofs)} free dofs; "
              f"HHT alpha {ALPHA}, dt {scene.analysis['dt']} s, {args.steps} steps")
        tip = _tip(scene, pb)
        rows, tips = [], {}
        for name in ("newton", "modified", "ngsolve"):
            if name == "ngsolve":
                wall, cpu, its, tips[name] = ngsolve_native(scene, args.steps)
            else:
                wall, cpu, its, u = ours(scene, args.steps, "iteration" if name == "newton" else "auto")
                tips[name] = u @ tip
            rows.append((name, np.median(wall), wall.sum(), np.median(cpu), cpu.sum(), its.mean()))
        scale = np.abs(tips["newton"]).max()
        print("| run | wall/step median [s] | wall total [s] | CPU/step median [s] | CPU total [s] | "
              "solves/step | max tip difference to newton |")
        print("|---|---|---|---|---|---|---|")
        for name, wm, wt, cm, ct, it in rows:
            diff = np.abs(tips[name] - tips["newton"]).max() / scale
            print(f"| {name} | {wm:.3f} | {wt:.1f} | {cm:.3f} | {ct:.1f} | {it:.2f} | {diff:.1e} |")
        print(f"peak tool-tip displacement {scale:.4g} m")


if __name__ == "__main__":
    main()
