"""Refinement table of the Land et al. 2015 ventricle (problem 2, isotropic Guccione, 10 kPa)
with the mixed u-p formulation (Taylor-Hood P2-P1, NGSolve, a tenth of the volumetric
penalty kept, as `tissuebench verify` runs it): apex z of the endocardium and epicardium per
netgen ``maxh`` [mm], beside the published spread of the 11 codes.

    python examples/lv_mixed_refinement.py [--maxh 2.0 1.6 1.3 1.0 0.8] [--out docs/studies]

maxh 2.0 is the catalogue's ci mesh, 0.8 its paper mesh. Writes ``lv_mixed_refinement.csv``
and ``lv_mixed_refinement.md`` (rows appended as each mesh finishes, so a long run shows
progress and keeps what it finished).
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import pandas as pd

from tissuebench.cases.scene import load
from tissuebench.refsolvers.mixed import static_run

SPREAD = {"endo": (-26.9, -26.4), "epi": (-28.5, -28.1)}  # Land et al. 2015, figure 6 (mm)


def solve_at(maxh: float, penalty_weight: float = 0.1) -> dict:
    base = load("left_ventricle", resolution="ci", variant="guccione")
    spec = {**base.mesh_spec, "params": {**base.mesh_spec["params"], "maxh": float(maxh)}}
    scene = dataclasses.replace(base, mesh_spec=spec)
    t0 = time.perf_counter()
    pb = scene.to_problem("P2")
    a = scene.analysis
    res = static_run(pb, "ngsolve", int(a.get("load_steps", 1)), float(a.get("max_load_factor", 1.0)),
                     lambda u, f: scene.evaluate_monitors(pb, u, f), penalty_weight=penalty_weight)
    row = {"maxh_mm": maxh, "tets": pb.mesh.n_cells, "vertices": pb.mesh.n_vertices,
           "dofs": pb.ndof + pb.mesh.n_vertices, "status": res["status"], "seconds": time.perf_counter() - t0}
    if res["status"] == "success":
        last = res["table"][res["table"]["converged"]].iloc[-1]
        row.update(endo_apex_z_mm=float(last["apex_endo_z"]), epi_apex_z_mm=float(last["apex_epi_z"]))
    return row


def _markdown(table: pd.DataFrame) -> str:
    lines = ["# Left ventricle (Land et al. 2015 problem 2), mixed P2-P1: refinement", "",
             "`python examples/lv_mixed_refinement.py` (NGSolve, a tenth of the volumetric penalty kept, as "
             "`tissuebench verify` runs it; 20 load increments; wall time on a 2-core machine, NGSolve's "
             "TaskManager used while a core is idle).", "",
             "| maxh [mm] | tets | dofs (u + p) | endocardial apex z [mm] | epicardial apex z [mm] | inside "
             "| wall [s] |", "|---|---|---|---|---|---|---|"]
    for r in table.itertuples():
        inside = (SPREAD["endo"][0] <= r.endo_apex_z_mm <= SPREAD["endo"][1]
                  and SPREAD["epi"][0] <= r.epi_apex_z_mm <= SPREAD["epi"][1])
        lines.append(f"| {r.maxh_mm:g} | {r.tets} | {r.dofs} | {r.endo_apex_z_mm:.3f} | {r.epi_apex_z_mm:.3f} | "
                     f"{'yes' if inside else 'no'} | {r.seconds:.0f} |")
    lines.append(f"\nPublished spread (Land et al. 2015, 11 codes): endocardium {SPREAD['endo']} mm, "
                 f"epicardium {SPREAD['epi']} mm.")
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--maxh", type=float, nargs="+", default=[2.0, 1.6, 1.3, 1.0, 0.8])
    p.add_argument("--out", type=Path, default=Path("docs/studies"))
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for maxh in args.maxh:
        rows.append(solve_at(maxh))
        print(rows[-1], flush=True)
        table = pd.DataFrame(rows)
        table.to_csv(args.out / "lv_mixed_refinement.csv", index=False)
        (args.out / "lv_mixed_refinement.md").write_text(_markdown(table[table["status"] == "success"]))


if __name__ == "__main__":
    main()
