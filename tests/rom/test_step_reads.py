"""A model refuses a parameter it does not read (issue 44): through the Python API,
``model.step({"load_factor": 0.3, "E": 6000})`` returned status ok and the state at 0.3, and so
did ``nu``, ``load_scale``, ``position`` and a misspelt key. Every model a method builds now
refuses them at ``start(mu0)`` and at the first step after the build or a ``start()`` given no
``mu0``, naming the key, the method and the keys it reads (``tissuebench.rom.reads``, installed by
the contract for every method); every other step is the model's own, unwrapped (the haptic path
pays nothing)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from tissuebench.rom import make_method
from tissuebench.testing.cases import contract_case

UNREAD = {"E": 6000.0, "nu": 0.3, "load_scale": 0.5, "position": 0.2, "bogus": 1.0}
#: (method, options, contract case, a step's parameters the model reads)
MODELS = [("pod_linear", {"n_modes": 3}, "path", {"load_factor": 0.3}),
          ("anm_pod", {"n_modes": 3, "order": 3}, "path", {"load_factor": 0.3}),
          ("nearest", {}, "path", {"load_factor": 0.3}),
          ("pod_interp", {"n_modes": 3}, "path", {"load_factor": 0.3}),
          ("linear_fe", {}, "path", {"load_factor": 0.3}),
          ("nearest", {}, "positions", {"position": 0.5, "load_factor": 0.5}),
          ("pgd", {"n_modes": 5}, "operators", {"position": 0.5})]


def _model(name, options, case):
    training = contract_case(case).training
    return make_method(name, **options).build(training)


@pytest.mark.parametrize("name, options, case, mu", MODELS, ids=[f"{m[0]}-{m[2]}" for m in MODELS])
@pytest.mark.parametrize("key", list(UNREAD))
def test_the_first_step_refuses_a_parameter_the_model_does_not_read(name, options, case, mu, key):
    if key in mu:
        pytest.skip(f"{name} trained on {case} reads {key}")
    model = _model(name, options, case)
    reads = sorted(set(mu) | {"load_factor"})
    with pytest.raises(ValueError, match=rf"{name}\.step: mu\['{key}'\] = .*a parameter this model does not read: "
                                         rf"method '{name}' reads .*{re.escape(repr(reads)[1:-1])}"):
        model.step({**mu, key: UNREAD[key]})
    assert model.step(dict(mu)).status == "ok"  # what it reads, it still answers


def test_start_refuses_it_and_a_start_without_parameters_checks_the_first_step():
    model = _model("pod_linear", {"n_modes": 3}, "path")
    with pytest.raises(ValueError, match=r"pod_linear\.start: mu\['E'\] = 6000.0"):
        model.start({"load_factor": 0.3, "E": 6000.0})
    model.start({"load_factor": 0.3})
    first = model.step({"load_factor": 0.3})
    with pytest.raises(ValueError, match=r"pod_linear\.step: mu\['E'\]"):  # a new run, unannounced: checked
        model.start()
        model.step({"load_factor": 0.3, "E": 6000.0})
    np.testing.assert_array_equal(model.step({"load_factor": 0.3}).q, first.q)


def test_no_step_of_a_run_started_with_its_parameters_is_wrapped():
    """After the first step of the model, and from a start given ``mu0`` (the harness's), ``model.step``
    is the class's own method: nothing added to the haptic path the latency protocol times."""
    model = _model("pod_linear", {"n_modes": 3}, "path")
    model.step({"load_factor": 0.3})
    for _ in range(2):
        model.start({"load_factor": 0.3})
        assert model.step.__func__ is type(model).step and "step" not in vars(model)
        model.step({"load_factor": 0.3})


def test_a_sliced_variant_reads_what_its_parent_reads():
    parent = _model("anm_pod", {"n_modes": 3, "order": 3}, "path")
    sliced = parent.variant(n_modes=2)
    with pytest.raises(ValueError, match=r"anm_pod\.step: mu\['nu'\]"):
        sliced.step({"load_factor": 0.3, "nu": 0.3})
    assert sliced.step({"load_factor": 0.3}).status == "ok"


def test_a_trajectory_model_reads_the_time_a_static_one_does_not():
    traj = contract_case("trajectory")
    model = make_method("linear_fe").build(traj.training)
    with pytest.raises(ValueError, match=r"linear_fe\.start: mu\['E'\]"):
        model.start({"time": 0.0, "load_factor": 0.0, "E": 1.0}, None, traj.training.dt)
    static = _model("pod_linear", {"n_modes": 3}, "path")
    with pytest.raises(ValueError, match=r"mu\['time'\]"):
        static.step({"time": 0.1, "load_factor": 0.3})


def test_a_first_step_that_raises_leaves_the_next_one_checked():
    model = _model("pod_linear", {"n_modes": 3}, "path")
    with pytest.raises(ValueError, match="is not a finite number"):
        model.step({"load_factor": float("nan")})
    with pytest.raises(ValueError, match=r"mu\['E'\]"):
        model.step({"load_factor": 0.3, "E": 6000.0})
