"""Can the training span the held-out motion? Singular values and projection errors (issue 42).

For the neo-Hookean liver in motion (``liver_dynamic``, variant ``neo_hookean``, ci) and the
held-out run at 0.75 of the scene's amplitude (the ``pod_galerkin_liver`` preset's evaluation),
per training (the scene's run alone; the scene's run and one at half its amplitude, the preset's)
and per snapshot set (displacements; displacements and velocities scaled to the same norm, the
``velocities`` option of ``pod_galerkin``): the leading singular values of the snapshots and the
peak-normalised error of the projection of the held-out trajectory on the first r modes,
``max_k |u_k - V V^T u_k| / max_k |u_k|`` (what no Galerkin model on that basis can beat).
The reference runs come from the cache (``$TISSUEBENCH_CACHE``), computed when missing::

    .venv/bin/python docs/studies/pod_galerkin_span.py
"""
from __future__ import annotations

import numpy as np
from threadpoolctl import threadpool_limits

from tissuebench.rom.galerkin.basis import snapshot_basis
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.evaluation import build_evaluation
from tissuebench.studies.training import build_training, case_scene

TRAININGS = {"amplitude 1": [], "amplitudes 1 and 0.5": [{"load_scale": 0.5}]}
MODES = (10, 20, 30, 40)


def main():
    with threadpool_limits(1):
        for label, runs in TRAININGS.items():
            case = CaseEntry(id="liver-nh", name="liver_dynamic", variant="neo_hookean",
                             training={"kind": "trajectory", "runs": runs},
                             evaluation={"kind": "trajectory", "load_scale": 0.75})
            scene = case_scene(case)
            training = build_training(case, scene)
            held = np.array([p.reference for p in build_evaluation(case, scene).points[1:]])
            free = np.asarray(training.system.free)
            H = held[:, free].T
            peak = np.linalg.norm(held, axis=1).max()
            for velocities in (False, True):
                options = {"n_modes": max(MODES), "energy": 1.0, "inner": "euclidean", "velocities": velocities}
                pod, _, info = snapshot_basis(training, free, options)
                s = pod.singular_values
                ratios = np.round(s[[0, 5, 10, 20, 30, 40]] / s[0], 6).tolist()
                errors = []
                for r in MODES:
                    V = pod.modes[:, :r]
                    errors.append(np.linalg.norm(H - V @ (V.T @ H), axis=0).max() / peak)
                print(f"training {label} ({info['snapshots']} states), velocities {velocities}: singular values "
                      f"s_r / s_0 at r = 0, 5, 10, 20, 30, 40: {ratios}")
                print("  held-out projection error (peak-normalised) with " +
                      ", ".join(f"{r} modes {e:.2e}" for r, e in zip(MODES, errors)))


if __name__ == "__main__":
    main()
