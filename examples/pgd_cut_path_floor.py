"""The rank floor of the scalpel path of cornea_cut: the least error any N-mode space reaches.

``python examples/pgd_cut_path_floor.py --resolution paper [--modes 1,2,3,4,5,6,8,10]``

The evaluation of the ``pgd_cutting`` preset (the scalpel along incision 0, one cut length
after another, each against the linear FE of the same cut mesh, :mod:`tissuebench.studies.evaluation`)
has one reference field per cut length. The paper's enrichment (cracking-node functions)
adds only jumps on the copies of the cracked nodes: on the original nodes its field lies in
the span of the N PGD modes. So, with ``e_c`` the relative error of cut length ``c`` on the
whole cut mesh and ``delta_c = |u_copies|^2 / |u_original|^2`` of the reference,

    rms_c e_c  >=  floor_N / sqrt(1 + max_c delta_c)

where ``floor_N`` is the Eckart-Young floor of the reference fields on the original nodes
(:func:`tissuebench.rom.pgd.floor.snapshot_floor`): no N-mode basis, however it is built
(even one fitted to this very path), brings the cracking-node model below it. The
``condensed`` enrichment also changes the original nodes and is not bounded by it.
"""
from __future__ import annotations

import argparse

import numpy as np

from tissuebench.rom import make_method
from tissuebench.rom.pgd.floor import snapshot_floor
from tissuebench.studies.evaluation import build_evaluation
from tissuebench.studies.spec import expand_units, load_spec
from tissuebench.studies.training import build_training, case_scene


def path_floor(resolution: str = "ci", modes=(1, 2, 3, 4, 5, 6, 8, 10)) -> dict:
    """``{"n_cut_lengths", "delta_max", "floors": {N: floor on the whole cut mesh}}``."""
    unit = next(u for u in expand_units(load_spec("pgd_cutting", resolution=resolution, only=["cornea_cut"]))
                if u.method == "pgd_cutting")
    scene = case_scene(unit.case)
    model = make_method("pgd_cutting", **{**unit.options, "n_modes": 1}).build(build_training(unit.case, scene))
    points = build_evaluation(unit.case, scene, model).points
    n_orig = model.ndof
    orig = np.column_stack([p.reference[:n_orig] for p in points])
    delta = max(float(np.sum(p.reference[n_orig:] ** 2) / np.sum(p.reference[:n_orig] ** 2)) for p in points)
    return {"n_cut_lengths": len(points), "delta_max": delta,
            "floors": {int(n): snapshot_floor(orig, int(n))["rms_rel_l2"] / np.sqrt(1.0 + delta) for n in modes}}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--resolution", default="ci", choices=["ci", "paper"])
    ap.add_argument("--modes", default="1,2,3,4,5,6,8,10", help="comma-separated mode counts")
    args = ap.parse_args(argv)
    out = path_floor(args.resolution, tuple(int(m) for m in args.modes.split(",")))
    print(f"cornea_cut ({args.resolution}), incision 0: {out['n_cut_lengths']} cut lengths, "
          f"max |u_copies|^2 / |u_original|^2 = {out['delta_max']:.3g}")
    print("modes  floor of the RMS relative error over the path (cracking-node enrichment, any basis)")
    for n, f in out["floors"].items():
        print(f"{n:5d}  {f:.4g}")
    return out


if __name__ == "__main__":
    main()
