"""Element energies, forces and tangents of a set of cells, fast enough for a haptic step.

The reduced force of a hyper-reduced Galerkin model sums a few hundred element force vectors
and tangents per Newton iteration. The backends' cell kernels
(:meth:`~tissuebench.refsolvers.backends.base.Backend.cell_kernel`) build the tangent from the
81-component ``dP/dF`` (about 4 ms for 200 P1 cells of a neo-Hookean liver; NGSolve's symbolic
kernel about 0.9 s per call); this kernel writes the total-Lagrangian form in Voigt notation
instead, ``K_e = sum_q dx (B^T D B + G S G^T (x) I)`` with ``D`` the 6 x 6 material tangent
``dS/dE`` and ``B`` the 6 x n_loc strain-displacement matrix, which costs a few batched
matrix products (about 0.2 ms for the same cells). The same quadrature, shape-function
gradients and material, so it agrees with the backends to round-off (checked in the tests).

``D`` comes from the invariant derivatives of the material for the invariant-based laws
(neo-Hookean, decoupled neo-Hookean, Mooney-Rivlin: :class:`~tissuebench.refsolvers.materials.
_InvariantMaterial`, the formula of its ``pk2``), from the constant Lame tensor for
Saint Venant-Kirchhoff, and from the material's own ``pk2`` otherwise (Guccione's fibres),
gathered into Voigt form.
"""
from __future__ import annotations

import numpy as np

from ...refsolvers import make_backend
from ...refsolvers.backends.base import material_on_cells
from ...refsolvers.materials import SaintVenantKirchhoff, _InvariantMaterial

__all__ = ["ElementKernel", "cell_geometry"]

# Voigt order of a symmetric 3 x 3 tensor: 00, 11, 22, 12, 02, 01 (strains with 2 E_IJ off the diagonal)
_VI = np.array([0, 1, 2, 1, 0, 0])
_VJ = np.array([0, 1, 2, 2, 2, 1])
_HALF = np.array([0.5, 0.5, 0.5, 1.0, 1.0, 1.0])
_I3 = np.eye(3)
_IV = np.array([1.0, 1.0, 1.0, 0.0, 0.0, 0.0])
_ISYM = np.diag([1.0, 1.0, 1.0, 0.5, 0.5, 0.5])  # Isym(I) in Voigt form
_II_MINUS_ISYM = np.outer(_IV, _IV) - _ISYM


def cell_geometry(backend, cells) -> tuple[np.ndarray, np.ndarray]:
    """``(grad (m, q, a, 3), dx (m, q))``: reference shape-function gradients and quadrature
    weights of ``cells``, from the backend's cell kernel, or from a scikit-fem backend on the
    same problem when the backend's kernel does not expose them (NGSolve: the two backends
    integrate with the same rules, :mod:`~tissuebench.refsolvers.quadrature`). Refused for the
    mean-dilatation hexahedra (issue 54): the Voigt kernel would integrate their volumetric part at
    the Gauss points, where it locks, and leave their per-cell correction out."""
    if getattr(backend, "formulation", "") == "mean_dilatation":
        raise NotImplementedError("the Galerkin models' Voigt kernel integrates the material law at the Gauss points; "
                                  "the mean-dilatation hexahedra take its volumetric part on each cell's mean "
                                  "dilatation, which it does not (their element operators: element_kernel)")
    k = backend.cell_kernel(np.asarray(cells, dtype=np.int64))
    if not (hasattr(k, "grad") and hasattr(k, "dx")):
        k = make_backend("skfem", backend.problem).cell_kernel(np.asarray(cells, dtype=np.int64))
    return np.asarray(k.grad, float), np.asarray(k.dx, float)


# the Voigt entry of each (I, J) of a symmetric tensor, and the gathers of Isym(A) (module docstring)
_VOIGT = np.array([[0, 5, 4], [5, 1, 3], [4, 3, 2]])
_SYM_A = (_VOIGT[_VI[:, None], _VI[None, :]], _VOIGT[_VJ[:, None], _VJ[None, :]])
_SYM_B = (_VOIGT[_VI[:, None], _VJ[None, :]], _VOIGT[_VJ[:, None], _VI[None, :]])


def _sym_outer(av):
    """``Isym(A)`` in Voigt form (n, 6, 6), ``(A_IK A_JL + A_IL A_JK) / 2``, of a symmetric
    tensor given by its Voigt entries ``av`` (n, 6)."""
    return 0.5 * (av[:, _SYM_A[0]] * av[:, _SYM_A[1]] + av[:, _SYM_B[0]] * av[:, _SYM_B[1]])


def _det(F):
    """det of (n, 3, 3) arrays by the explicit formula (LAPACK's batched det costs more at these sizes)."""
    return (F[:, 0, 0] * (F[:, 1, 1] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 1])
            - F[:, 0, 1] * (F[:, 1, 0] * F[:, 2, 2] - F[:, 1, 2] * F[:, 2, 0])
            + F[:, 0, 2] * (F[:, 1, 0] * F[:, 2, 1] - F[:, 1, 1] * F[:, 2, 0]))


# cof(F)_ij = F_(i+1)(j+1) F_(i+2)(j+2) - F_(i+1)(j+2) F_(i+2)(j+1), indices mod 3
_N1, _N2 = np.array([1, 2, 0]), np.array([2, 0, 1])


def _cofactor(F):
    """``cof F = det(F) F^-T`` of (n, 3, 3) arrays."""
    return (F[:, _N1[:, None], _N1[None, :]] * F[:, _N2[:, None], _N2[None, :]]
            - F[:, _N1[:, None], _N2[None, :]] * F[:, _N2[:, None], _N1[None, :]])


def _inv_sym_voigt(cv, det):
    """Voigt entries (n, 6) of the inverse of a symmetric tensor with Voigt entries ``cv`` (cofactors)."""
    a, b, c, e, f, d = cv.T  # 00, 11, 22, 12, 02, 01
    out = np.empty_like(cv)
    out[:, 0], out[:, 1], out[:, 2] = b * c - e * e, a * c - f * f, a * b - d * d
    out[:, 3], out[:, 4], out[:, 5] = d * f - a * e, d * e - b * f, f * e - d * c
    out /= det[:, None]
    return out


def _outer(a, b):
    return a[:, :, None] * b[:, None, :]


class ElementKernel:
    """Element quantities of ``cells`` from their local displacements (module docstring).

    Parameters
    ----------
    grad : (m, q, a, 3) array
        Reference shape-function gradients of the cells' local nodes at their quadrature points.
    dx : (m, q) array
        Quadrature weights times the reference Jacobian [volume].
    material : Material
        The problem's material (per-cell data already restricted to these cells, or ``cells``
        given to restrict it).
    cells : (m,) int array, optional
        Mesh cells, to restrict per-cell material data (Guccione fibres).

    Local dofs are node-major (``3 a + i``), as the backends' (``Backend.element_dofs``).
    """

    def __init__(self, grad, dx, material, cells=None):
        self.grad, self.dx = np.asarray(grad, float), np.asarray(dx, float)
        self.m, self.q, self.a = self.grad.shape[:3]
        self.material = material if cells is None else material_on_cells(material, np.asarray(cells))
        mat = type(material)
        self._invariant = (issubclass(mat, _InvariantMaterial) and mat.pk2 is _InvariantMaterial.pk2
                           and mat.energy is _InvariantMaterial.energy)
        self._svk = mat is SaintVenantKirchhoff
        self._gT = np.ascontiguousarray(self.grad.reshape(-1, self.a, 3).transpose(0, 2, 1))  # (mq, 3, a)
        self._g = np.ascontiguousarray(self.grad.reshape(-1, self.a, 3))  # (mq, a, 3)
        self._w = self.dx.reshape(-1)

    # ------------------------------------------------------------------ kinematics
    def _F(self, u_loc):
        """Deformation gradients (mq, 3, 3) of local displacements (m, 3 a)."""
        U = np.asarray(u_loc, float).reshape(self.m, 1, self.a, 3).transpose(0, 1, 3, 2)  # (m, 1, 3, a)
        H = np.matmul(U, self.grad)  # (m, q, 3, 3): H_iJ = sum_a u_ai g_aJ
        return (H + _I3).reshape(-1, 3, 3)

    def _stress(self, F, tangent):
        """(W (mq,), S (mq, 3, 3), D (mq, 6, 6) or None)."""
        if self._invariant:
            return self._invariant_stress(F, tangent)
        W = self.material.energy(F.reshape(self.m, self.q, 3, 3)).reshape(-1)
        S, CC = self.material.pk2(F.reshape(self.m, self.q, 3, 3), tangent=tangent)
        S = S.reshape(-1, 3, 3)
        if not tangent:
            return W, S, None
        if self._svk:
            lam, mu = self.material.lame
            D = lam * _outer(_IV[None], _IV[None])[0] + 2 * mu * _ISYM
            return W, S, np.broadcast_to(D, (len(F), 6, 6))
        CC = CC.reshape(-1, 3, 3, 3, 3)
        return W, S, CC[:, _VI[:, None], _VJ[:, None], _VI[None, :], _VJ[None, :]]

    def _invariant_stress(self, F, tangent):
        """The invariant form of :meth:`_InvariantMaterial.pk2`, with ``D`` in Voigt form."""
        C = np.matmul(F.transpose(0, 2, 1), F)
        cv = C[:, _VI, _VJ]
        I1 = cv[:, 0] + cv[:, 1] + cv[:, 2]
        I2 = 0.5 * (I1 ** 2 - np.einsum("nij,nij->n", C, C))
        J = _det(F)
        with np.errstate(invalid="ignore", divide="ignore"):
            civ = _inv_sym_voigt(cv, J * J)
            W, W1, W2, WJ, W1J, W2J, WJJ = self.material._derivs(I1, I2, J)
            bv = I1[:, None] * _IV - cv  # B = I1 I - C
            sv = 2 * W1[:, None] * _IV + 2 * W2[:, None] * bv + (WJ * J)[:, None] * civ
            S = sv[:, _VOIGT]
            if not tangent:
                return W, S, None
            # the terms of the invariant law's dS/dE whose coefficient is zero everywhere (neo-Hookean:
            # W2 = W1J = W2J = 0) are left out: a third of the tangent's cost on a few hundred points
            c = (J ** 2 * WJJ + J * WJ)[:, None, None]
            D = c * _outer(civ, civ) - (2 * J * WJ)[:, None, None] * _sym_outer(civ)
            if np.any(W2):
                D += 4 * W2[:, None, None] * _II_MINUS_ISYM
            if np.any(W1J):
                D += (2 * J * W1J)[:, None, None] * (_IV[None, :, None] * civ[:, None, :] + civ[:, :, None] * _IV)
            if np.any(W2J):
                D += (2 * J * W2J)[:, None, None] * (_outer(bv, civ) + _outer(civ, bv))
        return W, S, D

    def _invariant_pk1(self, F):
        """(W (mq,), P (mq, 3, 3)) of an invariant law without C^-1: ``P = F S = 2 (W1 + W2 I1) F
        - 2 W2 F C + W_J cof F`` (the force path of a step; the tangent needs S)."""
        C = np.matmul(F.transpose(0, 2, 1), F)
        I1 = C[:, 0, 0] + C[:, 1, 1] + C[:, 2, 2]
        I2 = 0.5 * (I1 ** 2 - np.einsum("nij,nij->n", C, C))
        cof = _cofactor(F)
        J = np.einsum("nj,nj->n", F[:, 0], cof[:, 0])
        with np.errstate(invalid="ignore", divide="ignore"):
            W, W1, W2, WJ = self.material._derivs(I1, I2, J)[:4]
            P = (2 * W1)[:, None, None] * F + WJ[:, None, None] * cof
            if np.any(W2):
                P += (2 * W2 * I1)[:, None, None] * F - (2 * W2)[:, None, None] * np.matmul(F, C)
        return W, P

    def _forces(self, F, S=None, P=None):
        """Element force vectors (m, 3 a) from the first Piola-Kirchhoff stress ``P = F S`` at the
        quadrature points: ``f_ai = sum_q dx P_iJ g_aJ``."""
        P = (np.matmul(F, S) if P is None else P) * self._w[:, None, None]  # (mq, 3, 3)
        fe = np.matmul(P, self._gT)  # (mq, 3, a)
        if self.q > 1:
            fe = fe.reshape(self.m, self.q, 3, self.a).sum(axis=1)
        return fe.transpose(0, 2, 1).reshape(self.m, -1)

    # ------------------------------------------------------------------ public
    def energies_and_forces(self, u_loc):
        """Strain energies (m,) [energy] and internal force vectors (m, 3 a) [force]."""
        F = self._F(u_loc)
        if self._invariant:
            W, P = self._invariant_pk1(F)
            fe = self._forces(F, P=P)
        else:
            W, S, _ = self._stress(F, False)
            fe = self._forces(F, S)
        W = W * self._w
        return (W if self.q == 1 else W.reshape(self.m, self.q).sum(axis=1)), fe

    def forces_and_tangents(self, u_loc):
        """Internal force vectors (m, 3 a) and tangents (m, 3 a, 3 a) [force / length]."""
        F = self._F(u_loc)
        _, S, D = self._stress(F, True)
        n = 3 * self.a
        # B^T (mq, 3a, 6): B[p, (a, i)] = c_p (F_i,Ip g_a,Jp + F_i,Jp g_a,Ip), c_p = 1/2 on the diagonal
        FI, FJ = F[:, None, :, _VI], F[:, None, :, _VJ]  # (mq, 1, i, 6)
        gI, gJ = self._g[:, :, None, _VI], self._g[:, :, None, _VJ]  # (mq, a, 1, 6)
        BT = ((FI * gJ + FJ * gI) * _HALF).reshape(-1, n, 6)
        K = np.matmul(BT * self._w[:, None, None], np.matmul(D, BT.transpose(0, 2, 1)))  # (mq, 3a, 3a)
        H = np.matmul(np.matmul(self._g, S), self._gT) * self._w[:, None, None]  # (mq, a, a)
        K = K.reshape(self.m, self.q, self.a, 3, self.a, 3).sum(axis=1)
        H = H.reshape(self.m, self.q, self.a, self.a).sum(axis=1)
        for i in range(3):  # the geometric stiffness acts on each component alike
            K[:, :, i, :, i] += H
        return self._forces(F, S), K.reshape(self.m, n, n)
