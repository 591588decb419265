"""The latency protocol and the error metrics of the studies."""
import numpy as np
import pytest

from tissuebench.rom import OnlineModel, StepResult
from tissuebench.studies.timing import latency_stats, max_displacement, relative_l2, time_online_steps


def test_latency_stats_are_median_and_tail():
    s = latency_stats(np.r_[np.full(99, 1e-3), 1.0])
    assert s.median == 1e-3 and s.max == 1.0 and s.n == 100
    assert 1e-3 <= s.p99 <= 1.0
    with pytest.raises(ValueError):
        latency_stats([])


class Counting(OnlineModel):
    name = "counting"

    def __init__(self):
        self.calls = 0

    @property
    def n_reduced(self):
        return 2

    def step(self, mu):
        self.calls += 1
        return StepResult(np.array([mu["load_factor"], 0.0]))

    def reconstruct(self, result):
        return np.repeat(result.q, 3)


def test_time_online_steps_times_each_call_and_returns_results():
    m = Counting()
    mus = [{"load_factor": x} for x in np.linspace(0, 1, 11)]
    step, both, res = time_online_steps(m, mus, warmup=5, repeats=2)
    assert m.calls == 5 + 22 and step.n == 22 and both.n == 22
    assert both.median >= step.median * 0.5
    assert [r.q[0] for r in res] == [mu["load_factor"] for mu in mus]


def test_metrics():
    u_ref = np.array([3.0, 4.0, 0.0, 0.0, 0.0, 0.0])
    assert relative_l2(u_ref * 1.01, u_ref) == pytest.approx(0.01)
    assert max_displacement(u_ref) == pytest.approx(5.0)
    with pytest.raises(ValueError, match="shapes differ"):
        relative_l2(u_ref[:3], u_ref)
