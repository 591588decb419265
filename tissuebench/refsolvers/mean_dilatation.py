"""Trilinear hexahedra that do not lock: the mean-dilatation (B-bar) formulation.

Trilinear hexahedra (Q1) integrated with 2x2x2 Gauss points impose the volume constraint of a
nearly incompressible solid at each of the 8 points of every cell, about 8 constraints for 3
unknowns per node, and the mesh answers too stiff: the catalogue's ci cornea (SVK, nu = 0.48)
moves 37 % less under its pinch with Q1 than without locking. The mean-dilatation element
(Nagtegaal, Parks & Rice 1974; Hughes 1980, "Generalization of selective integration procedures
to anisotropic and nonlinear media", IJNME 15, 1413-1418: the B-bar method) keeps Q1's shape
part at the Gauss points and takes the volumetric part on the cell mean of the dilatation: one
constraint per cell, which does not lock.

With the split of the isotropic laws into shape and volume, ``W = mu |dev e|^2 + kappa/2 (tr e)^2``
(``kappa = lambda + 2 mu / 3``, ``e`` the small strain of the linear material or the
Green-Lagrange strain E of Saint Venant-Kirchhoff), the energy is

    Pi(u) = sum_e sum_q dV_q [W(e_q) - kappa/2 theta_q^2] + sum_e kappa/2 V_e theta_e^2,
    theta_q = tr e_q,   theta_e = sum_q dV_q theta_q / V_e,

the Q1 energy of the backend plus a correction per cell ``kappa/2 (V_e theta_e^2 - sum_q dV_q
theta_q^2)`` (never positive: the mean's square is below the mean of the squares). For the
linear material ``theta = div u`` and this is Hughes' B-bar; for SVK ``theta = tr E =
div u + |grad u|^2 / 2``, the B-bar of the total Lagrangian form, so the energy stays a
polynomial of degree 4 (a cubic force, as the ANM and PGD methods of the cornea's papers need).
The force and the tangent are its exact first and second derivatives (symmetric). Q1 and this
element agree on every homogeneous deformation (theta_q = theta_e) and converge to the same
solution as the mesh is refined.

:class:`MeanDilatationBackend` wraps a Q1 displacement backend (scikit-fem or NGSolve): its
force and tangent are the backend's plus the correction, computed here from the cell geometry
with NumPy on the problem's own quadrature rule (:mod:`.quadrature`, which both backends use),
so the backends agree to round-off. Mass, loads and the linear solvers are the backend's. The
correction is cell by cell, so the element energies, forces and cell kernels (the hyper-reduction's
sampled cells: :class:`MeanDilatationKernel`) are defined.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .backends.base import CellKernel, check_cells
from .corrected_backend import CorrectedBackend
from .materials import LinearElastic, SaintVenantKirchhoff
from .mesh import HEX_CORNERS
from .quadrature import default_order, volume_rule
from .solver_base import canonical_csr

__all__ = ["MeanDilatationBackend", "MeanDilatationKernel", "mean_dilatation_applies", "MEAN_DILATATION_MATERIALS",
           "hex_gradients"]

#: the laws whose shape and volume parts split as mu |dev e|^2 + kappa/2 (tr e)^2 (names of the scene format)
MEAN_DILATATION_MATERIALS = ("linear", "svk")


def mean_dilatation_applies(problem) -> str:
    """Why the mean-dilatation formulation cannot model ``problem``, or ``""`` when it can."""
    if problem.element != "Q1" or problem.mesh.cell_type != "hexahedron":
        return f"the mean-dilatation formulation is for trilinear hexahedra (Q1), not {problem.element}"
    if type(problem.material) not in (LinearElastic, SaintVenantKirchhoff):
        return (f"material {problem.material.name!r} is not one whose volume part is kappa/2 (tr e)^2 "
                f"(valid: {', '.join(MEAN_DILATATION_MATERIALS)})")
    return ""


def hex_gradients(nodes, cells, order: int | None = None):
    """Shape-function gradients and quadrature weights of trilinear hexahedra.

    Parameters
    ----------
    nodes : (n, 3) array
    cells : (e, 8) int array
        Vertices in VTK order (:mod:`.mesh`).
    order : int, optional
        The quadrature order of :func:`~.quadrature.volume_rule` (default 3: 2x2x2 Gauss).

    Returns
    -------
    grad : (e, q, 8, 3) array
        dN_a / dX_i at each quadrature point.
    dx : (e, q) array
        det(dX/dxi) times the weight: the volume each point carries.
    """
    points, weights = volume_rule("Q1", order or default_order("Q1"))  # on the unit cube
    c = (HEX_CORNERS + 1.0) / 2.0  # VTK corners in {0, 1}^3
    s = 2.0 * c - 1.0
    X = np.asarray(nodes, float)[np.asarray(cells)]
    grads, dx = [], []
    for p, w in zip(np.asarray(points).T, weights):
        f = c * p + (1.0 - c) * (1.0 - p)  # (8, 3): the three 1D factors of each N_a
        dN = np.stack([s[:, 0] * f[:, 1] * f[:, 2], f[:, 0] * s[:, 1] * f[:, 2], f[:, 0] * f[:, 1] * s[:, 2]], axis=1)
        J = np.einsum("eai,ak->eik", X, dN)  # dX_i / dxi_k
        grads.append(np.einsum("ak,eki->eai", dN, np.linalg.inv(J)))
        dx.append(np.linalg.det(J) * w)
    return np.stack(grads, axis=1), np.stack(dx, axis=1)


class MeanDilatationKernel(CellKernel):
    """The element operators of a subset of cells: the Q1 backend's cell kernel plus the correction.

    It has no ``grad`` and ``dx``: a kernel that integrates the material law at the Gauss points
    from them (the Galerkin models' Voigt kernel) would leave the correction out.
    """

    def __init__(self, backend: "MeanDilatationBackend", cells):
        self.base = backend.base.cell_kernel(cells)
        self.cells, self.dofs, self.volumes = cells, self.base.dofs, self.base.volumes
        self._backend = backend

    def energies_and_forces(self, u_loc):
        u_loc = self._check_local(u_loc)
        W, f = self.base.energies_and_forces(u_loc)
        dW, df, _ = self._backend.cell_correction(u_loc, cells=self.cells, local=True)
        return W + dW, f + df

    def forces_and_tangents(self, u_loc):
        u_loc = self._check_local(u_loc)
        f, K = self.base.forces_and_tangents(u_loc)
        _, df, dK = self._backend.cell_correction(u_loc, tangent=True, cells=self.cells, local=True)
        return f + df, K + dK


class MeanDilatationBackend(CorrectedBackend):
    """A Q1 displacement backend with the volumetric energy taken on each cell's mean dilatation.

    Parameters
    ----------
    problem : Problem
        Trilinear hexahedra; the linear material or Saint Venant-Kirchhoff.
    backend : {"skfem", "ngsolve"} or Backend
        The Q1 backend of ``problem`` (reused when given).
    """

    def __init__(self, problem, backend="skfem"):
        super().__init__(problem, backend, mean_dilatation_applies(problem), "mean_dilatation")
        cells = problem.layout[1]
        self.grad, self.dx = hex_gradients(problem.layout[0], cells, problem.quadrature_order)
        self.volumes = self.dx.sum(axis=1)
        lam, mu = problem.material.lame
        self.kappa = lam + 2.0 * mu / 3.0
        self.linear = type(problem.material) is LinearElastic
        self.dofs = (3 * cells[:, :, None] + np.arange(3)).reshape(len(cells), 24)
        self._pattern = None
        # What does not depend on u, laid out once for batched matmul: the correction is evaluated at
        # every Newton iteration, and with einsum over (cells, points, 24 dofs) it cost 0.6 to 1.7 times
        # Q1's own assembly on the cornea (tools/bench_mean_dilatation.py). _gg: 27 MB at paper resolution.
        e, q = self.dx.shape
        self._gq = np.ascontiguousarray(self.grad.transpose(0, 1, 3, 2)).reshape(e, 3 * q, 8)  # [(q, J), a]
        self._gg = np.matmul(self.grad, self.grad.transpose(0, 1, 3, 2)).reshape(e, q, 64)  # grad N_a . grad N_b
        self._eye = np.tile(np.eye(3).ravel(), q)  # F^T = I + H^T in the layout [(q, J, i)]
        self._sqrt_k_dx = np.sqrt(self.kappa * self.dx)[:, :, None]
        self._dx_V = (self.dx / self.volumes[:, None])[:, None, :]
        self._where = None  # (indptr, indices, positions of the cells' 24 x 24 entries in K.data)

    # ------------------------------------------------------------------ the correction, cell by cell
    def cell_correction(self, u, tangent: bool = False, cells=None, local: bool = False):
        """The correction's cell energies (m,), forces (m, 24) and, with ``tangent``, tangents (m, 24, 24)
        of ``cells`` (all when None), from the full ``u`` (ndof,) or, with ``local``, the cells' local
        displacements (m, 24) in the order of :attr:`dofs`.

        With ``theta_q = tr e_q`` and its gradient ``d_q = d theta_q / d u_e`` (24,), the energy is
        ``kappa/2 (V mean^2 - sum_q dV_q theta_q^2)``, the force ``kappa sum_q w_q d_q`` with
        ``w_q = dV_q (mean - theta_q)``, the tangent ``-kappa sum_q dV_q (d_q - d_mean)(d_q - d_mean)^T``
        (the variance form of ``V d_mean d_mean^T - sum_q dV_q d_q d_q^T``: the two sums do not cancel,
        and ``X^T X`` is symmetric) plus, for SVK, ``kappa sum_q w_q d2 theta_q / du2`` =
        ``kappa delta_ik sum_q w_q grad N_a . grad N_b``.
        """
        cells = slice(None) if cells is None else cells
        u_loc = np.asarray(u, float) if local else self._check_u(u)[self.dofs[cells]]
        dx, V, k = self.dx[cells], self.volumes[cells], self.kappa
        m, q = dx.shape
        # H^T[(q, J), i] = sum_a dN_a/dX_J u_ai: the displacement gradient at every point in one product
        Ht = np.matmul(self._gq[cells], u_loc.reshape(m, 8, 3)).reshape(m, 9 * q)
        theta = np.einsum("eqii->eq", Ht.reshape(m, q, 3, 3))
        if self.linear:
            Ft = np.broadcast_to(self._eye, Ht.shape)  # d div u / d grad u = I
        else:
            H3 = Ht.reshape(m, q, 9)
            theta = theta + 0.5 * np.einsum("eqk,eqk->eq", H3, H3)  # tr E = div u + |grad u|^2 / 2
            Ft = Ht + self._eye  # d tr E / d grad u = F
        mean = np.einsum("eq,eq->e", dx, theta) / V
        energy = 0.5 * k * (V * mean**2 - np.einsum("eq,eq->e", dx, theta**2))
        weight = dx * (mean[:, None] - theta)
        # d_q[(a, i)] = sum_J dN_a/dX_J F_iJ at each point, (m, q, 24); the force from it with or without
        # the tangent (a cell kernel's two calls give the same force, to the bit)
        d = np.matmul(self.grad[cells], Ft.reshape(m, q, 3, 3)).reshape(m, q, 24)
        force = k * np.matmul(weight[:, None, :], d).reshape(m, 24)
        if not tangent:
            return energy, force, None
        X = d - np.matmul(self._dx_V[cells], d)
        X *= self._sqrt_k_dx[cells]
        Ke = np.matmul(np.negative(X.transpose(0, 2, 1)), X)  # -X^T made contiguous; symmetric to the bit
        if not self.linear:  # d2 tr E / du_ai du_bk = delta_ik grad N_a . grad N_b
            s = (k * np.matmul(weight[:, None, :], self._gg[cells])).reshape(m, 8, 8)
            K5 = Ke.reshape(m, 8, 3, 8, 3)
            for i in range(3):
                K5[:, :, i, :, i] += s
        return energy, force, Ke

    @property
    def pattern(self):
        if self._pattern is None:
            from .backends.skfem_backend import _Pattern

            self._pattern = _Pattern(self.dofs, self.ndof)
        return self._pattern

    def _positions(self, K):
        """Where each entry of the cells' 24 x 24 blocks sits in ``K.data``, or None when ``K``'s pattern
        lacks some of them; computed once per pattern (the backend's tangents share one)."""
        if self._where is not None and np.array_equal(self._where[0], K.indptr) \
                and np.array_equal(self._where[1], K.indices):
            return self._where[2]
        n = K.shape[0]
        keys = np.repeat(np.arange(n, dtype=np.int64), np.diff(K.indptr)) * n + K.indices  # sorted: canonical K
        wanted = (np.repeat(self.dofs, 24, axis=1).astype(np.int64) * n + np.tile(self.dofs, (1, 24))).ravel()
        pos = np.minimum(np.searchsorted(keys, wanted), max(len(keys) - 1, 0))
        pos = pos if len(keys) and np.array_equal(keys[pos], wanted) else None
        self._where = (K.indptr.copy(), K.indices.copy(), pos)
        return pos

    def _add(self, K, Ke):
        """``K`` plus the assembled cell tangents ``Ke``, on ``K``'s pattern when it holds the cells'
        entries (a sum would drop the entries that come out zero, and the direct solvers keep a
        factorisation per pattern): one ``bincount`` into a copy of ``K.data``, no second sparse matrix."""
        K = canonical_csr(K)
        pos = self._positions(K) if K.shape == (self.ndof, self.ndof) else None
        if pos is not None:
            data = K.data + np.bincount(pos, weights=Ke.ravel(), minlength=len(K.data))
            return sp.csr_matrix((data, K.indices, K.indptr), shape=K.shape)
        return canonical_csr(K + self.pattern.assemble(Ke))

    def _scatter(self, fe):
        return np.bincount(self.dofs.ravel(), weights=fe.ravel(), minlength=self.ndof)

    # ------------------------------------------------------------------ operators
    def internal_force(self, u):
        return self.base.internal_force(u) + self._scatter(self.cell_correction(u)[1])

    def tangent(self, u):
        return self._add(self.base.tangent(u), self.cell_correction(u, tangent=True)[2])

    def internal_force_and_tangent(self, u):
        f, K = self.base.internal_force_and_tangent(u)
        _, fe, Ke = self.cell_correction(u, tangent=True)  # force and tangent from one pass
        return f + self._scatter(fe), self._add(K, Ke)

    def strain_energy(self, u):
        return self.base.strain_energy(u) + float(self.cell_correction(u)[0].sum())

    def element_strain_energies(self, u):
        return self.base.element_strain_energies(u) + self.cell_correction(u)[0]

    def element_internal_forces(self, u):
        return self.base.element_internal_forces(u) + self.cell_correction(u)[1]

    def cell_kernel(self, cells=None):
        return MeanDilatationKernel(self, check_cells(cells, self.problem.mesh.n_cells))
