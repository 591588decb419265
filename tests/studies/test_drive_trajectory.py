"""The harness's trajectory pass (tissuebench/studies/protocol.py ``drive``): which steps are
recorded, and that a failure between two stored reference steps is not lost."""
from __future__ import annotations

import numpy as np

from tissuebench.rom.base import StepResult
from tissuebench.studies.evaluation import Evaluation, EvaluationPoint
from tissuebench.studies.protocol import drive


class _Counter:
    """A one-dof model: q = step count; fails at step ``fail_at``."""

    def __init__(self, fail_at=None):
        self.fail_at, self.k, self.steps = fail_at, 0, []

    def start(self, mu, state0=None, dt=None):
        self.k = 0

    def step(self, mu):
        self.k += 1
        self.steps.append(mu["time"])
        if self.k == self.fail_at:
            return StepResult(None, "failed", f"step {self.k}: Newton diverged")
        return StepResult(np.array([float(self.k)]))

    def outputs(self, res):
        return {}

    def reconstruct(self, res):
        return np.asarray(res.q, float)


def _evaluation(stride=4, n=5, dt=0.1):
    points = [EvaluationPoint({"time": k * stride * dt}, np.array([k * stride]), {}, k * stride * dt)
              for k in range(n + 1)]
    return Evaluation("trajectory", "time", points, dt=dt, state0={"u": np.zeros(1)},
                      info={"t_end": n * stride * dt})


def test_drive_steps_every_time_step_and_records_the_stored_ones():
    model = _Counter()
    driven = drive(model, _evaluation(), history=lambda t: 1.0)
    assert len(model.steps) == 20
    assert [None if r is None else float(r.q[0]) for r in driven.results] == [None, 4.0, 8.0, 12.0, 16.0, 20.0]


def test_a_failure_between_stored_steps_is_carried_by_the_next_stored_point():
    model = _Counter(fail_at=6)
    driven = drive(model, _evaluation(), history=lambda t: 1.0)
    assert len(model.steps) == 6  # stopped at the failure
    statuses = [None if r is None else r.status for r in driven.results]
    assert statuses == [None, "ok", "failed", None, None, None]
    assert "step 6" in driven.results[2].message and driven.fields[2] is None
