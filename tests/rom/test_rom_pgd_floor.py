"""The rank floor of a point-load family (``rom/pgd/floor.py``): the Eckart-Young bound that
no space of N modes beats, and the PGD vademecum against it (cornea_cut's anterior surface,
57 parameter nodes at ci; heat1d_source's interval)."""
from __future__ import annotations

import numpy as np
import pytest

from tissuebench.cases.scene import load
from tissuebench.refsolvers.sparse_direct import factorized
from tissuebench.rom import make_method
from tissuebench.rom.pgd import pgd_training
from tissuebench.rom.pgd.floor import rank_floor


@pytest.fixture(scope="module")
def cornea(cornea_cut_pgd):
    family = make_method("pgd", n_modes=1).build(cornea_cut_pgd).vademecum.family
    U = factorized(family.K)(family.loads.toarray())
    return cornea_cut_pgd, family, U


def _rms_rel(U, V):
    """RMS over the columns of the relative error of their l2 projection on span(V)."""
    Q, _ = np.linalg.qr(V)
    e = np.linalg.norm(U - Q @ (Q.T @ U), axis=0) / np.linalg.norm(U, axis=0)
    return float(np.sqrt(np.mean(e ** 2)))


@pytest.mark.parametrize("n", [1, 3, 8, 20])
def test_no_space_of_n_modes_beats_the_floor(cornea, n):
    _, family, U = cornea
    floor = rank_floor(family, n)
    assert floor["n_parameters"] == 57 and floor["n_zero_responses"] == 0
    rng = np.random.default_rng(n)
    Un = U / np.linalg.norm(U, axis=0)
    spaces = [rng.standard_normal((U.shape[0], n)) for _ in range(5)]  # random spaces
    spaces += [Un[:, rng.choice(57, n, replace=False)] for _ in range(5)]  # n of the responses themselves
    for V in spaces:
        assert _rms_rel(U, V) >= floor["rms_rel_l2"] * (1 - 1e-12)
    assert floor["max_rel_l2_svd"] >= floor["rms_rel_l2"]


def test_the_floor_falls_with_the_modes_to_zero_at_the_parameter_count(cornea):
    _, family, _ = cornea
    floors = [rank_floor(family, n)["rms_rel_l2"] for n in (1, 2, 4, 8, 16, 32, 57)]
    assert np.all(np.diff(floors) < 0)
    assert floors[0] > 0.8 and floors[-1] < 1e-12  # one mode cannot follow a load that moves


@pytest.mark.parametrize("n", [2, 4, 8, 12])
def test_the_pgd_vademecum_is_near_the_floor(cornea, n):
    """srb on the vademecum's N modes, at every parameter node, against the exact response:
    at or above the floor (a bound), and within 35 % of it (PGD's modes are the optimal ones
    of the weighted energy norm, not of this Euclidean one)."""
    training, family, U = cornea
    model = make_method("pgd", n_modes=n).build(training)
    e = []
    for j in range(family.n_parameters):
        u = model.reconstruct(model.step({"position": j}))[family.free_dofs]
        e.append(np.linalg.norm(u - U[:, j]) / np.linalg.norm(U[:, j]))
    rms = float(np.sqrt(np.mean(np.square(e))))
    floor = model.info["rank_floor"]
    assert floor["n_modes"] == n
    assert floor["rms_rel_l2"] <= rms <= 1.35 * floor["rms_rel_l2"]


def test_boundary_parameter_nodes_and_large_families():
    training = pgd_training(load("heat1d_source"))
    family = make_method("pgd", n_modes=1).build(training).vademecum.family
    floor = rank_floor(family, 3)
    assert floor["n_zero_responses"] == 2  # the two clamped ends: a load there moves nothing
    assert floor["n_parameters"] == family.n_parameters - 2
    assert rank_floor(family, floor["n_parameters"])["rms_rel_l2"] < 1e-12
    skipped = rank_floor(family, 3, max_parameters=10)
    assert "max_parameters = 10" in skipped["skipped"] and "rms_rel_l2" not in skipped
    with pytest.raises(ValueError, match="n_modes"):
        rank_floor(family, 0)


def _path_floor_example():
    import importlib.util
    import sys
    from pathlib import Path

    name = "pgd_cut_path_floor"
    if name not in sys.modules:
        path = Path(__file__).resolve().parents[2] / "examples" / f"{name}.py"
        spec = importlib.util.spec_from_file_location(name, path)
        sys.modules[name] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(sys.modules[name])
    return sys.modules[name]


def test_the_scalpel_path_floor_bounds_the_cracking_node_model():
    """examples/pgd_cut_path_floor.py at ci (2 cut lengths): zero from 2 modes (two fields),
    and the cracking-node model of 1 mode, srb or prb, is not below its 1-mode floor on the
    preset's own evaluation (the bound holds whatever the basis)."""
    from tissuebench.studies.evaluation import build_evaluation
    from tissuebench.studies.spec import expand_units, load_spec
    from tissuebench.studies.training import build_training, case_scene

    out = _path_floor_example().main(["--resolution", "ci", "--modes", "1,2"])
    assert out["n_cut_lengths"] == 2 and 0 < out["delta_max"] < 0.2
    assert out["floors"][1] > 0.3 and out["floors"][2] < 1e-12
    unit = next(u for u in expand_units(load_spec("pgd_cutting", only=["cornea_cut"])) if u.method == "pgd_cutting")
    scene = case_scene(unit.case)
    training = build_training(unit.case, scene)
    for projection in ("srb", "prb"):
        model = make_method("pgd_cutting", **{**unit.options, "n_modes": 1, "projection": projection}).build(training)
        points = build_evaluation(unit.case, scene, model).points
        e = [np.linalg.norm(model.reconstruct(model.step(p.mu)) - p.reference) / np.linalg.norm(p.reference)
             for p in points]
        assert np.sqrt(np.mean(np.square(e))) >= out["floors"][1], projection
