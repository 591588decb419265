"""The affine skinning subspace ``u = U q`` (wsc paper eqs. 7, 10-13) and its Dirichlet part.

Each handle j carries an affine map ``A_j`` (3 x 4, 12 reduced dofs); node i moves by
``u_i = sum_j w_ij A_j [1, X_i]`` (displacement form: ``A_j = 0`` is the rest state, the
partition of unity makes the paper's positions ``x = X + u``). With
``phi[i, 4 j + b] = w_ij [1, X_i][b]`` the subspace matrix is ``U = phi (x) I3`` and the
reduced vector is ``q = Q.ravel()``, ``Q = (A_0^T; ...; A_{k-1}^T)`` of shape (4 k, 3)
(q index ``12 j + 3 b + c``).

Dirichlet conditions (how we impose them, and how the paper does): the paper overwrites
the prescribed vertices with their values at the end of every step (outside the
subspace dynamics). We impose them *in* the subspace: every Dirichlet set has a
boundary handle with weight 1 on its nodes (:mod:`.weights`), so the constraint
``U_c q = g(t)`` only involves the boundary handles' 12 dofs. For an affine prescribed
motion (clamp, translation, rotation of an end face) it is met exactly by
``q_b = P g + N y``: ``P = pinv(U_c)``, ``N`` a basis of the null space of ``U_c`` (for a
planar face the 3 dofs of ``A e_normal`` stay free). The free coordinates are
``z = (q of the free handles, y)``; ``q = T z + q_p(t)``. A prescribed motion the
boundary handle cannot reproduce (not affine on its set) is refused at build time.

Redundancy: the 12 k columns of ``U T`` are independent only if every handle's support
holds enough affinely independent nodes (``4 k`` columns of ``phi`` against n nodes;
with a handle on every vertex each handle contributes one direction, not four). A
redundant direction moves no node: forces and the mass have no component along it, so
it is harmless in the dynamics; the solves with the reduced mass and the step matrix are
regularised (:data:`REGULARISATION` times their largest diagonal entry) instead of
restricting the coordinates (which would make ``T`` dense). The converged states are
defined by the residual, which the regularisation does not touch.
"""
from __future__ import annotations

from functools import cached_property

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

__all__ = ["Subspace", "MassProjector", "REGULARISATION", "regularised"]

#: relative shift of the reduced mass and step matrices (see the module docstring)
REGULARISATION = 1e-10


def regularised(A):
    """``A + REGULARISATION * max(diag A) * I`` (dense or sparse, symmetric positive semidefinite A)."""
    shift = REGULARISATION * float(np.max(A.diagonal()))
    if sp.issparse(A):
        return sp.csr_matrix(A + shift * sp.identity(A.shape[0]))
    return A + shift * np.eye(len(A))


class Subspace:
    """Skinning subspace of a problem.

    Parameters
    ----------
    nodes : (n, 3) array
        Reference coordinates of all discretisation nodes.
    weights : (n, k + n_groups) sparse
        Normalised skinning weights; the last ``n_groups`` columns are boundary handles.
    n_groups : int
        Number of boundary handles (Dirichlet sets).
    fixed_dofs : (n_fixed,) int array
        Constrained dofs (the problem's order).
    """

    def __init__(self, nodes, weights, n_groups: int, fixed_dofs):
        self.nodes = np.asarray(nodes, dtype=float)
        self.weights = sp.csr_matrix(weights)
        self.n_handles = self.weights.shape[1]
        self.n_groups = int(n_groups)
        self.n_free_handles = self.n_handles - self.n_groups
        self.fixed_dofs = np.asarray(fixed_dofs, dtype=np.int64)
        Xt = np.column_stack([np.ones(len(self.nodes)), self.nodes])  # [1, X]
        W = self.weights.tocoo()
        rows = np.repeat(W.row, 4)
        cols = (4 * W.col[:, None] + np.arange(4)).ravel()
        vals = (W.data[:, None] * Xt[W.row]).ravel()
        self.phi = sp.csr_matrix((vals, (rows, cols)), shape=(len(self.nodes), 4 * self.n_handles))
        self._constraints()

    # ------------------------------------------------------------------ sizes
    @property
    def ndof(self) -> int:
        return 3 * len(self.nodes)

    @property
    def n_q(self) -> int:
        """Reduced dofs of all handles (12 per handle)."""
        return 12 * self.n_handles

    @property
    def n_z(self) -> int:
        """Free reduced coordinates: the free handles' dofs and the free part of the boundary handles."""
        return 12 * self.n_free_handles + self.N.shape[1]

    @cached_property
    def U(self) -> sp.csr_matrix:
        """``U = phi (x) I3``, shape (ndof, n_q)."""
        return sp.csr_matrix(sp.kron(self.phi, sp.identity(3), format="csr"))

    def displacement(self, q) -> np.ndarray:
        """Full displacement ``U q`` (ndof,), prescribed values included."""
        return (self.phi @ np.asarray(q, dtype=float).reshape(-1, 3)).ravel()

    # ------------------------------------------------------------------ Dirichlet
    def _constraints(self):
        nb = 12 * self.n_groups
        self.bnd = np.arange(12 * self.n_free_handles, self.n_q)
        if not len(self.fixed_dofs):
            self.P, self.N = np.zeros((nb, 0)), np.eye(nb)
            return
        Uc = self.U[self.fixed_dofs]
        if Uc[:, :12 * self.n_free_handles].count_nonzero():
            raise ValueError("subspace: a free handle moves a constrained dof (boundary weights must be exact)")
        Uc = Uc[:, self.bnd].toarray()
        Us, s, Vt = sla.svd(Uc, full_matrices=True)
        rank = int(np.sum(s > 1e-10 * s.max())) if s.size else 0
        self.P = Vt[:rank].T @ (Us[:, :rank].T / s[:rank, None])  # pinv(U_c), (nb, n_fixed)
        self.N = Vt[rank:].T  # null space of U_c, (nb, nb - rank)
        self._Uc = Uc

    def prescribed_q(self, values) -> np.ndarray:
        """Boundary-handle dofs ``P g`` (12 n_groups,) of the fixed-dof values ``g``."""
        return self.P @ np.asarray(values, dtype=float)

    def constraint_residual(self, values) -> float:
        """``|U_c P g - g| / |g|``: 0 when the boundary handles reproduce ``g`` exactly."""
        g = np.asarray(values, dtype=float)
        if not len(g):
            return 0.0
        den = max(np.linalg.norm(g), 1e-300)
        return float(np.linalg.norm(self._Uc @ (self.P @ g) - g) / den) if np.any(g) else 0.0

    @cached_property
    def T(self) -> sp.csr_matrix:
        """``q = T z + lift(q_p)``: identity on the free handles, N on the boundary handles, (n_q, n_z)."""
        nf = 12 * self.n_free_handles
        return sp.csr_matrix(sp.block_diag([sp.identity(nf), sp.csr_matrix(self.N)], format="csr"))

    def reduced_matrix(self, A) -> sp.csr_matrix:
        """``U^T A U`` of a full (ndof, ndof) matrix; ``A = A_s (x) I3`` (the consistent mass)
        is reduced through its scalar block, nine times cheaper."""
        A = sp.csr_matrix(A)
        As = A[0::3][:, 0::3]
        if (abs(A[0::3][:, 1::3]).max() == 0 and abs(A[1::3][:, 1::3] - As).max() == 0
                and abs(A[2::3][:, 2::3] - As).max() == 0 and abs(A[0::3][:, 2::3]).max() == 0
                and abs(A[1::3][:, 2::3]).max() == 0):
            return sp.csr_matrix(sp.kron(self.phi.T @ As @ self.phi, sp.identity(3)))
        return sp.csr_matrix(self.U.T @ (A @ self.U))

    def q_of(self, z, qb_p) -> np.ndarray:
        """Full reduced vector (n_q,) of free coordinates ``z`` and prescribed ``qb_p``."""
        nf = 12 * self.n_free_handles
        q = np.empty(self.n_q)
        q[:nf] = z[:nf]
        q[nf:] = self.N @ z[nf:] + qb_p
        return q

    def z_of(self, f_q) -> np.ndarray:
        """``T^T f`` of a reduced (dual) vector f (n_q,): its free components (n_z,)."""
        nf = 12 * self.n_free_handles
        return np.concatenate([f_q[:nf], self.N.T @ f_q[nf:]])


class MassProjector:
    """Mass-orthogonal projection of full fields on the subspace, boundary part kept exact.

    ``project(u)`` returns ``(z, q_b)``: ``q_b = P u_c`` from the fixed dofs, then
    ``z = argmin |U (T z + q_b) - u|_M``, i.e. ``M_z z = T^T U^T M (u - U q_b)``.
    """

    def __init__(self, subspace: Subspace, mass):
        self.sub = subspace
        self.M = sp.csr_matrix(mass)
        M_q = subspace.reduced_matrix(self.M)
        self.M_z = (subspace.T.T @ M_q @ subspace.T).toarray()
        self._cho = sla.cho_factor(regularised(self.M_z))

    def project(self, u) -> tuple[np.ndarray, np.ndarray]:
        sub = self.sub
        u = np.asarray(u, dtype=float)
        qb = sub.prescribed_q(u[sub.fixed_dofs]) if len(sub.fixed_dofs) else np.zeros(12 * sub.n_groups)
        r = u - sub.displacement(sub.q_of(np.zeros(sub.n_z), qb))
        return sla.cho_solve(self._cho, sub.z_of(sub.U.T @ (self.M @ r))), qb
