"""Step latency of ``pod_galerkin`` on the neo-Hookean liver, in wall and CPU time (issue 42).

The sweep's latency protocol times wall-clock steps (``haptic_p99_s``); on a machine shared with
other work the wall time of a sub-millisecond step measures the scheduler more than the step.
This times the same steps both ways: the ``pod_galerkin_liver`` preset's case (trained on the
scene's run and one at half its amplitude, driven through the held-out run at 0.75), each
option set built once and stepped through the run ``--passes`` times (the first pass warms up),
one BLAS thread. Per option set: the held-out peak-normalised error, the median and p99 of the
step (``step`` + ``outputs``) in wall and CPU time, Newton iterations per step and the
elements the force is summed over. The references come from the cache::

    .venv/bin/python docs/studies/pod_galerkin_latency.py
"""
from __future__ import annotations

import argparse
import time

import numpy as np
from threadpoolctl import threadpool_limits

from tissuebench.rom import make_method
from tissuebench.studies.case_entry import CaseEntry
from tissuebench.studies.evaluation import build_evaluation
from tissuebench.studies.training import build_training, case_scene

OPTIONS = [{"n_modes": 20, "hyper": "ecsw"}, {"n_modes": 25, "hyper": "ecsw", "ecsw_tol": 0.002},
           {"n_modes": 30, "hyper": "ecsw", "ecsw_tol": 0.002}]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--passes", type=int, default=3)
    args = parser.parse_args(argv)
    case = CaseEntry(id="liver-nh", name="liver_dynamic", variant="neo_hookean",
                     training={"kind": "trajectory", "runs": [{"load_scale": 0.5}]},
                     evaluation={"kind": "trajectory", "load_scale": 0.75})
    with threadpool_limits(1):
        scene = case_scene(case)
        training, evaluation = build_training(case, scene), build_evaluation(case, scene)
        R = np.array([p.reference for p in evaluation.points[1:]])
        peak = np.linalg.norm(R, axis=1).max()
        print("| options | elements | peak_rel_l2 | wall median / p99 [ms] | CPU median / p99 [ms] | iterations |")
        print("|---|---|---|---|---|---|")
        for options in OPTIONS:
            model = make_method("pod_galerkin", **options).build(training)
            model.attach_outputs(training.outputs)
            for _ in range(args.passes):
                model.start(evaluation.points[0].mu, evaluation.state0, evaluation.dt)
                wall, cpu, U, its = [], [], [], []
                for p in evaluation.points[1:]:
                    t0, c0 = time.perf_counter(), time.process_time()
                    res = model.step(p.mu)
                    model.outputs(res)
                    wall.append(time.perf_counter() - t0)
                    cpu.append(time.process_time() - c0)
                    U.append(model.reconstruct(res))
                    its.append(res.info["iterations"])
            err = np.linalg.norm(np.array(U) - R, axis=1).max() / peak
            w, c = np.array(wall) * 1e3, np.array(cpu) * 1e3
            print(f"| {options} | {model.info['hyper']['elements']} | {err:.4f} | {np.median(w):.3f} / "
                  f"{np.percentile(w, 99):.3f} | {np.median(c):.3f} / {np.percentile(c, 99):.3f} | "
                  f"{np.mean(its):.2f} |")


if __name__ == "__main__":
    main()
