"""Each material's energy against its closed form, its stress P = dW/dF and tangent A = dP/dF
against central finite differences, and its volumetric part by hand (issue 41).

Deformation gradients: a small batch (2 cells x 2 points) of random F near the identity, det F > 0,
seeded. Finite differences: h = 1e-6, agreement to 1e-6 relative to the largest entry.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from tissuebench.refsolvers import materials as mat
from tissuebench.refsolvers.materials import (Guccione, LinearElastic, MooneyRivlin, NeoHookean, NeoHookeanDecoupled,
                                              SaintVenantKirchhoff, make_material)

I3 = np.eye(3)
RNG = np.random.default_rng(41)
F = I3 + 0.15 * RNG.standard_normal((2, 2, 3, 3))
FIBRES = np.array([[1.0, 2.0, 2.0], [0.0, 3.0, 4.0]])  # one per cell, not unit: normalised by Guccione


def _lame(E, nu):
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def _inv(F):
    C = np.swapaxes(F, -1, -2) @ F
    I1 = np.trace(C, axis1=-2, axis2=-1)
    I2 = 0.5 * (I1 ** 2 - np.trace(C @ C, axis1=-2, axis2=-1))
    return C, I1, I2, np.linalg.det(F)


def _guccione_Q(F, fibres, bf, bt, bfs):
    """Q in the fibre frame (f, s, n): bf E_ff^2 + bt (E_ss^2 + E_nn^2 + 2 E_sn^2) + 2 bfs (E_fs^2 + E_fn^2)."""
    E = 0.5 * (np.swapaxes(F, -1, -2) @ F - I3)
    Q = np.empty(F.shape[:2])
    for c in range(F.shape[0]):
        f = fibres[c] / np.linalg.norm(fibres[c])
        s = np.cross(f, [0.3, -0.5, 0.8])
        s /= np.linalg.norm(s)
        R = np.array([f, s, np.cross(f, s)])
        for q in range(F.shape[1]):
            L = R @ E[c, q] @ R.T
            Q[c, q] = (bf * L[0, 0] ** 2 + bt * (L[1, 1] ** 2 + L[2, 2] ** 2 + 2 * L[1, 2] ** 2)
                       + 2 * bfs * (L[0, 1] ** 2 + L[0, 2] ** 2))
    return Q


CASES = {
    "linear": (LinearElastic(E=3.0, nu=0.3), lambda F: (
        lambda lam, mu, eps: 0.5 * lam * np.trace(eps, axis1=-2, axis2=-1) ** 2 + mu * np.sum(eps * eps, (-2, -1)))(
        *_lame(3.0, 0.3), 0.5 * (F + np.swapaxes(F, -1, -2)) - I3)),
    "svk": (SaintVenantKirchhoff(E=3.0, nu=0.3), lambda F: (
        lambda lam, mu, E: 0.5 * lam * np.trace(E, axis1=-2, axis2=-1) ** 2 + mu * np.sum(E * E, (-2, -1)))(
        *_lame(3.0, 0.3), 0.5 * (np.swapaxes(F, -1, -2) @ F - I3))),
    "neo_hookean": (NeoHookean(E=3.0, nu=0.3), lambda F: (
        lambda lam, mu, C, I1, I2, J: 0.5 * mu * (I1 - 3) - mu * np.log(J) + 0.5 * lam * np.log(J) ** 2)(
        *_lame(3.0, 0.3), *_inv(F))),
    "neo_hookean_decoupled": (NeoHookeanDecoupled(E=3.0, nu=0.3), lambda F: (
        lambda mu, k, C, I1, I2, J: 0.5 * mu * (J ** (-2 / 3) * I1 - 3) + 0.25 * k * (J ** 2 - 1 - 2 * np.log(J)))(
        _lame(3.0, 0.3)[1], 3.0 / (3 * (1 - 0.6)), *_inv(F))),
    "mooney_rivlin": (MooneyRivlin(mu1=1.5, mu2=0.7, kappa=20.0), lambda F: (
        lambda C, I1, I2, J: 0.75 * (J ** (-2 / 3) * I1 - 3) + 0.35 * (J ** (-4 / 3) * I2 - 3) + 10.0 * (J - 1) ** 2)(
        *_inv(F))),
    "guccione": (Guccione(C=2.0, bf=8.0, bt=2.0, bfs=4.0, kappa=30.0, fibres=FIBRES), lambda F: (
        1.0 * (np.exp(_guccione_Q(F, FIBRES, 8.0, 2.0, 4.0)) - 1) + 15.0 * (np.linalg.det(F) - 1) ** 2)),
}


def _fd(fun, F, h=1e-6):
    """d fun / dF by central differences: shape fun(F).shape + (3, 3)."""
    out = None
    for k in range(3):
        for L in range(3):
            dF = np.zeros_like(F)
            dF[..., k, L] = h
            d = (fun(F + dF) - fun(F - dF)) / (2 * h)
            if out is None:
                out = np.zeros(d.shape + (3, 3))
            out[..., k, L] = d
    return out


def _close(a, b, rtol=1e-6):
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(np.abs(b).max(), 1e-300))


@pytest.mark.parametrize("name", CASES)
def test_energy_against_its_closed_form(name):
    m, closed = CASES[name]
    np.testing.assert_allclose(m.energy(F), closed(F), rtol=1e-12, atol=1e-14)
    assert m.name == name and isinstance(make_material(name, **_params(m)), type(m))


@pytest.mark.parametrize("name", CASES)
def test_stress_is_the_derivative_of_the_energy(name):
    m, _ = CASES[name]
    P = m.stress(F)
    _close(P, _fd(m.energy, F))
    W, P2 = m.energy_and_stress(F)
    np.testing.assert_allclose(W, m.energy(F), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(P2, P, rtol=1e-10, atol=1e-12)
    if name != "linear":
        S, none = m.pk2(F, tangent=False)
        assert none is None
        np.testing.assert_allclose(F @ S, P, rtol=1e-12, atol=1e-13)
        np.testing.assert_allclose(S, np.swapaxes(S, -1, -2), atol=1e-12)  # S is symmetric


@pytest.mark.parametrize("name", CASES)
def test_tangent_is_the_derivative_of_the_stress(name):
    m, _ = CASES[name]
    P, A = m.stress_and_tangent(F)
    np.testing.assert_allclose(P, m.stress(F), rtol=1e-12, atol=1e-13)
    assert A.shape == F.shape[:2] + (3, 3, 3, 3)
    _close(A, _fd(m.stress, F))
    np.testing.assert_allclose(A, np.einsum("...iJkL->...kLiJ", A), atol=1e-9 * np.abs(A).max())  # major symmetry


@pytest.mark.parametrize("name", ["neo_hookean", "neo_hookean_decoupled", "mooney_rivlin", "guccione"])
def test_stress_free_at_the_identity(name):
    m, _ = CASES[name]
    Fi = np.broadcast_to(I3, (2, 1, 3, 3)).copy()
    np.testing.assert_allclose(m.stress(Fi), 0.0, atol=1e-13)
    np.testing.assert_allclose(m.energy(Fi), 0.0, atol=1e-13)


def test_small_strain_limit_of_the_linear_tangent():
    # A of linear elasticity: lam d_ij d_kl + mu (d_ik d_jl + d_il d_jk)
    lam, mu = _lame(3.0, 0.3)
    _, A = LinearElastic(E=3.0, nu=0.3).stress_and_tangent(F)
    expected = lam * np.einsum("ij,kl->ijkl", I3, I3) + mu * (np.einsum("ik,jl->ijkl", I3, I3)
                                                              + np.einsum("il,jk->ijkl", I3, I3))
    np.testing.assert_allclose(A[1, 0], expected, rtol=1e-14)
    assert LinearElastic(E=3.0, nu=0.3).is_linear is True and NeoHookean(E=3.0, nu=0.3).is_linear is False


def test_lame_and_bulk_moduli_by_hand():
    lam, mu = LinearElastic(E=2.6, nu=0.3).lame
    assert lam == pytest.approx(2.6 * 0.3 / (1.3 * 0.4)) and mu == pytest.approx(1.0)
    assert NeoHookeanDecoupled(E=2.6, nu=0.3).bulk_modulus == pytest.approx(2.6 / 1.2)


@pytest.mark.parametrize("m, U", [
    (NeoHookean(E=3.0, nu=0.3), lambda J: 0.5 * _lame(3.0, 0.3)[0] * np.log(J) ** 2),
    (NeoHookeanDecoupled(E=3.0, nu=0.3), lambda J: 0.25 * 2.5 * (J ** 2 - 1 - 2 * np.log(J))),
    (MooneyRivlin(mu1=1.5, mu2=0.7, kappa=20.0), lambda J: 10.0 * (J - 1) ** 2),
    (Guccione(C=2.0, bf=8.0, bt=2.0, bfs=4.0, kappa=30.0), lambda J: 15.0 * (J - 1) ** 2),
])
def test_volumetric_part_and_its_derivatives(m, U):
    J = np.array([0.7, 1.0, 1.3])
    u, du, ddu = m.volumetric(J)
    h = 1e-5
    np.testing.assert_allclose(u, U(J), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(du, (U(J + h) - U(J - h)) / (2 * h), rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(ddu, (U(J + h) - 2 * U(J) + U(J - h)) / h ** 2, rtol=1e-5, atol=1e-5)
    assert np.shape(ddu) == J.shape


def test_no_volumetric_part_for_small_strain_models():
    with pytest.raises(TypeError, match=r"^material 'svk' has no volumetric part for an incompressible formulation$"):
        SaintVenantKirchhoff(E=1.0, nu=0.3).volumetric(np.ones(2))


def test_guccione_one_fibre_for_every_cell_and_per_cell_checks():
    one = Guccione(C=2.0, bf=8.0, bt=2.0, bfs=4.0, kappa=30.0, fibres=[0.0, 0.0, 2.0])
    np.testing.assert_allclose(one.fibres, [0.0, 0.0, 1.0])
    np.testing.assert_allclose(one.energy(F), 1.0 * (np.exp(_guccione_Q(F, np.array([[0, 0, 1.0]] * 2), 8.0, 2.0,
                                                                        4.0)) - 1)
                               + 15.0 * (np.linalg.det(F) - 1) ** 2, rtol=1e-12)
    one.validate_for_mesh(7)
    g = CASES["guccione"][0]
    g.validate_for_mesh(2)
    with pytest.raises(ValueError, match=r"^fibres has 2 rows, the mesh has 3 cells$"):
        g.validate_for_mesh(3)
    assert Guccione(C=1.0, bf=1.0, bt=1.0, bfs=1.0, kappa=1.0).fibres.tolist() == [1.0, 0.0, 0.0]


@pytest.mark.parametrize("fibres, message", [
    ([1.0, 0.0], r"fibres must be finite with shape \(3,\) or \(n_cells, 3\), got \(2,\)"),
    (np.ones((2, 2, 3)), r"fibres must be finite with shape \(3,\) or \(n_cells, 3\), got \(2, 2, 3\)"),
    ([1.0, np.nan, 0.0], r"fibres must be finite with shape \(3,\) or \(n_cells, 3\), got \(3,\)"),
    ([[1.0, 0.0, 0.0], [0.0, 0.0, 1e-13]], r"fibres contains a zero vector"),
])
def test_guccione_refuses_bad_fibres(fibres, message):
    with pytest.raises(ValueError, match="^" + message + "$"):
        Guccione(C=1.0, bf=1.0, bt=1.0, bfs=1.0, kappa=1.0, fibres=fibres)


@pytest.mark.parametrize("make, message", [
    (lambda: NeoHookean(E=0.0, nu=0.3), "E must be a finite number > 0, got 0.0"),
    (lambda: NeoHookean(E=math.inf, nu=0.3), "E must be a finite number > 0, got inf"),
    (lambda: NeoHookean(E="1", nu=0.3), "E must be a finite number > 0, got '1'"),
    (lambda: NeoHookean(E=1.0, nu=0.5), "nu must lie in (-1, 0.5), got 0.5"),
    (lambda: NeoHookean(E=1.0, nu=-1.0), "nu must lie in (-1, 0.5), got -1.0"),
    (lambda: NeoHookean(E=1.0, nu=math.nan), "nu must lie in (-1, 0.5), got nan"),
    (lambda: NeoHookean(E=1.0, nu="0.3"), "nu must lie in (-1, 0.5), got '0.3'"),
    (lambda: MooneyRivlin(mu1=0.0, mu2=0.0, kappa=1.0), "mu1 must be a finite number > 0, got 0.0"),
    (lambda: MooneyRivlin(mu1=1.0, mu2=-1e-9, kappa=1.0), "mu2 must be a finite number >= 0, got -1e-09"),
    (lambda: MooneyRivlin(mu1=1.0, mu2=math.inf, kappa=1.0), "mu2 must be a finite number >= 0, got inf"),
    (lambda: MooneyRivlin(mu1=1.0, mu2=0.0, kappa=-1.0), "kappa must be a finite number > 0, got -1.0"),
    (lambda: Guccione(C=1.0, bf=1.0, bt=1.0, bfs=0.0, kappa=1.0), "bfs must be a finite number > 0, got 0.0"),
    (lambda: make_material("rubber"), "unknown material 'rubber'; valid: ['guccione', 'linear', 'mooney_rivlin', "
                                      "'neo_hookean', 'neo_hookean_decoupled', 'svk']"),
    (lambda: make_material("svk", E=1.0), "material 'svk': "),
])
def test_parameters_refused_by_name(make, message):
    with pytest.raises(ValueError) as exc:
        make()
    assert str(exc.value).startswith(message) and (message.endswith(": ") or str(exc.value) == message)


def test_limits_of_the_parameters_are_accepted():
    assert NeoHookean(E=1e-300, nu=-0.999).lame[1] > 0 and NeoHookean(E=1, nu=0.499).nu == 0.499
    assert MooneyRivlin(mu1=1.0, mu2=0.0, kappa=1.0).mu2 == 0.0
    assert make_material(SaintVenantKirchhoff, E=1.0, nu=0.0).lame == (0.0, 0.5)
    assert NeoHookean(E=np.float64(2.0), nu=np.float32(0.25)).E == 2.0 and NeoHookean(E=np.int64(2), nu=0).E == 2


def test_the_explicit_determinant_and_symmetric_inverse():
    C = np.swapaxes(F, -1, -2) @ F
    det = mat._det3(F)
    np.testing.assert_allclose(det, np.linalg.det(F), rtol=1e-13)
    np.testing.assert_allclose(mat._inv_sym3(C, np.linalg.det(C)), np.linalg.inv(C), rtol=1e-12, atol=1e-13)


def _params(m):
    return {k: getattr(m, k) for k in m.__dataclass_fields__}
