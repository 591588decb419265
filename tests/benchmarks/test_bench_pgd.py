"""Haptic step of the PGD cutting model (cornea_cut, ci resolution; the paper-resolution
figures come from ``tissuebench sweep --preset pgd_cutting --resolution paper``, which also
times the full FE step of each cut and draws the step time per cut length).

Timed with pytest-benchmark (``pytest -n 0 tests/benchmarks/test_bench_pgd.py --benchmark-enable``);
the plain test run executes each once, untimed. Target (issue 12, at paper resolution):
step + outputs median <= 0.2 ms, p99 <= 1 ms, including the enrichment after a cut.
"""
import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.rom import make_method
from tissuebench.rom.pgd import pgd_training

pytestmark = pytest.mark.benchmark


@pytest.fixture(scope="module", params=["srb", "prb"])
def model(request):
    tr = pgd_training(load("cornea_cut"))
    return make_method("pgd_cutting", n_modes=6, projection=request.param, radii=[1.5, 5.2]).build(tr)


def test_haptic_step(benchmark, model):
    """Step + outputs at the crack tip of the longest cut (enrichment already built)."""
    c = model.strip.max_cut_length
    mu = {"node": model.strip.tip(c), "cut_length": c}
    model.step(mu)

    def haptic():
        return model.outputs(model.step(mu))

    out = benchmark(haptic)
    assert np.isfinite(out["contact_uz"]) and out["contact_uz"] < 0


def test_haptic_step_with_enrichment(benchmark, model):
    """The step that enriches: the intact state, then the longest cut at once."""
    c = model.strip.max_cut_length
    mu = {"node": model.strip.tip(c), "cut_length": c}

    def enrich():
        model.start()
        return model.step(mu)

    res = benchmark(enrich)
    assert res.status == "ok" and len(res.q) == model.r + 3 * int(model.strip.n_enriched[c])
