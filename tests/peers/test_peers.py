"""The field's libraries as tissuebench methods (issue 51, ``peers/``): each adapter keeps the method
contract (``tissuebench.testing``'s battery, on a small built-in case), registers through its
distribution's entry points under its class's name, says when its library is missing, and runs the
library's own algorithm where the pair with ours must agree (EZyRB's RBF is SciPy's, as ``pod_interp``'s).

The adapters are imported from ``peers/src`` when the distribution is not installed; each is skipped,
saying why, when its library is not (``pip install -e peers/``; EZyRB: ``pip install -e "peers/[ezyrb]"``).
"""
from __future__ import annotations

import importlib.metadata
import importlib.util
import os
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from _plugin_dist import Installed
from tissuebench.rom import METHODS, make_method
from tissuebench.testing import check_method, parametrize_with_checks
from tissuebench.testing.cases import contract_case

PEERS = Path(__file__).resolve().parents[2] / "peers"
_SOURCE = None if importlib.util.find_spec("tissuebench_peers") else str(PEERS / "src")
if _SOURCE:  # the repository's copy, not installed: imported from there, then off the path again (the
    sys.path.insert(0, _SOURCE)  # other tests of this process read the installed distributions on it)

from tissuebench_peers.ezyrb_interp import Ezyrb  # noqa: E402
from tissuebench_peers.opinf_model import OpInf  # noqa: E402
from tissuebench_peers.pymor_galerkin import PymorGalerkin  # noqa: E402
from tissuebench_peers.romtools_ecsw import RomtoolsEcsw  # noqa: E402

if _SOURCE:
    sys.path.remove(_SOURCE)

ADAPTERS = {PymorGalerkin: "pymor", RomtoolsEcsw: "romtools", OpInf: "opinf", Ezyrb: "ezyrb"}
ENTRY_POINTS = tomllib.loads((PEERS / "pyproject.toml").read_text())["project"]["entry-points"]["tissuebench.methods"]


@pytest.fixture(autouse=True)
def _registry(tmp_path, monkeypatch):
    """The methods a test registers (a spec naming "module:Class") leave the registry after it: the
    plugin tests count the methods of other packages."""
    installed = Installed(tmp_path / "site", monkeypatch)
    yield
    installed.undo()


def _installed() -> bool:
    try:
        importlib.metadata.distribution("tissuebench-peers")
    except importlib.metadata.PackageNotFoundError:
        return False
    return True


def _preset(folder, monkeypatch, **protocol):
    """The peers preset written to ``folder``: its scene files' paths absolute, its methods named by
    their "module:Class" where the distribution is not installed (CI installs the libraries only: the
    plugin tests count the installed methods of other packages), ``protocol`` over every unit's."""
    from _fuzz import dumps
    from tissuebench.studies.spec import PRESETS_DIR

    doc = tomllib.loads((PRESETS_DIR / "peers.toml").read_text())
    for c in doc["case"]:
        if c["name"].endswith(".toml"):
            c["name"] = str(PRESETS_DIR / c["name"])
    if not _installed():
        source = str(PEERS / "src")
        monkeypatch.syspath_prepend(source)  # and for every process the sweep starts:
        monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, (source, os.environ.get("PYTHONPATH")))))
        for m in doc["method"]:
            m["name"] = ENTRY_POINTS.get(m["name"], m["name"])
    if protocol:
        doc["protocol"] = protocol
        for m in doc["method"]:
            m.pop("protocol", None)
    path = folder / "peers.toml"
    path.write_text(dumps(doc))
    return path


def _needs(cls):
    module = ADAPTERS[cls]
    return pytest.mark.skipif(importlib.util.find_spec(module) is None,
                              reason=f"{module} is not installed (pip install -e peers/, or its extra)")


SMALL = {"n_modes": 3}


_MARKS = {(cls.name, "*"): _needs(cls) for cls in ADAPTERS}
for _cls in (PymorGalerkin, OpInf):  # their parameter contract steps several trajectories: 10-40 s
    if importlib.util.find_spec(ADAPTERS[_cls]) is not None:
        _MARKS[(_cls.name, "parameters_are_honoured")] = pytest.mark.slow


@parametrize_with_checks([(cls, SMALL) for cls in ADAPTERS], marks=_MARKS)
def test_adapter_contract(method, check):
    """Each adapter on the first built-in case it applies to (a trajectory for those that learn one)."""
    check(method)


@parametrize_with_checks([(PymorGalerkin, SMALL)], training="prescribed",
                         marks={(PymorGalerkin.name, "*"): _needs(PymorGalerkin)})
def test_pymor_on_a_static_path_with_a_moving_support(method, check):
    """pyMOR's static path (Newton on the reduced model) on the cube its supports stretch."""
    check(method)


def test_the_entry_points_name_the_classes_by_their_names():
    assert sorted(ENTRY_POINTS) == sorted(cls.name for cls in ADAPTERS)
    for name, target in ENTRY_POINTS.items():
        module, cls = target.split(":")
        assert getattr(importlib.import_module(module), cls).name == name
    if _installed():  # the distribution registers them under these names
        assert {n: METHODS[n].__name__ for n in ENTRY_POINTS} == {n: t.split(":")[1] for n, t in ENTRY_POINTS.items()}


def test_a_missing_library_makes_the_method_apply_nowhere_and_a_spec_skip_it(monkeypatch, tmp_path):
    from tissuebench.cases import load
    from tissuebench.studies.spec import load_spec

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ezyrb" else real(name, *a))
    assert Ezyrb.unavailable() == "needs ezyrb, which is not installed (pip install ezyrb)"
    assert Ezyrb.why_not(load("cornea_pinch")) == Ezyrb.unavailable()
    spec = tmp_path / "spec.toml"
    spec.write_text('[sweep]\nname = "s"\n[[case]]\nname = "cornea_pinch"\ntraining = { kind = "path" }\n'
                    '[[method]]\nname = "tissuebench_peers.ezyrb_interp:Ezyrb"\n[[method]]\nname = "nearest"\n')
    loaded = load_spec(spec)
    assert [m["name"] for m in loaded.methods] == ["nearest"]
    assert loaded.skipped == [{"case": "cornea_pinch", "method": "ezyrb", "options": "",
                               "why": "needs ezyrb, which is not installed (pip install ezyrb)"}]
    spec.write_text('[sweep]\nname = "s"\n[[case]]\nname = "cornea_pinch"\ntraining = { kind = "path" }\n'
                    '[[method]]\nname = "tissuebench_peers.ezyrb_interp:Ezyrb"\n')
    with pytest.raises(ValueError, match=r"method = \['ezyrb'\]: no method of the spec can run here: needs ezyrb"):
        load_spec(spec)
    results = check_method(Ezyrb, raise_on_failure=False)  # nothing to build: skipped, saying why
    assert all(r.status != "failed" for r in results)
    assert "'ezyrb' cannot run here: needs ezyrb" in next(r for r in results
                                                           if r.check == "builds_an_online_model").message
    monkeypatch.undo()
    if importlib.util.find_spec("ezyrb") is not None:
        assert Ezyrb.unavailable() == ""


@_needs(Ezyrb)
def test_ezyrb_rbf_is_pod_interps_rbf():
    """EZyRB's RBF is SciPy's RBFInterpolator on the same POD coefficients: the same step."""
    training = contract_case("path").training
    theirs = Ezyrb(n_modes=3).build(training)
    ours = make_method("pod_interp", n_modes=3, interpolation="rbf").build(training)
    for lam in (0.1, 0.55, 1.0):
        a, b = theirs.step({"load_factor": lam}), ours.step({"load_factor": lam})
        np.testing.assert_allclose(theirs.reconstruct(a), ours.reconstruct(b), rtol=0,
                                   atol=1e-10 * np.abs(training.snapshots).max())
    assert theirs.step({"load_factor": 1.5}).status == "extrapolation"


@_needs(RomtoolsEcsw)
def test_romtools_ecsw_meets_its_tolerance_and_keeps_more_elements_for_a_tighter_one():
    training = contract_case("trajectory").training  # linear: the rule is fitted, the model is exact anyway
    loose, tight = (RomtoolsEcsw(n_modes=4, ecsw_tol=tol).build(training).info["hyper"] for tol in (5e-2, 5e-3))
    for rule in (loose, tight):
        assert rule["solver"] == "romtools ECSWsolverNNLS" and rule["train_residual"] <= rule["tol"]
        assert 0 < rule["elements"] < rule["candidates"] and rule["fit_s"] >= 0
    assert loose["elements"] < tight["elements"]


@_needs(OpInf)
def test_opinf_discrete_steps_only_at_its_snapshot_spacing():
    training = contract_case("trajectory").training
    spacing = float(np.diff(training.parameter_values("time")[:2])[0])
    model = OpInf(n_modes=3, time="discrete").build(training)
    assert model.info["snapshot_spacing_s"] == pytest.approx(spacing) and model.info["time"] == "discrete"
    with pytest.raises(ValueError, match=rf"dt = {spacing / 2!r}: the discrete model steps at the training's "
                                         rf"snapshot spacing"):
        model.start(None, None, spacing / 2)
    model.start(None, None, spacing)
    res = model.step({"time": spacing, "load_factor": float(training.parameter_values("load_factor")[1])})
    assert res.ok and res.q.shape == (6,)


@_needs(PymorGalerkin)
def test_pymor_deim_on_a_static_path_interpolates_the_force_at_reduced_newton_iterates():
    """The force snapshots of a static path are not only its equilibria (a multiple of the load): the
    iterates of pyMOR's reduced Newton solves give DEIM more than one direction."""
    training = contract_case("path").training
    model = PymorGalerkin(n_modes=3).build(training)
    hyper = model.info["hyper"]
    assert hyper["scheme"] == "deim" and model.info["newton_stages"] > 0
    assert hyper["force_snapshots"] == training.snapshots.shape[1] + model.info["newton_stages"]
    assert hyper["interpolation_dofs"] > 1 and hyper["elements"] < training.backend.problem.mesh.n_cells
    model.start()
    for j, lam in enumerate(training.parameter_values("load_factor")):
        res = model.step({"load_factor": lam})
        assert res.ok
        np.testing.assert_allclose(model.reconstruct(res), training.snapshots[:, j], rtol=0,
                                   atol=1e-4 * np.abs(training.snapshots).max())


@pytest.mark.parametrize("resolution", ["ci", "paper"])
def test_the_peers_preset_gives_every_peer_unit_its_counterpart(resolution, tmp_path, monkeypatch):
    from tissuebench.rom import method_class
    from tissuebench.studies.spec import expand_units, load_spec

    # the peers whose library is installed (README's test command installs none of them: `.[test]`;
    # CI's .ci/run installs `.[peers]`, pyMOR, romtools and OpInf): a spec skips the others, saying why
    installed = {cls.name for cls in (PymorGalerkin, RomtoolsEcsw, OpInf) if not cls.unavailable()}
    if not installed:
        pytest.skip("none of pyMOR, romtools, OpInf is installed (pip install -e \".[peers]\")")
    units = expand_units(load_spec(_preset(tmp_path, monkeypatch), resolution=resolution))
    peers = [u for u in units if method_class(u.method).counterpart is not None]
    assert {u.method for u in peers} >= installed
    for u in peers:
        name, wanted = method_class(u.method).counterpart_for(u.case.training_kind)
        mates = [v for v in units if v.case.id == u.case.id and v.method == name
                 and all(v.options.get(k) == val for k, val in wanted.items())]
        assert mates, (u.case.id, u.label)
        if "n_modes" in u.options:  # the same basis size beside it
            assert any(v.options.get("n_modes") == u.options["n_modes"] for v in mates), (u.case.id, u.label)


@pytest.mark.slow
def test_a_small_peers_sweep_reports_its_pairs(tmp_path, monkeypatch):
    """The preset on its two small static cases at ci (the cube its supports stretch, the kidney), every
    unit timed on 20 steps (the preset's protocol only times; issue 29: CI time), then the report: every
    installed peer ran, and each sits beside its counterpart in the peers section."""
    from tissuebench.cli import main
    from tissuebench.studies.results import read_units

    spec = _preset(tmp_path, monkeypatch, latency_steps=20, warmup=2)
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--cases", "cube-tension,kidney", "--out", str(out), "--quiet"]) == 0
    units = read_units(out)
    assert (units["unit_status"] == "ok").all(), units.loc[units["unit_status"] != "ok", "message"].tolist()
    ran = set(units["method"])
    assert {"pymor_galerkin", "pod_newton", "pod_interp"} <= ran
    assert ("ezyrb" in ran) == (importlib.util.find_spec("ezyrb") is not None)
    assert main(["report", str(out)]) == 0
    html = (out / "_report" / "report.html").read_text()
    assert '<h2 id="peers">Peers beside ours</h2>' in html
    pairs = pd.read_csv(out / "_report" / "report_data" / "peers.csv")
    assert set(pairs["case"]) == {"cube-tension", "kidney"} and pairs["verdict"].notna().all()
    pymor = pairs[pairs["peer_method"] == "pymor_galerkin"]
    assert len(pymor) == 6 and (pymor["ours_method"] == "pod_newton").all()
    # pyMOR's projected operator and pod_newton solve the same reduced equations (the same basis where
    # both keep every mode): the same error
    none = pymor[pymor["peer"].str.startswith("pymor_galerkin hyper=none")]
    np.testing.assert_allclose(none["peer_error"], none["ours_error"], rtol=1e-3)


def test_a_trajectory_step_starts_from_the_last_one_and_refuses_another_time():
    """The adapters' shared time check (``_common.step_start``): the next step within 1e-6 dt is
    taken, from ``t - dt`` at the first step; a skipped or repeated step is refused naming it."""
    from tissuebench_peers._common import step_start

    assert step_start("m", 0.1, None, 0.1) == pytest.approx(0.0)
    assert step_start("m", 0.3, 0.2, 0.1) == 0.2
    assert step_start("m", 0.3 + 0.9e-7, 0.2, 0.1) == 0.2
    for t in (0.3 + 1.1e-7, 0.4, 0.2):
        with pytest.raises(ValueError, match=r"m\.step: mu\['time'\] = .* is not the next step 0\.3"):
            step_start("m", t, 0.2, 0.1)


@_needs(RomtoolsEcsw)  # without romtools every scene is refused for that first (a fresh `pip install -e ".[test]"`)
@pytest.mark.parametrize("element, refused", [('element = "P1"\n', False), ("", True)])
def test_romtools_ecsw_is_refused_where_pod_galerkin_is(tmp_path, element, refused, monkeypatch):
    """Its element rule and online model are pod_galerkin's: a reference with average nodal pressure
    tetrahedra (the example dome in motion without element = "P1") has no element split for either."""
    pytest.importorskip("gmsh")
    from tissuebench.cases.scene import load

    folder = PEERS.parent / "examples" / "nearly_incompressible_organ"
    monkeypatch.syspath_prepend(str(folder.parent / "bring_your_own_organ"))  # make_dome.py imports gmsh_body
    spec = importlib.util.spec_from_file_location("make_dome", folder / "make_dome.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.dome_mesh(str(tmp_path / "dome.msh"), 30.0)
    scene = tmp_path / "dome_motion.toml"
    scene.write_text((folder / "dome_motion.toml").read_text().replace('element = "P1"\n', element))
    why = RomtoolsEcsw.why_not(load(scene))
    assert (why != "") == refused and (not refused or "average nodal pressure" in why)
