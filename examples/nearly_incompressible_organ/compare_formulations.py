"""The dome's apex displacement and solve time with P1, ANP, P2 or the mixed P2-P1
(docs/explanation/nearly-incompressible.md).

    python make_dome.py dome.msh
    python compare_formulations.py dome.msh 0.499 anp          # P1 | anp | P2 | mixed
    python compare_formulations.py dome.msh 0.499 mixed --backend ngsolve

Prints one JSON line: the apex displacement [mm], Newton iterations, and the time in assembly and in
the linear solves (factorisation apart), wall and CPU.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from tissuebench.cases.scene import load
from tissuebench.refsolvers.anp import AnpBackend, volumetric_modulus
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.mixed import MixedBackend
from tissuebench.refsolvers.newton import NewtonOptions, newton_solve

HERE = Path(__file__).resolve().parent


def scene_for(mesh: Path, nu: float, element: str, folder: Path):
    """dome.toml on ``mesh`` at ``nu`` with ``element`` (copied into ``folder``)."""
    shutil.copy(mesh, folder / "dome.msh")
    text = (HERE / "dome.toml").read_text()
    text = text.replace('unit = "mm"\n', f'unit = "mm"\nelement = "{element}"\n', 1).replace("nu = 0.499", f"nu = {nu}")
    (folder / "dome.toml").write_text(text)
    return load(folder / "dome.toml")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("mesh", type=Path)
    p.add_argument("nu", type=float)
    p.add_argument("form", choices=["P1", "anp", "P2", "mixed"])
    p.add_argument("--backend", default="skfem", choices=["skfem", "ngsolve"])
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        scene = scene_for(args.mesh, args.nu, "P1" if args.form in ("P1", "anp") else "P2", Path(tmp))
        t0, c0 = time.perf_counter(), time.process_time()
        pb = scene.to_problem()
        be = make_backend(args.backend, pb)
        if args.form == "anp":
            be = AnpBackend(pb, be)
        elif args.form == "mixed":
            be = MixedBackend(pb, be, bulk_modulus=volumetric_modulus(pb.material))
        steps = int(scene.analysis["load_steps"])
        res = newton_solve(be, 1.0, NewtonOptions(n_increments=steps, max_increment=1.0 / steps))
        tab = res.table()
        apex = scene.evaluate_monitors(pb, res.u[:pb.ndof])["apex_uz"]
        print(json.dumps({"form": args.form, "nu": args.nu, "backend": args.backend, "vertices": pb.mesh.n_vertices,
                          "unknowns": int(be.ndof), "status": res.status, "load_factor": res.load_factor,
                          "apex_uz_mm": 1e3 * apex, "newton_iterations": int(tab.newton_iterations.sum()),
                          "assembly_s": float(tab.assembly_s.sum()), "solve_s": float(tab.solve_s.sum()),
                          "factor_s": float(tab.factor_s.sum()), "wall_s": time.perf_counter() - t0,
                          "cpu_s": time.process_time() - c0}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
