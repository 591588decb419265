"""The public contract's element operators (issue 51): ``tissuebench.rom.element_kernel`` (the
internal force and tangent of a set of elements of a training), ``tissuebench.rom.galerkin_model``
(``pod_galerkin``'s online model on another method's basis and element rule) and
``RomMethod.counterpart_for`` (the shipped method a method of another package is measured beside).

A library's adapter (``peers/``) builds on these alone: the kernel's element sums are the backend's
assembled operators; the Galerkin model on ``pod_galerkin``'s own basis and rule is ``pod_galerkin``
to round-off, so a rule of another library is measured with our integrator.
"""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from test_pod_galerkin import DT, T_END, _history, _training

from tissuebench.rom import RomMethod, Training, element_kernel, galerkin_model, make_method
from tissuebench.testing.cases import contract_case


def _assembled(kernel, values, ndof):
    out = np.zeros(ndof)
    np.add.at(out, kernel.dofs.ravel(), values.ravel())
    return out


@pytest.fixture(scope="module")
def bar():
    """The neo-Hookean bar of test_pod_galerkin, bent by its tip load (48 free dofs, milliseconds)."""
    return _training(False, alpha=-0.05)[0]


def test_the_element_sums_are_the_backends_force_and_tangent(bar):
    be = bar.backend
    u = bar.snapshots[:, 25]
    kernel = element_kernel(bar)
    assert kernel.dofs.shape == (be.problem.mesh.n_cells, 12)
    f_e, K_e = kernel.forces_and_tangents(kernel.gather(u))
    f = be.internal_force(u)
    np.testing.assert_allclose(_assembled(kernel, f_e, be.ndof), f, rtol=0, atol=1e-11 * np.abs(f).max())
    K = np.zeros((be.ndof, be.ndof))
    rows = np.repeat(kernel.dofs[:, :, None], 12, axis=2)
    np.add.at(K, (rows.ravel(), np.swapaxes(rows, 1, 2).ravel()), K_e.ravel())
    K_be = be.tangent(u).toarray()
    np.testing.assert_allclose(K, K_be, rtol=0, atol=1e-11 * np.abs(K_be).max())
    energies, forces = kernel.energies_and_forces(kernel.gather(u))
    np.testing.assert_allclose(energies.sum(), be.strain_energy(u), rtol=1e-12)
    np.testing.assert_allclose(forces, f_e, rtol=0, atol=1e-12 * np.abs(f_e).max())


def test_a_subset_keeps_its_order_and_an_index_past_the_mesh_is_refused(bar):
    be, u = bar.backend, bar.snapshots[:, 25]
    n = be.problem.mesh.n_cells
    every = element_kernel(bar)
    cells = np.array([n - 1, 2, n - 1])  # the last cell (twice) and another, in this order
    subset = element_kernel(bar, cells)
    np.testing.assert_array_equal(subset.dofs, be.element_dofs()[cells])
    np.testing.assert_allclose(subset.forces(subset.gather(u)), every.forces(every.gather(u))[cells], rtol=0,
                               atol=1e-14)
    with pytest.raises(ValueError, match=rf"cells: index out of range 0..{n - 1} \(min 2, max {n}\)"):
        element_kernel(bar, [2, n])


def test_a_linear_material_takes_the_backends_own_kernel():
    training = contract_case("trajectory").training  # the linear wave block
    be, u = training.backend, training.snapshots[:, 40]
    kernel = element_kernel(training)
    f = be.internal_force(u)
    np.testing.assert_allclose(_assembled(kernel, kernel.forces(kernel.gather(u)), be.ndof), f, rtol=0,
                               atol=1e-11 * np.abs(f).max())


def test_a_formulation_without_element_quantities_is_refused_naming_it():
    class Anp:  # a backend whose energy does not split into cells (the average nodal pressure tetrahedra)
        problem = SimpleNamespace(mesh=SimpleNamespace(n_cells=3), material=SimpleNamespace(is_linear=False),
                                  free_dofs=np.arange(3))

        def cell_kernel(self, cells):
            raise NotImplementedError("the average nodal pressure force does not split into cell forces")

    with pytest.raises(ValueError, match="the Anp formulation has no element quantities .the average nodal"):
        element_kernel(Training(backend=Anp()))
    with pytest.raises(ValueError, match="element_kernel: the training has no backend"):
        element_kernel(Training())


def _trajectory(model):
    mus = [{"time": float(k * DT), "load_factor": _history(k * DT)} for k in range(1, round(T_END / DT) + 1)]
    results = model.solve(mus, dt=DT)
    assert all(r.ok for r in results), [r.message for r in results if not r.ok][:1]
    return np.array([model.reconstruct(r) for r in results])


@pytest.mark.parametrize("hyper", ["none", "ecsw"])
def test_pod_galerkins_own_basis_and_rule_give_pod_galerkin(bar, hyper):
    """On pod_galerkin's basis and element rule (every element; its ECSW cells and weights) the
    public model is pod_galerkin's, step for step."""
    ours = make_method("pod_galerkin", n_modes=6, hyper=hyper, ecsw_tol=1e-2).build(bar)
    forces = ours.system.forces
    rule = {} if hyper == "none" else {"cells": forces.cells, "weights": forces.weights}
    if hyper == "ecsw":
        assert forces.size < bar.backend.problem.mesh.n_cells  # a real sample
    theirs = galerkin_model(bar, ours.basis, name="peer", **rule)
    assert theirs.name == "peer" and theirs.kind == "trajectory" and theirs.n_reduced == 6
    assert theirs.info["elements_per_evaluation"] == forces.size
    U_ours, U_theirs = _trajectory(ours), _trajectory(theirs)
    assert np.abs(U_ours).max() > 0.1
    np.testing.assert_allclose(U_theirs, U_ours, rtol=0, atol=1e-12 * np.abs(U_ours).max())


def test_the_galerkin_model_refuses_what_it_cannot_build_naming_it(bar):
    n_free = len(bar.system.free)
    V = np.linalg.qr(bar.snapshots[bar.system.free][:, 1:5])[0]
    with pytest.raises(ValueError, match=rf"basis must be a finite \(n_free, r\) array with n_free = {n_free} rows.*"
                                         rf"got shape \({n_free - 1}, 4\)"):
        galerkin_model(bar, V[1:])
    cells = np.arange(3)
    with pytest.raises(ValueError, match=r"weights must be finite, >= 0 and one per cell \(3\), got shape \(3,\), "
                                         r"min -0.1"):
        galerkin_model(bar, V, cells, [1.0, -0.1, 2.0])
    galerkin_model(bar, V, cells, [1.0, 0.0, 2.0])  # a zero weight is a weight
    with pytest.raises(ValueError, match=r"one per cell \(3\), got shape \(2,\)"):
        galerkin_model(bar, V, cells, [1.0, 2.0])
    with pytest.raises(ValueError, match="galerkin_model: rtol must be a finite number > 0, got 0"):
        galerkin_model(bar, V, rtol=0)
    path = contract_case("path").training
    with pytest.raises(ValueError, match="galerkin_model: the training has no system, dt"):
        galerkin_model(path, V)


class _Peer(RomMethod):
    name = "peer_of_test"

    def build(self, training):
        raise NotImplementedError


@pytest.mark.parametrize("declared, kind, expected", [
    (None, "path", None),
    (("pod_galerkin", {"hyper": "ecsw"}), "trajectory", ("pod_galerkin", {"hyper": "ecsw"})),
    (("pod_galerkin", {"hyper": "ecsw"}), None, ("pod_galerkin", {"hyper": "ecsw"})),
    ({"path": ("pod_newton", {}), "trajectory": ("pod_galerkin", {})}, "path", ("pod_newton", {})),
    ({"path": ("pod_newton", {})}, "trajectory", None),
])
def test_counterpart_for_reads_the_declaration(monkeypatch, declared, kind, expected):
    monkeypatch.setattr(_Peer, "counterpart", declared)
    assert _Peer.counterpart_for(kind) == expected
    assert RomMethod.counterpart is None and make_method("pod_galerkin").counterpart_for("trajectory") is None


@pytest.mark.parametrize("declared", [("pod_galerkin",), ("", {}), ("pod_galerkin", "hyper=ecsw"),
                                      ["pod_galerkin", {}], {"path": "pod_newton"}])
def test_a_malformed_counterpart_is_refused_naming_the_class(monkeypatch, declared):
    monkeypatch.setattr(_Peer, "counterpart", declared)
    with pytest.raises(ValueError, match=r"_Peer.counterpart = .*: expected \(method name, options dict\)"):
        _Peer.counterpart_for("path")


class _Recorded(RomMethod):
    """A method of another package whose build returns a model with an ``info`` dict."""

    name = "recorded_of_test"
    counterpart = {"path": ("pod_newton", {"n_modes": 3})}

    def build(self, training):
        from tissuebench.rom import LinearReconstruction, OnlineModel

        class Model(LinearReconstruction, OnlineModel):
            n_reduced = 1

            def __init__(self):
                self.name, self.info = "recorded_of_test", {"n_modes": 1}

            def step(self, mu):
                raise NotImplementedError
        return Model()


@pytest.mark.parametrize("kind, expected", [("path", ["pod_newton", {"n_modes": 3}]), ("trajectory", None)])
def test_a_build_records_the_counterpart_its_class_declares_for_the_training_kind(kind, expected):
    """A sweep stores the model's info: a report pairs the unit from the store where the class is gone."""
    info = _Recorded().build(Training(info={"training_kind": kind})).info
    assert info.get("counterpart") == expected and info["n_modes"] == 1
    assert "counterpart" not in make_method("pod_galerkin", n_modes=6).build(_training(False, alpha=-0.05)[0]).info
