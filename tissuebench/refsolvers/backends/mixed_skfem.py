"""Taylor-Hood forms of the mixed u-p formulation with scikit-fem bases and NumPy kernels.

Same Lagrangian as :mod:`.mixed_ngsolve`, L = W(F) - U(J) + p (J - 1) - p^2 / (2 kappa)
(with (1 - w) U, w = ``penalty_weight``), differentiated by hand (with cof F = J F^-T):

* f_u = int (P - U' cof F + p cof F) : grad N_a,   g = int M_b (J - 1 - p / kappa)
* A = dP/dF - U'' J^2 F^-T (x) F^-T + (p - U') J (F^-T_iJ F^-T_kL - F^-T_iL F^-T_kJ)
* K_up = int (cof F : grad N_a) M_b = K_pu^T,   K_pp = -int M_a M_b / kappa

P and dP/dF are the material's analytical kernels and U its :meth:`Material.volumetric`,
so this is independent of the symbolic NGSolve forms. Unknowns are ordered
``z = [u (3 n_nodes), p (n_vertices)]`` in tissuebench numbering.
"""
from __future__ import annotations

import numpy as np
import skfem

from ..quadrature import volume_rule
from .skfem_backend import _Pattern


class SkfemMixedForms:
    """f = [f_u; g] and its Jacobian for a :class:`SkfemBackend` ``be`` (P2 only).

    Parameters
    ----------
    be : SkfemBackend
    bulk_modulus : float or None
        None: incompressible; a number: perturbed Lagrangian with that modulus.
    penalty_weight : float
        Fraction w of U kept in the density (see :class:`~tissuebench.refsolvers.mixed.MixedBackend`).
    """

    def __init__(self, be, bulk_modulus=None, penalty_weight=0.0):
        self.be, self.k = be, be._k
        self.drop_u = 1.0 - float(penalty_weight)
        self.inv_kappa = 0.0 if bulk_modulus is None else 1.0 / float(bulk_modulus)
        mesh = be.problem.mesh
        basis = skfem.Basis(be._skmesh, skfem.ElementTetP1(), quadrature=volume_rule("P2", be._order))
        vertex_of_dof = np.empty(basis.N, dtype=np.int64)
        vertex_of_dof[basis.nodal_dofs[0]] = np.arange(mesh.n_vertices)
        self.pnodes = vertex_of_dof[basis.element_dofs].T  # (n_cells, 4) vertex ids
        self.M = np.ascontiguousarray(np.stack([np.asarray(basis.basis[a][0]) for a in range(4)]).transpose(1, 2, 0))
        self.n_u, self.n_p = be.ndof, mesh.n_vertices
        self.dofs = np.hstack([self.k.dofs, self.n_u + self.pnodes])
        self._pattern = None

    @property
    def pattern(self):
        if self._pattern is None:
            self._pattern = _Pattern(self.dofs, self.n_u + self.n_p)
        return self._pattern

    def _state(self, z):
        u, p = z[:self.n_u], z[self.n_u:]
        F = self.k.deformation_gradient(u)
        J = np.linalg.det(F)
        FiT = np.swapaxes(np.linalg.inv(F), -1, -2)
        ph = np.einsum("eqa,ea->eq", self.M, p[self.pnodes])
        return F, J, FiT, ph

    def _vectors(self, P, J, ph):
        """Element vectors (n_cells, 3 n_loc + 4) of f_u and g."""
        fu = np.einsum("eq,eqiJ,eqaJ->eai", self.k.dx, P, self.k.grad, optimize=True).reshape(len(P), -1)
        g = np.einsum("eq,eqa->ea", self.k.dx * (J - 1 - ph * self.inv_kappa), self.M)
        return np.hstack([fu, g])

    def _scatter(self, fe):
        return np.bincount(self.dofs.ravel(), weights=fe.ravel(), minlength=self.n_u + self.n_p)

    def force(self, z):
        """[f_u; g], shape (n_u + n_p,)."""
        F, J, FiT, ph = self._state(np.asarray(z, float))
        _, dU, _ = self.be.problem.material.volumetric(J)
        P = self.be.problem.material.stress(F) + ((ph - self.drop_u * dU) * J)[..., None, None] * FiT
        return self._scatter(self._vectors(P, J, ph))

    def force_and_tangent(self, z):
        """Force and its Jacobian (symmetric, indefinite), CSR (n_u + n_p)^2."""
        F, J, FiT, ph = self._state(np.asarray(z, float))
        mat = self.be.problem.material
        P, A = mat.stress_and_tangent(F)
        _, dU, d2U = (self.drop_u * v for v in mat.volumetric(J))
        s = ((ph - dU) * J)[..., None, None]
        cof = J[..., None, None] * FiT
        P = P + s * FiT
        FF = np.einsum("...iJ,...kL->...iJkL", FiT, FiT)
        FFx = np.einsum("...iL,...kJ->...iJkL", FiT, FiT)
        A = A - (d2U * J**2)[..., None, None, None, None] * FF + s[..., None, None] * (FF - FFx)
        G = self.k.grad * self.k.dx[:, :, None, None]
        n_c, n_loc = len(F), G.shape[2]
        Kuu = np.einsum("eqaJ,eqiJkL,eqbL->eaibk", G, A, self.k.grad, optimize=True).reshape(n_c, 3 * n_loc, -1)
        Kup = np.einsum("eqaJ,eqiJ,eqb->eaib", G, cof, self.M, optimize=True).reshape(n_c, 3 * n_loc, 4)
        Kpp = -self.inv_kappa * np.einsum("eq,eqa,eqb->eab", self.k.dx, self.M, self.M)
        Ke = np.block([[Kuu, Kup], [np.swapaxes(Kup, 1, 2), Kpp]])
        return self._scatter(self._vectors(P, J, ph)), self.pattern.assemble(Ke)

    def tangent(self, z):
        """The Jacobian alone (assembled with the force: they share every kernel here)."""
        return self.force_and_tangent(z)[1]

    def lagrangian(self, z):
        """Integral of L over the reference volume."""
        F, J, _, ph = self._state(np.asarray(z, float))
        mat = self.be.problem.material
        dens = mat.energy(F) - self.drop_u * mat.volumetric(J)[0] + ph * (J - 1) - 0.5 * self.inv_kappa * ph**2
        return float(np.sum(self.k.dx * dens))
