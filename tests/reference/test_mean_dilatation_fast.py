"""The mean-dilatation correction's fast path (issue 54, item 1): the same numbers as the formulas.

:class:`~tissuebench.refsolvers.mean_dilatation.MeanDilatationBackend` evaluates its correction
with batched matrix products on operands laid out once and adds its cell tangents straight into
the Q1 backend's ``K.data`` (with einsum it cost 0.6 to 1.7 times Q1's own assembly). Checked here
against a cell-by-cell, point-by-point evaluation of the energy's first and second derivatives
written from the module's formulas (test-only, slow), on a distorted mesh, to 1e-12 relative; the
finite-difference check of the tangent is
``tests/reference/test_hex_locking.py::test_force_and_tangent_are_the_energys_derivatives``."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from tissuebench.cases.meshes import box_mesh
from tissuebench.refsolvers.backends import make_backend
from tissuebench.refsolvers.materials import LinearElastic, SaintVenantKirchhoff
from tissuebench.refsolvers.mean_dilatation import MeanDilatationBackend, hex_gradients
from tissuebench.refsolvers.problem import Dirichlet, Problem

MATERIALS = [LinearElastic(2.0, 0.48), SaintVenantKirchhoff(2.0, 0.48)]


def _problem(material, seed=5):
    mesh = box_mesh((1.0, 1.5, 2.0), (2, 3, 2), "hexahedron", jitter=0.25, seed=seed)
    return Problem(mesh, material, "Q1", dirichlet=[Dirichlet(lambda x: np.abs(x[:, 2]) < 1e-9)])


def _slow_correction(pb, u):
    """Energies (e,), forces (e, 24), tangents (e, 24, 24) of the correction
    ``kappa/2 (V theta_mean^2 - sum_q dV_q theta_q^2)``, one cell and one point at a time: theta_q,
    its gradient d_q and Hessian h_q, then the energy's derivatives by the product rule (the mean's
    square and the points' squares, not the variance form the backend uses)."""
    grad, dx = hex_gradients(pb.mesh.points, pb.mesh.cells, pb.quadrature_order)
    lam, mu = pb.material.lame
    k, svk = lam + 2.0 * mu / 3.0, isinstance(pb.material, SaintVenantKirchhoff)
    W, f, K = [], [], []
    for c, cell in enumerate(pb.mesh.cells):
        ue = u.reshape(-1, 3)[cell]  # (8, 3)
        V = dx[c].sum()
        theta, d, h = [], [], []
        for q in range(dx.shape[1]):
            G = grad[c, q]  # (8, 3): dN_a / dX_J
            H = ue.T @ G  # H_iJ = sum_a u_ai dN_a/dX_J
            F = np.eye(3) + H if svk else np.eye(3)
            theta.append(np.trace(H) + (0.5 * np.sum(H * H) if svk else 0.0))
            d.append((G @ F.T).ravel())  # d theta / d u_ai = sum_J F_iJ dN_a/dX_J, dofs (a, i)
            h.append(np.kron(G @ G.T, np.eye(3)) if svk else np.zeros((24, 24)))
        theta, d, h, w = np.array(theta), np.array(d), np.array(h), dx[c]
        mean, d_mean, h_mean = w @ theta / V, w @ d / V, np.einsum("q,qkl->kl", w, h) / V
        W.append(0.5 * k * (V * mean**2 - w @ theta**2))
        f.append(k * (V * mean * d_mean - (w * theta) @ d))
        K.append(k * (V * (np.outer(d_mean, d_mean) + mean * h_mean)
                      - sum(w[q] * (np.outer(d[q], d[q]) + theta[q] * h[q]) for q in range(len(w)))))
    return np.array(W), np.array(f), np.array(K)


def _assemble(pb, fe, Ke):
    dofs = (3 * pb.mesh.cells[:, :, None] + np.arange(3)).reshape(len(pb.mesh.cells), 24)
    f, K = np.zeros(pb.ndof), np.zeros((pb.ndof, pb.ndof))
    for c, dof in enumerate(dofs):
        f[dof] += fe[c]
        K[np.ix_(dof, dof)] += Ke[c]
    return f, K


def _close(actual, expected, rtol=1e-12):
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert np.abs(actual - expected).max() <= rtol * np.abs(expected).max()


@pytest.mark.parametrize("material", MATERIALS, ids=["linear", "svk"])
def test_the_fast_correction_is_the_formulas(material):
    """Cell by cell (all cells and a subset, as a hyper-reduction's kernel asks) and assembled
    (force, tangent, both from one pass), on a distorted mesh at strains of a few percent."""
    pb = _problem(material)
    q1 = make_backend("skfem", pb)
    md = MeanDilatationBackend(pb, q1)
    u = 0.05 * np.random.default_rng(7).normal(size=pb.ndof)
    W, fe, Ke = _slow_correction(pb, u)
    energy, force, tangent = md.cell_correction(u, tangent=True)
    _close(energy, W)
    _close(force, fe)
    _close(tangent, Ke)
    some = np.array([4, 0, 4])
    _, force_some, tangent_some = md.cell_correction(u[md.dofs[some]], tangent=True, cells=some, local=True)
    _close(force_some, fe[some])
    _close(tangent_some, Ke[some])
    f_corr, K_corr = _assemble(pb, fe, Ke)
    _close(md.internal_force(u) - q1.internal_force(u), f_corr)
    _close((md.tangent(u) - q1.tangent(u)).toarray(), K_corr)
    f, K = md.internal_force_and_tangent(u)
    _close(f - q1.internal_force(u), f_corr)
    _close((K - q1.tangent(u)).toarray(), K_corr)
    assert md.strain_energy(u) - q1.strain_energy(u) == pytest.approx(W.sum(), rel=1e-12)


def test_the_cell_tangents_go_into_the_backends_pattern_without_a_second_matrix(monkeypatch):
    """Where Q1's K holds every entry of the cells' blocks (its own pattern, or one with more
    entries), the correction is added into a copy of ``K.data`` on K's pattern and no sparse matrix
    of the cells is assembled; where K lacks some (a diagonal), the two are summed."""
    pb = _problem(SaintVenantKirchhoff(2.0, 0.48))
    q1 = make_backend("skfem", pb)
    md = MeanDilatationBackend(pb, q1)
    u = 0.05 * np.random.default_rng(8).normal(size=pb.ndof)
    _, fe, Ke = _slow_correction(pb, u)
    K_corr = _assemble(pb, fe, Ke)[1]
    K_q1 = q1.tangent(u)
    wider = sp.csr_matrix(K_q1 + sp.csr_matrix(([1.0], ([0], [pb.ndof - 1])), shape=K_q1.shape))  # off the cells'
    assert wider.nnz == K_q1.nnz + 1
    pattern = md.pattern
    assembled = []
    monkeypatch.setattr(pattern, "assemble", lambda Ke: assembled.append(1) or type(pattern).assemble(pattern, Ke))
    for K_base in (K_q1, wider):
        monkeypatch.setattr(q1, "tangent", lambda u, K_base=K_base: K_base)
        K = md.tangent(u)
        assert not assembled
        assert K.nnz == K_base.nnz and np.array_equal(K.indices, K_base.indices)
        _close((K - K_base).toarray(), K_corr)
    diagonal = sp.diags(K_q1.diagonal()).tocsr()
    monkeypatch.setattr(q1, "tangent", lambda u: diagonal)
    K = md.tangent(u)
    assert assembled == [1]
    _close((K - diagonal).toarray(), K_corr)
