"""A step that returns NaN or inf is a failed step, not an "ok" one with an infinite error (issue 50,
item 2): the harness's evaluation pass (tissuebench/studies/protocol.py ``drive``) checks the state
``q``, the reconstructed field and the outputs of every step, for every method, shipped or plugin,
and records a step with a non-finite one as failed, saying which; the unit counts it with its
failed steps (``n_failed``), says it in its row's message, and the sweep's summary counts it."""
from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from tissuebench.rom.base import StepResult
from tissuebench.studies.evaluation import Evaluation, EvaluationPoint
from tissuebench.studies.metrics import point_rows, summarise_points
from tissuebench.studies.protocol import NON_FINITE, drive, non_finite_note


class _Scripted:
    """A map model of one dof answering the script ``answers[k]`` = (q, status, field, output) at step k
    (``field``/``output`` None: q itself)."""

    def __init__(self, answers):
        self.answers, self.k, self.reconstructed = answers, 0, 0

    def start(self, mu, state0=None, dt=None):
        self.k = 0

    def step(self, mu):
        q, status, self._field, self._output = self.answers[self.k]
        self.k += 1
        message = "outside the training range" if status == "extrapolation" else ""
        return StepResult(None if q is None else np.array([q]), status, message, mu=mu)

    def outputs(self, res):
        if res.q is None:
            return {"tip": math.nan}
        return {"tip": float(res.q[0]) if self._output is None else self._output}

    def reconstruct(self, res):
        self.reconstructed += 1
        return np.array([float(res.q[0]), 0.0]) if self._field is None else np.array(self._field, float)


def _path(n):
    points = [EvaluationPoint({"load_factor": 0.1 * (k + 1)}, np.array([0.1 * (k + 1), 0.0]),
                              {"tip": 0.1 * (k + 1)}, 0.1 * (k + 1)) for k in range(n)]
    return Evaluation("path", "load_factor", points)


def _statuses(driven):
    return [r.status for r in driven.results]


def test_a_finite_step_keeps_its_status_and_values():
    """The boundary's finite side: ok and extrapolation (a shipped method's legitimate flags) stay."""
    model = _Scripted([(0.1, "ok", None, None), (0.2, "extrapolation", None, None)])
    driven = drive(model, _path(2))
    assert _statuses(driven) == ["ok", "extrapolation"]
    assert driven.results[1].message == "outside the training range"
    assert [float(f[0]) for f in driven.fields] == [0.1, 0.2] and driven.outputs == [{"tip": 0.1}, {"tip": 0.2}]
    assert non_finite_note(driven) == ""


@pytest.mark.parametrize("answer, said", [
    ((math.nan, "ok", None, None), "(q has 1 NaN)"),
    ((math.inf, "ok", None, None), "(q has 1 inf)"),
    ((0.1, "ok", [0.1, math.nan], None), "(the reconstructed field has 1 NaN)"),
    ((0.1, "ok", [-math.inf, math.nan], None), "(the reconstructed field has 1 NaN and 1 inf)"),
    ((0.1, "ok", None, math.nan), "(output 'tip' has 1 NaN)"),
    ((math.nan, "extrapolation", None, None), "(q has 1 NaN); the model said extrapolation: outside the training"),
])
def test_a_non_finite_state_field_or_output_is_a_failed_step_saying_which(answer, said):
    model = _Scripted([(0.1, "ok", None, None), answer, (0.3, "ok", None, None)])
    driven = drive(model, _path(3))
    assert _statuses(driven) == ["ok", "failed", "ok"]  # the steps after it still run
    bad = driven.results[1]
    assert bad.q is None and bad.message.startswith(f"{NON_FINITE} {said}"), bad.message
    assert bad.mu == {"load_factor": 0.2}
    assert driven.fields[1] is None and math.isnan(driven.outputs[1]["tip"])  # nothing of the step is kept
    assert non_finite_note(driven) == f"1 of 3 evaluation steps failed: {bad.message}"


def test_the_unit_counts_the_non_finite_steps_as_failed_and_its_error_is_inf():
    """What the store gets (metrics.point_rows, summarise_points): the NaN steps in n_failed, none ok."""
    evaluation = _path(3)
    model = _Scripted([(math.nan, "ok", None, None), (0.2, "ok", None, None), (math.nan, "ok", None, None)])
    driven = drive(model, evaluation)
    points = pd.DataFrame(point_rows(evaluation, driven))
    row = summarise_points(points, pd.DataFrame(columns=["rel_error"]), evaluation, driven.fields)
    assert (row["n_ok"], row["n_failed"]) == (1, 2) and row["max_rel_l2"] == math.inf
    assert points.loc[0, "message"].startswith(NON_FINITE)
    # the state is checked before the model reconstructs it: no field is built from a NaN state
    assert model.reconstructed == 1


class _Trajectory:
    """A one-dof trajectory model: q = step count, NaN from step ``nan_at`` on."""

    def __init__(self, nan_at):
        self.nan_at, self.k, self.steps = nan_at, 0, 0

    def start(self, mu, state0=None, dt=None):
        self.k = 0

    def step(self, mu):
        self.k += 1
        self.steps += 1
        return StepResult(np.array([math.nan if self.k >= self.nan_at else float(self.k)]))

    def outputs(self, res):
        return {}

    def reconstruct(self, res):
        return np.asarray(res.q, float)


def test_a_nan_between_stored_trajectory_steps_ends_the_trajectory_as_a_failure_does():
    stride, dt, n = 4, 0.1, 5
    points = [EvaluationPoint({"time": k * stride * dt}, np.array([k * stride]), {}, k * stride * dt)
              for k in range(n + 1)]
    evaluation = Evaluation("trajectory", "time", points, dt=dt, state0={"u": np.zeros(1)},
                            info={"t_end": n * stride * dt})
    model = _Trajectory(nan_at=6)
    driven = drive(model, evaluation, history=lambda t: 1.0)
    assert model.steps == 6  # stopped at the first NaN (step 6 lies between the stored steps 4 and 8)
    assert [None if r is None else r.status for r in driven.results] == [None, "ok", "failed", None, None, None]
    assert driven.results[2].message == f"{NON_FINITE} (q has 1 NaN)" and driven.fields[2] is None
    assert driven.results[2].mu["time"] == pytest.approx(0.6)
