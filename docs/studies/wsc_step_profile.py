"""Where the wsc online step's time goes, at paper resolution (issue 31).

    PYTHONPATH=$PWD python docs/studies/wsc_step_profile.py 364 2820 [bgbc|rbf] [option=value ...]

Builds the ROM on the paper cube (``cube_tension_twist/tension_dynamic``, 7744 vertices /
37 800 tets), runs the pull with one BLAS thread (as the harness does) and, after 20 warm-up
steps, times every step and its parts over 150 steps: the cubature evaluation (blending the
handles' maps onto the sample nodes, the element kernel, projecting the forces), the product
with the reduced mass, the step-matrix solve, and the rest (L-BFGS vector work, Python).
Prints per-step medians / means and the counts per step, then a cProfile of 40 more steps.
"""
from __future__ import annotations

import cProfile
import io
import os
import pstats
import sys
import time
from collections import defaultdict

import numpy as np
from threadpoolctl import threadpool_limits

from tissuebench.cases import load
from tissuebench.refsolvers.backends import make_backend
from tissuebench.rom import Training, make_method


def _timed(fn, name, acc):
    def wrapper(*a, **k):
        t0 = time.perf_counter()
        out = fn(*a, **k)
        acc[name].append(time.perf_counter() - t0)
        return out
    return wrapper


class _TimedMatrix:
    """The reduced mass with its products timed (the stepper calls ``.dot`` and ``@``)."""

    def __init__(self, A, acc):
        self.A, self.acc = A, acc
        self.dot = _timed(A.dot, "mass product", acc)

    def __matmul__(self, x):
        return self.dot(x)

    def __getattr__(self, name):
        return getattr(self.A, name)


def main(handles, elements, cubature="bgbc", *options):
    opts = dict(handles=int(handles), cubature_elements=int(elements), cubature=cubature, rtol=1e-3)
    for o in options:
        k, v = o.split("=")
        opts[k] = v
    scene = load("cube_tension_twist", resolution="paper", variant="tension_dynamic")
    be = make_backend("skfem", scene.to_problem())
    dt = float(scene.analysis["dt"])
    model = make_method("wsc", **opts).build(Training(backend=be, dt=dt))
    st = model.stepper
    print(f"{opts}: n_z {model.info['n_z']}, step matrix {model.info.get('step_matrix')}, load {os.getloadavg()}")
    acc = defaultdict(list)
    with threadpool_limits(1):
        model.start()
        k = 0

        def step():
            nonlocal k
            k = k + 1 if k < 200 else 1
            if k == 1:
                model.start()
            return model.step({"time": k * dt, "load_factor": float(scene.history(k * dt))})

        for _ in range(20):
            step()
        f = st.forces
        f.local = _timed(f.local, "blend (local)", acc)
        f.kernel.energies_and_forces = _timed(f.kernel.energies_and_forces, "element kernel", acc)
        f.project = _timed(f.project, "project forces", acc)
        st.H.solve = _timed(st.H.solve, "step-matrix solve", acc)
        st.M_z = _TimedMatrix(st.M_z, acc)
        steps, evals = [], []
        for _ in range(150):
            t0 = time.perf_counter()
            r = step()
            steps.append(time.perf_counter() - t0)
            evals.append(r.info["evaluations"])
        n = len(steps)
        print(f"step: median {1e3 * np.median(steps):.2f} ms, mean {1e3 * np.mean(steps):.2f} ms, "
              f"p99 {1e3 * np.percentile(steps, 99):.2f} ms; evaluations per step {np.mean(evals):.2f}")
        parts = 0.0
        for name in ("blend (local)", "element kernel", "project forces", "mass product", "step-matrix solve"):
            t = np.array(acc[name])
            per = t.sum() / n
            parts += per
            print(f"  {name:18s} {1e3 * per:7.2f} ms per step  ({len(t) / n:.2f} calls, "
                  f"{1e3 * np.median(t):.3f} ms each)")
        print(f"  {'rest':18s} {1e3 * (np.mean(steps) - parts):7.2f} ms per step (L-BFGS vector work, Python)")
        st.M_z = st.M_z.A  # the restart at the end of the pull needs the matrix itself
        prof = cProfile.Profile()
        prof.enable()
        for _ in range(40):
            step()
        prof.disable()
    s = io.StringIO()
    pstats.Stats(prof, stream=s).sort_stats("tottime").print_stats(12)
    print(s.getvalue())


if __name__ == "__main__":
    main(*sys.argv[1:])
