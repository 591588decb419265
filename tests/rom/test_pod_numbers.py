"""POD (:func:`tissuebench.rom.pod.pod_basis`) on snapshot matrices built from a known SVD: the
modes, singular values, eigenvalues (s**2, no 1/P), energy captured, rank and the energy
criterion at its boundary on both sides, with and without an inner product (issue 41)."""
from __future__ import annotations

import re

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.rom.pod import pod_basis

RNG = np.random.default_rng(7)
N_DOF = 12
U_TRUE, _ = np.linalg.qr(RNG.standard_normal((N_DOF, 4)))
V_TRUE, _ = np.linalg.qr(RNG.standard_normal((5, 4)))
S_TRUE = np.array([4.0, 2.0, 1.0, 0.5])  # energies 16, 4, 1, 0.25 of 21.25
SNAP = U_TRUE @ np.diag(S_TRUE) @ V_TRUE.T  # (12, 5), rank 4
CUM = np.cumsum(S_TRUE ** 2) / np.sum(S_TRUE ** 2)


def _same_span(A, B):
    """Columns equal up to sign."""
    signs = np.sign(np.sum(A * B, axis=0))
    np.testing.assert_allclose(A * signs, B, atol=1e-12)


def test_modes_singular_values_and_eigenvalues_by_construction():
    b = pod_basis(SNAP, n_modes=3)
    _same_span(b.modes, U_TRUE[:, :3])
    np.testing.assert_allclose(b.singular_values[:4], S_TRUE, rtol=1e-13)
    assert b.singular_values.shape == (5,) and b.singular_values[4] < 1e-14
    np.testing.assert_allclose(b.eigenvalues[:4], S_TRUE ** 2, rtol=1e-13)  # no 1/P factor
    assert b.energy_captured == pytest.approx(CUM[2], rel=1e-14) and b.n_modes == 3
    assert (b.rank, b.rank_deficient) == (4, False)
    assert b.message == f"3 modes requested, capturing {CUM[2]:.6g} of the energy (rank 4)"
    assert b.modes.flags["C_CONTIGUOUS"]


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_the_energy_criterion_at_its_boundary(n):
    # exactly the energy of n modes: n; a hair more: n + 1 (at most the rank)
    at = pod_basis(SNAP, energy=float(CUM[n - 1]))
    assert at.n_modes == n and at.energy_captured == pytest.approx(CUM[n - 1])
    assert at.message == f"{n} modes capture {CUM[n - 1]:.6g} of the energy (criterion {CUM[n - 1]:g}; rank 4)"
    if n < 4:
        assert pod_basis(SNAP, energy=float(CUM[n - 1]) * (1 + 1e-9)).n_modes == n + 1
    assert pod_basis(SNAP, energy=float(CUM[n - 1]) * (1 - 1e-9)).n_modes == n


def test_energy_one_keeps_the_rank_not_the_numerical_noise():
    b = pod_basis(SNAP, energy=1.0)
    assert b.n_modes == 4 and b.rank == 4 and b.energy_captured == pytest.approx(1.0)
    assert pod_basis(SNAP).n_modes == 4  # the default 0.999 > CUM[2] = 0.988


def test_more_modes_than_the_rank_are_reported_not_raised():
    b = pod_basis(SNAP, n_modes=5)
    assert (b.n_modes, b.rank, b.rank_deficient) == (4, 4, True)
    assert b.message == "rank 4 < requested 5 modes: 4 returned"
    assert pod_basis(SNAP, n_modes=4).rank_deficient is False
    assert pod_basis(SNAP, n_modes=4.0).n_modes == 4


def test_rank_at_its_relative_tolerance():
    S = U_TRUE @ np.diag([1.0, 1e-6, 0.0, 0.0]) @ V_TRUE.T
    assert pod_basis(S, n_modes=2).rank == 2
    assert pod_basis(S, n_modes=2, rtol_rank=1e-6 * (1 + 1e-9)).rank == 1  # s <= rtol * s0: zero
    assert pod_basis(S, n_modes=2, rtol_rank=1e-6 * (1 - 1e-6)).rank == 2


def test_a_mass_inner_product_by_hand():
    # W = diag(w): W-orthonormal modes are D^{-1/2} times the Euclidean modes of D^{1/2} S
    w = np.linspace(1.0, 3.0, N_DOF)
    ref = pod_basis(np.sqrt(w)[:, None] * SNAP, n_modes=3)
    for W in (np.diag(w), sp.diags(w).tocsr()):
        b = pod_basis(SNAP, n_modes=3, inner=W)
        np.testing.assert_allclose(b.singular_values[:4], ref.singular_values[:4], rtol=1e-12)
        _same_span(b.modes, ref.modes / np.sqrt(w)[:, None])
        np.testing.assert_allclose(b.modes.T @ (w[:, None] * b.modes), np.eye(3), atol=1e-12)
        assert b.energy_captured == pytest.approx(ref.energy_captured, rel=1e-13)


def test_a_non_symmetric_round_off_in_the_gram_matrix_is_symmetrised():
    w = np.linspace(1.0, 3.0, N_DOF)
    W = np.diag(w)
    W[0, 1] += 1e-13  # not exactly symmetric
    b = pod_basis(SNAP, n_modes=2, inner=W)
    np.testing.assert_allclose(b.modes.T @ (np.diag(w) @ b.modes), np.eye(2), atol=1e-11)


@pytest.mark.parametrize("kwargs, message", [
    ({"snapshots": np.zeros((0, 3))}, "pod_basis: snapshots must be a non-empty finite (n_dof, n_snap) array "
                                      "(shape (0, 3))"),
    ({"snapshots": np.ones(4)}, "pod_basis: snapshots must be a non-empty finite (n_dof, n_snap) array (shape (4,))"),
    ({"snapshots": np.array([[1.0, np.inf]])}, "pod_basis: snapshots must be a non-empty finite (n_dof, n_snap) "
                                               "array (shape (1, 2))"),
    ({"snapshots": np.zeros((3, 2))}, "pod_basis: every snapshot is zero; no basis can be extracted"),
    ({"energy": 0.0}, "pod_basis: energy must lie in (0, 1], got 0.0"),
    ({"energy": 1.0 + 1e-12}, "pod_basis: energy must lie in (0, 1], got 1.000000000001"),
    ({"n_modes": 0}, "pod_basis: n_modes must be a positive integer, got 0"),
    ({"n_modes": 1.5}, "pod_basis: n_modes must be a positive integer, got 1.5"),
    ({"inner": np.eye(3)}, "pod_basis: inner has shape (3, 3), expected (12, 12)"),
    ({"inner": -np.eye(N_DOF)}, "pod_basis: inner is not positive definite on the span of the snapshots"),
])
def test_bad_input_is_refused_with_its_value(kwargs, message):
    args = {"snapshots": SNAP, **kwargs}
    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        pod_basis(args.pop("snapshots"), **args)


def test_n_modes_one_is_accepted():
    b = pod_basis(SNAP, n_modes=1)
    assert b.n_modes == 1 and b.energy_captured == pytest.approx(CUM[0])
