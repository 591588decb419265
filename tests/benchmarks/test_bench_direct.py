"""Haptic step of the PGD-POD direct integrator and our full HHT step on the same system.

Timed with pytest-benchmark (``pytest -n 0 tests/benchmarks/test_bench_direct.py --benchmark-enable``);
the plain test run executes each once, untimed. Targets (issue 14): step + outputs median
<= 0.1 ms and p99 <= 0.5 ms on every scene; the speed-up is the ratio to the HHT step
(the direct_* presets report both measured in one run, with p99: ``tissuebench sweep --preset
direct_liver_dynamic``).
"""
import numpy as np
import pytest

from tissuebench.refsolvers.dynamics import make_integrator
from tissuebench.rom import make_method
from tissuebench.studies.trajectories import scene_system, trajectory_training

pytestmark = pytest.mark.benchmark


@pytest.fixture(scope="module", params=[("central_difference", 8), ("bathe", 8), ("hht", 3)])
def wave_model(request):
    integ, m = request.param
    tr = trajectory_training("wave_block")
    return make_method("pgd_direct", pod_modes=m, integrator=integ).build(tr), tr


def test_haptic_step_wave_block(benchmark, wave_model):
    model, tr = wave_model
    model.start({"time": 0.0, "load_factor": 1.0}, None, tr.dt)
    mu = {"time": tr.dt, "load_factor": 1.0}

    def haptic():
        return model.outputs(model.step(mu))

    out = benchmark(haptic)
    assert np.isfinite(out["top_uz"])


def test_full_hht_step_wave_block(benchmark):
    ss = scene_system("wave_block")
    integ = make_integrator("hht", alpha=-0.05).start(ss.system, None, None, 0.00125)
    rep = benchmark(integ.step)
    assert rep.converged
