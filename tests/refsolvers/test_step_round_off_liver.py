"""The step Newton's round-off floor on the case that showed it (issue 54): the neo-Hookean liver in motion
at load_scale 1e-6 failed its first step on a24e7fa, "modified Newton did not converge in 25 iterations
(||r|| = 9.567e-14 N, tolerance 9.500e-18 N)": its residual cannot go below round-off (~1e-13 N, the
statics' floor eps x the force of a unit strain is 3.2e-13 N here), which the tolerance now honours."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tissuebench.cases import load
from tissuebench.refsolvers.dynamics import integrate
from tissuebench.reference.runner import dynamics_system


@pytest.fixture(scope="module")
def liver():
    """The scene at load_scale 1e-6 over two steps of 5 ms, and its system."""
    scene = load("liver_dynamic", variant="neo_hookean").at({"load_scale": 1e-6, "t_end": 0.01})
    return scene, dynamics_system(scene)


def _run(scene, system, t_end):
    a = scene.analysis
    return integrate(system, None, None, a["dt"], t_end, method=a["integrator"], **a["integrator_options"])


def test_a_small_load_converges_at_the_round_off_floor(liver):
    scene, system = liver
    assert scene.analysis["dt"] == 0.005 and 1e-13 < system.round_off_floor < 1e-12
    res = _run(scene, system, 0.01)
    assert res.success, res.message
    assert list(res.newton_iterations) == [0, 1, 1]
    # a strain far above double precision: the small-strain response, 1e-6 x the load's, is resolved
    assert 1e-10 < np.abs(res.u).max() < 1e-8


def test_a_load_below_round_off_is_refused_saying_so(liver):
    """The other side: 1e-12 x the load (forces ~1e-13 N, under the floor) cannot be resolved in float64."""
    scene, system = liver
    smaller = dataclasses.replace(system, load=lambda t, u: 1e-6 * system.load(t, u))
    res = _run(scene, smaller, 0.005)
    assert res.status == "newton_failed" and res.rejected_step == 1
    assert "the step's forces are below round-off" in res.message and "round-off floor 3.2" in res.message
